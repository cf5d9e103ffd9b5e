"""Residual vibration that a current sequence leaves in unit-gain modes the model may lack.

A lightly damped mode ``k0 g / (s^2 + 2 zeta w s + w^2)`` at ``f`` excited by the sub-step current
``i(l)`` (sample rate ``L fs``) rings after the seek with a complex amplitude proportional to the
discrete-time Fourier transform of ``i`` at ``f``; these maps give that residual (in tracks) for a
grid of frequencies, as matrices for the design QP's guard rows and as sums for reports.  Used by
:mod:`seekopt.design.qp` and :mod:`seekopt.design.guard`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["mode_residual_phasors", "mode_residuals", "dtft", "mode_residual_rows", "hf_guard_matrix"]


def mode_residual_phasors(k0: float, fs: float, L: int, nsub: int, freqs_hz, gains=1.0) -> np.ndarray:
    """Complex map from the sub-step current sequence to the residual vibration of unmodelled modes.

    A mode ``k0 g / (s^2 + w^2)`` (undamped: conservative) driven by the ZOH current ``i_m``
    on sub-steps of ``h = 1/(L fs)`` is left vibrating with complex amplitude::

        z(w) = k0 g |1 - exp(-j w h)| / w^2 * sum_m i_m exp(-j w m h)        [track]

    Parameters
    ----------
    freqs_hz : array_like
        Mode frequencies [Hz] (any band: near and above Nyquist, inside controller notches...).
    gains : float or array_like
        Mode gain(s) relative to the rigid body, one per frequency or one for all.

    Returns
    -------
    E : (nf, nsub) complex ndarray
        ``z = E @ i`` [track] for sub-step currents ``i`` [A], ``m < nsub``.
    """
    wt, wh = _mode_weights(k0, fs, L, freqs_hz, gains)
    return wt[:, None] * np.exp(-1j * np.outer(wh, np.arange(int(nsub))))


def _mode_weights(k0, fs, L, freqs_hz, gains):
    """``(k0 g |1 - exp(-j w h)| / w^2, w h)`` per frequency of :func:`mode_residual_phasors`."""
    h = 1.0 / (L * fs)
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    g = np.broadcast_to(np.asarray(gains, dtype=float), f.shape)
    w = 2 * np.pi * f
    return k0 * g * np.abs(1 - np.exp(-1j * w * h)) / w ** 2, w * h


def mode_residuals(k0: float, fs: float, L: int, current_sub, freqs_hz, gains=1.0) -> np.ndarray:
    """``mode_residual_phasors(k0, fs, L, len(i), freqs_hz, gains) @ i`` for one current sequence
    ``i`` [A] without forming the ``(nf, len(i))`` matrix: the sum over sub-steps ``m = a B + b``
    is split as ``sum_a exp(-j w h a B) sum_b i_(aB+b) exp(-j w h b)`` (``B ~ sqrt(len(i))``
    complex exponentials per frequency instead of ``len(i)``; the same sum up to rounding)."""
    wt, wh = _mode_weights(k0, fs, L, freqs_hz, gains)
    return wt * dtft(current_sub, wh)


def dtft(x, wh) -> np.ndarray:
    """``sum_m x_m exp(-j wh m)`` for each normalised angular frequency ``wh`` [rad/sample].

    The sum over ``m = a B + b`` is split as ``sum_a exp(-j wh a B) sum_b x_(aB+b) exp(-j wh b)``
    with ``B ~ sqrt(len(x))``: ``2 sqrt(len(x))`` complex exponentials per frequency instead of
    ``len(x)`` (the same sum up to rounding)."""
    x = np.asarray(x, dtype=float).ravel()
    wh = np.atleast_1d(np.asarray(wh, dtype=float))
    B = max(int(np.ceil(np.sqrt(x.size))), 1)
    nA = max(-(-x.size // B), 1)
    blocks = np.zeros(nA * B)
    blocks[:x.size] = x
    inner = np.exp(-1j * np.outer(wh, np.arange(B))) @ blocks.reshape(nA, B).T       # (nf, nA)
    outer = np.exp(-1j * np.outer(wh * B, np.arange(nA)))                           # (nf, nA)
    return np.sum(inner * outer, axis=1)


def mode_residual_rows(E: np.ndarray, npoly: int = 4) -> np.ndarray:
    """Linear rows bounding the complex residuals ``E @ i``: for each frequency ``npoly`` rows
    ``Re(exp(j theta) z)`` (theta = 0, pi/npoly, ...); bounding them by ``tol`` bounds
    ``|z| <= tol / cos(pi / (2 npoly))``.  Returns ``(nf * npoly, nsub)`` rows."""
    th = np.arange(npoly) * np.pi / npoly
    return (E[:, None, :] * np.exp(1j * th)[None, :, None]).real.reshape(-1, E.shape[1])


def hf_guard_matrix(k0: float, fs: float, L: int, nsub: int, f_lo: float, f_hi: float,
                    gain: float = 1.0, spacing_hz: float | None = None, npoly: int = 4):
    """Guard rows for unmodelled modes of gain ``gain`` in ``[f_lo, f_hi]`` [Hz] on a grid of
    ``spacing_hz`` (default ``fs / 64``): :func:`mode_residual_rows` of
    :func:`mode_residual_phasors` (arbitrary bands: :mod:`seekopt.design.guard`).

    Returns
    -------
    G : (nf * npoly, nsub) ndarray
        Rows acting on the sub-step currents ``i_m`` [A], ``m < nsub``.
    freqs : (nf,) ndarray
    """
    spacing = spacing_hz or fs / 64.0
    freqs = np.arange(f_lo, f_hi + 0.5 * spacing, spacing)
    return mode_residual_rows(mode_residual_phasors(k0, fs, L, nsub, freqs, gain), npoly), freqs
