"""The effect-aware design's length search: the shortest seek length an NLP shows feasible.

:func:`_search_length` brackets from the warm start's length and closes the bracket with secant steps on
the NLP's worst residual (bisection when the secant does not help); it assumes that a length above a
feasible one is feasible, which the correction basis keeps true across size classes
(:mod:`seekopt.design.nlp_basis`).  :func:`_stretch` time-stretches a warm start to another length;
:func:`_verified_samples` reads a full-plant play's settle in samples.
"""
from __future__ import annotations

import math

import numpy as np

from seekopt.design.metrics import SeekMetrics

__all__ = ["_search_length", "_stretch", "_verified_samples"]


def _verified_samples(m: SeekMetrics, fs: float, imax: float) -> int | None:
    """Seek-settle samples of a design played on the full plant, None if it did not settle within Imax."""
    if not (m.settled and math.isfinite(m.settle_time_s) and m.peak_current_a <= imax * (1 + 1e-9)):
        return None
    return max(int(math.ceil(m.settle_time_s * fs - 1e-9)), 1)


def _search_length(feasible, residual, n0: int, beta: float, n_max: int):
    """Shortest feasible seek length: bracket from ``n0`` and close it with secant steps on the
    residual (roughly linear in the length near ``beta``), bisection when the secant does not help.
    Returns ``(lo, hi)``: ``lo`` infeasible (or 0), ``hi`` the shortest feasible (None if none up to
    ``n_max``)."""
    lo, hi, n, step = 0, None, max(int(n0), 1), max(2, int(n0) // 12)
    seen, slow, width = [], False, None
    while True:
        ok = feasible(n)
        seen.append(n)
        if ok:
            hi = n if hi is None else min(hi, n)
        else:
            lo = max(lo, n)
        if hi is not None and hi - lo <= 1:
            return lo, hi
        fin = [(m, residual(m)) for m in seen if math.isfinite(residual(m))]
        guess = None
        if len(fin) >= 2:       # secant on the two points nearest the crossing
            a, b = sorted(fin, key=lambda mr: abs(mr[1] - beta))[:2]
            # only a residual that falls with the length is extrapolated: a flat or rising one (e.g. a
            # friction-excited ring the feedforward cannot remove at these lengths) would step by one sample
            if a[0] != b[0] and (b[1] - a[1]) / (b[0] - a[0]) < 0:
                guess = math.ceil(a[0] + (beta - a[1]) * (b[0] - a[0]) / (b[1] - a[1]))
        if hi is None:          # nothing feasible yet: go up
            nxt = n + step if guess is None else min(max(guess, n + 1), n + 4 * step)
            step *= 2
            if nxt > n_max:
                if n >= n_max:
                    return lo, None
                nxt = n_max
        elif lo == 0 and hi == min(seen):   # everything feasible so far: go down
            nxt = hi - step if guess is None else max(min(guess, hi - 1), hi - 4 * step)
            step *= 2
            if nxt < 1:
                nxt = 1
        else:                   # bracketed: secant clipped inside, bisection when it does not help
            nxt = (lo + hi) // 2 if guess is None or slow else min(max(guess, lo + 1), hi - 1)
            if nxt in seen:
                nxt = (lo + hi) // 2
        # a step that did not halve the bracket (a residual that jumps at the feasible length) -> bisect next
        slow = hi is not None and width is not None and 2 * (hi - lo) > width
        width = None if hi is None else hi - lo
        if nxt in seen or nxt <= lo or (hi is not None and nxt >= hi):
            nxt = (lo + hi) // 2 if hi is not None else n + 1
        n = nxt


def _stretch(a: np.ndarray, m: int, n: int) -> np.ndarray:
    """Resample a length-``m`` sequence to length ``n`` (time-stretched warm start)."""
    a = np.asarray(a, float)[:m]
    if m == n:
        return a.copy()
    return np.interp((np.arange(n) + 0.5) * m / n - 0.5, np.arange(m), a)
