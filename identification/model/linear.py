"""The vectorised linear fast path of :class:`identification.model.discrete.DiscretePlant`.

The stepping engine's ``Phi`` is block diagonal (rigid body, each mode) apart from the
amplifier-lag column, so the linear part's output is a sum of 2nd-order filters, each the
block's own recursion run by :func:`scipy.signal.lfilter`: through its transfer functions
(:func:`block_tf`), or, for a slow block (poles near ``z = 1``, e.g.
a pivot spring), in its modal coordinates ``q = V^-1 z`` (``Phi_s = V diag(lam) V^-1``, one
first-order recursion per conjugate pair); the free rigid body ``Phi_s = [[1, dt], [0, 1]]`` as
two running sums.  No new discretisation: the
coefficients are the engine's ``Phi``, ``Gamma`` and ``C``; the results equal stepping to ~1e-14
relative (the rounding of the stepping itself)::

    z_s[k+1] = Phi_s z_s[k] + w_s[k],   z_s[0] = x0_s,   y_s[k] = C_s z_s[k]
    w[k] = Gamma_new c[k-m] + Gamma_old c[k-m-1] + Gamma_f f[k] + Phi[:, lag] x_lag[k]
    x_lag[k+1] = Phi[lag, lag] x_lag[k] + w_lag[k]

Used by :meth:`DiscretePlant.linear_response`.
"""
from __future__ import annotations

import numpy as np

__all__ = ["block_responses", "block_tf", "SLOW_POLE"]

#: Blocks with a pole within this distance of ``z = 1`` (below ~0.05 fs / 2 pi Hz) run in modal
#: coordinates (complex first-order recursions, accurate near ``z = 1``); the others as real
#: 2nd-order filters (about 10x faster).
SLOW_POLE = 0.05


def block_tf(Phi: np.ndarray, c: np.ndarray, g: np.ndarray):
    """Transfer function ``c (zI - Phi)^-1 g`` of one 2-state block of a :class:`DiscretePlant`
    (rigid body or one mode): numerator ``[n1, n0]`` and denominator ``[1, a1, a2]`` in powers of
    ``z^-1`` after one sample (``(n1 z + n0) / (z^2 + a1 z + a2)``)."""
    (p00, p01), (p10, p11) = Phi
    n1 = c[0] * g[0] + c[1] * g[1]
    n0 = -c[0] * p11 * g[0] + c[0] * p01 * g[1] + c[1] * p10 * g[0] - c[1] * p00 * g[1]
    return np.array([n1, n0]), np.array([1.0, -(p00 + p11), p00 * p11 - p01 * p10])


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
    from scipy.signal import lfilter    # on first use: importing scipy.signal costs ~0.8 s CPU (seekopt design start-up)
    N = len(c)
    ext = np.r_[np.asarray(hist0, float)[::-1], c]       # ext[j] = c[j - m - 1]
    # the inputs of step k (k = 0..N-2; the last step's input is not needed): c[k-m], c[k-m-1], f[k]
    U = [ext[1:N], ext[:N - 1], np.asarray(f, float)[:N - 1]]
    G = [dp.G_new, dp.G_old, dp.G_f]
    if dp.lag is not None:
        la = dp.lag
        zl = np.r_[x0[la], dp.G_new[la] * U[0] + dp.G_old[la] * U[1]]
        U.append(lfilter([1.0], [1.0, -dp.Phi[la, la]], zl)[:N - 1])       # the lag state x_lag[k]
        G.append(dp.Phi[:, la])
    U = np.vstack(U)
    G = np.column_stack(G)
    Y = np.empty((len(dp.blocks), N))
    for b, s in enumerate(dp.blocks):
        P, cs = dp.Phi[s, s], dp.C[s]
        lam, V = np.linalg.eig(P)
        rigid = P[0, 0] == 1.0 and P[1, 1] == 1.0 and P[1, 0] == 0.0
        slow = (np.min(np.abs(1.0 - lam)) < SLOW_POLE and abs(lam[0] - lam[1]) > 1e-6
                and np.linalg.cond(V) < 1e6)
        if not (rigid or slow):
            # y = (n1 + n0 z^-1) / (1 + a1 z^-1 + a2 z^-2) applied to [z_s[0], w_s[0], w_s[1], ...];
            # the numerators are linear in the input column, so each input sequence gets its own
            # taps (block_tf of its Gamma column) and one filter runs per block
            e = np.zeros(N)
            (e[0], n0), den = block_tf(P, cs, x0[s])
            if N > 1:
                e[1] += n0
                for j in range(U.shape[0]):
                    (n1, n0), _ = block_tf(P, cs, G[s, j])
                    e[1:] += n1 * U[j]
                    e[2:] += n0 * U[j, :N - 2]
            Y[b] = lfilter([1.0], den, e)
            continue
        Zs = np.empty((2, N))                # [z_s[0], w_s[0], ..., w_s[N-2]]
        Zs[:, 0] = x0[s]
        Zs[:, 1:] = G[s] @ U
        if rigid:                            # free rigid body: two running sums
            v = np.cumsum(Zs[1])
            p = np.cumsum(np.r_[Zs[0, 0], P[0, 1] * v[:N - 1] + Zs[0, 1:]])
            Y[b] = cs[0] * p + cs[1] * v
            continue
        # slow block (poles near z = 1, where a 2nd-order filter loses digits), distinct
        # poles: modal coordinates q = V^-1 z, each a first-order recursion
        Vi, cv = np.linalg.inv(V), cs @ V
        if np.iscomplexobj(lam) and lam[0].imag != 0.0:  # conjugate pair: one recursion
            q = lfilter([1.0], [1.0, -lam[0]], Vi[0, 0] * Zs[0] + Vi[0, 1] * Zs[1])
            Y[b] = 2.0 * (cv[0].real * q.real - cv[0].imag * q.imag)
        else:
            Y[b] = sum(np.real(cv[i] * lfilter([1.0], [1.0, -lam[i]], Vi[i] @ Zs)) for i in range(2))
    return Y.T
