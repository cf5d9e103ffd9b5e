"""The unmodelled-mode guard: where the identified model is blind, the profile must not ring.

A mode the identification could not see (near and above Nyquist, inside the controller's notches and
multirate-filter zeros: the *blind bands*, :mod:`seekopt.design.guard_bands`) is also one the feedback
cannot damp (the controller's gain is low in its notch): it rings for milliseconds.

The guard bounds, for every frequency ``f`` of those blind bands, the residual vibration the
profile's total current (feedforward + feedback + hold, every sub-step) leaves in an undamped mode
``k0 g / (s^2 + w^2)``::

    |z(f)| <= tol * band          (g the band's guard gain, default 1: a unit-gain mode)

with the linear rows of :func:`seekopt.design.modal_residual.mode_residual_rows` (one map for every band;
the former fixed 0.45-0.65 fs guard is the ``nyquist`` band here) on a grid fine enough for a seek's
current spectrum (:func:`guard_grid`, :func:`grid_spacing`) plus the closed loop's narrow peaks
(:func:`loop_peaks`): :func:`build_guard_rows`, shared by content between designers
(:func:`design_guard_rows`).

:func:`guard_report` measures a finished profile's worst guard residual (in bands) by simulation.
The bands' names (:class:`GuardBand`, :func:`problem_bands`, ...) are re-exported from
:mod:`seekopt.design.guard_bands`.
"""
from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from seekopt.design.guard_bands import (GuardBand, band_gains, controller_notches, curve_gain,  # noqa: F401
                                        merge_bands, nyquist_band, plant_blind_bands, plant_gain_curve,
                                        problem_bands)
from seekopt.design.modal_residual import dtft, mode_residual_phasors, mode_residual_rows, mode_residuals

__all__ = ["GuardBand", "controller_notches", "nyquist_band", "plant_blind_bands", "plant_gain_curve", "curve_gain",
           "band_gains", "merge_bands",
           "problem_bands", "guard_grid", "grid_spacing", "loop_peaks", "guard_rows", "design_guard_rows", "build_guard_rows", "GRID_PER_LOBE", "GuardReport", "guard_report"]


def guard_grid(bands: list, spacing_hz: float, fmin_hz: float = 1.0, curve=None):
    """Frequencies [Hz] and gains (:func:`band_gains`) covering ``bands`` at most ``spacing_hz`` apart
    (each band's edges included; where bands overlap the larger gain is kept)."""
    fr, gn = [], []
    for b in bands:
        lo, hi = max(b.lo_hz, fmin_hz), b.hi_hz
        if hi < lo:
            continue
        m = max(int(math.ceil((hi - lo) / spacing_hz)), 1)
        x = np.linspace(lo, hi, m + 1) if hi > lo else np.array([lo])
        fr.append(x); gn.append(band_gains(b, x, curve))
    if not fr:
        return np.zeros(0), np.zeros(0)
    f, g = np.concatenate(fr), np.concatenate(gn)
    order = np.lexsort((-g, f))
    f, g = f[order], g[order]
    keep = np.r_[True, np.diff(f) > 1e-9 * f[1:]]
    return f[keep], g[keep]


#: Guard grid points per ``fs / N`` (``N`` the seek-size class plus the inputs' tail after the settle
#: sample): a seek's current spectrum has lobes about ``fs / N`` wide, and constraints on a grid of
#: ``fs / (2 N)`` let a lobe reach 3 x the bound between two points (measured: K = 200, unit-gain modes in
#: the NSS notches).  4 points still let the optimiser place a residual of 2.3-3.1 x the bound between two
#: (``tests/test_guard.py``'s 2900-3300 Hz band, K = 50 / 200: 0.227 / 0.310 band at 3000 Hz against 0.1);
#: 6 points: at most 0.134.
GRID_PER_LOBE = 6


def grid_spacing(fs: float, nmax: int, floor_hz: float = 25.0) -> float:
    """Guard grid spacing [Hz] for seeks of at most ``nmax`` samples: ``fs / (GRID_PER_LOBE nmax)``."""
    return max(fs / (GRID_PER_LOBE * max(int(nmax), 1)), floor_hz)


