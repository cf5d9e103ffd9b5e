"""Damped-mode estimation from free-decay windows: LS Prony, pooled matrix pencil, Cramér–Rao bound.

A *window* is a 1-D real array of equally spaced samples (e.g. PES after settling) that is a sum of
decaying modes plus white noise. All functions pool any number of windows that share the same poles
but have their own amplitudes and phases. Discrete poles ``z`` relate to the continuous pole
``s = ln(z) * fs``; a mode is reported by its *natural* frequency ``|s| / 2 pi`` (Hz) and damping ratio
``zeta = -Re(s) / |s|`` (seed ERRATA item 2: the ``omega_r`` of the paper's eq. (1) is the *damped*
frequency). Only the pole with ``Im z > 0`` of each conjugate pair is reported.

Amplitude convention: a window is modelled as ``h(k) = sum_r c_r z_r**k`` (k = 0 at the window start,
conjugate poles carry conjugate ``c``), so a real mode ``A e^{-sigma k/fs} cos(omega_d k/fs + phi)`` has
``A = 2|c_r|`` and ``phi = arg c_r``. :attr:`PoleEstimate.amplitude` is this real amplitude ``A``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

__all__ = ["PoleEstimate", "PencilDiagnostics", "z_to_modal", "modal_to_z", "damped_sinusoid",
           "ls_prony", "matrix_pencil", "fit_amplitudes", "refine_poles", "stabilisation_diagram",
           "crb_modes", "crb_damped_sinusoid", "snr_db"]


@dataclass(frozen=True)
class PoleEstimate:
    """One identified mode: natural frequency (Hz), damping ratio, discrete pole (Im z > 0),
    mean real amplitude ``2|c|`` over windows, mean per-window energy ``sum_k x_r(k)**2`` of the mode."""
    freq_hz: float
    zeta: float
    z: complex
    amplitude: float
    energy: float


@dataclass
class PencilDiagnostics:
    """What :func:`matrix_pencil` saw and decided.

    ``singular_values`` of the stacked Hankel matrix (shape ``hankel_shape``), ``order`` used (number of
    complex exponentials, 2 per mode), ``order_mdl`` (MDL's choice, None if the order was given),
    ``sv_noise`` (noise RMS per Hankel entry estimated from the singular values), ``sv_threshold``,
    ``sigma`` (noise std per sample from the LS fit residual), ``pencil`` (L), ``n_windows`` used,
    ``candidates`` (all pencil poles), ``rejected`` (list of ``(z, reason)``) and ``significance``
    (list of ``(z, T)``: the amplitude statistic of every pole that reached the amplitude test).
    """
    singular_values: np.ndarray
    order: int
    order_mdl: int | None
    sv_noise: float
    sv_threshold: float
    sigma: float
    pencil: int
    n_windows: int
    hankel_shape: tuple
    candidates: np.ndarray
    rejected: list = field(default_factory=list)
    significance: list = field(default_factory=list)


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
    solution is biased in noise (the equation error is not white); see :func:`matrix_pencil`.

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
    b = np.linalg.lstsq(H[:p, :p], -H[:p, p], rcond=None)[0]
    return np.roots(np.r_[1.0, b[::-1]])                          # eq. (4), highest power first


# ----------------------------------------------------------------------------------- matrix pencil
def _hankel_stack(ws, L):
    return np.vstack([np.lib.stride_tricks.sliding_window_view(w, L + 1) for w in ws])


def _svd(Y):
    """SVD of a tall matrix; through its R factor when it is much taller than wide (same s and V)."""
    if Y.shape[0] > 2 * Y.shape[1]:
        Y = np.linalg.qr(Y, mode="r")
    return np.linalg.svd(Y, full_matrices=False)


def _mdl(s, K, kmax):
    """Wax–Kailath MDL on the eigenvalues ``s**2`` of ``Y^T Y`` with K rows; returns argmin over 0..kmax."""
    lam = s ** 2
    P = len(lam)
    crit = []
    for k in range(kmax + 1):
        tail = lam[k:]
        ratio = np.exp(np.mean(np.log(tail))) / np.mean(tail)
        crit.append(-K * (P - k) * np.log(ratio) + 0.5 * k * (2 * P - k) * np.log(K))
    return int(np.argmin(crit))


def _pencil_poles(Vh, order):
    """Shift invariance of the rank-``order`` right singular subspace: eig(pinv(V1) V2)."""
    V = Vh[:order].conj().T
    return np.linalg.eigvals(np.linalg.lstsq(V[:-1], V[1:], rcond=None)[0])


def _real_basis(n, zs):
    """Real regressors of poles ``zs`` (Im z >= 0): cos/sin pair per complex pole, one column per real pole."""
    k = np.arange(n)
    cols, owner = [], []
    for i, z in enumerate(zs):
        if abs(z.imag) > 1e-12:
            env, th = np.abs(z) ** k, np.angle(z)
            cols += [env * np.cos(th * k), env * np.sin(th * k)]
            owner += [i, i]
        else:
            cols.append(z.real ** k)
            owner.append(i)
    return np.column_stack(cols) if cols else np.zeros((n, 0)), np.array(owner, dtype=int)


def matrix_pencil(windows, fs, order=None, max_order=24, pencil=None, *, min_len=32, noise_gate=1.6,
                  max_zeta=0.5, freq_range=None, keep_real=False, keep_unstable=False, amp_sigmas=4.0,
                  refine=False):
    """Pooled matrix-pencil (Hua–Sarkar) estimate of the damped modes common to several windows.

    The Hankel matrices ``Y_w[i, :] = w(i .. i+L)`` of all windows (same pencil parameter ``L``) are
    stacked vertically, ``Y = U S V^T``; the right singular vectors of the ``order`` largest singular
    values span ``{[1, z, ..., z^L]}`` of the poles, whose shift invariance ``V1 F = V2`` gives the poles
    as ``eig(F)`` (rank-truncated pencil).

    Order selection (``order=None``), on the stacked singular values ``s`` (K x P Hankel stack):

    1. ``k_mdl`` = Wax–Kailath MDL over ``k = 0..max_order`` (eigenvalues ``s**2``, K snapshots;
       singular values below ``1e-9 s_0`` are set to that numerical floor first);
    2. explicit noise floor: the noise RMS per Hankel entry is
       ``nu = sqrt(sum_{i>=k_mdl} s_i^2 / (K (P - k_mdl)))`` and white noise alone gives ``s_0 <~ nu (sqrt K + sqrt P)`` (Hankel noise exceeds this by at most ~1.5x,
       measured); the order is the number of ``s_i`` (i < k_mdl) above ``noise_gate * nu (sqrt K + sqrt P)``,
       rounded up to even (modes of a real signal come in pairs).

    Spurious-pole rejection (reason recorded in the diagnostics): ``|z| >= 1`` unless ``keep_unstable``;
    real poles and those whose damped frequency lies outside ``freq_range`` unless ``keep_real``;
    ``zeta > max_zeta``; and poles whose amplitude is not significant. For the last, all candidate poles
    (rejected ones too, so that they absorb what they model) are fitted by LS per window with real
    cos/sin regressors ``Phi_w``, the noise std ``sigma`` is taken from the pooled residual, and the
    statistic ``T = sum_w a_w^T C_w^{-1} a_w / (2 W)`` (``a_w`` the pole's cos/sin coefficients,
    ``C_w = sigma^2 (Phi_w^T Phi_w)^{-1}``) must reach ``amp_sigmas**2``. ``T ~ 1`` for noise at a fixed
    pole; for pencil poles fitted to white noise (forced order 2-12) it was measured at 99 % <= 10.5,
    max 14.8 (one window of 200) and max 6.3 (three windows), hence the default 16.

    Parameters
    ----------
    windows : array_like or sequence of array_like
        Free-decay windows sharing the poles; windows shorter than ``min_len`` are skipped.
    fs : float
        Sample rate (Hz).
    order : int, optional
        Number of complex exponentials (2 per mode). None: automatic (see above).
    max_order : int
        Upper bound for the automatic order (capped by the pencil size).
    pencil : int, optional
        Pencil parameter L; default ``N_min // 3`` of the shortest usable window.
    min_len : int
        Shortest usable window.
    noise_gate : float
        Factor on the white-noise singular-value edge for the automatic order.
    max_zeta : float
        Largest damping ratio reported.
    freq_range : (float, float), optional
        Band (Hz) of damped frequencies reported; default 1 % of Nyquist away from DC and Nyquist.
    keep_real, keep_unstable : bool
        Report real / out-of-band and unstable poles too.
    amp_sigmas : float
        Amplitude significance threshold (``T >= amp_sigmas**2``); 0 disables the test.
    refine : bool
        Polish the retained poles with :func:`refine_poles` (variable projection) before reporting.

    Returns
    -------
    poles : list of PoleEstimate
        Sorted by frequency.
    diagnostics : PencilDiagnostics
    """
    ws = _as_windows(windows, min_len)
    if not ws:
        raise ValueError(f"matrix_pencil: no window has at least {min_len} samples")
    n_min = min(len(w) for w in ws)
    L = int(pencil) if pencil is not None else max(n_min // 3, 2)
    if not 2 <= L <= n_min - 2:
        raise ValueError(f"pencil parameter {L} out of range for a {n_min}-sample window")
    Y = _hankel_stack(ws, L)
    K, P = Y.shape
    _, s, Vh = _svd(Y)
    kmax = max(0, min(int(max_order), P - 2, K - 1))
    sf = np.maximum(s, 1e-9 * s[0]) if s[0] > 0 else np.ones_like(s)
    order_mdl = None
    if order is None:
        order_mdl = _mdl(sf, K, kmax)
        nu = np.sqrt(np.sum(sf[order_mdl:] ** 2) / (K * (P - order_mdl)))
        thr = noise_gate * nu * (np.sqrt(K) + np.sqrt(P))
        order = int(np.sum(sf[:order_mdl] > thr))
        order = min(order + order % 2, kmax)
    else:
        order = int(order)
        if not 0 <= order <= P - 2:
            raise ValueError(f"order {order} must lie in 0..{P - 2} for pencil {L}")
        nu = np.sqrt(np.sum(sf[order:] ** 2) / (K * (P - order)))
        thr = noise_gate * nu * (np.sqrt(K) + np.sqrt(P))
    cand = _pencil_poles(Vh, order) if order > 0 else np.zeros(0, complex)
    diag = PencilDiagnostics(s, order, order_mdl, float(nu), float(thr), 0.0, L, len(ws), (K, P), cand)
    # one representative per conjugate pair (Im z >= 0)
    upper = cand[cand.imag > 1e-12]
    real = cand[np.abs(cand.imag) <= 1e-12].real.astype(complex)
    lo, hi = freq_range if freq_range is not None else (0.01 * fs / 2, 0.99 * fs / 2)
    keep = []
    for z in upper:
        fd = np.angle(z) * fs / (2 * np.pi)
        _, zeta = z_to_modal(z, fs)
        if abs(z) >= 1 and not keep_unstable:
            diag.rejected.append((z, "unstable"))
        elif not (lo <= fd <= hi) and not keep_real:
            diag.rejected.append((z, "near DC/Nyquist"))
        elif zeta > max_zeta:
            diag.rejected.append((z, f"zeta {float(zeta):.3g} > {max_zeta}"))
        else:
            keep.append(z)
    for z in real:
        (keep.append(z) if keep_real and (abs(z) < 1 or keep_unstable) else diag.rejected.append((z, "real")))
    keep = np.array(keep, dtype=complex)
    # amplitude significance: fit the kept poles plus all other candidates (they absorb what they model)
    others = np.array([z for z in np.r_[upper, real] if not np.any(z == keep)], dtype=complex)
    if refine and np.any(keep.imag > 0):
        keep = np.r_[refine_poles(ws, fs, keep[keep.imag > 0]), keep[keep.imag == 0]]
    fit_set = np.r_[keep, others]
    coefs, bases, rss, dof = [], [], 0.0, 0
    for w in ws:
        Phi, owner = _real_basis(len(w), fit_set)
        scale = np.linalg.norm(Phi, axis=0)
        scale[scale == 0] = 1.0
        c = np.linalg.lstsq(Phi / scale, w, rcond=None)[0] / scale
        rss += float(np.sum((w - Phi @ c) ** 2))
        dof += len(w) - Phi.shape[1]
        coefs.append(c)
        Gs = (Phi / scale).T @ (Phi / scale)
        try:
            Ginv = np.linalg.inv(Gs)
        except np.linalg.LinAlgError:
            Ginv = np.linalg.pinv(Gs)
        bases.append((Phi, owner, Ginv / np.outer(scale, scale)))
    dof -= 2 * len(fit_set)
    rms = np.sqrt(np.mean(np.concatenate(ws) ** 2))
    sigma = max(np.sqrt(rss / max(dof, 1)), 1e-12 * rms, 1e-300)
    diag.sigma = float(sigma)
    out = []
    for i, z in enumerate(keep):
        stat, amps, energies = 0.0, [], []
        for (Phi, owner, Ginv), c in zip(bases, coefs):
            idx = np.flatnonzero(owner == i)
            cov = sigma ** 2 * Ginv[np.ix_(idx, idx)]
            a = c[idx]
            stat += float(a @ np.linalg.lstsq(cov, a, rcond=None)[0])
            amps.append(np.linalg.norm(a))
            energies.append(float(np.sum((Phi[:, idx] @ a) ** 2)))
        stat /= len(idx) * len(ws)
        diag.significance.append((complex(z), stat))
        if stat < amp_sigmas ** 2:
            diag.rejected.append((z, f"amplitude T={stat:.3g} < {amp_sigmas ** 2:.3g}"))
            continue
        fn, zeta = z_to_modal(z, fs)
        out.append(PoleEstimate(float(fn), float(zeta), complex(z), float(np.mean(amps)),
                                float(np.mean(energies))))
    return sorted(out, key=lambda p: p.freq_hz), diag


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
    scale = np.linalg.norm(V, axis=0)
    scale[scale == 0] = 1.0
    c = np.linalg.lstsq(V / scale, h.astype(complex), rcond=None)[0] / scale
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
    ks = [np.arange(len(w))[:, None] for w in ws]

    def resid(x):
        env_a, th = x[:m], x[m:]
        out = []
        for w, k in zip(ws, ks):
            e = np.exp(-env_a * k)
            Phi = np.hstack([e * np.cos(th * k), e * np.sin(th * k)])
            out.append(w - Phi @ np.linalg.lstsq(Phi, w, rcond=None)[0])
        return np.concatenate(out)

    r = least_squares(resid, x0, method="lm" if sum(map(len, ws)) >= 2 * m else "trf",
                      x_scale="jac", max_nfev=max_nfev)
    return np.exp(-r.x[:m] + 1j * r.x[m:])


def stabilisation_diagram(windows, fs, orders, pencil=None, min_len=32):
    """Pooled matrix-pencil poles at each model order (one SVD), for a stabilisation diagram.

    Returns
    -------
    list of numpy.ndarray, shape (m_i, 2)
        For each ``orders[i]`` (number of complex exponentials) the stable poles with ``Im z > 0`` as
        rows ``(natural frequency Hz, damping ratio)`` sorted by frequency.
    """
    ws = _as_windows(windows, min_len)
    L = int(pencil) if pencil is not None else max(min(len(w) for w in ws) // 3, 2)
    Vh = _svd(_hankel_stack(ws, L))[2]
    out = []
    for o in orders:
        z = _pencil_poles(Vh, int(o)) if o > 0 else np.zeros(0, complex)
        z = z[(z.imag > 1e-12) & (np.abs(z) < 1)]
        fz = np.column_stack(z_to_modal(z, fs)) if len(z) else np.zeros((0, 2))
        out.append(fz[np.argsort(fz[:, 0])])
    return out


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
    C = np.linalg.inv(J.T @ J) * sigma ** 2
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
