"""Figures of closing the loop, drawn on the validation data (before and after).

* ``residual_seeks.png`` -- residual [track] of the four longest validation seeks;
* ``spectra.png`` -- residual PSD [track^2/Hz] and residual-current coherence;
* ``correlation.png`` -- residual autocorrelation (white band) and cross-correlation
  with the current (Ljung's coloured band), lags in samples;
* ``dependence.png`` -- free-form corrections along position, velocity sign,
  |current|, current and time (force [mA] or gain [%], +-2 sigma cluster-robust);
* ``sync.png`` -- synchronous average over spindle revolutions [track];
* ``steps.png`` -- validation RMS of every candidate tried, per iteration.

Each function takes a :class:`identification.loop.result.LoopResult` and a path.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["FIGURES", "figures"]

BEFORE, AFTER = "#9a9a9a", "#1f5fbf"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    plt.rcParams.update({"font.size": 11, "axes.grid": True, "grid.alpha": 0.3, "figure.dpi": 110})
    return plt


def _longest_groups(res, k=4):
    lens = {}
    for (a, b), g in zip(res.windows.bounds, res.windows.groups):
        lo, hi = lens.get(g, (a, b))
        lens[g] = (min(lo, a), max(hi, b))
    return sorted(lens.values(), key=lambda ab: -(ab[1] - ab[0]))[:k]


def fig_residual_seeks(R, path):
    plt = _plt()
    spans = _longest_groups(R.res_after)
    fig, axes = plt.subplots(len(spans), 1, figsize=(10, 2.3 * len(spans) + 0.6), squeeze=False)
    eb, ea = R.res_before.full(), R.res_after.full()
    log = R.res_after.log
    for ax, (a, b) in zip(axes[:, 0], spans):
        t = 1e3 * (log.time_s[a:b] - log.time_s[a])
        ax.plot(t, eb[a:b], color=BEFORE, lw=1.0, label=f"before (rms {np.sqrt(np.nanmean(eb[a:b] ** 2)):.3g})")
        ax.plot(t, ea[a:b], color=AFTER, lw=1.0, label=f"after (rms {np.sqrt(np.nanmean(ea[a:b] ** 2)):.3g})")
        seek = log.target_track[a] - log.target_track[a - 1] if a > 0 else 0.0
        ax.set_title(f"validation seek at t = {log.time_s[a]:.3f} s, {seek:+.0f} track", fontsize=10)
        ax.set_ylabel("residual [track]")
        ax.legend(loc="upper right", fontsize=9)
    axes[-1, 0].set_xlabel("time from seek start [ms]")
    fig.suptitle("Measured minus simulated position (re-anchored every window)")
    fig.tight_layout()
    fig.savefig(path); plt.close(fig)


def fig_spectra(R, path):
    plt = _plt()
    sb, sa = R.analysis_before["spectra"], R.analysis_after["spectra"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    a1.semilogy(sb.f, sb.See, color=BEFORE, label="before")
    a1.semilogy(sa.f, sa.See, color=AFTER, label="after")
    a1.set_ylabel("residual PSD [track$^2$/Hz]"); a1.legend()
    a2.plot(sb.f, sb.coh, color=BEFORE, label="before")
    a2.plot(sa.f, sa.coh, color=AFTER, label="after")
    a2.axhline(sa.coh_band, color="k", ls="--", lw=1, label=f"95 % null ({sa.coh_band:.2f})")
    a2.set_ylim(0, 1.02); a2.set_ylabel("coherence with current [-]"); a2.set_xlabel("frequency [Hz]")
    a2.legend(loc="upper left")
    a2.set_title("closed loop: noise fed back through the controller is coherent with the current "
                 "even for an exact model", fontsize=9)
    fig.suptitle("Residual spectrum and coherence with the current (validation)")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_correlation(R, path):
    plt = _plt()
    cb, ca = R.analysis_before["corr"], R.analysis_after["corr"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    k = ca.lags >= 0
    a1.plot(ca.lags[k], cb.auto[k], "o-", ms=3, color=BEFORE, label="before")
    a1.plot(ca.lags[k], ca.auto[k], "o-", ms=3, color=AFTER, label="after")
    a1.fill_between(ca.lags[k], -ca.white_band, ca.white_band, color="g", alpha=0.2, label="white 95 %")
    a1.set_xlabel("lag [samples]"); a1.set_ylabel("autocorrelation [-]"); a1.legend(); a1.set_title("whiteness")
    a2.plot(ca.lags, cb.cross, color=BEFORE, label="before")
    a2.plot(ca.lags, ca.cross, color=AFTER, label="after")
    a2.fill_between(ca.lags, -ca.cross_band, ca.cross_band, color="g", alpha=0.2,
                    label="Ljung 95 % (after)")
    a2.axvline(0, color="k", lw=0.8)
    a2.set_xlabel("lag tau [samples] (tau > 0: current in the past)")
    a2.set_ylabel("rho(e(t), u(t - tau)) [-]"); a2.legend(); a2.set_title("cross-correlation with the current")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_dependence(R, path):
    plt = _plt()
    db = {d.name: d for d in R.analysis_before["dependence"]}
    da = {d.name: d for d in R.analysis_after["dependence"]}
    names = list(da)
    ncol = 3
    nrow = math.ceil(len(names) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(14, 3.8 * nrow), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        for d, col, lab in ((db.get(name), BEFORE, "before"), (da[name], AFTER, "after")):
            if d is None:
                continue
            sc = 1e3 if d.unit == "A" else 100.0
            if len(d.x) > 1:
                x, val, se = d.x, d.value, d.se
            else:                       # Coulomb-like step: +f for v < 0, -f for v > 0
                x, val, se = np.array([-1.0, 1.0]), np.r_[d.value, -d.value], np.r_[d.se, d.se]
            ax.errorbar(x, sc * val, yerr=2 * sc * se, fmt="o-", color=col, capsize=3, ms=4,
                        label=f"{lab} (chi2 {d.chi2:.0f}/{d.dof})")
        d = da[name]
        ax.axhline(0, color="k", lw=0.8)
        ax.set_title(d.label, fontsize=10)
        ax.set_ylabel("force [mA]" if d.unit == "A" else "gain [%]")
        xl = {"position": "position [track]", "abs_current": "|current| [A]", "current": "current [A]",
              "time": "time [s]"}
        ax.set_xlabel(next((v for k, v in xl.items() if name.endswith(k)), "sign of the velocity [-]"))
        if name.endswith("current"):        # quantile bins crowd near zero current
            ax.set_xscale("symlog", linthresh=1e-3)
            ticks = [0, 1e-3, 1e-2, 1e-1, 1.0]
            ticks = ticks if name.endswith("abs_current") else sorted({-t for t in ticks} | set(ticks))
            xmax = float(np.max(np.abs(d.x))) * 1.5
            ax.set_xticks([t for t in ticks if abs(t) <= xmax])
            ax.set_xticklabels([f"{t:g}" for t in ticks if abs(t) <= xmax], fontsize=8)
            ax.set_xlim(0 if name.endswith("abs_current") else -xmax, xmax)
        ax.legend(fontsize=8)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle("Free-form corrections of the validation residual (+-2 sigma, clusters = seeks)")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_sync(R, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4))
    for an, col, lab in ((R.analysis_before, BEFORE, "before"), (R.analysis_after, AFTER, "after")):
        if "sync" in an:
            ph, m, se, frac = an["sync"]
            ax.fill_between(ph, m - 2 * se, m + 2 * se, color=col, alpha=0.2)
            ax.plot(ph, m, color=col, label=f"{lab}: {an['spindle_hz']:.2f} Hz, {100 * frac:.0f} % repeatable")
    ax.set_xlabel("spindle phase [rev]"); ax.set_ylabel("mean residual [track]"); ax.legend()
    ax.set_title(f"Synchronous average over revolutions ({R.analysis_after['spindle_source']})")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_steps(R, path):
    plt = _plt()
    steps = R.steps or []
    fig, ax = plt.subplots(figsize=(10, 0.32 * max(len(steps), 4) + 1.4))
    y = np.arange(len(steps))[::-1]
    rel = [100 * (s.rms_after / s.rms_before - 1) for s in steps]
    shown = np.clip(rel, -100, 50)
    ax.barh(y, shown, color=[AFTER if s.accepted else "#d9a0a0" for s in steps])
    ax.set_yticks(y, [f"it {s.iteration}: {s.effect}" + ("  (accepted)" if s.accepted else "") for s in steps],
                  fontsize=9)
    for yi, r, sh in zip(y, rel, shown):
        ax.text(sh + (1 if sh >= 0 else -1), yi, f"{r:+.1f} %", va="center", ha="left" if sh >= 0 else "right",
                fontsize=8)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlim(-115, 65)
    ax.set_xlabel("change of the validation RMS against the model of that iteration [%] (clipped to -100..50)")
    ax.set_title(f"Candidates tried: validation RMS {R.error_before['rms_track']:.3g} -> "
                 f"{R.error_after['rms_track']:.3g} track")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


FIGURES = {"residual_seeks.png": fig_residual_seeks, "spectra.png": fig_spectra,
           "correlation.png": fig_correlation, "dependence.png": fig_dependence,
           "sync.png": fig_sync, "steps.png": fig_steps}


def figures(R, folder) -> list:
    """Write all figures into ``folder``; returns their file names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, fn in FIGURES.items():
        if name == "sync.png" and "sync" not in R.analysis_after:
            continue
        fn(R, folder / name)
        out.append(name)
    return out
