"""Proofs of infeasibility for the design QP's constraints ``lba <= A x <= uba, lbx <= x <= ubx``.

A length is called infeasible only on a proof: a Farkas certificate (row multipliers ``y`` with
``A^T y`` balanced by the variable bounds and a negative bound value) checked here on the data, from
a solver's multipliers (:func:`proves_infeasible`) or from a phase-1 LP solved by HiGHS on a subset
of rows (:func:`farkas_certificate`): a certificate over a subset of rows proves the whole set
infeasible, so a reduced (working-set) QP never needs the full QP to confirm an infeasible length.
"""
from __future__ import annotations

import numpy as np

__all__ = ["proves_infeasible", "farkas_certificate", "phase1_lp"]


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