def loop_peaks(maps, bands: list, fs: float, spacing_hz: float) -> np.ndarray:
    """Frequencies [Hz] inside ``bands`` where the closed loop's current responses have a peak
    narrower than ``spacing_hz``.

    The total current is ``i = h_iu * u_ff + h_ir * r``: the feedforward and reference of an
    ``N``-sample seek have spectra smooth on the scale ``fs / N`` (the uniform guard grid), but a
    lightly damped closed-loop pole makes ``|H_iu|`` or ``|H_ir|`` peak within its bandwidth and a
    uniform grid may step over it.  Each such peak of the two responses of ``maps``
    (:class:`seekopt.design.qp.LoopMaps`, the one simulator's) is returned with the points half its
    half-power width either side."""
    L = int(maps.L)
    h = 1.0 / (L * fs)
    out = []
    for resp in (maps.i_u, maps.i_r):
        x = np.asarray(resp, dtype=float).reshape(-1)
        step = min(spacing_hz / 8.0, 1.0 / (2 * x.size * h))
        for b in bands:
            f = np.arange(max(b.lo_hz, step), b.hi_hz + step, step)
            if f.size < 3:
                continue
            mag = np.abs(dtft(x, 2 * np.pi * f * h))
            db = 20 * np.log10(np.maximum(mag, 1e-300))
            for i in range(1, f.size - 1):
                if not (db[i] > db[i - 1] and db[i] >= db[i + 1]):
                    continue
                lo, hi = i, i
                while lo > 0 and db[lo] > db[i] - 3.0:
                    lo -= 1
                while hi < f.size - 1 and db[hi] > db[i] - 3.0:
                    hi += 1
                if db[lo] > db[i] - 3.0 or db[hi] > db[i] - 3.0 or f[hi] - f[lo] >= spacing_hz:
                    continue              # not a narrow resonance peak: the uniform grid follows it
                half = 0.25 * (f[hi] - f[lo])
                out += [f[i] - half, f[i], f[i] + half]
    return np.unique(np.round(np.asarray(out, dtype=float), 3))


def guard_rows(bands: list, k0: float, fs: float, L: int, nsub: int, spacing_hz: float, npoly: int = 4,
               extra_hz=(), curve=None):
    """``(G, freqs)``: the guard's linear rows on the sub-step currents (for :class:`seekopt.design.qp.SeekQP`)
    on the grid of :func:`guard_grid` plus ``extra_hz`` (e.g. :func:`loop_peaks`) inside the bands,
    or ``None`` when there is no band."""
    f, g = guard_grid(bands, spacing_hz, curve=curve)
    if not f.size:
        return None
    for x in np.asarray(extra_hz, dtype=float):
        gx = [float(band_gains(b, x, curve)[0]) for b in bands if b.lo_hz <= x <= b.hi_hz]
        if gx:
            f, g = np.r_[f, x], np.r_[g, max(gx)]
    keep = g > 0
    f, g = f[keep], g[keep]
    if not f.size:
        return None
    return mode_residual_rows(mode_residual_phasors(k0, fs, L, nsub, f, g), npoly), f


#: Guard rows built, by what they are made of (:func:`design_guard_rows`): the designers of one plant (its
#: nominal and robust designers, a sweep's cells) share a size class's rows (``loop_peaks`` and
#: ``mode_residual_rows``: 30-90 ms per class).  Kept for the last ``GUARD_CACHE_SIZE`` classes.
GUARD_CACHE_SIZE = 16
_GUARD_CACHE: "OrderedDict[tuple, tuple]" = OrderedDict()


def _fingerprint(*arrays) -> str:
    """Content hash of arrays (shape, dtype and bytes)."""
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.shape, a.dtype.str)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def design_guard_rows(bands: list, k0: float, fs: float, nmax: int, horizon: int, nominal_maps, curve=None):
    """:func:`build_guard_rows`, cached by content (the bands, ``k0``, ``fs``, ``nmax``, ``horizon``, the
    maps' current responses and the curve: equal inputs, the same rows); the arrays returned are
    read-only and shared."""
    if not bands:
        return None
    key = (repr(list(bands)), float(k0), float(fs), int(nmax), int(horizon), int(nominal_maps.L),
           _fingerprint(nominal_maps.i_u, nominal_maps.i_r),
           None if curve is None else _fingerprint(*curve))
    if key in _GUARD_CACHE:
        _GUARD_CACHE.move_to_end(key)
        return _GUARD_CACHE[key]
    rows = build_guard_rows(bands, k0, fs, nmax, horizon, nominal_maps, curve)
    for a in rows:
        a.setflags(write=False)
    _GUARD_CACHE[key] = rows
    while len(_GUARD_CACHE) > GUARD_CACHE_SIZE:
        _GUARD_CACHE.popitem(last=False)
    return rows


