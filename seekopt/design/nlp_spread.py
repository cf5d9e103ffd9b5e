"""The robust set of the effect-aware NLP (:class:`seekopt.design.nlp_problem.SeekNLP`): every plant's PES
and currents as the nominal's plus the difference of the linear loops' responses (module notes of
:mod:`seekopt.design.nlp_problem`).
"""
from __future__ import annotations

import numpy as np

from seekopt.design.qp_samples import set_row_samples

__all__ = ["RobustSpread"]


class RobustSpread:
    """The robust set's spread around the nominal loop, for seeks of at most ``nmax`` samples.

    ``maps``: :class:`seekopt.design.qp.LoopMaps` of the set's (linear) plants, nominal first, horizon
    above ``horizon``.  Every other plant's PES [band] and sub-step current [Imax] minus the nominal's
    is linear in the scaled ``(v, q)``: ``dT_u Imax v + dT_r |K| q + K ds_r``.  Band rows of the NLP on
    the samples ``band_samples`` (the linear designer's rule, :func:`seekopt.design.qp_samples.set_row_samples`
    with its row ``stride``) (:meth:`rows`); :meth:`spread` for checks and the current envelope.

    ``current_only``: the last ``current_only`` maps are plants the design holds **only** the current limit
    on (the torque-constant headroom of :class:`EffectAwareDesigner`: the design plant with its gain
    scaled by ``1 +- kt_uncertainty``); they give no band rows and no band spread.
    """

    def __init__(self, maps: list, nmax: int, horizon: int, band: float, nmax_prev: int = 0, stride: int = 1,
                 current_only: int = 0):
        N, H = int(nmax), int(horizon)
        ks = np.arange(H + 1)
        (Y0u, Y0r, y0), (I0u, I0r, i0) = maps[0].position_rows(ks, N), maps[0].current_rows(H, N)
        self.DY, self.dy, self.DI, self.di = [], [], [], []
        for m in maps[1:]:
            (Yu, Yr, yj), (Iu, Ir, ij) = m.position_rows(ks, N), m.current_rows(H, N)
            self.DY.append(np.hstack([Yu - Y0u, Yr - Y0r]) / band); self.dy.append((yj - y0) / band)
            self.DI.append(np.hstack([Iu - I0u, Ir - I0r])); self.di.append(ij - i0)
        self.n, self.N, self.H = len(maps) - 1, N, H
        self.n_band = self.n - int(current_only)     # plants with band rows (the first n_band of the others)
        if self.n_band < 0:
            raise ValueError(f"{current_only} current-only plants of a set of {self.n} others")
        del self.DY[self.n_band:], self.dy[self.n_band:]
        # robust rows of the NLP: the linear designer's rows of the set's other plants
        # (seekopt.design.qp_samples.set_row_samples, ``stride`` its thinning of this class) on the samples that can
        # follow a seek of this class (k > nmax_prev; the spread is re-checked on every sample and the
        # simulator plays every sample); currents on every sub-step of the seek and 8 samples more (as the
        # linear designer)
        kb = set_row_samples(N, H + 1, stride)
        self.band_samples = kb[kb > nmax_prev]
        self.current_substeps = np.arange(min(H, N + 8) * maps[0].L)

    def rows(self):
        """``(DY, dy, DI, di)``: the spread on the robust rows, plant-major ``(n_band, rows, 2N)`` /
        ``(n_band, rows)`` [band] and ``(n, rows, 2N)`` / ``(n, rows)`` [A]; ``DY, dy`` None without band plants."""
        kb, kc = self.band_samples, self.current_substeps
        band = (np.stack([D[kb] for D in self.DY]), np.stack([d[kb] for d in self.dy])) if self.n_band else (None, None)
        return (*band, np.stack([D[kc] for D in self.DI]), np.stack([d[kc] for d in self.di]))

    def spread(self, v, q, K: float, imax: float):
        """``(dE (n_band, H + 1) [band], dI (n, H L) [Imax])`` for scaled feedforward ``v`` and reference ``q``."""
        w = np.r_[imax * np.asarray(v[:self.N]), abs(K) * np.asarray(q[:self.N])]
        dE = np.array([D @ w + K * d for D, d in zip(self.DY, self.dy)]) if self.n_band else np.zeros((0, self.H + 1))
        dI = np.array([(D @ w + K * d) / imax for D, d in zip(self.DI, self.di)])
        return dE, dI
