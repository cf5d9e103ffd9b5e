"""The vectorised linear fast path of :class:`identification.model.discrete.DiscretePlant`.

The stepping engine's ``Phi`` is block diagonal (rigid body, each mode) apart from the
amplifier-lag column, so the linear part's output is a sum of 2nd-order filters, each the
block's own recursion run by :func:`scipy.signal.lfilter` (no new discretisation: the
coefficients are the engine's ``Phi``, ``Gamma`` and ``C`` through :func:`~identification.model.discrete.block_tf`)::

    z_s[k+1] = Phi_s z_s[k] + w_s[k],   z_s[0] = x0_s,   y_s[k] = C_s z_s[k]
    w[k] = Gamma_new c[k-m] + Gamma_old c[k-m-1] + Gamma_f f[k] + Phi[:, lag] x_lag[k]
    x_lag[k+1] = Phi[lag, lag] x_lag[k] + w_lag[k]

Used by :meth:`DiscretePlant.linear_response`.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

__all__ = ["block_responses"]


def block_responses(dp, c, f, x0, hist0) -> np.ndarray:
    """Per-block outputs ``(N, nblocks)`` of ``dp`` for command ``c`` and force ``f`` [A].

    Parameters
    ----------
    dp : DiscretePlant
    c, f : (N,) ndarray
        Command entering the delay line and the total undelayed force at each step [A].
    x0 : (n,) ndarray
        State at step 0.
    hist0 : (m + 1,) ndarray
        Delay line at step 0 (``hist0[i] = c[-1-i]``).

    Returns
    -------
    ndarray
        ``Y[k, b] = C_b x_b[k]`` (block ``b``: 0 the rigid body, then each mode), before step ``k``.
    """
    from identification.model.discrete import block_tf
    N, m = len(c), dp.m
    ext = np.r_[np.asarray(hist0, float)[::-1], c]       # ext[j] = c[j - m - 1]
    W = np.outer(ext[1:N + 1], dp.G_new) + np.outer(ext[:N], dp.G_old) + np.outer(f, dp.G_f)
    if dp.lag is not None:
        la = dp.lag
        xl = lfilter([1.0], [1.0, -dp.Phi[la, la]], np.r_[x0[la], W[:N - 1, la]])
        col = dp.Phi[:, la].copy()
        col[la] = 0.0
        W = W + np.outer(xl, col)
    Y = np.empty((N, len(dp.blocks)))
    eye = np.eye(2)
    for b, s in enumerate(dp.blocks):
        P, cs = dp.Phi[s, s], dp.C[s]
        y = np.zeros(N + 1)
        for j in range(2):
            num, den = block_tf(P, cs, eye[j])
            y += lfilter(np.r_[0.0, num], den, np.r_[x0[s][j], W[:, s][:, j]])
        Y[:, b] = y[1:]
    return Y
