"""The ``daqp`` package (PyPI) as the design QP solver, called directly (:class:`DaqpQP`), and the
optimality check its warm answers must pass (:func:`kkt_holds`).

Same problem form as the other solvers of :mod:`seekopt.design.solvers` (which re-exports both names):
``min 1/2 x'Hx + g'x  s.t. lba <= A x <= uba, lbx <= x <= ubx``.
"""
from __future__ import annotations

import time

import numpy as np

from seekopt.design.certificates import proves_infeasible
from seekopt.design.qp_status import DAQP_PKG, QPSolution, QPStatus, classify_status

__all__ = ["DaqpQP", "kkt_holds", "PROX_OPTIONS"]

#: daqp with proximal-point iterations (``eps_prox``) for an ill-conditioned Hessian: on the whole-row QP
#: of nominal K = 3888 on the truth plant (cond(H) ~ 7e10) where both daqps cycle (exit -2) it answers in
#: ~1 s CPU within the constraint re-check (violation 3e-16).  :class:`DaqpQP` retries a cycling solve
#: with it; ``daqp_prox`` is the same as a fallback of its own (a chain whose primary is not the package).
PROX_OPTIONS = {"eps_prox": 1e-6, "iter_limit": 20000, "primal_tol": 1e-9}


class DaqpQP:
    """The ``daqp`` package (PyPI) on a dense QP of ``n`` variables and ``m`` rows, called directly.

    Same problem form as :class:`ConicQP`; the bounds go to daqp as its simple bounds, rows and
    variables with ``lb == ub`` as equalities.  Nothing is built per size (daqp sets up its workspace
    per call), so one instance serves any ``m``.

    Warm start: ``lam_a0``/``lam_x0`` (multipliers in casadi's sign convention, e.g. a previous
    answer's mapped to these rows) give daqp its starting active set (``dual_start``: the nonzero
    entries start active).  A warm start that ends in anything but an answer or an infeasibility
    (a linearly dependent starting set: -6; cycling) is retried cold once; a cold solve that cycles or
    hits the iteration limit once more with proximal iterations (:data:`PROX_OPTIONS`).  ``x0`` is not used.

    On ``infeasible`` (daqp exit flag -1) the multipliers daqp returns (its Farkas direction, of
    opposite sign to casadi's convention; returned in casadi's) are checked on the data
    (:func:`proves_infeasible`): ``QPSolution.proven`` says whether they prove it.

    Parameters
    ----------
    n, m : int
        Variables and rows (``m`` informative: any row count is accepted).
    options : dict, optional
        daqp settings (``iter_limit``, ``primal_tol``, ``dual_tol``, ...), merged over
        ``iter_limit=5000, primal_tol=1e-9`` (the settings :class:`ConicQP` gives casadi's daqp).
    name : str
        ``daqp_pkg``, or ``daqp_prox`` for the proximal fallback (:data:`seekopt.design.solvers.PROX_OPTIONS`).
    prox_retry : bool
        Retry a cold solve that cycles or hits the iteration limit with proximal iterations (above).  False
        where PIQP is the next solver of the chain (:class:`seekopt.design.solvers.SolverChain`): on the
        long robust seeks' reduced QPs (cond(H) ~ 3e11) the retry ran its 20000 iterations for 19 s CPU
        and failed, where PIQP answered in 0.05 s (docs/results_sweep_scaling.md, session 9).
    """

    name = DAQP_PKG
    warm_duals = True

    def __init__(self, n: int, m: int, options: dict | None = None, name: str = DAQP_PKG, prox_retry: bool = True):
        import daqp
        self._daqp = daqp
        self.n, self.m, self.plugin = int(n), int(m), name
        self.name = name
        self.prox_retry = bool(prox_retry)
        self.settings = {"iter_limit": 5000, "primal_tol": 1e-9}
        self.settings.update(options or {})
        self.warm_retries = 0           # warm starts that failed and were solved cold (statistics)
        self.prox_retries = 0           # cycling / iteration-limit solves retried with proximal iterations

    def _call(self, H, f, A, bu, bl, sense, dual0):
        kw = dict(self.settings)
        if dual0 is not None:
            kw["dual_start"] = dual0
        try:
            x, _, flag, info = self._daqp.solve(H, f, A, bu, bl, sense, **kw)
            return np.asarray(x, dtype=float), int(flag), np.asarray(info["lam"], dtype=float)
        except (ValueError, RuntimeError) as exc:      # ill-posed data: numerical trouble, not a proof
            return None, f"error: {exc}", None

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None) -> QPSolution:
        """Solve with numpy data; ``lam_a0``/``lam_x0`` (length ``len(A)``/``n``) start the active set."""
        H = np.ascontiguousarray(H, dtype=float)
        A = np.ascontiguousarray(A, dtype=float)
        n, m = H.shape[0], A.shape[0]
        lba, uba = np.asarray(lba, dtype=float).ravel(), np.asarray(uba, dtype=float).ravel()
        lbx, ubx = np.asarray(lbx, dtype=float).ravel(), np.asarray(ubx, dtype=float).ravel()
        bu, bl = np.concatenate([ubx, uba]), np.concatenate([lbx, lba])
        sense = np.where(bl == bu, 5, 0).astype(np.intc)
        dual0 = None
        if lam_a0 is not None or lam_x0 is not None:
            dual0 = np.concatenate([np.zeros(n) if lam_x0 is None else np.asarray(lam_x0, dtype=float).ravel(),
                                    np.zeros(m) if lam_a0 is None else np.asarray(lam_a0, dtype=float).ravel()])
            dual0 = np.nan_to_num(dual0)
            dual0[sense == 5] = 0.0         # equalities are active from the start anyway
            if not np.any(dual0):
                dual0 = None
        t0, c0 = time.perf_counter(), time.process_time()
        g = np.asarray(g, dtype=float).ravel()
        x, flag, lam = self._call(H, g, A, bu, bl, sense, dual0)
        if dual0 is not None and (flag not in (1, 2, -1) or (flag in (1, 2) and not kkt_holds(
                H, g, A, lba, uba, lbx, ubx, x, lam[n:], lam[:n]))):
            # daqp has answered a bad starting set with flag 1 and NaN (or a point that is no optimum):
            # a warm answer stands only when it satisfies the optimality conditions, else solved cold
            self.warm_retries += 1
            x, flag, lam = self._call(H, g, A, bu, bl, sense, None)
        if flag in (-2, -4) and self.prox_retry and "eps_prox" not in self.settings:
            # cycling or the iteration limit: an ill-conditioned Hessian (cond ~ 1e10 at K >= 3888); the
            # proximal iterations answer it in ~1 s where casadi's daqp cycles too (PROX_OPTIONS)
            self.prox_retries += 1
            kw = dict(self.settings, **PROX_OPTIONS)
            try:
                xp, _, fp, ip = self._daqp.solve(H, g, A, bu, bl, sense, **kw)
                if int(fp) in (1, 2, -1):
                    x, flag, lam = np.asarray(xp, dtype=float), int(fp), np.asarray(ip["lam"], dtype=float)
            except (ValueError, RuntimeError):
                pass
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        raw = str(flag)
        if x is None:
            x, lam, outcome = np.full(n, np.nan), np.full(n + m, np.nan), QPStatus.NUMERICAL
        else:
            outcome = classify_status(self.name, raw, flag in (1, 2))
        ok = outcome is QPStatus.OPTIMAL and bool(np.all(np.isfinite(x)))
        if outcome is QPStatus.OPTIMAL and not ok:
            outcome = QPStatus.NUMERICAL
        proven = None
        if outcome is QPStatus.INFEASIBLE:
            lam = -lam                      # daqp's Farkas direction -> casadi's sign convention
            proven = bool(proves_infeasible(A, lba, uba, lbx, ubx, lam[n:]))
            if not proven:          # daqp 0.11 returns no usable multipliers with most "infeasible"s
                lam = np.zeros(n + m)
        return QPSolution(x, lam[n:].copy(), lam[:n].copy(), ok, raw, dt, dc, outcome, self.name, proven=proven)


