"""The effect-aware NLP's correction basis: which samples of a seek get their own correction column.

The NLP (:class:`seekopt.design.nlp_problem.SeekNLP`) corrects the warm start's feedforward and reference
with piecewise-linear hats on knots [samples] (:func:`correction_knots`, one column of the condensed NLP
each, the same knots for both signals).  Every column is dense in every band, current and guard row
(3600-4400 rows at K = 200), and Ipopt's cost per iteration grows much faster than the number of columns,
so the knots go where a servo engineer would put them:

* every sample of short seeks (up to ``per_sample_samples``);
* beyond, every sample of the **arrival** (the last ``arrival_samples``: the deceleration's end, which
  sets the loop's residual and so the settle) and one knot every ``knot_spacing`` samples on the
  **run** before it (the current-limited acceleration and coast, whose shape the warm start already has
  and whose corrections only move the arrival's start and speed).

The count grows with the length (``arrival + (n - arrival) / spacing``) and the arrival never loses
resolution, so a longer seek's basis is about as strong as a shorter one's: the length search, which
assumes that a length above a feasible one is feasible, is not misled at a size-class boundary.  (The
former rule -- per sample up to 48 samples, then 24 uniform hats whatever the length -- dropped from 96
columns at 48 samples to 48 at 49: on the Kt study drive from 50 % the search then found no NLP design
shorter than the linear one.)

Measured (K = 200 on the Kt study drive's loop-fitted plant from 50 % of the range, nominal; the same
designer, only the basis differs; this machine at load 4-7 on 2 cores):

============================================  ==========  ==========================  ==============
basis                                          columns      NLPs (length: residual)       Ipopt s / it
============================================  ==========  ==========================  ==============
per sample to 48, arrival beyond (48/24/4)     94-96 @ 47-48  47: 0.814, 50: 0.732, 48: 0.757  309 / 103
per sample to 32, arrival beyond (32/24/4)     60-62 @ 47-48  47: 0.853, 50: 0.732, 49: 0.749, 48: 0.796  74 / 131
============================================  ==========  ==========================  ==============

Both designs are 48 samples (1.818 ms on the model); the 96-column NLPs cost 2-6 s per Ipopt iteration
(the first one 229 s), the 60-column ones 0.5-0.65 s.
"""
from __future__ import annotations

import numpy as np

__all__ = ["correction_knots", "hat_basis"]


def correction_knots(n: int, settings) -> np.ndarray:
    """Knots [samples] of the corrections of a seek of ``n`` samples (one NLP column each), for
    :class:`~seekopt.design.nlp_problem.NLPSettings` ``settings``: every sample up to
    ``per_sample_samples``; beyond, every sample of the last ``arrival_samples`` and a knot every
    ``knot_spacing`` samples before them (sample 0 and ``n - 1`` always knots)."""
    n = int(n)
    if n <= int(settings.per_sample_samples):
        return np.arange(n, dtype=float)
    a = min(int(settings.arrival_samples), n)
    head = n - a
    coarse = np.arange(0, head, max(int(settings.knot_spacing), 1), dtype=float)
    return np.unique(np.r_[coarse, np.arange(head, n, dtype=float), n - 1.0])


def hat_basis(knots: np.ndarray, nmax: int, ncol: int) -> np.ndarray:
    """``(nmax, ncol)``: the piecewise-linear hat of each knot (1 at its knot, 0 at its neighbours) over
    the samples ``0 .. knots[-1]``, zero from ``knots[-1] + 1`` on; columns from ``len(knots)`` on are zero
    (the NLP fixes their coefficients at 0)."""
    knots = np.asarray(knots, float)
    n = int(knots[-1]) + 1
    k = np.arange(n, dtype=float)
    B = np.zeros((int(nmax), int(ncol)))
    eye = np.eye(len(knots))
    for j in range(len(knots)):
        B[:n, j] = np.interp(k, knots, eye[j])
    return B
