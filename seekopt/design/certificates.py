"""Proofs of infeasibility for the design QP's constraints ``lba <= A x <= uba, lbx <= x <= ubx``.

A length is called infeasible only on a proof: a Farkas certificate (row multipliers ``y`` with
``A^T y`` balanced by the variable bounds and a negative bound value) checked here on the data, from
a solver's multipliers (:func:`proves_infeasible`), from non-negative least squares on a subset of rows
with cutting planes (:func:`nnls_certificate`) or from a phase-1 LP solved by HiGHS on a subset of rows
(:func:`farkas_certificate`): a certificate over a subset of rows proves the whole set infeasible, so a
reduced (working-set) QP never needs the full QP to confirm an infeasible length.
"""
from __future__ import annotations

import numpy as np

__all__ = ["proves_infeasible", "farkas_certificate", "phase1_lp", "phase1_daqp", "nnls_certificate"]


def proves_infeasible(A: np.ndarray, lba, uba, lbx, ubx, lam_a, rel_tol: float = 1e-9) -> bool:
    """True when the row multipliers ``lam_a`` (casadi's sign convention: < 0 lower bound, > 0 upper
    bound) are a Farkas certificate that ``lba <= A x <= uba, lbx <= x <= ubx`` has no solution.

    Every feasible ``x`` satisfies ``lam' A x <= sum_{lam>0} lam uba + sum_{lam<0} lam lba`` (the
    rows) and ``lam' A x >= min over the box of (A' lam)' x`` (the bounds); a certificate makes the
    first smaller than the second by more than ``rel_tol`` of the size of the terms (rounding).  A
    solver's "infeasible" is only taken as proven on a reduced problem when its multipliers pass this
    check (a reduced problem's infeasibility proves the full problem's: it has fewer rows).
    """
    lam = np.nan_to_num(np.asarray(lam_a, dtype=float).ravel())
    big = float(np.max(np.abs(lam))) if lam.size else 0.0
    if not big > 0:
        return False
    lam = lam / big
    lam[np.abs(lam) < 1e-14] = 0.0
    pos, neg = lam > 0, lam < 0
    lba, uba = np.asarray(lba, dtype=float), np.asarray(uba, dtype=float)
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    if not (np.all(np.isfinite(uba[pos])) and np.all(np.isfinite(lba[neg]))):
        return False
    sup = float(lam[pos] @ uba[pos] + lam[neg] @ lba[neg])
    c = A.T @ lam
    low = np.where(c > 0, c * np.where(c > 0, lbx, 0.0), c * np.where(c < 0, ubx, 0.0))
    low[c == 0] = 0.0
    if not np.all(np.isfinite(low)):
        return False
    xmax = np.maximum(np.abs(np.where(np.isfinite(lbx), lbx, 0.0)), np.abs(np.where(np.isfinite(ubx), ubx, 0.0)))
    bnd = np.where(pos, uba, np.where(neg, lba, 0.0))
    scale = 1.0 + float(np.abs(lam) @ (np.abs(A) @ xmax + np.abs(bnd)))
    return sup < float(low.sum()) - rel_tol * scale


def farkas_certificate(A: np.ndarray, lba, uba, lbx, ubx):
    """Row multipliers proving ``lba <= A x <= uba, lbx <= x <= ubx`` infeasible, or ``None``
    (:func:`phase1_lp`'s verified multipliers)."""
    return phase1_lp(A, lba, uba, lbx, ubx)[0]