def kkt_holds(H, g, A, lba, uba, lbx, ubx, x, lam_a, lam_x, tol: float = 1e-6) -> bool:
    """True when ``x`` and the multipliers (casadi's sign convention: > 0 upper bound active, < 0 lower)
    satisfy the optimality conditions of ``min 1/2 x'Hx + g'x, lba <= A x <= uba, lbx <= x <= ubx``
    (a convex QP: then ``x`` is its optimum) -- stationarity ``H x + g + A' lam_a + lam_x = 0``, primal
    feasibility and complementarity, each relative to the size of its terms (``tol``)."""
    if x is None or lam_a is None or not (np.all(np.isfinite(x)) and np.all(np.isfinite(lam_a))
                                          and np.all(np.isfinite(lam_x))):
        return False
    Hx, At = H @ x, A.T @ lam_a
    r = Hx + g + At + lam_x
    scale = 1.0 + np.abs(Hx) + np.abs(g) + np.abs(A).T @ np.abs(lam_a) + np.abs(lam_x)
    if np.any(np.abs(r) > tol * scale):
        return False
    ax = A @ x
    row = 1.0 + np.abs(A) @ np.abs(x)
    if np.any(ax < lba - tol * row) or np.any(ax > uba + tol * row) or np.any(x < lbx - tol) or np.any(x > ubx + tol):
        return False
    big = tol * (1.0 + float(np.max(np.abs(np.r_[lam_a, lam_x]), initial=0.0)))
    up, lo = lam_a > big, lam_a < -big
    if np.any(np.abs(ax[up] - uba[up]) > tol * row[up]) or np.any(np.abs(ax[lo] - lba[lo]) > tol * row[lo]):
        return False
    up, lo = lam_x > big, lam_x < -big
    return not (np.any(np.abs(x[up] - ubx[up]) > tol) or np.any(np.abs(x[lo] - lbx[lo]) > tol))

