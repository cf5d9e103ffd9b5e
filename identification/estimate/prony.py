"""Damped modes of free-decay windows: the modal/pole conversions, the paper's LS Prony (eqs. (4)-(7)),
amplitudes, variable-projection refinement and the Cramér–Rao bound.

A *window* is a 1-D real array of equally spaced samples (e.g. PES after settling) that is a sum of
decaying modes plus white noise. All functions pool any number of windows that share the same poles
but have their own amplitudes and phases. Discrete poles ``z`` relate to the continuous pole
``s = ln(z) * fs``; a mode is reported by its *natural* frequency ``|s| / 2 pi`` (Hz) and damping ratio
``zeta = -Re(s) / |s|`` (seed ERRATA item 2: the ``omega_r`` of the paper's eq. (1) is the *damped*
frequency). Only the pole with ``Im z > 0`` of each conjugate pair is reported.  The pooled matrix
pencil with automatic order selection is :mod:`identification.estimate.pencil`.

Amplitude convention: a window is modelled as ``h(k) = sum_r c_r z_r**k`` (k = 0 at the window start,
conjugate poles carry conjugate ``c``), so a real mode ``A e^{-sigma k/fs} cos(omega_d k/fs + phi)`` has
``A = 2|c_r|`` and ``phi = arg c_r``. :attr:`PoleEstimate.amplitude` is this real amplitude ``A``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from identification.estimate.linalg import lstsq, white_cov

__all__ = ["PoleEstimate", "z_to_modal", "modal_to_z", "damped_sinusoid", "damped_basis", "real_basis",
           "ls_prony", "fit_amplitudes", "refine_poles", "crb_modes", "crb_damped_sinusoid", "snr_db"]


@dataclass(frozen=True)
class PoleEstimate:
    """One identified mode: natural frequency (Hz), damping ratio, discrete pole (Im z > 0),
    mean real amplitude ``2|c|`` over windows, mean per-window energy ``sum_k x_r(k)**2`` of the mode."""
    freq_hz: float
    zeta: float
    z: complex
    amplitude: float
    energy: float


# ----------------------------------------------------------------------------------- conversions
def z_to_modal(z, fs):
    """Natural frequency (Hz) and damping ratio of discrete pole(s) ``z``: ``s = ln(z) fs``,
    ``f_n = |s| / 2 pi``, ``zeta = -Re(s) / |s|`` (not the paper's ``zeta`` of eq. (1); ERRATA item 2)."""
    s = np.log(np.asarray(z, dtype=complex)) * fs
    wn = np.abs(s)
    with np.errstate(invalid="ignore", divide="ignore"):
        zeta = np.where(wn > 0, -s.real / np.where(wn > 0, wn, 1.0), 1.0)
    return wn / (2 * np.pi), zeta


def modal_to_z(freq_hz, zeta, fs):
    """Discrete pole with ``Im z >= 0`` of a mode with natural frequency ``freq_hz`` and damping ``zeta`` (< 1)."""
    wn = 2 * np.pi * np.asarray(freq_hz, dtype=float)
    zeta = np.asarray(zeta, dtype=float)
    return np.exp((-zeta * wn + 1j * wn * np.sqrt(1 - zeta ** 2)) / fs)


def damped_sinusoid(n, fs, freq_hz, zeta, amplitude=1.0, phase=0.0):
    """``A e^{-zeta w_n t} cos(w_d t + phase)`` at ``t = k / fs``, ``k = 0..n-1`` (w_d = w_n sqrt(1 - zeta^2))."""
    wn = 2 * np.pi * freq_hz
    t = np.arange(n) / fs
    return amplitude * np.exp(-zeta * wn * t) * np.cos(wn * np.sqrt(1 - zeta ** 2) * t + phase)


def _as_windows(windows, min_len=1):
    if isinstance(windows, np.ndarray) and windows.ndim == 1:
        windows = [windows]
    out = [np.asarray(w, dtype=float).ravel() for w in windows]
    return [w for w in out if len(w) >= min_len]


def _pole_array(poles):
    """Complex z from an array or a sequence of :class:`PoleEstimate`."""
    if isinstance(poles, np.ndarray):
        return poles.astype(complex).ravel()
    items = poles if np.iterable(poles) else [poles]
    return np.array([p.z if isinstance(p, PoleEstimate) else p for p in items], dtype=complex)


def damped_basis(n: int, decay, theta) -> np.ndarray:
    """Real regressors ``[e^{-a_r k} cos(theta_r k), e^{-a_r k} sin(theta_r k)]`` (one cos/sin pair per
    mode, interleaved), ``k = 0..n-1``; ``a_r`` the decay per sample and ``theta_r`` the damped angle
    per sample [rad] (pole ``z_r = e^{-a_r + j theta_r}``)."""
    k = np.arange(n)[:, None]
    decay, theta = np.atleast_1d(decay), np.atleast_1d(theta)
    env = np.exp(-decay * k)
    out = np.empty((n, 2 * len(theta)))
    out[:, 0::2] = env * np.cos(theta * k)
    out[:, 1::2] = env * np.sin(theta * k)
    return out


def real_basis(n: int, zs):
    """Real regressors of poles ``zs`` (Im z >= 0): a cos/sin pair per complex pole
    (:func:`damped_basis`), one column ``z**k`` per real pole.  Returns ``(Phi, owner)`` with
    ``owner[j]`` the index of the pole of column ``j``."""
    cols, owner = [], []
    for i, z in enumerate(zs):
        if abs(z.imag) > 1e-12:
            cols.append(damped_basis(n, -np.log(np.abs(z)), np.angle(z)))
            owner += [i, i]
        else:
            cols.append((z.real ** np.arange(n))[:, None])
            owner.append(i)
    return np.hstack(cols) if cols else np.zeros((n, 0)), np.array(owner, dtype=int)


# ----------------------------------------------------------------------------------- LS Prony
def ls_prony(windows, order_pairs, fs):
    """The paper's least-squares Prony method (Section 2, eqs. (4)-(7)).

    For ``n = order_pairs`` modes the characteristic polynomial ``sum_{k=0}^{2n} b_k z^k`` of eq. (4)
    (``b_{2n} = 1``) annihilates the free response (eq. (5)); its coefficients minimise eq. (6), i.e.
    solve the normal equations of eq. (7), ``[H_{j,k}] b = -[H_{j,2n}]`` (j, k = 0..2n-1) with
    ``H_{j,k} = sum_i h(i+j) h(i+k)``. Several windows are pooled by summing their ``H`` matrices (each
    window's sum over i runs to its own ``M = N - 2n - 1``). The poles are the roots of eq. (4).

    Note (ERRATA item 2): in eq. (1) ``omega_r`` is the damped frequency; convert a pole with
    :func:`z_to_modal` (``s = ln(z) fs``, ``f_n = |s|/2 pi``, ``zeta = -Re(s)/|s|``). The plain LS
    solution is biased in noise (the equation error is not white); see :func:`identification.estimate.pencil.matrix_pencil`.

    Parameters
    ----------
    windows : array_like or sequence of array_like
        One window or several (windows shorter than ``2n + 1`` are skipped).
    order_pairs : int
        Number of mode pairs ``n``; the polynomial order is ``2n``.
    fs : float
        Sample rate (Hz); kept for a uniform signature (the poles are discrete).

    Returns
    -------
    numpy.ndarray of complex, shape (2n,)
        All roots ``x_r`` of eq. (4) (conjugate pairs and possibly real roots).
    """
    p = 2 * int(order_pairs)
    if p < 2:
        raise ValueError("order_pairs must be >= 1")
    ws = _as_windows(windows, p + 1)
    if not ws:
        raise ValueError(f"ls_prony needs a window of at least {p + 1} samples")
    H = np.zeros((p + 1, p + 1))
    for h in ws:
        X = np.lib.stride_tricks.sliding_window_view(h, p + 1)   # row i = h(i..i+2n)
        H += X.T @ X                                              # H_{j,k} = sum_i h(i+j) h(i+k), eq. (7)
    b = lstsq(H[:p, :p], -H[:p, p])
    return np.roots(np.r_[1.0, b[::-1]])                          # eq. (4), highest power first


# ----------------------------------------------------------------------------------- amplitudes, refinement
def fit_amplitudes(window, poles, fs):
    """Complex amplitudes ``c_r`` of ``h(k) = sum_r c_r z_r**k`` by LS on the Vandermonde matrix (the
    paper's amplitude step after eq. (7)).

    Parameters
    ----------
    window : array_like
        Samples ``h(0..N-1)``.
    poles : array_like of complex or sequence of PoleEstimate
        Discrete poles. For a real window, the conjugate of any complex pole that is not in the set is
        added to the fit (so upper-half-plane poles alone are enough); its amplitude is ``conj(c_r)``.
    fs : float
        Sample rate (Hz); kept for a uniform signature (the poles are discrete).

    Returns
    -------
    numpy.ndarray of complex
        ``c_r`` for the given poles, in their order; the real-mode amplitude is ``2 |c_r|``, phase ``arg c_r``.
    """
    h = np.asarray(window).ravel()
    z = _pole_array(poles)
    full = list(z)
    if np.isrealobj(h):
        for zr in z:
            if abs(zr.imag) > 1e-12 and not np.any(np.isclose(np.conj(zr), full, rtol=0, atol=1e-12)):
                full.append(np.conj(zr))
    V = np.power.outer(np.asarray(full), np.arange(len(h))).T
    c = lstsq(V, h.astype(complex))
    return c[:len(z)]


def refine_poles(windows, fs, poles, max_nfev=200):
    """Variable-projection (ML in white noise) refinement of complex poles over pooled windows.

    Minimises ``sum_w || w - Phi_w(z) Phi_w(z)^+ w ||^2`` over the poles, the per-window real cos/sin
    amplitudes being projected out (Golub–Pereyra), with Levenberg–Marquardt on
    ``(alpha_r, theta_r)``, ``z_r = exp(-alpha_r + j theta_r)``.

    Parameters
    ----------
    windows : array_like or sequence of array_like
    fs : float
        Sample rate (Hz); kept for a uniform signature.
    poles : array_like of complex or sequence of PoleEstimate
        Starting poles; only those with ``Im z > 0`` are used (one per mode).

    Returns
    -------
    numpy.ndarray of complex
        Refined poles (``Im z > 0``), same order as the used inputs.
    """
    ws = _as_windows(windows, 2)
    z0 = _pole_array(poles)
    z0 = z0[z0.imag > 0]
    m = len(z0)
    if m == 0:
        return z0
    x0 = np.r_[-np.log(np.abs(z0)), np.angle(z0)]

    def resid(x):
        out = []
        for w in ws:
            Phi = damped_basis(len(w), x[:m], x[m:])
            out.append(w - Phi @ lstsq(Phi, w))
        return np.concatenate(out)

    r = least_squares(resid, x0, method="lm" if sum(map(len, ws)) >= 2 * m else "trf",
                      x_scale="jac", max_nfev=max_nfev)
    return np.exp(-r.x[:m] + 1j * r.x[m:])


# ----------------------------------------------------------------------------------- Cramér–Rao bound
def crb_modes(n, fs, freqs_hz, zetas, amplitudes, phases, sigma):
    """CRB (std) of natural frequency (Hz) and damping ratio of each mode of ``sum_r A_r e^{-a_r t}
    cos(w_r t + phi_r)``, ``t = k/fs``, k = 0..n-1, in white Gaussian noise of std ``sigma``.

    Fisher information ``J^T J / sigma^2`` of ``(A_r, phi_r, w_r, a_r)`` (``w_r`` damped frequency,
    ``a_r`` decay rate, analytic derivatives), inverted, then mapped to ``(f_n, zeta)`` with the Jacobian
    of ``f_n = sqrt(w^2 + a^2) / 2 pi``, ``zeta = a / sqrt(w^2 + a^2)``.

    Returns
    -------
    std_freq_hz, std_zeta : numpy.ndarray
    """
    f, zt, A, ph = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (freqs_hz, zetas, amplitudes, phases))
    t = np.arange(n) / fs
    wn = 2 * np.pi * f
    a, wd = zt * wn, wn * np.sqrt(1 - zt ** 2)
    cols = []
    for Ar, ar, wr, pr in zip(A, a, wd, ph):
        e, c, s = np.exp(-ar * t), np.cos(wr * t + pr), np.sin(wr * t + pr)
        cols += [e * c, -Ar * e * s, -Ar * t * e * s, -Ar * t * e * c]
    J = np.column_stack(cols)
    C = white_cov(J, sigma2=sigma ** 2)
    sf, sz = [], []
    for r in range(len(f)):
        G = np.array([[wd[r] / (2 * np.pi * wn[r]), a[r] / (2 * np.pi * wn[r])],
                      [-a[r] * wd[r] / wn[r] ** 3, wd[r] ** 2 / wn[r] ** 3]])
        Cr = G @ C[4 * r + 2:4 * r + 4, 4 * r + 2:4 * r + 4] @ G.T
        sf.append(np.sqrt(Cr[0, 0]))
        sz.append(np.sqrt(Cr[1, 1]))
    return np.array(sf), np.array(sz)


