"""PIQP (proximal interior point, ``piqp`` on PyPI) on the dense design QP (:class:`PiqpQP`): a fallback
whose "infeasible" comes with a verified Farkas certificate.

Same problem form as the other solvers of :mod:`seekopt.design.solvers` (which builds it for the name
``piqp``): ``min 1/2 x'Hx + g'x  s.t. lba <= A x <= uba, lbx <= x <= ubx``.

Measured (``studies/qp_solvers.py``, the 229 nominal / 406 robust reduced QPs of a 13-length run on the
truth plant): PIQP is no faster than the warm-started ``daqp`` package on the solves (1.2x / 2.6x its CPU),
but it proved 32 of the 34 nominal and 50 of the 54 robust "infeasible" reduced QPs with multipliers that
pass :func:`seekopt.design.certificates.proves_infeasible`, where the ``daqp`` package's multipliers prove
none of them.  It is a dependency of seekopt (``pyproject.toml``); on a machine without the package, building it raises
:class:`ImportError`.
"""
from __future__ import annotations

import time

import numpy as np

from seekopt.design.certificates import proves_infeasible
from seekopt.design.qp_status import QPSolution, QPStatus

__all__ = ["PiqpQP", "PIQP", "piqp_available", "piqp_installed"]

#: The solver name (:func:`seekopt.design.solvers.make_qp_solver`).
PIQP = "piqp"


#: PIQP's relative tolerance (``eps_rel``; with ``eps_abs = 1e-9``).  With 0 (the absolute tolerance alone)
#: PIQP stopped at its iteration limit (0.9-2.2 s) on reduced QPs of the long robust seeks (objective
#: 4e5-1e6, cond(H) ~ 3e11) already at the optimum (objective to 10 digits, violation 1e-16); 1e-12 answered
#: some of them (0.05 s), 1e-9 all those captured (0.08-0.13 s; 900k TPI / 8859 tracks).  An answer still
#: passes the designer's constraint re-check and an "infeasible" still needs a verified certificate: the
#: tolerance decides when PIQP stops, not what is trusted.
EPS_REL = 1e-9


#: A row (or variable) farther than this from both its bounds is inactive at PIQP's answer [row units,
#: relative to ``max(1, |bound|)``]: on the long robust seeks' reduced QPs the active rows' slacks were
#: < 1e-9 and the inactive rows' > 1e-5 (multipliers >= 4.5e-6 against <= 8.2e-9).
ACTIVE_TOL = 1e-7


def active_only(r, lb, ub, lam):
    """``lam`` with the multipliers of inactive rows set to zero (``r``: the rows' values at the answer).

    An interior-point method leaves a small multiplier on every row (436 nonzero on a reduced QP of 737 rows
    with 158 active); read as an active set -- the working set's hint and the ``daqp`` package's starting
    active set of the next solve (:class:`seekopt.design.working_set.WorkingSetQP`) -- they start daqp from
    hundreds of wrong rows (there it reported an unproven "infeasible" of a feasible QP).  The zeroed
    multipliers are below 1e-8 of the active ones: the answer's optimality conditions hold as before."""
    slack = np.minimum(np.abs(ub - r), np.abs(r - lb))
    with np.errstate(invalid="ignore"):
        tol = ACTIVE_TOL * np.maximum(1.0, np.minimum(np.abs(lb), np.abs(ub)))
    return np.where(slack <= tol, lam, 0.0)


def piqp_installed() -> bool:
    """True when the ``piqp`` package can be found (without importing it: the solver settings' default
    chain asks this, and ``seekopt design`` must start fast)."""
    import importlib.util
    try:
        return importlib.util.find_spec("piqp") is not None
    except (ImportError, ValueError):        # e.g. sys.modules["piqp"] = None: blocked, not installed
        return False


def piqp_available() -> bool:
    """True when the ``piqp`` package imports."""
    try:
        import piqp  # noqa: F401
    except ImportError:
        return False
    return True


