"""Fit and validation data of closing the loop, and the positions the augmented plant is defined on.

A position-dependent effect is pinned by the dwell at the positions the fit seeks settled on
(:func:`settled_range`) and can only be extrapolated beyond them, so validation uses the seeks
that stay inside that range (:func:`split_data`); the others are returned apart.
Units: tracks.
"""
from __future__ import annotations

import numpy as np

from identification.logs.seeklog import SeekLog
from identification.loop.fit_engine import Data
from identification.loop.settings import LoopSettings
from identification.loop.windows import seek_windows

__all__ = ["settled_range", "inside_groups", "split_data"]


def settled_range(log: SeekLog, windows) -> tuple:
    """``(lo, hi)`` [track]: the span of the positions the seeks of ``windows`` settled on (their
    targets).  A position-dependent effect is pinned there by the dwell -- a force error of 1e-5 A
    shows as about a track over a 10 ms window -- and only passed over beyond it; it is the range
    the augmented plant is defined on (``meta["position_range_track"]``)."""
    t = log.target_track[windows.index()]
    return float(np.min(t)), float(np.max(t))


def inside_groups(log: SeekLog, windows, lo: float, hi: float) -> list:
    """The seeks (groups) of ``windows`` whose measured position stays inside ``[lo, hi]`` [track]."""
    out = {}
    for (a, b), g in zip(windows.bounds, windows.groups):
        p = log.position_track[a:b]
        out[g] = out.get(g, True) and float(p.min()) >= lo and float(p.max()) <= hi
    return [g for g, ok in out.items() if ok]


def split_data(log: SeekLog, validation: SeekLog | None = None, settings: LoopSettings | None = None,
               outside: bool = False):
    """Fit and validation :class:`Data` (held-out odd seeks when no validation log) and whether
    they share the log.  Position-dependent effects are tabulated over the positions both logs
    visit (``Data.domain``).

    Validation uses the seeks that stay inside the positions the fit seeks settled on
    (:func:`settled_range`): beyond them a position-dependent effect can only be extrapolated,
    and an extrapolation error of a bias table (2 mA at 10 ktrack past the last settled track on
    the independent 50.4 kHz drive: 37 track validation RMS there) would decide every choice of
    the loop.  When fewer than a quarter of the validation seeks (or fewer than 2) stay inside,
    all are used.  ``outside=True`` also returns the left-out validation seeks as a fourth
    item (``Data`` or None)."""
    st = settings or LoopSettings()

    def win(lg):
        return seek_windows(lg, st.window_s, st.min_window_samples)
    logs = [log] + ([validation] if validation is not None else [])
    dom = (min(float(np.min(lg.position_track)) for lg in logs), max(float(np.max(lg.position_track)) for lg in logs))
    w = win(log)
    if validation is not None:
        fit = Data(log, w, effect_step_s=st.effect_step_s, domain=dom)
        vlog, vw, same = validation, win(validation), False
    else:
        if w.n_groups < 4:
            raise ValueError(f"{log.source or 'log'}: needs at least 4 seeks to hold some out "
                             f"(has {w.n_groups}); give a validation log")
        fw, vw = w.split(2)
        fit = Data(log, fw, effect_step_s=st.effect_step_s, domain=dom)
        vlog, same = log, True
    lo, hi = settled_range(log, fit.windows)
    keep = inside_groups(vlog, vw, lo, hi)
    out_w = None
    if len(keep) < vw.n_groups and len(keep) >= max(2, 0.25 * vw.n_groups):
        out_w = vw.select_groups([g for g in dict.fromkeys(vw.groups) if g not in set(keep)])
        vw = vw.select_groups(keep)

    def data(wins):
        return (Data(vlog, wins, grid=fit.grid, domain=dom, cache=fit.cache) if same
                else Data(vlog, wins, effect_step_s=st.effect_step_s, domain=dom))
    val = data(vw)
    if outside:
        return fit, val, same, (data(out_w) if out_w is not None else None)
    return fit, val, same
