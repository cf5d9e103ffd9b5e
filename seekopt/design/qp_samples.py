"""The row-sample rules of the seek QP (:class:`seekopt.design.qp.SeekQP`): which samples after the start
carry settle-band rows, of the nominal plant (:func:`pes_row_samples`) and of the robust set's other plants
(:func:`set_row_samples`, also the effect-aware NLP's robust rows and the long seeks' steps).
"""
from __future__ import annotations

import numpy as np

__all__ = ["pes_row_samples", "set_row_samples"]


def pes_row_samples(nmax: int, horizon: int) -> np.ndarray:
    """Samples carrying settle-band rows: every sample up to ``nmax + 96``, then two adjacent samples of
    every 4 up to ``nmax + 192`` and of every 8 after (the slow closed-loop tail; the designer re-checks
    every sample of the nominal plant by simulation).  Pairs, not single samples: a lightly damped mode
    near Nyquist makes the PES alternate ``a + b (-1)^k`` and rows on every 2nd sample saw only
    ``|a + b|`` (a robust-set plant at +4 % frequency then exceeded the band on the odd samples)."""
    edges = [(0, nmax + 96, 1), (nmax + 96, nmax + 192, 4), (nmax + 192, horizon, 8)]
    parts = []
    for a, b, s in edges:
        if a < horizon:
            k = np.arange(a, min(b, horizon))
            parts.append(k if s == 1 else k[(k - a) % s < 2])
    return np.concatenate(parts).astype(int)


def set_row_samples(nmax: int, horizon: int, stride: int = 1) -> np.ndarray:
    """Samples carrying the settle-band rows of the robust set's other plants (not the nominal):
    :func:`pes_row_samples`, and with ``stride > 1`` (large size classes) the samples before
    ``nmax + 32`` thinned to two adjacent samples of every ``2 stride`` (pairs, as there).  The one rule of
    the seek QP (:class:`SeekQP`) and the effect-aware NLP's robust rows
    (:class:`seekopt.design.nlp_problem.RobustSpread`)."""
    ks = pes_row_samples(nmax, horizon)
    stride = max(int(stride), 1)
    near = ks[ks < nmax + 32]
    return np.unique(np.r_[near[(near % (2 * stride)) < 2] if stride > 1 else near, ks[ks >= nmax + 32]]).astype(int)