def phase1_lp(A: np.ndarray, lba, uba, lbx, ubx):
    """``(lam, x, t)``: verified Farkas multipliers ``lam`` proving ``lba <= A x <= uba, lbx <= x <= ubx``
    infeasible (or ``None``), and the phase-1 LP's point ``x`` and its largest row violation ``t``
    (``None, inf`` when the LP gave none): a cutting-plane search for a certificate adds the rows of
    a larger set that ``x`` violates by more than ``t``.

    The phase-1 LP ``min t  s.t.  A x - t <= uba,  -A x - t <= -lba,  lbx <= x <= ubx,  t >= 0``
    (HiGHS through :func:`scipy.optimize.linprog`) has a positive optimum exactly when the rows and
    bounds admit no ``x``; its duals ``mu_u, mu_l >= 0`` then satisfy the Farkas alternative, returned
    as ``lam = mu_u - mu_l`` in casadi's sign convention (> 0 upper bound, < 0 lower bound).  The
    multipliers are only returned when :func:`proves_infeasible` verifies them on the data given
    (the LP's tolerances prove nothing by themselves).  Rows of a subset of a problem's constraints
    proven infeasible prove the whole problem infeasible.
    """
    from scipy.optimize import linprog
    A = np.asarray(A, dtype=float)
    lba, uba = np.asarray(lba, dtype=float), np.asarray(uba, dtype=float)
    m, n = A.shape
    up, lo = np.flatnonzero(np.isfinite(uba)), np.flatnonzero(np.isfinite(lba))
    if not (up.size + lo.size):
        return None, None, float("inf")
    A_ub = np.zeros((up.size + lo.size, n + 1))
    A_ub[:up.size, :n], A_ub[up.size:, :n] = A[up], -A[lo]
    A_ub[:, n] = -1.0
    b_ub = np.concatenate([uba[up], -lba[lo]])
    c = np.zeros(n + 1)
    c[n] = 1.0
    bounds = [(None if not np.isfinite(a) else a, None if not np.isfinite(b) else b)
              for a, b in zip(np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float))] + [(0.0, None)]
    try:
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
    except ValueError:
        return None, None, float("inf")
    if res.status != 0 or getattr(res, "x", None) is None:
        return None, None, float("inf")
    x, t = np.asarray(res.x[:n], dtype=float), float(res.fun)
    if not t > 0 or getattr(res, "ineqlin", None) is None:
        return None, x, t
    mu = -np.asarray(res.ineqlin.marginals, dtype=float)        # HiGHS: d(objective)/d(b_ub) <= 0
    mu = np.maximum(mu, 0.0)
    lam = np.zeros(m)
    np.add.at(lam, up, mu[:up.size])
    np.subtract.at(lam, lo, mu[up.size:])
    return (lam if proves_infeasible(A, lba, uba, lbx, ubx, lam) else None), x, t


