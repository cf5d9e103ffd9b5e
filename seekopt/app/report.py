"""Markdown/HTML reports (a self-contained ``report.html``), the compare-style validation fit and the
plant's frequency-response figure; the sweep figures and savings table of
:mod:`seekopt.evaluate.sweep_figures` are re-exported here.

*Seek-settle time* is the time from the start of the seek until the position error stays within the
settle band (:func:`seek_settle_s`).
"""
from __future__ import annotations

import html
import math
import os
from pathlib import Path

import numpy as np

from seekopt.evaluate.sweep_figures import (KIND_LABELS, plot_gain_over_baselines, plot_heatmap,  # noqa: F401
                                            save_figure, plot_seek_settle_vs_length, plot_sweep, plot_vs_tpi,
                                            savings_table, seek_settle_s)

__all__ = ["seek_settle_s", "plot_sweep", "plot_seek_settle_vs_length", "plot_gain_over_baselines",
           "plot_heatmap", "plot_vs_tpi", "savings_table", "markdown_table", "write_report",
           "KIND_LABELS", "compare_fit", "COMPARE_DEFINITION", "plot_frequency_response"]

COMPARE_DEFINITION = (
    "Fit % is defined as MATLAB's `compare` does (NRMSE): fit = 100 (1 - ||y - ŷ|| / ||y - mean(y)||), "
    "per settle window, with y the measured PES after the seek settled (from the settling point N, the "
    "first sample after which |PES| stays within the band, to the next seek) and ŷ the PES of the model "
    "simulated from the measured current (effects included). The simulation is seek-anchored: it starts at "
    "the seek's start, with the initial position and velocity fitted by least squares over the whole seek, "
    "and is not corrected inside the window. 100 % is a perfect prediction, 0 % predicts no better than the "
    "window's mean, and a negative fit means the model's error is larger than the PES's own variation "
    "about its mean.")


def _plt():
    import matplotlib
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    return plt


def compare_fit(residual, band: float = 0.1):
    """Per-window NRMSE fit [%] of the settle PES, as MATLAB's ``compare`` defines it.

    Parameters
    ----------
    residual : identification.loop.residual.Residual
        A seek-anchored simulation of a model from the measured current (``y_sim`` [track] on the
        full log grid, ``windows`` with one group per seek), e.g. ``LoopResult.res_before`` /
        ``res_after`` of :func:`identification.loop.closing.close_loop`.
    band : float
        Settle band [track] that defines the settling point ``N``.

    Returns
    -------
    pandas.DataFrame
        One row per settled seek: ``start`` (log index), ``settle`` (``N``), ``end``,
        ``fit_percent`` ``= 100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` with ``y`` the measured PES
        on ``[N, end)`` and ``y_hat`` the simulated PES there (:data:`COMPARE_DEFINITION`), and
        ``pes_rms_track`` / ``error_rms_track`` (RMS of ``y - mean(y)`` and of ``y - y_hat``),
        ``error_trend_rms_track`` (RMS of the straight line, offset + drift, fitted to ``y - y_hat``).
    """
    import pandas as pd
    from seekopt.design.metrics import settle_index
    log, w = residual.log, residual.windows
    pes = log.position_track - log.target_track
    spans = {}
    for (a, b), g in zip(w.bounds, w.groups):
        lo, hi = spans.get(g, (a, b))
        spans[g] = (min(lo, a), max(hi, b))
    rows = []
    for a, b in spans.values():
        n = settle_index(pes[a:b], band)
        if n is None or b - (a + n) < 4:
            continue
        k = slice(a + n, b)
        y, yh = pes[k], residual.y_sim[k] - log.target_track[k]
        ok = np.isfinite(yh)
        if ok.sum() < 4:
            continue
        y, yh = y[ok], yh[ok]
        den = float(np.linalg.norm(y - y.mean()))
        err = float(np.linalg.norm(y - yh))
        t = np.arange(y.size, dtype=float)
        V = np.column_stack([np.ones_like(t), t])
        trend = V @ np.linalg.lstsq(V, y - yh, rcond=None)[0]
        rows.append({"start": a, "settle": a + n, "end": b,
                     "fit_percent": 100.0 * (1.0 - err / den) if den > 0 else float("nan"),
                     "pes_rms_track": den / np.sqrt(y.size), "error_rms_track": err / np.sqrt(y.size),
                     "error_trend_rms_track": float(np.linalg.norm(trend)) / np.sqrt(y.size)})
    return pd.DataFrame(rows, columns=["start", "settle", "end", "fit_percent", "pes_rms_track",
                                       "error_rms_track", "error_trend_rms_track"])


