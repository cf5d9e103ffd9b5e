"""Sweep figures and the savings table (one module of the evaluate stage; :mod:`seekopt.app.report`
re-exports them).

All figures are written with the non-interactive Agg backend, with units on every axis.  Input is
the tidy sweep table (``results.csv`` of :mod:`seekopt.evaluate.sweep`): one row per (TPI, seek
length, profile kind).  *Seek-settle time* is the time from the start of the seek until the position
error stays within the settle band (:func:`seek_settle_s`).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["seek_settle_s", "plot_sweep", "plot_seek_settle_vs_length", "plot_gain_over_baselines",
           "plot_heatmap", "plot_vs_tpi", "savings_table", "KIND_LABELS", "save_figure"]

KIND_LABELS = {"optimal": "optimal", "sine": "sine", "windowed_sine": "windowed sine",
               "sine_tuned": "sine (best T)", "windowed_sine_tuned": "windowed sine (best T)",
               "bang_bang": "bang-bang"}
_KIND_STYLE = {"optimal": ("C3", "-", "o"), "sine": ("C0", "--", "s"), "windowed_sine": ("C2", ":", "^"),
               "sine_tuned": ("C1", "-.", "D"), "windowed_sine_tuned": ("C4", (0, (5, 1, 1, 1)), "v")}
_BASELINES = ("sine", "windowed_sine", "sine_tuned", "windowed_sine_tuned")


def _plt():
    import matplotlib
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    return plt


def seek_settle_s(df):
    """Seek-settle time [s] per row: ``settle_time_s`` (from seek start), NaN where the
    row failed or never settled within the evaluation horizon."""
    t = df["settle_time_s"].astype(float).copy()
    ok = (df["status"] == "ok") & df["settled"].astype(str).str.lower().isin(["true", "1", "1.0"])
    t[~ok] = np.nan
    return t


def _with_t(df):
    df = df.copy()
    df["seek_settle_s"] = seek_settle_s(df)
    return df


def _tpi_label(tpi: float) -> str:
    return f"{tpi / 1e3:.0f}k TPI" if tpi >= 1e3 else f"{tpi:g} TPI"


def _tpi_colors(tpis):
    plt = _plt()
    cmap = plt.get_cmap("viridis")
    n = max(len(tpis) - 1, 1)
    return {t: cmap(0.9 * i / n) for i, t in enumerate(sorted(tpis))}


def plot_seek_settle_vs_length(df, path) -> Path:
    """Seek-settle time vs seek length, one panel per profile kind, one line per TPI."""
    plt = _plt()
    df = _with_t(df)
    kinds = [k for k in _KIND_STYLE if k in set(df["kind"])]
    tpis = sorted(set(df["tpi"]))
    col = _tpi_colors(tpis)
    ncol = min(3, len(kinds))
    nrow = math.ceil(len(kinds) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.6 * nrow + 0.4), sharey=True, squeeze=False)
    for ax in list(axes.flat)[len(kinds):]:
        ax.set_visible(False)
    for ax, kind in zip(axes.flat, kinds):
        for tpi in tpis:
            d = df[(df["kind"] == kind) & (df["tpi"] == tpi)].sort_values("tracks")
            ax.plot(d["tracks"], 1e3 * d["seek_settle_s"], "-o", ms=3, color=col[tpi], label=_tpi_label(tpi))
            ax.plot(d["tracks"], 1e3 * d["t_bb_s"].astype(float), ":", lw=0.8, color=col[tpi])
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlim(df["tracks"].min() / 1.5, df["tracks"].max() * 1.5)
        ax.set_title(KIND_LABELS.get(kind, kind))
        ax.set_xlabel("seek length [track]")
        ax.grid(True, which="both", alpha=0.3)
    for row in axes:
        row[0].set_ylabel("seek-settle time [ms]")
    axes[0][0].legend(fontsize=7, title="track density", title_fontsize=7, loc="upper left")
    fig.suptitle("Seek-settle time vs seek length (dotted: rigid-body bang-bang bound $T_{bb}$; "
                 "missing point: not settled or failed)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def savings_table(df):
    """Per (tpi, tracks): seek-settle times of each kind and the optimal's saving [%] over each
    baseline kind and over the best baseline of that cell that settled (``saving_vs_best_pct``)."""
    import pandas as pd
    df = _with_t(df)
    wide = df.pivot_table(index=["tpi", "tracks"], columns="kind", values="seek_settle_s", aggfunc="first", dropna=False)
    out = pd.DataFrame(index=wide.index)
    for k in wide.columns:
        out[f"{k}_ms"] = 1e3 * wide[k]
    if "optimal" in wide.columns:
        for k in _BASELINES:
            if k in wide.columns:
                out[f"saving_vs_{k}_pct"] = 100.0 * (1.0 - wide["optimal"] / wide[k])
        base = [k for k in _BASELINES if k in wide.columns]
        if base:
            out["saving_vs_best_pct"] = 100.0 * (1.0 - wide["optimal"] / wide[base].min(axis=1, skipna=True))
    return out.reset_index()


def plot_gain_over_baselines(df, path) -> Path:
    """The optimal profile's saving in seek-settle time over each baseline [%] vs seek length."""
    plt = _plt()
    s = savings_table(df)
    tpis = sorted(set(s["tpi"]))
    col = _tpi_colors(tpis)
    bases = [k for k in _BASELINES if f"saving_vs_{k}_pct" in s]
    ncol = 2 if len(bases) == 4 else max(min(len(bases), 3), 1)
    nrow = max(math.ceil(len(bases) / ncol), 1)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol + 0.4, 3.6 * nrow), sharey=True, squeeze=False)
    for ax, k in zip(axes.flat, bases):
        for tpi in tpis:
            d = s[s["tpi"] == tpi].sort_values("tracks")
            ax.plot(d["tracks"], d[f"saving_vs_{k}_pct"], "-o", ms=3, color=col[tpi], label=_tpi_label(tpi))
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlim(s["tracks"].min() / 1.5, s["tracks"].max() * 1.5)
        if not np.isfinite(s[f"saving_vs_{k}_pct"].to_numpy(dtype=float)).any():
            ax.text(0.5, 0.5, f"no length where both optimal and\n{KIND_LABELS[k]} settled",
                    transform=ax.transAxes, ha="center", va="center", color="0.4")
        ax.set_title(f"optimal vs {KIND_LABELS[k]}")
        ax.set_xlabel("seek length [track]")
        ax.grid(True, which="both", alpha=0.3)
    for row in axes:
        row[0].set_ylabel("time saved by optimal [%]")
    axes[0][-1].legend(fontsize=7, title="track density", title_fontsize=7)
    fig.suptitle("Seek-settle time saved by the optimal profile (> 0: optimal faster)", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def plot_heatmap(df, path, column: str = "saving_vs_best_pct") -> Path:
    """Heatmap over (TPI, seek length) of the optimal's saving over the best baseline [%]."""
    plt = _plt()
    s = savings_table(df)
    if column not in s:
        column = "optimal_ms" if "optimal_ms" in s else [c for c in s.columns if c.endswith("_ms")][0]
    grid = s.pivot(index="tpi", columns="tracks", values=column).sort_index()
    vals = grid.to_numpy(dtype=float)
    fig, ax = plt.subplots(figsize=(2.5 + 0.75 * max(grid.shape[1], 5), 1.8 + 0.45 * grid.shape[0]))
    finite = vals[np.isfinite(vals)]
    lim = max(float(np.max(np.abs(finite))) if finite.size else 1.0, 1e-9)
    pct = column.endswith("_pct")
    im = ax.imshow(np.ma.masked_invalid(vals), aspect="auto", origin="lower",
                   cmap="RdBu" if pct else "viridis", vmin=-lim if pct else None, vmax=lim if pct else None)
    im.set_cmap(im.cmap.with_extremes(bad="0.85"))
    for (i, j), v in np.ndenumerate(vals):
        dark = math.isfinite(v) and pct and abs(v) > 0.6 * lim
        ax.text(j, i, "×" if not math.isfinite(v) else f"{v:.0f}" if pct else f"{v:.2g}",
                ha="center", va="center", fontsize=7, color="white" if dark else "black")
    ax.set_xticks(range(grid.shape[1]), [f"{t:g}" for t in grid.columns], rotation=45)
    ax.set_yticks(range(grid.shape[0]), [_tpi_label(t) for t in grid.index])
    ax.set_xlabel("seek length [track]")
    ax.set_ylabel("track density")
    label = {"saving_vs_best_pct": "time saved vs best baseline [%]"}.get(column, column)
    fig.colorbar(im, ax=ax, label=label)
    ax.set_title("Seek-settle time saved by the optimal profile over the best baseline\n"
                 "of the cell (× : no settled result)", fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


def plot_vs_tpi(df, path, max_lengths: int = 6) -> Path:
    """Seek-settle time of each profile kind vs TPI, one panel per seek length."""
    plt = _plt()
    df = _with_t(df)
    lengths = sorted(set(df["tracks"]))
    if len(lengths) > max_lengths:
        idx = np.unique(np.round(np.linspace(0, len(lengths) - 1, max_lengths)).astype(int))
        lengths = [lengths[i] for i in idx]
    ncol = min(3, len(lengths))
    nrow = math.ceil(len(lengths) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.0 * ncol, 3.2 * nrow), squeeze=False)
    for ax, L in zip(axes.flat, lengths):
        for kind, (c, ls, mk) in _KIND_STYLE.items():
            d = df[(df["kind"] == kind) & (df["tracks"] == L)].sort_values("tpi")
            if len(d):
                ax.plot(d["tpi"] / 1e3, 1e3 * d["seek_settle_s"], linestyle=ls, marker=mk, ms=3, color=c,
                        label=KIND_LABELS[kind])
        d = df[(df["tracks"] == L)].drop_duplicates("tpi").sort_values("tpi")
        ax.plot(d["tpi"] / 1e3, 1e3 * d["t_bb_s"].astype(float), color="0.5", lw=0.8, label="$T_{bb}$")
        ax.set_title(f"{L:g} track seek", fontsize=9)
        ax.set_xlabel("track density [kTPI]")
        ax.set_ylabel("seek-settle time [ms]")
        ax.grid(True, alpha=0.3)
    for ax in list(axes.flat)[len(lengths):]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def plot_sweep(df, outdir) -> list[Path]:
    """All sweep figures into ``outdir``; returns their paths (nothing if the table is empty)."""
    outdir = Path(outdir)
    if df is None or len(df) == 0:
        return []
    outdir.mkdir(parents=True, exist_ok=True)
    paths = [plot_seek_settle_vs_length(df, outdir / "seek_settle_vs_length.png"),
             plot_vs_tpi(df, outdir / "seek_settle_vs_tpi.png")]
    if "optimal" in set(df["kind"]) and len(set(df["kind"])) > 1:
        paths += [plot_gain_over_baselines(df, outdir / "gain_over_baselines.png"),
                  plot_heatmap(df, outdir / "heatmap_saving.png")]
    return paths


def save_figure(fig, path) -> Path:
    plt = _plt()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, metadata={"Software": None})
    plt.close(fig)
    return path


_save = save_figure
