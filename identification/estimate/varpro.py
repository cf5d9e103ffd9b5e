"""Variable projection for the robust method's output-error fit, and its noise model.

:class:`VarPro` generalises the paper's eqs. (10)-(11) (:mod:`identification.estimate.gains`) to the
robust method: for given poles and delay, all linear parameters (``k0``, bias, gains, per-segment
initial conditions, run-out) are one LS problem that is projected out.  The noise model
(:func:`ar_whitener`, :func:`fir_filter`) and the run-out period (:func:`detect_period`,
:func:`periodic_columns`) are here too; the covariance is :func:`identification.estimate.linalg.sandwich_cov`.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from identification.estimate.gains import mode_regressors
from identification.estimate.linalg import SegmentProjector, lstsq
from identification.estimate.rigid import bias_response, zoh_rigid_response

__all__ = ["VarPro", "fir_filter", "ar_whitener", "detect_period", "periodic_columns"]


class VarPro:
    """Output-error fit of position to current over seek segments, linear parameters projected out.

    The model of the measured position on each segment ``[i0, i1)`` is::

        y = k0 R_delay + (k0 bias) B + sum_r (k0 g_r) y_r(f_r, zeta_r, delay) + Z rho + p0_s + v0_s t

    ``R_delay`` the unit-``k0`` ZOH rigid response with the delay restarted at ``i0``
    (:func:`identification.estimate.rigid.zoh_rigid_response`), ``B = t^2/2`` the unit-force bias response,
    ``y_r`` the unit mode responses over the whole log (eq. (9), :func:`mode_regressors`), ``Z``
    optional nuisance columns (e.g. run-out harmonics) and ``p0_s, v0_s`` each segment's initial
    position and velocity.  For given nonlinear parameters the linear ones come from one LS (the
    generalisation of eqs. (10)-(11) to all linear parameters); the data and every column are first
    filtered by the whitening FIR ``ar = [1, a_1..a_p]`` (prediction-error form), restricted to the
    fit rows (each segment minus its first ``p`` samples, where the filter would mix segments) and
    projected orthogonally to the per-segment ``[1, t]`` (an affine signal stays affine under an
    FIR filter, so this removes ``p0_s, v0_s`` exactly).

    With ``residual_hz > 0`` the model has one more column, the *residual compliance* of the modes
    the model does not hold: every mode far above the fitted ones (or above Nyquist) responds to the
    seek current quasi-statically, ``g / w^2`` times the delayed current, and without a term of its
    own that compliance is taken up by the gains and damping of the highest fitted modes (on the
    50.4 kHz test drive a missed 19.5 kHz mode of gain-to-std 5 moved the 14.8 kHz mode's gain by
    4.7 of its std on average, and the 7.8 / 10.6 kHz modes' by about 2).  The column is the response of
    an overdamped unit mode (damping :attr:`RESIDUAL_ZETA`) at ``residual_hz`` scaled by its
    ``w^2`` -- the delayed, held current smoothed over a fraction of a sample, through the one
    discretisation like every mode (modal analysis's "upper residual").

    Nonlinear parameters ``x = [ln f_1..ln f_R, ln zeta_1..ln zeta_R, delay / dt]``; linear
    coefficients ``c = [k0, k0 bias, k0 g_1..k0 g_R(, k0 D)]`` (``D`` the residual compliance
    [s^2]: ``k0 D u`` track for a held current ``u``); the nuisance columns are projected out once
    (Frisch-Waugh-Lovell: the same estimates and covariance as fitting ``rho`` jointly) and ``rho``
    is available from :meth:`nuisance_coef`.
    """

    #: finite-difference steps of :meth:`jacobian`: in ln f [-], ln zeta [-] and the delay [samples]
    STEP_LN_FREQ, STEP_LN_ZETA, STEP_DELAY_SAMPLES = 1e-6, 1e-4, 1e-3
    #: solver tolerances of :meth:`fit` (relative change of x and of the cost) [-]
    XTOL = FTOL = 1e-9
    #: damping ratio of the residual-compliance column's overdamped mode [-]
    RESIDUAL_ZETA = 0.7

    def __init__(self, current_a, position_track, dt: float, segments, ar=None, nuisance=None,
                 residual_hz: float = 0.0):
        self.u = np.asarray(current_a, dtype=float)
        self.residual_hz = float(residual_hz)
        self.dt = float(dt)
        self.n = len(self.u)
        self.ar = None if ar is None else np.asarray(ar, dtype=float)
        p = 0 if self.ar is None else len(self.ar) - 1
        self.segments = [(a, b) for a, b in segments if b - a >= p + 8]
        if not self.segments:
            raise ValueError("VarPro: no segment long enough")
        self.starts = [a for a, _ in self.segments]
        self.proj = SegmentProjector([(a + p, b) for a, b in self.segments], offsets=[p] * len(self.segments))
        # a whitener with a double root at z = 1 (sum h_j = sum j h_j = 0) maps every affine signal to 0:
        # the per-segment p0 + v0 t is then gone from the fit rows and is not projected out again
        # (that would also remove the bias column, a constant after the double difference)
        self.affine_free = self.ar is not None and \
            max(abs(self.ar.sum()), abs(np.arange(len(self.ar)) @ self.ar)) <= 1e-12 * np.abs(self.ar).sum() * len(self.ar)
        self.bias = bias_response(self.n, self.dt, self.starts)
        self.position = np.asarray(position_track, dtype=float)
        # whitening commutes with the (time-invariant) mode filters: whiten the current once
        self.uw = self.u if self.ar is None else fir_filter(self.ar, self.u, steady=True)
        self.Z = self.Zq = None
        self.y0 = self.transform(np.asarray(position_track, dtype=float))
        self.yt = self.y0
        if nuisance is not None:                # fixed columns: projected out once (Frisch-Waugh)
            self.Z = self.transform(nuisance)
            self.Zq = np.linalg.qr(self.Z)[0]
            self.yt = self.y0 - self.Zq @ (self.Zq.T @ self.y0)
        self.nfev = 0
        self._last = (None, None)

    def transform(self, cols):
        """Whiten, take the fit rows, project out the per-segment ``[1, t]`` (and the nuisance
        columns, once they are set)."""
        cols = np.asarray(cols, dtype=float)
        if self.ar is not None:
            cols = fir_filter(self.ar, cols)
        return self._project(self.proj.take(cols))

    def _project(self, rows):
        out = np.asarray(rows, dtype=float) if self.affine_free else self.proj.project(rows)
        if self.Zq is not None:
            out = out - self.Zq @ (self.Zq.T @ out)
        return out

    def nuisance_coef(self, x):
        """LS coefficients ``rho`` of the nuisance columns at ``x``:
        ``rho = Z^+ (y - X c)`` without the nuisance projection (Frisch-Waugh-Lovell)."""
        if self.Z is None:
            return np.zeros(0)
        _, c, _, _ = self.solve(x)
        f, z, d = self.unpack(x)
        Zq, self.Zq = self.Zq, None
        try:
            X0 = self.columns(f, z, d)
        finally:
            self.Zq = Zq
        return lstsq(self.Z, self.y0 - X0 @ c)

    def mode_columns(self, freqs, zetas, delay_samples):
        """Transformed unit-mode columns (the modes filter the whitened current)."""
        M = mode_regressors(self.uw, freqs, zetas, self.dt, delay_samples * self.dt)
        return self._project(self.proj.take(M))

    def residual_columns(self, u, delay_samples) -> np.ndarray:
        """The residual-compliance column of current ``u`` (``(n, 0)`` without one): the unit
        overdamped mode at ``residual_hz`` times ``w^2`` [track per unit ``k0 D`` -- i.e. A s^2]."""
        if not self.residual_hz:
            return np.zeros((len(u), 0))
        w2 = (2 * np.pi * self.residual_hz) ** 2
        return mode_regressors(u, [self.residual_hz], [self.RESIDUAL_ZETA], self.dt, delay_samples * self.dt) * w2

    def columns(self, freqs, zetas, delay_samples):
        """Transformed ``[rigid, bias, modes..., residual compliance]`` columns."""
        R = zoh_rigid_response(self.u, self.dt, delay_samples * self.dt, self.starts)
        return np.column_stack([self.transform(np.column_stack([R, self.bias])),
                                self.mode_columns(freqs, zetas, delay_samples),
                                self._project(self.proj.take(self.residual_columns(self.uw, delay_samples)))])

    @staticmethod
    def unpack(x, R=None):
        """``(freqs_hz, zetas, delay_samples)`` from ``x``."""
        R = (len(x) - 1) // 2 if R is None else R
        return np.exp(x[:R]), np.exp(x[R:2 * R]), float(x[2 * R])

    def solve(self, x):
        """``(X, c, r, Q)``: transformed columns, coefficients, residual, orthonormal column basis (the
        nuisance columns are projected out of everything, so ``c`` holds no ``rho``)."""
        key = np.asarray(x, dtype=float).tobytes()
        if self._last[0] == key:
            return self._last[1]
        f, z, d = self.unpack(x)
        X = self.columns(f, z, d)
        s = np.linalg.norm(X, axis=0)
        s[s == 0] = 1.0
        Q, Rm = np.linalg.qr(X / s)
        c = lstsq(Rm, Q.T @ self.yt) / s
        r = self.yt - X @ c
        self.nfev += 1
        self._last = (key, (X, c, r, Q))
        return X, c, r, Q

    def residual(self, x):
        return self.solve(x)[2]

    def jacobian(self, x, full: bool = False):
        """Kaufman's variable-projection Jacobian ``-P_perp (dX/dx_k) c`` (the derivative columns by
        finite differences of the affected regressors only).  ``full=True`` returns
        ``(J, r)`` with ``J = -[dX/dx c, X]``, the Jacobian with respect to ``[x, c]`` (the
        per-segment nuisance already projected out), for the covariance."""
        R = (len(x) - 1) // 2
        X, c, r, Q = self.solve(x)
        f, z, d = self.unpack(x)
        D = np.zeros((len(r), len(x)))
        hf, hz, h = self.STEP_LN_FREQ, self.STEP_LN_ZETA, self.STEP_DELAY_SAMPLES
        if R:
            cols = self.mode_columns(np.r_[f * np.exp(hf), f], np.r_[z, z * np.exp(hz)], d)
            D[:, :R] = (cols[:, :R] - X[:, 2:2 + R]) / hf * c[2:2 + R]
            D[:, R:2 * R] = (cols[:, R:] - X[:, 2:2 + R]) / hz * c[2:2 + R]
        Xd = self.columns(f, z, d + h)
        D[:, 2 * R] = (Xd - X) @ c / h
        if full:
            return -np.column_stack([D, X]), r
        return -(D - Q @ (Q.T @ D))

    def output_error(self, x):
        """The unwhitened output error ``v = y - X_raw c`` over the whole log [track], ``c`` this
        problem's LS coefficients at ``x`` (whitened when it has a noise model), ``X_raw`` the
        rigid, bias and mode responses to the measured current (per-segment initial conditions and
        run-out not removed).  Its segments, projected as in :meth:`transform`, are the noise the
        AR model must whiten at this estimate."""
        _, c, _, _ = self.solve(x)
        f, z, d = self.unpack(x)
        R = zoh_rigid_response(self.u, self.dt, d * self.dt, self.starts)
        M = mode_regressors(self.u, f, z, self.dt, d * self.dt)
        return self.position - np.column_stack([R, self.bias, M, self.residual_columns(self.u, d)]) @ c

    def fit(self, x0, lb, ub, max_nfev: int = 40):
        """Levenberg-Marquardt-like trust-region refinement of ``x`` within bounds."""
        x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
        res = least_squares(self.residual, x0, jac=self.jacobian, bounds=(lb, ub), method="trf",
                            x_scale="jac", max_nfev=max_nfev, xtol=self.XTOL, ftol=self.FTOL)
        return res.x

    def scan(self, x, freqs, zetas=(0.01, 0.05), chunk: int = 32):
        """RSS reduction ``(v . r)^2 / ||v||^2`` (``v = P_perp y_r``) of adding one unit mode
        ``(f, zeta)`` to the model at ``x``, for every grid point.  Returns ``(stat, r)`` with
        ``stat`` of shape ``(len(freqs), len(zetas))`` and the residual ``r`` at ``x``."""
        X, c, r, Q = self.solve(x)
        stat = np.zeros((len(freqs), len(zetas)))
        for j, zt in enumerate(zetas):
            for i in range(0, len(freqs), chunk):
                fs_ = freqs[i:i + chunk]
                V = self.mode_columns(fs_, [zt] * len(fs_), x[-1])
                V -= Q @ (Q.T @ V)
                stat[i:i + len(fs_), j] = (V.T @ r) ** 2 / np.maximum(np.einsum("ij,ij->j", V, V), 1e-300)
        return stat, r


def ar_whitener(resid_segments, order: int):
    """AR(``order``) prediction-error filter ``[1, a_1..a_p]`` by pooled LS (covariance method) over
    residual segments: the noise model of the prediction-error fit."""
    rows, rhs = [], []
    for e in resid_segments:
        if len(e) > order + 4:
            W = np.lib.stride_tricks.sliding_window_view(e, order + 1)
            rows.append(W[:, :-1][:, ::-1])
            rhs.append(W[:, -1])
    if not rows:
        return None
    a = lstsq(np.vstack(rows), -np.concatenate(rhs))
    return np.r_[1.0, a]


def detect_period(rows, r, periods=range(20, 2001), f_min: float = 4.0):
    """Period (samples) of a repeatable disturbance (run-out) in the residual ``r`` at log indices
    ``rows``: the period whose phase-bin means explain most variance per bin,
    ``F(P) = sum_b n_b mean_b^2 / (P sigma^2)`` (~1 without periodicity).  None if ``F < f_min``."""
    s2 = float(np.mean(r ** 2))
    best, fbest = None, f_min
    for P in periods:
        ph = rows % P
        cnt = np.bincount(ph, minlength=P)
        sm = np.bincount(ph, weights=r, minlength=P)
        ok = cnt > 0
        F = float(np.sum(sm[ok] ** 2 / cnt[ok])) / ok.sum() / s2
        if F > fbest:
            best, fbest = int(P), F
    return best, fbest


def periodic_columns(n: int, period: float, harmonics: int, offset: int = 0) -> np.ndarray:
    """``[cos(2 pi h k / P), sin(2 pi h k / P)]`` for ``h = 1..harmonics``, ``k = offset..offset+n-1``
    (run-out nuisance; ``k`` is the log's sample index)."""
    k = np.arange(offset, offset + n)
    cols = []
    for h in range(1, harmonics + 1):
        cols += [np.cos(2 * np.pi * h * k / period), np.sin(2 * np.pi * h * k / period)]
    return np.column_stack(cols)


def fir_filter(h, x, steady: bool = False) -> np.ndarray:
    """``y[k] = sum_j h[j] x[k - j]`` along axis 0, for 1-D or 2-D ``x``; before ``k = 0`` the input is
    0, or ``x[0]`` held since ``-inf`` if ``steady``."""
    x = np.asarray(x, dtype=float)
    p = len(h) - 1
    xp = np.concatenate([np.repeat(x[:1] * (1.0 if steady else 0.0), p, axis=0), x]) if p else x
    y = h[0] * xp[p:]
    for j in range(1, p + 1):
        y = y + h[j] * xp[p - j:len(xp) - j]
    return y
