"""Modal gains from the measured current: the paper's eqs. (9)-(11).

Given the poles of the vibration modes (frequency and damping, e.g. from Prony's method),
each mode's response to the *measured* actuator current is a regressor (eq. (9))::

    y_r(n) = sum_k h_r(k) u(n - k)

and the gains minimise the squared error over the settle windows (eq. (10))::

    J = sum_{i=N}^{M} ( y(i) - sum_r c_r y_r(i) )^2

whose normal equations are eq. (11), ``[Y_{j,k}] c = [sum_i y(i) y_j(i)]`` with
``Y_{j,k} = sum_i y_j(i) y_k(i)``.  Several windows are pooled by summing their normal
equations.

Convention.  ``h_r`` is the ZOH discretisation, with the plant's fractional input delay, of the
unit mode ``1 / (s^2 + 2 zeta_r w_r s + w_r^2)`` (``w_r = 2 pi f_r`` the natural frequency,
ERRATA item 2), so the linear coefficient is ``c_r = k0 g_r`` [track/(A s^2)] and the modal
gain of :class:`identification.model.plant.ModalPlant` is ``g_r = c_r / k0``.  The discretisation is
*not* re-derived here: :func:`mode_filters` takes the matrices of the one discretisation
(:class:`identification.model.plant.DiscretePlant`) of a plant with these modes and turns each mode's
block into the transfer function that :func:`scipy.signal.lfilter` runs, which is exact for the
linear plant stepped at the log's rate.

:class:`VarPro` generalises eqs. (10)-(11) to the robust method's output-error fit: for given poles
and delay, all linear parameters (``k0``, bias, gains, per-segment initial conditions, run-out) are
one LS problem that is projected out (variable projection).  The noise model (:func:`ar_whitener`),
the run-out period (:func:`detect_period`, :func:`periodic_columns`) and the covariance
(:func:`sandwich_cov`) of that fit are here too.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from identification.model.plant import ModalPlant, Mode, block_tf

__all__ = ["mode_filter", "mode_filters", "fir_filter", "mode_response", "mode_regressors", "modal_gains",
           "GainFit", "VarPro", "ar_whitener", "detect_period", "periodic_columns", "sandwich_cov"]


def mode_filters(freqs_hz, zetas, dt: float, delay_s: float = 0.0):
    """Discrete transfer functions ``[(b, a), ...]`` (powers of ``z^-1``) of unit modes.

    Continuous mode ``e^{-s delay} / (s^2 + 2 zeta w s + w^2)``, ZOH on the input over ``dt`` with the
    fractional delay ``delay = (m + f) dt``, taken from :class:`identification.model.plant.DiscretePlant`
    of ``ModalPlant(k0=1, modes=[Mode(f_r, zeta_r, 1), ...])`` (one discretisation for all the
    modes; the modes' states are decoupled, so each mode's 2x2 block is its own discretisation)::

        x[k+1] = Phi x[k] + Gamma_new u[k-m] + Gamma_old u[k-m-1],   y = C x

    i.e. ``H_r(z) = C_r (zI - Phi_r)^-1 (Gamma_new,r z^-m + Gamma_old,r z^-(m+1))``.

    Parameters
    ----------
    freqs_hz, zetas : sequence of float
        Natural frequencies [Hz] and damping ratios [-].
    dt : float
        Sample period of the current [s].
    delay_s : float
        Input delay [s], fractional samples allowed.

    Returns
    -------
    list of (b, a)
        ``lfilter`` coefficients; each DC gain is ``1 / w_r^2`` [s^2].
    """
    freqs_hz, zetas = list(freqs_hz), list(zetas)
    if not freqs_hz:
        return []
    dp = ModalPlant(k0=1.0, modes=[Mode(float(f), float(z), 1.0) for f, z in zip(freqs_hz, zetas)],
                    delay_s=float(delay_s)).discretize(dt)
    m = dp.m
    out = []
    for r in range(len(freqs_hz)):
        i = slice(2 + 2 * r, 4 + 2 * r)
        Phi, C = dp.Phi[i, i], dp.C[i]
        nn, a = block_tf(Phi, C, dp.G_new[i])
        no, _ = block_tf(Phi, C, dp.G_old[i])
        b = np.zeros(m + 4)
        # (n1 z + n0) / (z^2 + ..) = (n1 z^-1 + n0 z^-2) / (1 + ..); shifted by m (new), m + 1 (old)
        b[m + 1:m + 3] += nn
        b[m + 2:m + 4] += no
        out.append((b, a))
    return out


def mode_filter(freq_hz: float, zeta: float, dt: float, delay_s: float = 0.0):
    """``(b, a)`` of one unit mode; see :func:`mode_filters`."""
    return mode_filters([freq_hz], [zeta], dt, delay_s)[0]


def _steady_filter(b, a, u, steady):
    if not steady:
        return signal.lfilter(b, a, u)
    # transposed direct form II state of a constant input u[0] held since -inf
    n = len(b) - 1
    a = np.r_[a, np.zeros(n + 1 - len(a))]
    g = b.sum() / a.sum()                           # DC gain
    zi = np.cumsum((b - g * a)[::-1])[::-1][1:] * u[0]
    return signal.lfilter(b, a, u, zi=zi)[0]


def mode_response(u, freq_hz: float, zeta: float, dt: float, delay_s: float = 0.0, steady: bool = True):
    """Response ``y_r = h_r * u`` of the unit mode to the current ``u`` (eq. (9)'s regressor).

    Parameters
    ----------
    u : array_like
        Measured current [A], one value per sample (held over the sample).
    freq_hz, zeta, dt, delay_s : float
        See :func:`mode_filters`.
    steady : bool
        Start in the steady state of a constant ``u[0]`` held since ``-inf`` (a drive at rest
        before the log starts); otherwise from zero state.

    Returns
    -------
    ndarray
        ``y_r(n)`` [track per unit ``c_r``], same length as ``u``.
    """
    return mode_regressors(u, [freq_hz], [zeta], dt, delay_s, steady)[:, 0]


def mode_regressors(u, freqs_hz, zetas, dt: float, delay_s: float = 0.0, steady: bool = True) -> np.ndarray:
    """Matrix of unit-mode responses, one column per mode: ``Y[:, r] = y_r = h_r * u`` (eq. (9)).

    ``u`` of shape ``(n, L)`` is a multirate current, ``u[k, j]`` held over the ``j``-th of ``L``
    equal sub-intervals of sample ``k`` (:meth:`identification.logs.seeklog.SeekLog.input_current`): the
    modes are then discretised at ``dt / L`` and sampled at the log's instants (exact hold)."""
    u = np.asarray(u, dtype=float)
    if u.ndim == 2:
        L = u.shape[1]
        fine = mode_regressors(u.reshape(-1), freqs_hz, zetas, dt / L, delay_s, steady)
        return np.asfortranarray(fine[::L])
    filters = mode_filters(freqs_hz, zetas, dt, delay_s)
    out = np.empty((len(u), len(filters)), order="F")
    for r, (b, a) in enumerate(filters):
        out[:, r] = _steady_filter(b, a, u, steady)
    return out


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


class GainFit:
    """Result of :func:`modal_gains`.

    Attributes
    ----------
    coef : ndarray
        ``c_r = k0 g_r`` [track/(A s^2)] (divide by ``k0`` for the :class:`Mode` gain).
    std : ndarray
        One standard deviation of ``coef`` (white-residual LS covariance).
    normal_matrix : ndarray
        ``[Y_{j,k}]`` of eq. (11).
    rhs : ndarray
        ``[sum_i y(i) y_j(i)]`` of eq. (11).
    residual_rms : float
        RMS of ``y - sum_r c_r y_r`` over the windows [track].
    n_samples : int
        Number of samples in the windows.
    """

    def __init__(self, coef, std, normal_matrix, rhs, residual_rms, n_samples):
        self.coef, self.std, self.normal_matrix, self.rhs = coef, std, normal_matrix, rhs
        self.residual_rms, self.n_samples = residual_rms, n_samples


def modal_gains(y, regressors, windows) -> GainFit:
    """LS modal gains over the settle windows: eqs. (10)-(11).

    Parameters
    ----------
    y : array_like, shape (n,)
        Measured output over the whole log [track] (the paper: the PES).
    regressors : array_like, shape (n, R)
        ``y_r(n)`` from :func:`mode_regressors` computed over the whole log (so each window sees
        the full current history, the ``sum_{k=0}^{inf}`` of eq. (9)).
    windows : sequence of (int, int)
        Half-open index ranges ``[N, M + 1)``; ``N`` is the settle point and ``M`` the last
        available sample of each seek (eq. (10)).

    Returns
    -------
    GainFit
        ``coef`` solves eq. (11), ``[Y_{j,k}] c = [sum_{i=N}^{M} y(i) y_j(i)]``, with the windows'
        sums added together.
    """
    y = np.asarray(y, dtype=float)
    X = np.asarray(regressors, dtype=float)
    if X.ndim == 1:
        X = X[:, None]
    R = X.shape[1]
    Ymat, rhs, yy, n = np.zeros((R, R)), np.zeros(R), 0.0, 0
    for i0, i1 in windows:
        Xi, yi = X[i0:i1], y[i0:i1]
        Ymat += Xi.T @ Xi                   # Y_{j,k} = sum_i y_j(i) y_k(i), eq. (11)
        rhs += Xi.T @ yi                    # sum_i y(i) y_j(i), eq. (11)
        yy += float(yi @ yi)
        n += i1 - i0
    if n == 0:
        raise ValueError("modal_gains: no samples in the windows")
    scale = np.sqrt(np.diag(Ymat))
    scale[scale == 0] = 1.0
    Ys = Ymat / np.outer(scale, scale)
    coef = np.linalg.lstsq(Ys, rhs / scale, rcond=None)[0] / scale
    # from the residuals themselves: yy - 2 c.rhs + c'Yc cancels catastrophically on exact data
    rss = float(sum(np.sum((y[i0:i1] - X[i0:i1] @ coef) ** 2) for i0, i1 in windows))
    dof = max(n - R, 1)
    cov = np.linalg.pinv(Ys) / np.outer(scale, scale) * rss / dof
    return GainFit(coef, np.sqrt(np.abs(np.diag(cov))), Ymat, rhs, float(np.sqrt(rss / n)), n)


# ------------------------------------------------------------------------- variable projection
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

    Nonlinear parameters ``x = [ln f_1..ln f_R, ln zeta_1..ln zeta_R, delay / dt]``; linear
    coefficients ``c = [k0, k0 bias, k0 g_1..k0 g_R]``; the nuisance columns are projected out once
    (Frisch-Waugh-Lovell: the same estimates and covariance as fitting ``rho`` jointly) and ``rho``
    is available from :meth:`nuisance_coef`.
    """

    def __init__(self, current_a, position_track, dt: float, segments, ar=None, nuisance=None):
        from identification.estimate.rigid import SegmentProjector, bias_response
        self.u = np.asarray(current_a, dtype=float)
        self.dt = float(dt)
        self.n = len(self.u)
        self.ar = None if ar is None else np.asarray(ar, dtype=float)
        p = 0 if self.ar is None else len(self.ar) - 1
        self.segments = [(a, b) for a, b in segments if b - a >= p + 8]
        if not self.segments:
            raise ValueError("VarPro: no segment long enough")
        self.starts = [a for a, _ in self.segments]
        self.proj = SegmentProjector([(a + p, b) for a, b in self.segments], offsets=[p] * len(self.segments))
        self.bias = bias_response(self.n, self.dt, self.starts)
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
        out = self.proj.project(rows)
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
        return np.linalg.lstsq(self.Z, self.y0 - X0 @ c, rcond=None)[0]

    def mode_columns(self, freqs, zetas, delay_samples):
        """Transformed unit-mode columns (the modes filter the whitened current)."""
        M = mode_regressors(self.uw, freqs, zetas, self.dt, delay_samples * self.dt)
        return self._project(self.proj.take(M))

    def columns(self, freqs, zetas, delay_samples):
        """Transformed ``[rigid, bias, modes...]`` columns."""
        from identification.estimate.rigid import zoh_rigid_response
        R = zoh_rigid_response(self.u, self.dt, delay_samples * self.dt, self.starts)
        return np.column_stack([self.transform(np.column_stack([R, self.bias])),
                                self.mode_columns(freqs, zetas, delay_samples)])

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
        c = np.linalg.lstsq(Rm, Q.T @ self.yt, rcond=None)[0] / s
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
        hf, hz = 1e-6, 1e-4                    # steps in ln f and ln zeta
        if R:
            cols = self.mode_columns(np.r_[f * np.exp(hf), f], np.r_[z, z * np.exp(hz)], d)
            D[:, :R] = (cols[:, :R] - X[:, 2:2 + R]) / hf * c[2:2 + R]
            D[:, R:2 * R] = (cols[:, R:] - X[:, 2:2 + R]) / hz * c[2:2 + R]
        h = 1e-3
        Xd = self.columns(f, z, d + h)
        D[:, 2 * R] = (Xd - X[:, :2 + R]) @ c[:2 + R] / h
        if full:
            return -np.column_stack([D, X]), r
        return -(D - Q @ (Q.T @ D))

    def fit(self, x0, lb, ub, max_nfev: int = 40):
        """Levenberg-Marquardt-like trust-region refinement of ``x`` within bounds."""
        from scipy.optimize import least_squares
        x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
        res = least_squares(self.residual, x0, jac=self.jacobian, bounds=(lb, ub), method="trf",
                            x_scale="jac", max_nfev=max_nfev, xtol=1e-9, ftol=1e-9)
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


# ------------------------------------------------------------------------- noise model, covariance
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
    a = np.linalg.lstsq(np.vstack(rows), -np.concatenate(rhs), rcond=None)[0]
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


def sandwich_cov(J, r, bounds, lags: int = 32, kind: str = "newey-west"):
    """Covariance of LS estimates with serially correlated residuals: ``B M B``, ``B = (J^T J)^-1``.

    ``J`` (rows x params) and ``r`` are stacked segments with row ``bounds``.  ``kind="newey-west"``:
    ``M = sum_{|l| <= lags} (1 - |l|/(lags+1)) sum_i g_i g_{i+l}^T`` over pairs within a segment
    (``g_i = r_i J_i``, Bartlett weights); ``kind="cluster"``: ``M = sum_s G_s G_s^T`` with
    ``G_s = sum_{i in s} g_i`` (any correlation within a segment, none across; needs many more
    segments than parameters).  Returns ``(cov, cov_white)`` where ``cov_white = s^2 (J^T J)^-1`` is
    the plain Gauss-Newton covariance scaled by the residual variance.
    """
    s = np.linalg.norm(J, axis=0)
    s[s == 0] = 1.0
    Js = J / s
    B = np.linalg.pinv(Js.T @ Js)
    dof = max(len(r) - J.shape[1], 1)
    cov_white = B * float(r @ r) / dof
    G = Js * r[:, None]
    if kind == "cluster":
        Gs = np.add.reduceat(G, np.asarray(bounds[:-1], dtype=int), axis=0)
        k = len(Gs)
        cov = B @ (Gs.T @ Gs) @ B * (k / max(k - 1, 1)) * len(r) / dof
        return cov / np.outer(s, s), cov_white / np.outer(s, s)
    M = G.T @ G
    inner = np.asarray(bounds[1:-1], dtype=int)
    for lag in range(1, lags + 1):
        w = 1.0 - lag / (lags + 1.0)
        C = G[:-lag].T @ G[lag:]
        # remove the pairs (i, i + lag) that straddle a segment boundary
        idx = (inner[:, None] - np.arange(1, lag + 1)[None, :]).ravel()
        idx = np.unique(idx[(idx >= 0) & (idx + lag < len(r))])
        if len(idx):
            C -= G[idx].T @ G[idx + lag]
        M += w * (C + C.T)
    cov = B @ M @ B * len(r) / dof
    return cov / np.outer(s, s), cov_white / np.outer(s, s)
