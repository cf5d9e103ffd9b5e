"""The effect-aware design's length search: the shortest seek length an NLP shows feasible.

:func:`_search_length` brackets from the warm start's length and closes the bracket with secant steps on
the NLP's worst residual (bisection when the secant does not help); it assumes that a length above a
feasible one is feasible, which the correction basis keeps true across size classes
(:mod:`seekopt.design.nlp_basis`).  :func:`_warm_for` starts each length's NLP from the answers at other lengths
(or the warm start), :func:`_stretch` time-stretching one to another length;
:func:`_verified_samples` reads a full-plant play's settle in samples.
"""
from __future__ import annotations

import math

import numpy as np

from seekopt.design.metrics import SeekMetrics

__all__ = ["_search_length", "_stretch", "_verified_samples", "_warm_for"]


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


def _warm_for(n: int, nmax: int, tin: int, cache: dict, imaps: dict, first) -> tuple:
    """The NLP's starting feedforward and reference for a seek of ``n`` samples (length ``nmax``), and
    the input map ``(gain, offset)`` along it for the guard rows.

    ``tin``: input samples after the settle sample; ``cache``: ``{length: (feasible, v, q, residual)}`` of the
    NLPs solved so far, ``imaps``: ``{length: (gain, offset)}`` the guard's input map each of them used;
    ``first``: ``(n0, v, q, (gain, offset))``, the warm start (the linear design compensated) and its length.

    A shorter seek's NLP answer at rest from ``m < n`` on is a seek of ``n`` samples as it is, with the
    same worst residual after ``n`` or less: padded with rest, the best of them (lowest residual) starts
    the NLP, so that the residual the search reads cannot rise with the length.  Time-stretching it
    instead (the former rule, and still the rule going down) started the NLP at 54 and 62 samples
    of the combination drive's K = 200 from 50 % far from the 50-sample answer and Ipopt stopped in
    a worse point: residual 0.80 / 1.32 / 1.36 band at 50 / 54 / 62 samples.  Without a shorter answer:
    the nearest feasible length, else the warm start, time-stretched to ``n`` samples."""
    n0, v_w, q_w, (g_w, o_w) = first
    below = [m for m, (_, _, _, res) in cache.items() if m < n and math.isfinite(res)]
    if below:
        m = min(below, key=lambda m: (cache[m][3], -m))
        g, o = imaps[m]            # and its guard's input map, padded at rest: the same guard rows
        return (np.r_[cache[m][1], np.zeros(nmax - len(cache[m][1]))],
                np.r_[cache[m][2], np.zeros(nmax - len(cache[m][2]))],
                (np.r_[g, np.ones(n + tin - len(g))], np.r_[o, np.zeros(n + tin - len(o))]))
    ok_prev = [m for m, (ok, *_ ) in cache.items() if ok]
    m = min(ok_prev, key=lambda m: abs(m - n)) if ok_prev else n0
    vb, qb, (g, o) = (cache[m][1], cache[m][2], imaps[m]) if ok_prev else (v_w, q_w, (g_w, o_w))
    a, b = len(vb), n + tin                                   # input lengths
    return (np.r_[_stretch(vb, a, b) * (a / b) ** 2, np.zeros(nmax - b)],   # same distance in n samples
            np.r_[_stretch(qb, a, b), np.zeros(nmax - b)],
            (_stretch(g, len(g), b), _stretch(o, len(g), b) * (len(g) / b) ** 2))   # the plan, time-stretched
