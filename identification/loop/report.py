"""The report of closing the loop: JSON (exact keys, read by other tools) and Markdown.

:func:`write_report` writes the JSON report and a Markdown report (with the figures of
:mod:`identification.loop.figures` when a folder is given).
"""
from __future__ import annotations

import json
from pathlib import Path

from identification.loop.figures import figures
from identification.model.plant import atomic_write_text

__all__ = ["write_report", "markdown"]


def _fmt_params(p: dict) -> str:
    def f(v):
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(f(x) for x in v) + "]"
        return f"{v:.4g}" if isinstance(v, float) else str(v)
    return ", ".join(f"{k}={f(v)}" for k, v in p.items())


def _range_lines(vo) -> list:
    """The validation seeks left out (outside the positions the fit log settled on), Markdown lines."""
    if not vo or not vo["seeks"]:
        return []
    lo, hi = vo["position_range_track"]
    return [f"{vo['seeks']} validation seek(s) leave the positions the fit log settled on ({lo:.0f}..{hi:.0f} track, "
            f"where the plant is defined) and are not used above: RMS there {vo['rms_before_track']:.4g} -> "
            f"{vo['rms_after_track']:.4g} track.", ""]


def markdown(R, figs=(), fig_dir: str = ".") -> str:
    """The human-readable report (figures referenced relative to ``fig_dir``)."""
    eb, ea = R.error_before, R.error_after
    loop = R.info
    L = ["# Closing the loop: residual analysis and model augmentation", "",
         f"* fit log: `{R.fit.log.source or 'arrays'}` ({len(set(R.fit.windows.groups))} seeks), "
         f"validation: {loop.get('validation', '?')} ({len(set(R.val.windows.groups))} seeks)",
         f"* simulation: {loop.get('simulation', '')} (the rigid body integrates force errors twice)",
         f"* base re-fit of k0 and bias on the fit data: {'kept' if loop.get('base_refit', {}).get('kept') else 'not kept'}"
         f" (validation RMS {loop.get('base_refit', {}).get('rms_track', float('nan')):.4g} track)",
         f"* effects fitted on positions {R.plant.meta.get('position_range_track')} track",
         f"* runtime {R.runtime_s:.1f} s", "",
         "## Validation error", "", "| | RMS [track] | fit [%] |", "|---|---|---|",
         f"| before (identified model) | {eb['rms_track']:.4g} | {eb['fit_percent']:.4f} |",
         f"| after | {ea['rms_track']:.4g} | {ea['fit_percent']:.4f} |", "",
         *_range_lines(loop.get("validation_outside_range")),
         f"Ratio after/before: {ea['rms_track'] / max(eb['rms_track'], 1e-300):.3f}. Fit % is "
         "100 (1 - |e| / |y - mean_w(y)|) with the mean per window (the seek motion dominates it).", "",
         "## Steps", "",
         "Each candidate is fitted on the fit data (jointly with k0, bias, the declared modes' gains and the "
         "linear parameters of the effects already accepted), simulated, and accepted if its BIC on the fit "
         "data drops, its validation RMS drops by the required fraction (a re-parameterisation with fewer "
         "parameters, e.g. an amplifier lag in place of extra delay and a damped mode: does not rise), most "
         "validation seeks improve, and no free-form correction along a variable outside the library explains "
         "clearly more.", "",
         "| it | effect | accepted | val RMS before | val RMS after | seeks improved | params | evidence |",
         "|---|---|---|---|---|---|---|---|"]
    for s in R.steps:
        L.append(f"| {s.iteration} | {s.effect} | {'**yes**' if s.accepted else 'no'} | {s.rms_before:.4g} | "
                 f"{s.rms_after:.4g} | {100 * s.improved_fraction:.0f} % | {_fmt_params(s.params)} | {s.evidence}"
                 + (f"; {s.note}" if s.note else "") + " |")
    if R.notes:
        L += [""] + [f"Note: {n}" for n in R.notes]
    L += ["", "## Final plant effects", ""]
    L += [f"* `{e.name}`: {_fmt_params(e.params)}" for e in R.plant.effects] or ["* none"]
    L += [f"* k0 = {R.plant.k0:.6g} track/(A s^2) (model {R.model.k0:.6g}), bias = {1e3 * R.plant.bias_a:.4g} mA "
          f"(model {1e3 * R.model.bias_a:.4g} mA)", "", "## Unexplained", ""]
    L += [f"* {u}" for u in R.unexplained] or ["* nothing significant"]
    if figs:
        L += ["", "## Figures (validation data)", ""]
        L += [f"![{f}]({fig_dir}/{f})" for f in figs]
    return "\n".join(L) + "\n"


def write_report(R, report_path, figures_dir=None) -> dict:
    """Write ``report_path`` (JSON) and, with ``figures_dir``, the figures and
    ``figures_dir/loop_report.md``; otherwise the Markdown goes next to the JSON."""
    rep = R.report()
    atomic_write_text(report_path, json.dumps(rep, indent=2))
    if figures_dir is not None:
        figs = figures(R, figures_dir)
        atomic_write_text(Path(figures_dir) / "loop_report.md", markdown(R, figs, "."))
    else:
        atomic_write_text(Path(report_path).with_suffix(".md"), markdown(R))
    return rep
