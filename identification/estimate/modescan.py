"""The robust identification's scan for missed modes (:class:`identification.estimate.robust._Run`, step b):
the whitened residual scanned over the frequency grid (:func:`identification.estimate.scangrid.scan_grids`),
the best peaks refined on a fine local grid and added, then refit and prune, round by round.  Also the
layout of the nonlinear parameter vector the method works on."""
from __future__ import annotations

import math

import numpy as np

from identification.estimate.scangrid import scan_grids
from identification.estimate.varpro import VarPro

__all__ = ["ModeScan"]


# --------------------------------------------------------------------------- parameter vector
# x = [ln f_1..ln f_R, ln zeta_1..ln zeta_R, delay / dt] (VarPro's nonlinear parameters)
def _n_modes(x) -> int:
    return (len(x) - 1) // 2


def _drop(x, keep):
    """``x`` without the modes where ``keep`` is False."""
    R = _n_modes(x)
    keep = np.asarray(keep, dtype=bool)
    return np.r_[x[:R][keep], x[R:2 * R][keep], x[2 * R]]


def _add(x, freq_hz: float, zeta: float):
    """``x`` with one more mode."""
    R = _n_modes(x)
    return np.r_[x[:R], math.log(freq_hz), x[R:2 * R], math.log(zeta), x[2 * R]]


class ModeScan:
    """The scan's methods of :class:`identification.estimate.robust._Run` (which supplies ``s``, ``lo``,
    ``hi``, ``fs``, ``tabu``, ``added``, :meth:`refine` and :meth:`prune`)."""

    def scan_grids(self, vp: VarPro) -> list[tuple[float, np.ndarray]]:
        """The scan's ``[(zeta, frequencies [Hz]), ...]`` for ``vp`` (:func:`identification.estimate.scangrid.scan_grids`)."""
        return scan_grids(self.s, vp.ar, self.lo, self.hi, self.fs)

    def _peaks(self, vp: VarPro, x, grids):
        """Frequencies [Hz] of the best scan peaks of this round (see :meth:`search`) on ``grids``
        (:meth:`scan_grids`) and the residual variance."""
        s, R = self.s, _n_modes(x)
        freqs, best, r = [], [], None
        for zt, grid in grids:
            stat, r = vp.scan(x, grid, (zt,))
            freqs.append(grid)
            best.append(stat[:, 0])
        freqs, best = np.concatenate(freqs), np.concatenate(best)
        s2 = float(r @ r) / max(len(r) - R - 2, 1)
        best = best / s2
        for f0 in self.tabu:                        # not again where a mode was proposed or dropped
            best[np.abs(freqs / f0 - 1) < s.tabu_sep_rel] = 0.0
        for f0 in np.exp(x[:R]):                    # nor where one is
            best[np.abs(freqs / f0 - 1) < s.existing_sep_rel] = 0.0
        new = []
        for i in np.argsort(best)[::-1]:           # the best peaks, scan_peak_sep_rel apart
            if best[i] <= s.scan_gate * s.t_min ** 2 or len(new) >= min(s.scan_max_new, s.max_modes - R):
                break
            if all(abs(freqs[i] / f0 - 1) > s.scan_peak_sep_rel for f0 in new):
                new.append(float(freqs[i]))
        return new, s2

    def _proposals(self, vp: VarPro, x, centres, s2):
        """Each peak (``centres`` [Hz]) refined on a fine local grid: ``[(freq_hz, zeta, statistic), ...]``."""
        s, props = self.s, []
        span = s.scan_fine_span_rel
        for fc in centres:
            fl = fc * np.exp(np.linspace(-span, span, s.scan_fine_points))
            st = vp.scan(x, fl, s.scan_fine_zetas)[0]
            k, j = np.unravel_index(int(np.argmax(st)), st.shape)
            if all(abs(fl[k] / f0 - 1) > s.scan_proposal_sep_rel for f0, _, _ in props) and \
                    all(abs(fl[k] / f0 - 1) > s.tabu_sep_rel for f0 in self.tabu):
                props.append((float(fl[k]), s.scan_fine_zetas[j], float(st[k, j] / s2)))
        return props

    def search(self, vp: VarPro, x):
        """Add the modes the whitened residual shows (a scan over the frequency grid, the best
        peaks refined and added, then refit and prune) until ``scan_idle_rounds`` rounds add none."""
        s, idle = self.s, 0
        grids = self.scan_grids(vp)                 # vp's noise model is fixed over the rounds
        for _ in range(s.max_modes):
            R0 = _n_modes(x)
            if not s.scan or R0 >= s.max_modes:
                break
            peaks, s2 = self._peaks(vp, x, grids)
            if not peaks:
                break
            for f0, zt, st in self._proposals(vp, x, peaks, s2):
                self.added.append((f0, zt, st))
                self.tabu.append(f0)                # each frequency is proposed once
                x = _add(x, f0, zt)
            x = self.prune(vp, self.refine(vp, x))
            idle = idle + 1 if _n_modes(x) <= R0 else 0
            if idle >= s.scan_idle_rounds:
                break
        return x