def crb_damped_sinusoid(n, fs, freq_hz, zeta, amplitude, sigma, phase=0.0):
    """Cramér–Rao bound (std) of natural frequency (Hz) and damping ratio for ONE real damped sinusoid
    ``x(k) = A e^{-a k/fs} cos(w_d k/fs + phi)`` (``a = zeta w_n``, ``w_d = w_n sqrt(1-zeta^2)``), n samples,
    white Gaussian noise of std ``sigma``; see :func:`crb_modes`.

    Returns
    -------
    std_freq_hz, std_zeta : float
    """
    sf, sz = crb_modes(n, fs, [freq_hz], [zeta], [amplitude], [phase], sigma)
    return float(sf[0]), float(sz[0])


def snr_db(amplitude, zeta, freq, n, fs, sigma):
    """Per-record SNR ``10 log10(E / (n sigma^2))`` of a damped sinusoid in white noise of std ``sigma``.

    ``E = (A^2 / 2) sum_{k<n} e^{-2 zeta w_n k / fs}`` is the signal energy averaged over the phase
    (mean signal power over the record divided by the noise variance). Arrays of modes are summed
    (energies add, cross terms average out over independent phases).
    """
    A, z, f = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (amplitude, zeta, freq))
    t = np.arange(n) / fs
    E = sum(0.5 * Ar ** 2 * np.sum(np.exp(-2 * zr * 2 * np.pi * fr * t)) for Ar, zr, fr in zip(A, z, f))
    return float(10 * np.log10(E / (n * sigma ** 2)))