def plot_frequency_response(plants: dict, path, f_lo_hz: float = 30.0) -> Path:
    """Magnitude [track/A] and phase [deg] of each plant's frequency response (``{label: ModalPlant}``,
    delay included) from ``f_lo_hz`` to the Nyquist frequency of the first plant."""
    plt = _plt()
    first = next(iter(plants.values()))
    f_hi = 0.5 * (first.sample_rate_hz or 26400.0)
    f = np.logspace(np.log10(f_lo_hz), np.log10(f_hi), 1200)
    fig, (am, ap) = plt.subplots(2, 1, figsize=(7.5, 6.0), sharex=True)
    styles = [("C3", "-", 1.4), ("C0", "-", 0.9), ("k", "--", 0.9), ("C2", ":", 0.9)]
    for (label, p), (c, ls, lw) in zip(plants.items(), styles):
        h = p.frf(f)
        am.loglog(f, np.abs(h), color=c, ls=ls, lw=lw, label=label)
        ph = np.degrees(np.unwrap(np.angle(h)))
        ap.semilogx(f, ph - 360.0 * np.round(ph[0] / 360.0 + 0.5), color=c, ls=ls, lw=lw, label=label)
    am.set_ylabel("|P(j2πf)| [track/A]")
    ap.set_ylabel("phase [deg]")
    ap.set_xlabel("frequency [Hz]")
    am.set_title("Plant frequency response (delay included)")
    for a in (am, ap):
        a.grid(True, which="both", alpha=0.3)
    am.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


# ------------------------------------------------------------------ Markdown / HTML
def _cell(v, fmt: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, float, np.floating, np.integer)):
        x = float(v)
        return str(int(x)) if x.is_integer() and abs(x) < 1e9 else format(x, fmt)
    return str(v).replace("|", "\\|")


def markdown_table(df, columns=None, headers=None, fmt: str = ".3g") -> str:
    """A GitHub-flavoured Markdown table of ``df`` (selected ``columns``, renamed ``headers``)."""
    columns = list(columns or df.columns)
    headers = list(headers or columns)
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    for _, row in df[columns].iterrows():
        lines.append("| " + " | ".join(_cell(row[c], fmt) for c in columns) + " |")
    return "\n".join(lines) + "\n"


def write_report(outdir, title: str, sections: list, html_too: bool = True) -> Path:
    """Write ``report.md`` (and ``report.html``) into ``outdir``.

    ``sections`` is a list of ``(heading, markdown_text, [figure paths])``; in ``report.md`` figure
    paths are linked relative to ``outdir``, in ``report.html`` the PNGs are embedded as base64
    ``data:`` URIs (a self-contained file that can be mailed).
    """
    outdir = Path(outdir)
    md = [f"# {title}\n"]
    for heading, text, figs in sections:
        md.append(f"\n## {heading}\n\n{text.strip()}\n")
        for f in figs or []:
            rel = Path(os.path.relpath(Path(f).resolve(), outdir.resolve())).as_posix()
            md.append(f"\n![{Path(f).stem.replace('_', ' ')}]({rel})\n")
    path = outdir / "report.md"
    path.write_text("".join(md))
    if html_too:
        (outdir / "report.html").write_text(_md_to_html(title, "".join(md), outdir))
    return path


def _data_uri(path: Path) -> str:
    import base64
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def _md_to_html(title: str, md: str, root=".") -> str:
    """Minimal Markdown subset (headings, tables, images, paragraphs, lists, code) to HTML; images
    (paths relative to ``root``) are embedded as base64 data URIs; wide tables scroll."""
    import re
    out, table, para = [], [], []

    def inline(t):
        t = html.escape(t)
        t = re.sub(r"`([^`]+)`", r"<code>\1</code>", t)
        return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", t)

    def flush():
        if table:
            rows = [r for r in table if not re.fullmatch(r"\|[-|: ]+\|", r)]
            cells = [[c.strip() for c in r.strip("|").split(" | ")] for r in rows]
            body = "".join("<tr>" + "".join(f"<{'th' if i == 0 else 'td'}>{inline(c)}</{'th' if i == 0 else 'td'}>"
                                            for c in r) + "</tr>" for i, r in enumerate(cells))
            out.append(f"<div class='wide'><table>{body}</table></div>")
            table.clear()
        if para:
            out.append("<p>" + inline(" ".join(para)) + "</p>")
            para.clear()

    for line in md.splitlines():
        m = re.fullmatch(r"!\[([^]]*)\]\(([^)]+)\)", line.strip())
        if line.startswith("|"):
            if para:
                flush()
            table.append(line)
            continue
        flush()
        if line.startswith("#"):
            n = len(line) - len(line.lstrip("#"))
            out.append(f"<h{n}>{inline(line[n:].strip())}</h{n}>")
        elif m:
            out.append(f'<p><img src="{_data_uri(Path(root) / m.group(2))}" alt="{html.escape(m.group(1))}" '
                       'style="max-width:100%"></p>')
        elif line.startswith("- "):
            out.append(f"<ul><li>{inline(line[2:].strip())}</li></ul>")
        elif line.strip():
            para.append(line.strip())
    flush()
    style = ("body{font-family:sans-serif;max-width:70em;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}.wide{overflow-x:auto;max-width:100%}"
             "img{max-width:100%}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>{''.join(out)}</body></html>\n")
