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
gain of :class:`identification.plant.ModalPlant` is ``g_r = c_r / k0``.  The discretisation is
*not* re-derived here: :func:`mode_filter` takes the matrices of the one discretisation
(:class:`identification.plant.DiscretePlant`) of a one-mode plant and turns them into the
transfer function that :func:`scipy.signal.lfilter` runs, which is exact for the linear plant
stepped at the log's rate.

These regressors are also the linear step of the variable-projection fit in
:mod:`identification.identify` (the gains are projected out for given poles).
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from .plant import ModalPlant, Mode

__all__ = ["mode_filter", "mode_response", "mode_regressors", "modal_gains", "GainFit"]


def mode_filter(freq_hz: float, zeta: float, dt: float, delay_s: float = 0.0):
    """Discrete transfer function ``(b, a)`` (in powers of ``z^-1``) of the unit mode.

    Continuous mode ``e^{-s delay} / (s^2 + 2 zeta w s + w^2)`` [track per (track/(A s^2)) A],
    ZOH on the input over ``dt`` with the fractional delay ``delay = (m + f) dt``, taken from
    :class:`identification.plant.DiscretePlant` of ``ModalPlant(k0=1, modes=[Mode(f, zeta, 1)])``::

        x[k+1] = Phi x[k] + Gamma_new u[k-m] + Gamma_old u[k-m-1],   y = C x

    restricted to the mode's two states (the rigid states are decoupled), i.e.
    ``H(z) = C (zI - Phi)^-1 (Gamma_new z^-m + Gamma_old z^-(m+1))``.

    Parameters
    ----------
    freq_hz : float
        Natural frequency [Hz].
    zeta : float
        Damping ratio [-].
    dt : float
        Sample period of the current [s].
    delay_s : float
        Input delay [s], fractional samples allowed.

    Returns
    -------
    b, a : ndarray
        ``lfilter`` coefficients; the DC gain is ``1 / w^2`` [s^2].
    """
    dp = ModalPlant(k0=1.0, modes=[Mode(float(freq_hz), float(zeta), 1.0)],
                    delay_s=float(delay_s)).discretize(dt)
    Phi = dp.Phi[2:4, 2:4]
    gn, go, C = dp.G_new[2:4], dp.G_old[2:4], dp.C[2:4]
    # H(z) = (C adj(zI - Phi) G) / det(zI - Phi); det = z^2 - tr z + det
    a = np.array([1.0, -np.trace(Phi), np.linalg.det(Phi)])

    def num(g):  # C adj(zI - Phi) g = (C g) z + (C adj(-Phi) g)
        adj = np.array([[-Phi[1, 1], Phi[0, 1]], [Phi[1, 0], -Phi[0, 0]]])
        return np.array([C @ g, C @ adj @ g])          # coefficients of z^1, z^0

    m = dp.m
    b = np.zeros(m + 4)
    # (n1 z + n0) / (z^2 ...) = (n1 z^-1 + n0 z^-2) / (1 ...); shift by m (new) and m+1 (old)
    b[m + 1:m + 3] += num(gn)
    b[m + 2:m + 4] += num(go)
    return np.trim_zeros(b, "b") if np.any(b) else b[:1], a


def mode_response(u, freq_hz: float, zeta: float, dt: float, delay_s: float = 0.0, steady: bool = True):
    """Response ``y_r = h_r * u`` of the unit mode to the current ``u`` (eq. (9)'s regressor).

    Parameters
    ----------
    u : array_like
        Measured current [A], one value per sample (held over the sample).
    freq_hz, zeta, dt, delay_s : float
        See :func:`mode_filter`.
    steady : bool
        Start in the steady state of a constant ``u[0]`` held since ``-inf`` (a drive at rest
        before the log starts); otherwise from zero state.

    Returns
    -------
    ndarray
        ``y_r(n)`` [track per unit ``c_r``], same length as ``u``.
    """
    u = np.asarray(u, dtype=float)
    b, a = mode_filter(freq_hz, zeta, dt, delay_s)
    n = max(len(a), len(b)) - 1
    if steady and n > 0:
        zi = signal.lfilter_zi(np.pad(b, (0, n + 1 - len(b))), np.pad(a, (0, n + 1 - len(a)))) * u[0]
        return signal.lfilter(b, a, u, zi=zi)[0]
    return signal.lfilter(b, a, u)


def mode_regressors(u, freqs_hz, zetas, dt: float, delay_s: float = 0.0, steady: bool = True) -> np.ndarray:
    """Matrix of :func:`mode_response` columns, one per mode: ``Y[:, r] = y_r`` (eq. (9))."""
    u = np.asarray(u, dtype=float)
    cols = [mode_response(u, f, z, dt, delay_s, steady) for f, z in zip(freqs_hz, zetas)]
    return np.column_stack(cols) if cols else np.zeros((len(u), 0))


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
    rss = max(yy - 2 * coef @ rhs + coef @ Ymat @ coef, 0.0)
    dof = max(n - R, 1)
    cov = np.linalg.pinv(Ys) / np.outer(scale, scale) * rss / dof
    return GainFit(coef, np.sqrt(np.abs(np.diag(cov))), Ymat, rhs, float(np.sqrt(rss / n)), n)
