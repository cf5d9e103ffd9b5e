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
(:class:`identification.model.discrete.DiscretePlant`) of a plant with these modes and turns each
mode's block into the transfer function (:func:`identification.model.discrete.block_tf`) that
:func:`scipy.signal.lfilter` runs, which is exact for the linear plant stepped at the log's rate; a
multirate current is run through the same discretisation at the sub-step period.

The robust method's output-error fit, which generalises eqs. (10)-(11) to all linear parameters,
is :class:`identification.estimate.varpro.VarPro`.
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from identification.estimate.linalg import lstsq, white_cov
from identification.model.discrete import block_tf
from identification.model.plant import ModalPlant, Mode

__all__ = ["mode_filters", "mode_response", "mode_regressors", "modal_gains", "GainFit"]


def mode_filters(freqs_hz, zetas, dt: float, delay_s: float = 0.0):
    """Discrete transfer functions ``[(b, a), ...]`` (powers of ``z^-1``) of unit modes.

    Continuous mode ``e^{-s delay} / (s^2 + 2 zeta w s + w^2)``, ZOH on the input over ``dt`` with the
    fractional delay ``delay = (m + f) dt``, taken from :class:`identification.model.discrete.DiscretePlant`
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
    n = sum(i1 - i0 for i0, i1 in windows)
    if n == 0:
        raise ValueError("modal_gains: no samples in the windows")
    Xw = np.concatenate([X[i0:i1] for i0, i1 in windows])
    yw = np.concatenate([y[i0:i1] for i0, i1 in windows])
    Ymat = Xw.T @ Xw                        # Y_{j,k} = sum_i y_j(i) y_k(i), eq. (11)
    rhs = Xw.T @ yw                         # sum_i y(i) y_j(i), eq. (11)
    coef = lstsq(Ymat, rhs)                 # eq. (11)
    r = yw - Xw @ coef                      # (from the residuals: yy - 2 c.rhs + c.Y.c cancels)
    cov = white_cov(Xw, r, dof=max(n - R, 1))
    return GainFit(coef, np.sqrt(np.abs(np.diag(cov))), Ymat, rhs, float(np.sqrt(float(r @ r) / n)), n)