class PiqpQP:
    """PIQP's dense interface on a QP of ``n`` variables and any number of rows (set up per call).

    Rows with ``lba == uba`` go to PIQP as equalities, the others as two-sided inequalities, the
    variable bounds as its box.  Statuses: solved -> ``optimal``; primal infeasible -> ``infeasible``
    with ``proven`` saying whether PIQP's row multipliers pass the Farkas check on the data (an
    unproven one carries zero multipliers, as :class:`seekopt.design.daqp_solver.DaqpQP`'s); the
    iteration limit -> ``iteration_limit``; anything else (numerics, dual infeasible, bad data) ->
    ``numerical``.  Multipliers are returned in casadi's sign convention (> 0: upper bound active).
    Cold starts only (an interior-point method): ``x0``, ``lam_a0``, ``lam_x0`` are ignored.

    Parameters
    ----------
    n, m : int
        Variables and rows (``m`` informative).
    options : dict, optional
        PIQP settings (``eps_abs``, ``eps_rel``, ``max_iter``, ...) over ``eps_abs=1e-9``,
        ``eps_rel=EPS_REL``, ``max_iter=500``.
    """

    name = PIQP
    warm_duals = False

    def __init__(self, n: int, m: int, options: dict | None = None):
        import piqp
        self._piqp = piqp
        self.n, self.m, self.plugin = int(n), int(m), PIQP
        self.settings = {"eps_abs": 1e-9, "eps_rel": EPS_REL, "max_iter": 500}
        self.settings.update(options or {})

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None) -> QPSolution:
        """Solve with numpy data (any row count)."""
        piqp = self._piqp
        H = np.asfortranarray(H, dtype=float)
        A = np.asarray(A, dtype=float)
        g = np.asarray(g, dtype=float).ravel()
        lba, uba = np.asarray(lba, dtype=float).ravel(), np.asarray(uba, dtype=float).ravel()
        lbx, ubx = np.asarray(lbx, dtype=float).ravel(), np.asarray(ubx, dtype=float).ravel()
        n, m = len(g), len(A)
        eq = lba == uba
        iq = ~eq & (np.isfinite(lba) | np.isfinite(uba))     # free rows (both bounds infinite) are left out
        t0, c0 = time.perf_counter(), time.process_time()
        x, lam_a, lam_x = np.full(n, np.nan), np.full(m, np.nan), np.full(n, np.nan)
        try:
            s = piqp.DenseSolver()
            for k, v in self.settings.items():
                setattr(s.settings, k, v)
            s.settings.verbose = False
            s.setup(H, g, np.asfortranarray(A[eq]), lba[eq], np.asfortranarray(A[iq]), lba[iq], uba[iq], lbx, ubx)
            flag = s.solve()
            r = s.result
            x = np.asarray(r.x, dtype=float).copy()
            lam_a = np.zeros(m)
            lam_a[eq] = r.y
            lam_a[iq] = np.asarray(r.z_u, dtype=float) - np.asarray(r.z_l, dtype=float)
            lam_x = np.asarray(r.z_bu, dtype=float) - np.asarray(r.z_bl, dtype=float)
            raw = str(flag).split(".")[-1]
            outcome = {piqp.PIQP_SOLVED: QPStatus.OPTIMAL, piqp.PIQP_PRIMAL_INFEASIBLE: QPStatus.INFEASIBLE,
                       piqp.PIQP_MAX_ITER_REACHED: QPStatus.ITERATION_LIMIT}.get(flag, QPStatus.NUMERICAL)
        except (ValueError, RuntimeError, TypeError) as exc:     # ill-posed data: trouble, not a proof
            raw, outcome = f"error: {exc}", QPStatus.NUMERICAL
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if outcome is QPStatus.OPTIMAL and not np.all(np.isfinite(x)):
            outcome = QPStatus.NUMERICAL
        proven = None
        if outcome is QPStatus.OPTIMAL:
            lam_a, lam_x = active_only(A @ x, lba, uba, lam_a), active_only(x, lbx, ubx, lam_x)
        if outcome is QPStatus.INFEASIBLE:
            proven = bool(proves_infeasible(A, lba, uba, lbx, ubx, lam_a))
            if not proven:
                lam_a, lam_x = np.zeros(m), np.zeros(n)
        return QPSolution(x, lam_a, lam_x, outcome is QPStatus.OPTIMAL, raw, dt, dc, outcome, PIQP, proven=proven)
