"""QP results and solver statuses shared by every design QP solver.

:class:`QPStatus` is the one classification of a solve (``optimal``, ``infeasible`` -- the solver
proved it --, ``numerical`` or ``iteration_limit``, neither of which proves anything);
:func:`classify_status` maps each solver's raw status to it; :class:`QPSolution` is one solve's answer
(``x`` and multipliers in casadi's sign convention, wall and CPU time [s]).  Also the small helpers the
solvers share: :func:`dm` (numpy -> casadi.DM, once per array) and ``_quiet_stdout``.  The solvers are
in :mod:`seekopt.design.solvers` and :mod:`seekopt.design.daqp_solver`.
"""
from __future__ import annotations

import contextlib
import io
import os
import sys
from dataclasses import dataclass, field
from enum import Enum

import casadi as ca
import numpy as np

__all__ = ["QPStatus", "classify_status", "QPSolution", "DAQP_PKG", "DAQP_PROX", "dm"]

#: The ``daqp`` package called directly (:class:`seekopt.design.daqp_solver.DaqpQP`).
DAQP_PKG = "daqp_pkg"
#: The same package with proximal-point iterations (a fallback for ill-conditioned Hessians).
DAQP_PROX = "daqp_prox"


class QPStatus(str, Enum):
    """Outcome of one QP solve."""

    OPTIMAL = "optimal"
    INFEASIBLE = "infeasible"
    NUMERICAL = "numerical"
    ITERATION_LIMIT = "iteration_limit"


#: daqp exit flags (daqp ``api.h``): 1 optimal, 2 soft optimal, -1 infeasible, -2 cycling,
#: -3 unbounded, -4 iteration limit, -5 non-convex, -6 overdetermined initial active set.
_DAQP = {1: QPStatus.OPTIMAL, 2: QPStatus.OPTIMAL, -1: QPStatus.INFEASIBLE, -2: QPStatus.NUMERICAL,
         -3: QPStatus.NUMERICAL, -4: QPStatus.ITERATION_LIMIT, -5: QPStatus.NUMERICAL, -6: QPStatus.NUMERICAL}
#: Text statuses of the other solvers (lower case, substring match, first hit wins).
_TEXT = (("primal infeasible", QPStatus.INFEASIBLE), ("infeasib", QPStatus.INFEASIBLE),
         ("max_iter", QPStatus.ITERATION_LIMIT), ("maximum iterations", QPStatus.ITERATION_LIMIT),
         ("iteration limit", QPStatus.ITERATION_LIMIT), ("maximum number of working set", QPStatus.ITERATION_LIMIT),
         ("maximum_iterations", QPStatus.ITERATION_LIMIT), ("time limit", QPStatus.ITERATION_LIMIT))


def classify_status(solver: str, raw, success: bool) -> QPStatus:
    """Map a solver's raw ``return_status`` (and casadi's ``success``) to a :class:`QPStatus`.

    daqp reports an integer exit flag (see ``_DAQP``; -2 is cycling: numerical trouble, not
    infeasibility).  The other plugins report text: infeasibility only when the text says so,
    iteration and time limits as ``iteration_limit``; anything else that is not a success is
    ``numerical``.  Unknown statuses are never taken as proof of infeasibility.
    """
    text = str(raw).strip()
    if solver in ("daqp", DAQP_PKG, DAQP_PROX):
        try:
            return _DAQP.get(int(float(text)), QPStatus.NUMERICAL)
        except ValueError:
            pass
    if success:
        return QPStatus.OPTIMAL
    low = text.lower()
    if "inaccurate" in low:
        return QPStatus.NUMERICAL
    for key, status in _TEXT:
        if key in low:
            return status
    return QPStatus.NUMERICAL


def _flush_c_stdio() -> None:
    """``fflush(NULL)`` of the C library (a no-op where it cannot be loaded)."""
    try:
        import ctypes
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


@contextlib.contextmanager
def _quiet_stdout(active: bool = True):
    """Silence stdout inside the block: the C-level file descriptor 1 and Python's ``sys.stdout`` (casadi
    prints its plugins' messages through Python)."""
    if not active:
        yield
        return
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:         # no file descriptor 1 (embedded use): Python's stdout only
        with contextlib.redirect_stdout(io.StringIO()):
            yield
        return
    try:
        with open(os.devnull, "w") as null, contextlib.redirect_stdout(io.StringIO()):
            os.dup2(null.fileno(), 1)
            yield
            _flush_c_stdio()    # C stdio buffers (full when stdout is a pipe or file) go to /dev/null too
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def dm(a: np.ndarray) -> ca.DM:
    """numpy -> casadi.DM (dense).  Slow for big arrays (~0.1 s per million entries): do it once."""
    a = np.asarray(a, dtype=float)
    return ca.DM(a if a.ndim == 2 else a.reshape(-1, 1))


@dataclass
class QPSolution:
    """Result of one QP solve: ``x``, multipliers, raw status, wall and CPU time [s].

    ``outcome`` is the classified :class:`QPStatus` (derived from ``success``/``status`` when not
    given); ``solver`` the solver that produced it; ``attempts`` the ``(solver, raw status,
    outcome)`` of every solve a :class:`SolverChain` made for this answer.  ``proven``: for an
    ``infeasible`` of a solver that checks its own multipliers (:class:`DaqpQP`), whether they are a
    verified Farkas certificate on the data solved; ``None`` where the solver's status is all there is.
    """

    x: np.ndarray
    lam_a: np.ndarray
    lam_x: np.ndarray
    success: bool
    status: str
    solve_time_s: float
    cpu_time_s: float
    outcome: QPStatus | None = None
    solver: str = ""
    attempts: list = field(default_factory=list)
    proven: bool | None = None

    def __post_init__(self):
        if self.outcome is None:          # raw flags without a solver name: daqp's integer flags
            name = self.solver or ("daqp" if self.status.strip().lstrip("-").isdigit() else "")
            self.outcome = classify_status(name, self.status, self.success)
        if self.outcome is not QPStatus.OPTIMAL:
            self.success = False
        elif not self.success:
            self.outcome = QPStatus.NUMERICAL

    @property
    def infeasible(self) -> bool:
        """The solver proved the problem infeasible."""
        return self.outcome is QPStatus.INFEASIBLE


def _nan_safe(a, n):
    a = np.asarray(a, dtype=float).ravel()
    return a if a.size == n else np.full(n, np.nan)

