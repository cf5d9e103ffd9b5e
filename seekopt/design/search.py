"""The seek-length search of :class:`~seekopt.design.designer.SeekDesigner`'s minimum seek-settle design.

Feasibility of the band-constrained QP is monotone in the seek length ``N`` (a longer seek can
always wait), so the shortest feasible ``N`` is found by bisection (:func:`bisect_length`).
``probe(n, warm=None, confirm=True)`` solves the QP at ``n`` samples and returns the solution
(``.success``, ``.x``); ``confirm=False`` lets a reduced (working-set) QP's unproven "infeasible"
steer the search, and the one length the answer rests on is confirmed before it stands.  A probe
just below a feasible length (``hi - 1``) is made with ``confirm=True`` at once: if infeasible, the
answer rests on it and it would be confirmed anyway (the confirmation is not a second solve).

A sweep designs neighbouring lengths one after another; the settle overhead (designed settle samples
minus the rigid bang-bang samples) of the nearest earlier designs predicts where the next one's
shortest feasible length lies, so the search starts there instead of scanning the size classes from
the shortest (``studies/design_speed.py``).
"""
from __future__ import annotations

import math

__all__ = ["predict_length", "prior_length", "bisect_length", "gallop_length", "PRIOR_RATIO", "PRIOR_OVER"]

#: A designer's first seek (no neighbouring design yet) starts its search at ``PRIOR_RATIO`` x the rigid
#: bang-bang samples + ``PRIOR_OVER`` (:func:`prior_length`): designed lengths of the bundled plants run
#: 1.25-1.45 x n_rigid + 0-9 nominal and up to 1.9 x robust (studies/design_speed.py).  The search gallops
#: from there (a miss by d samples costs ~log2(d) probes); the class scan it replaces proved the longest
#: seek of every class below the answer infeasible first (cold robust K = 1000: 0.4-0.6 s of 1.5 s).
PRIOR_RATIO = 1.25
PRIOR_OVER = 4


def predict_length(history: dict, n_rigid: int) -> int | None:
    """Settle samples predicted for a seek whose rigid bang-bang takes ``n_rigid`` samples.

    ``history`` maps the rigid bang-bang samples of earlier designs to their designed settle samples.
    The prediction is ``n_rigid`` plus the settle overhead (designed settle samples - rigid samples)
    of the nearest earlier design (a sweep's neighbouring length, within a factor 1.5 of
    ``n_rigid``), interpolated between the two nearest when they bracket it; None when there is none.
    The overhead varies less with the length than the settle/T_bb ratio, which falls as seeks get
    longer (studies/design_speed.py's 4 x 10 predicted lengths: 13 exact and 27 within one sample,
    sum of |errors| 60, against 2, 9 and 120 from the ratio, which overshot by 2-3 samples from
    K = 290 on and cost the search 2-4 extra lengths)."""
    near = [k for k in history if 2 / 3 <= max(k, 1) / max(n_rigid, 1) <= 1.5]
    if not near:            # no neighbouring length designed yet: the class scan is cheaper than a bad guess
        return None
    keys = sorted(near)
    below = [k for k in keys if k <= n_rigid]
    above = [k for k in keys if k >= n_rigid]
    if below and above and below[-1] != above[0]:
        a, b = below[-1], above[0]
        oa, ob = history[a] - a, history[b] - b
        over = oa + (ob - oa) * (n_rigid - a) / (b - a)
    else:
        k = min(keys, key=lambda k: abs(math.log(max(k, 1) / max(n_rigid, 1))))
        over = history[k] - k
    return max(int(round(n_rigid + over)), 1)


def prior_length(n_rigid: int) -> int:
    """Settle samples guessed for a seek of ``n_rigid`` rigid bang-bang samples without an earlier design
    to go by (:data:`PRIOR_RATIO`, :data:`PRIOR_OVER`); only a search's starting point."""
    return int(math.ceil(PRIOR_RATIO * max(n_rigid, 1))) + PRIOR_OVER


def bisect_length(probe, lo: int, hi: int, best, unconfirmed, floor: int | None = None):
    """Fewest feasible seek samples in ``(lo, hi]``.

    ``hi`` is feasible with answer ``best``.  ``unconfirmed(n)`` says (and forgets) whether a search
    step took ``n`` as infeasible without proof; when the answer rests on such a step (``hi - 1``),
    ``hi - 1`` is solved again with ``confirm=True`` and, if feasible after all, the search reopens
    down to ``floor`` (default ``lo``: proven infeasible).  Returns ``(N, answer)``.
    """
    floor = lo if floor is None else floor
    while True:
        while hi - lo > 1:
            mid = (lo + hi) // 2
            s = probe(mid, best.x, mid == hi - 1)
            if s.success:
                hi, best = mid, s
            else:           # infeasible, or undecided: either way not a design at ``mid``
                lo = mid
        if hi - 1 <= floor or not unconfirmed(hi - 1):
            return hi, best
        s = probe(hi - 1, best.x, True)
        if not s.success:
            return hi, best
        hi, best, lo = hi - 1, s, floor


def gallop_length(probe, lo: int, n0: int, nmax: int):
    """Bracket the shortest feasible length around a predicted ``n0`` in ``(lo, nmax]``.

    Feasible at ``n0``: steps down by 1, 2, 4, ... until a length fails; infeasible: steps up the same
    way until one succeeds.  Returns ``(lo, hi, answer at hi)`` for :func:`bisect_length`, or None
    when nothing up to ``nmax`` is feasible; ``nmax`` itself is probed with ``confirm=True`` (the
    caller's next question is whether it is proven infeasible).
    """
    s = probe(n0, None, n0 >= nmax)     # the class's longest seek: its "infeasible" ends the class (confirmed)
    if s.success:
        hi, best, step = n0, s, 1
        while hi - step > lo:
            m = hi - step
            t = probe(m, best.x, m == hi - 1)
            if not t.success:
                return m, hi, best
            hi, best, step = m, t, 2 * step
        return lo, hi, best
    if n0 >= nmax:
        return None
    lo, step = n0, 1
    while True:
        m = min(lo + step, nmax)
        t = probe(m, None, m == nmax)
        if t.success:
            return lo, m, t
        if m == nmax:
            return None
        lo, step = m, 2 * step
