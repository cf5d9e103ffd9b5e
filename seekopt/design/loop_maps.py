"""The closed-loop convolution maps of the seek designs: the linear 2DOF loop ``u = u_ff + C (r - y)`` of one
plant as impulse responses from the one simulator (:func:`seekopt.drive.simulator.closed_loop_responses`),
turned into Toeplitz rows on demand (:class:`LoopMaps`, :func:`toeplitz_rows`; notes:
:mod:`seekopt.design.qp`).
"""
from __future__ import annotations

import numpy as np

from seekopt.drive.simulator import closed_loop_responses

__all__ = ["LoopMaps", "toeplitz_rows"]


def toeplitz_rows(h: np.ndarray, rows: np.ndarray, ncols: int) -> np.ndarray:
    """``T[i, j] = h[rows[i] - j]`` for ``rows[i] >= j`` else 0 (convolution rows).

    ``h`` may be ``(H,)`` or ``(H, L)``; for 2-D ``h`` the result has ``len(rows) * L``
    rows ordered ``(k, l)`` (sub-step ``l`` of sample ``rows[i]``).
    """
    rows = np.asarray(rows, dtype=int)
    idx = rows[:, None] - np.arange(ncols)[None, :]
    ok = idx >= 0
    idx = np.where(ok, idx, 0)
    if h.ndim == 1:
        return np.where(ok, h[idx], 0.0)
    L = h.shape[1]
    out = np.where(ok[:, :, None], h[idx], 0.0)          # (rows, ncols, L)
    return out.transpose(0, 2, 1).reshape(len(rows) * L, ncols)


class LoopMaps:
    """Impulse and step responses of the linear 2DOF loop of one plant (servo rate).

    Parameters
    ----------
    plant : ModalPlant
        Only its linear part is used (no bias, no nonlinear effects); ``hold_a = -bias_a``.
    controller : Controller
    horizon : int
        Samples of response computed.

    Attributes
    ----------
    y_u, y_r : (H,) ndarray
        Position per unit feedforward impulse [track/A] / unit reference impulse [track/track].
    i_u, i_r : (H, L) ndarray
        Sub-step currents per unit impulse [A/A], [A/track].
    s_yr, s_ir : ndarray
        Step responses to ``r = 1`` from sample 0 (cumulative sums).
    """

    def __init__(self, plant, controller, horizon: int):
        R = closed_loop_responses(plant, controller, int(horizon))
        self.horizon = int(horizon)
        self.L = int(controller.fast_multiple)
        self.y_u, self.y_r = R["y_uff"], R["y_r"]
        self.i_u, self.i_r = R["u_sub_uff"], R["u_sub_r"]
        self.s_yr = np.cumsum(self.y_r)
        self.s_ir = np.cumsum(self.i_r, axis=0)
        self.hold_a = -float(plant.bias_a)
        self.k0 = float(plant.k0)
        finite = all(np.all(np.isfinite(a)) for a in (self.y_u, self.y_r, self.i_u, self.i_r))
        if not finite or np.max(np.abs(self.y_r[-10:])) > 1e3:
            raise ValueError("closed loop of this plant and controller is unstable")

    def response(self, u, r, n: int, currents: bool = True):
        """``(y [track], i (n, L) [A] or None)``: the loop's position and sub-step currents (without the hold
        ``hold_a``) over ``n`` samples for feedforward ``u`` [A] and reference ``r`` [track] from rest at 0,
        by superposition of its impulse responses (``y = h_yu * u + h_yr * r``, ``i`` likewise); ``currents``
        False: ``i`` is None.  ``n`` at most :attr:`horizon`."""
        u, r = np.asarray(u, dtype=float)[:n], np.asarray(r, dtype=float)[:n]
        # response first: np.convolve sums in the order of its arguments when they are equally long
        y = np.convolve(self.y_u[:n], u)[:n] + np.convolve(self.y_r[:n], r)[:n]
        if not currents:
            return y, None
        i = np.stack([np.convolve(self.i_u[:n, l], u)[:n] + np.convolve(self.i_r[:n, l], r)[:n]
                      for l in range(self.L)], axis=1)
        return y, i

    def position_rows(self, rows, ncols):
        """``(T_yu, T_yr, s_yr[rows])`` for samples ``rows`` and ``ncols`` input samples."""
        rows = np.asarray(rows, dtype=int)
        return (toeplitz_rows(self.y_u, rows, ncols), toeplitz_rows(self.y_r, rows, ncols),
                self.s_yr[rows])

    def current_rows(self, nsamples, ncols):
        """``(T_iu, T_ir, s_ir)`` for the ``L`` sub-steps of samples ``0..nsamples-1``."""
        rows = np.arange(int(nsamples))
        return (toeplitz_rows(self.i_u, rows, ncols), toeplitz_rows(self.i_r, rows, ncols),
                self.s_ir[rows].ravel())
