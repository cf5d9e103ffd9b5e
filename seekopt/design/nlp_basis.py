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

Measured (K = 200 on the Kt study drive's loop-fitted plant, nominal, Imax 0.3 A; the same designer, only
the basis differs; "settle" played on the drive's truth; this machine at load 4-7 on 2 cores)::

    start  basis (per sample to / arrival / spacing)  NLPs (length: worst residual [band])         design   settle    Ipopt
    50 %   48 / 24 / 4   (94-96 columns at 47-48)      47: 0.814  50: 0.732  48: 0.757             48       2.159 ms  309 s
    50 %   32 / 24 / 4   (60-62 columns)                47: 0.853  50: 0.732  49: 0.749  48: 0.796  48       2.311 ms   74 s
    20 %   32 / 24 / 4                                  48: 0.915  52: 1.14  60: 0.959  76: 0.312
                                                        68: 0.352  64: 0.249 (budget spent)        64       2.424 ms  125 s
    20 %   32 / 32 / 4   (default; 62-66 columns)       48: 0.903  52: 0.735  51: 0.740  49: 0.840
                                                        50: 0.780                                  50       1.970 ms  104 s

Per sample, the NLPs of 94-96 columns cost 2-6 s per Ipopt iteration (the first 229 s), 60-66 columns
0.4-0.8 s: Ipopt's own linear algebra, not CasADi's derivatives (13 s of Hessians and 3 s of Jacobians
in that 229 s).  An arrival of 24 samples was too short from 20 % (the residual rose from 48 to 52
samples and the search ended at 64); 32 samples of arrival make it fall with the length.  The reference
the study states its target against is 1.780 ms (the same seek designed for the effect-free drive).
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
