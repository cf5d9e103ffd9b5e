"""The seek QP's objective (:class:`seekopt.design.qp.SeekQP`): smoothness of the feedforward and the
reference, and the energy of the settle-band residual after the seek, as a quadratic in the seek's size.

On the scaled decision vector ``x = [v, q, t]`` (:class:`~seekopt.design.qp.SeekQP`)::

    J = rho |D v|^2 + rho_q |D q|^2 + w_e mean_{i, k >= nmax} e_i(k)^2 (+ w_t t^2) + eps |x|^2

with ``D`` the first difference and ``e_i(k) = (y_i(k) - K) / band`` of every plant of the set.  ``K``
enters the residual as ``|K|`` times the reference columns plus ``K``-linear offsets, so that
``H(K) = P0 + |K| P1 + K^2 P2`` and ``g(K) = K q1 + K |K| q2``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["seek_objective"]


def seek_objective(maps: list, nmax: int, horizon: int, nin: int, R, imax: float, band: float, epigraph: bool,
                   rho: float, rho_q: float, w_e: float, w_t: float, eps: float):
    """``(P0, P1, P2, q1, q2)`` of the seek QP's objective (module notes).

    Parameters
    ----------
    maps : list of LoopMaps
        The plant set's closed-loop maps (:class:`seekopt.design.loop_maps.LoopMaps`), nominal first.
    nmax, horizon : int
        The size class [samples] (the residual counts from ``nmax`` on) and the horizon [samples].
    nin : int
        Input samples (``nmax`` plus the inputs' tail after the settle sample).
    R : ndarray or None
        The reference model's Toeplitz map ``(horizon, nin)`` (``reference="model"`` or ``"rigid"``: no ``q``);
        None: the reference is designed (``q`` has ``nin`` entries).
    imax, band : float
        Current limit [A] and settle band [track]: the scales of ``v`` and of the residual.
    epigraph : bool
        With the worst-residual variable ``t`` (last entry).
    rho, rho_q, w_e, w_t, eps : float
        Weights (module notes).
    """
    N, Ns, Hn = int(nin), int(nmax), int(horizon)
    free_ref = R is None
    nq = N if free_ref else 0
    n = N + nq + int(epigraph)
    D = np.eye(N) - np.eye(N, k=-1)
    P = np.zeros((n, n))
    P[:N, :N] += 2 * rho * D.T @ D
    if nq:
        P[N:N + nq, N:N + nq] += 2 * rho_q * D.T @ D
    if epigraph:
        P[-1, -1] += 2 * w_t
    P += 2 * eps * np.eye(n)
    kt = np.arange(Ns, Hn)
    eblocks, e1 = [], []
    for m in maps:
        Tyu, Tyr, syr = m.position_rows(kt, N if free_ref else Hn)
        eblocks.append((imax * Tyu / band, Tyr / band, None) if free_ref
                       else (imax * (Tyu[:, :N] + Tyr @ R) / band, None, None))
        e1.append((syr - 1.0) / band if free_ref else -np.ones(len(kt)) / band)
    e1 = np.concatenate(e1)
    # the blocks stacked on their own columns only (feedforward E0v, reference E1q; the full-width
    # arrays were zero elsewhere): products on those, a quarter of the full-width work, the same numbers
    E0v = np.concatenate([b[0] for b in eblocks])
    E1q = np.concatenate([b[1] for b in eblocks]) if nq else None
    w = 2 * w_e / E0v.shape[0]
    v, q = slice(0, N), slice(N, N + nq)
    P0, P1, P2 = P.copy(), np.zeros((n, n)), np.zeros((n, n))
    q1, q2 = np.zeros(n), np.zeros(n)       # g = K q1 + K|K| q2
    P0[v, v] += (w * E0v.T) @ E0v
    q1[v] = (w * E0v.T) @ e1
    if nq:
        P1[v, q] = w * (E0v.T @ E1q)
        P1[q, v] = w * (E1q.T @ E0v)
        P2[q, q] = (w * E1q.T) @ E1q
        q2[q] = (w * E1q.T) @ e1
    return P0, P1, P2, q1, q2