def build_guard_rows(bands: list, k0: float, fs: float, nmax: int, horizon: int, nominal_maps, curve=None):
    """The guard rows of a design for seeks (or velocity steps) of at most ``nmax`` samples: ``(G, freqs)``
    of :func:`guard_rows` on the sub-step currents of samples ``0..horizon-1``, on the grid
    :func:`grid_spacing` ``(fs, nmax)`` plus the narrow peaks of the nominal loop ``nominal_maps``
    (:func:`loop_peaks`); None when there is no band.  The one guard of the linear designer, the
    effect-aware NLP and the long seeks (``bands``: :func:`problem_bands`, ``curve``:
    :func:`plant_gain_curve` of the design plant)."""
    if not bands:
        return None
    dfg = grid_spacing(fs, nmax)
    L = int(nominal_maps.L)
    return guard_rows(bands, k0, fs, L, int(horizon) * L, spacing_hz=dfg, curve=curve,
                      extra_hz=loop_peaks(nominal_maps, bands, fs, dfg))


@dataclass
class GuardReport:
    """Worst residual a profile leaves in the guarded modes.

    ``worst_band`` is ``max |z(f)| / settle band`` over the bands' grid (guard gain included),
    ``worst_hz`` where, ``worst_reason`` the band's reason; ``per_band`` the worst per band."""

    worst_band: float
    worst_hz: float
    worst_reason: str
    per_band: list

    def to_meta(self) -> dict:
        return {"guard_worst_residual_band": round(self.worst_band, 4), "guard_worst_hz": round(self.worst_hz, 1),
                "guard_bands": ";".join(f"{b.lo_hz:.0f}-{b.hi_hz:.0f}:{b.reason}:{b.gain:g}"
                                        for b, _ in self.per_band)}


def guard_report(plant, controller, profile, bands: list, settle: float | None = None,
                 spacing_hz: float = 25.0, horizon_s: float | None = None, curve=None,
                 current_sub=None) -> GuardReport:
    """Play ``profile`` on ``plant`` (:func:`seekopt.design.metrics.simulate_profile`, sub-steps
    recorded) and measure the residual of the guarded modes left by the total current.
    ``current_sub``: the ``(n, L)`` total sub-step currents [A] of that play when already at hand
    (e.g. :func:`seekopt.design.predict.play_linear`)."""
    from seekopt.design.metrics import DEFAULT_TAIL_S
    from seekopt.drive.simulator import simulate_2dof
    band = float(settle or profile.settle_track)
    fs, L = float(controller.sample_rate_hz), int(controller.fast_multiple)
    if current_sub is None:
        n = profile.n + int(round(DEFAULT_TAIL_S * fs)) if horizon_s is None else int(round(horizon_s * fs))
        u, r = profile.padded(max(n, profile.n + 1))
        current_sub = simulate_2dof(plant, controller, u - plant.bias_a, r, position0=0.0,
                                    record_substeps=True).current_sub_a
    i_sub = (np.asarray(current_sub) + plant.bias_a).ravel()       # the seek's current (steady hold removed)
    per, worst = [], (0.0, float("nan"), "")
    for b in bands:
        f, g = guard_grid([b], spacing_hz, curve=curve)
        if not f.size:
            continue
        z = np.abs(mode_residuals(plant.k0, fs, L, i_sub, f, g)) / band
        k = int(np.argmax(z))
        per.append((b, float(z[k])))
        if z[k] > worst[0]:
            worst = (float(z[k]), float(f[k]), b.reason)
    return GuardReport(worst[0], worst[1], worst[2], per)