def nnls_certificate(A: np.ndarray, lba, uba, lbx, ubx, rows, max_rounds: int = 4, cap: int | None = None):
    """Verified Farkas multipliers proving ``lba <= A x <= uba, lbx <= x <= ubx`` infeasible, found on
    the rows ``rows`` first (e.g. those a solver's "infeasible" names) and cutting planes; or ``None``.

    The rows ``a_i x <= u_i``, ``-a_i x <= -l_i`` of the subset and the finite variable bounds form
    ``G x <= h`` (each row scaled to unit norm).  Lawson and Hanson's least-distance programme: the
    non-negative least squares ``min_{y >= 0} |[G'; h'] y - [0; -1]|`` (:func:`scipy.optimize.nnls`)
    has zero residual exactly when ``G x <= h`` has no solution, and then ``y`` is a Farkas certificate
    (``G' y = 0``, ``h' y = -1``); otherwise the residual gives the subset's least-norm point ``x``,
    and the rows of ``A`` it violates (the most violated, at most ``cap``, default ``max(n / 2, 10)``)
    join the subset for the next round, up to ``max_rounds`` rounds.  Multipliers are returned only
    when :func:`proves_infeasible` verifies them on the whole data (the least squares' rounding
    proves nothing by itself).  On the design's reduced QPs (100-160 variables, 100-130 named rows):
    1-150 ms where the phase-1 LPs of :func:`phase1_lp` took 4-220 ms (``docs/results_speed.md``).
    """
    from scipy.optimize import nnls
    A = np.asarray(A, dtype=float)
    lba, uba = np.asarray(lba, dtype=float), np.asarray(uba, dtype=float)
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    m, n = A.shape
    bu, bl = np.flatnonzero(np.isfinite(ubx)), np.flatnonzero(np.isfinite(lbx))
    eye = np.eye(n)
    Gb, hb = np.vstack([eye[bu], -eye[bl]]), np.r_[ubx[bu], -lbx[bl]]
    norm = np.linalg.norm(A, axis=1)
    norm[norm == 0] = 1.0
    cap = cap or max(n // 2, 10)
    sub = np.unique(np.asarray(rows, dtype=int))
    for _ in range(max_rounds):
        up = sub[np.isfinite(uba[sub])]
        lo = sub[np.isfinite(lba[sub])]
        G = np.vstack([A[up], -A[lo], Gb])
        h = np.r_[uba[up], -lba[lo], hb]
        sc = np.linalg.norm(G, axis=1)
        sc[sc == 0] = 1.0
        Gs, hs = G / sc[:, None], h / sc
        hmax = max(float(np.max(np.abs(hs), initial=0.0)), 1.0)
        E = np.vstack([Gs.T, hs[None, :] / hmax])
        f = np.zeros(n + 1)
        f[-1] = -1.0
        try:
            y, _ = nnls(E, f, maxiter=50 * (n + 1))
        except RuntimeError:            # iteration limit: no certificate from here
            return None
        lam = np.zeros(m)
        y = y / sc
        np.add.at(lam, up, y[:up.size])
        np.subtract.at(lam, lo, y[up.size:up.size + lo.size])
        if proves_infeasible(A, lba, uba, lbx, ubx, lam):
            return lam
        r = E @ (y * sc) - f
        if not abs(r[-1]) > 1e-14:
            return None
        x = -r[:n] / r[-1] * hmax        # the subset's least-norm point
        ax = A @ x
        viol = np.maximum(ax - uba, lba - ax) / norm
        viol[sub] = -np.inf
        new = np.flatnonzero(viol > 1e-9)
        if not new.size:
            return None
        sub = np.union1d(sub, new[np.argsort(-viol[new])][:cap])
    return None


#: Weights of ``|x|^2`` against ``t^2`` in :func:`phase1_daqp`, tried in turn (each solve warm-started from
#: the last one's active set): the multipliers' residual ``eps x`` must stay below the certificate's
#: margin, which is small on a barely infeasible length (``t`` 4e-4-5e-3 on the K = 50-1000 nominal
#: working sets: 1e-5 proved none of six, 1e-7 four, 1e-9 one more; a cold 1e-7 solve costs as much as
#: the 1e-5 one, a warm one 5-25 % of it).
PHASE1_EPS = (1e-5, 1e-7, 1e-9)


def phase1_daqp(A: np.ndarray, lba, uba, lbx, ubx, eps: tuple = PHASE1_EPS, iter_limit: int = 2500):
    """Verified Farkas multipliers proving ``lba <= A x <= uba, lbx <= x <= ubx`` infeasible, or ``None``,
    from a phase-1 QP solved by the ``daqp`` package::

        min  eps/2 |x|^2 + 1/2 t^2   s.t.  A x - t <= uba,  A x + t >= lba,  lbx <= x <= ubx,  t >= 0

    (always feasible; ``t > 0`` at its optimum when the rows admit no ``x``).  Its row multipliers ``mu``
    satisfy ``eps x + A' mu + lam_x = 0`` with ``sum |mu| = t``: up to the small ``eps x`` they balance
    the variable bounds, a Farkas certificate of the :func:`phase1_lp` kind without scipy's LP; returned
    once :func:`proves_infeasible` verifies them on the data, for the first weight of ``eps`` that gives
    a verified certificate (each solve warm-started from the previous one's active set).  On the
    design's reduced QPs (60-150 variables, 290-940 rows) 4-120 ms, about one solve of the QP itself.

    Returns ``(lam, mu)``: the verified multipliers or ``None``, and the last solve's multipliers
    unverified (``None`` without a phase-1 answer): the rows they name seed :func:`nnls_certificate`."""
    import daqp
    A = np.asarray(A, dtype=float)
    lba, uba = np.asarray(lba, dtype=float), np.asarray(uba, dtype=float)
    lbx, ubx = np.asarray(lbx, dtype=float), np.asarray(ubx, dtype=float)
    m, n = A.shape
    iu, il = np.flatnonzero(np.isfinite(uba)), np.flatnonzero(np.isfinite(lba))
    if not (iu.size + il.size):
        return None, None
    G = np.zeros((iu.size + il.size, n + 1))
    G[:iu.size, :n], G[:iu.size, n] = A[iu], -1.0
    G[iu.size:, :n], G[iu.size:, n] = A[il], 1.0
    bu = np.r_[ubx, np.inf, uba[iu], np.full(il.size, np.inf)]
    bl = np.r_[lbx, 0.0, np.full(iu.size, -np.inf), lba[il]]
    sense = np.where(bl == bu, 5, 0).astype(np.intc)
    dual, mu = None, None
    for e in np.atleast_1d(eps):
        H = np.diag(np.r_[np.full(n, float(e)), 1.0])
        kw = {} if dual is None else {"dual_start": dual}
        try:
            x, _, flag, info = daqp.solve(H, np.zeros(n + 1), G, bu, bl, sense, primal_tol=1e-9,
                                          iter_limit=iter_limit, **kw)
        except (ValueError, RuntimeError):
            return None, mu
        if int(flag) not in (1, 2) or not float(np.asarray(x)[n]) > 0:
            return None, mu
        dual = np.asarray(info["lam"], dtype=float)
        lam = dual[n + 1:]
        mu = np.zeros(m)
        np.add.at(mu, iu, lam[:iu.size])
        np.add.at(mu, il, lam[iu.size:])
        if proves_infeasible(A, lba, uba, lbx, ubx, mu):
            return mu, mu
    return None, mu
