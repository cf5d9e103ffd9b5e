"""What a design returns or raises: :class:`DesignResult`, :class:`DesignInfeasible`, :class:`DesignError`,
and the per-design solve bookkeeping (:class:`SolveStats`) behind the counts in a result."""
from __future__ import annotations

from dataclasses import dataclass

from seekopt.design.guard import GuardReport
from seekopt.design.metrics import SeekMetrics
from seekopt.design.predict import SetPrediction
from seekopt.design.problem import ProblemError
from seekopt.design.profiles import Profile
from seekopt.design.solvers import QPStatus

__all__ = ["DesignInfeasible", "DesignError", "DesignResult", "SolveStats"]


class DesignInfeasible(ProblemError):
    """The request cannot be met (e.g. seek too short for ``Imax``); names the shortest feasible time."""


class DesignError(RuntimeError):
    """No verified design: every solver failed without proof, or the answer failed the simulator check."""


@dataclass
class DesignResult:
    """A verified design.

    ``metrics`` are measured by :func:`seekopt.design.metrics.evaluate_profile` on the design plant
    (the full plant, effects included); ``worst_metrics`` the worst case over the robust set (when
    checked).  ``prediction`` holds the profile's seek-settle time on every plant of the set (nominal,
    family members, drift vertices: :class:`seekopt.design.family.SetPrediction`, worst and binding
    plant) and ``guard`` the worst residual it leaves in the guarded unmodelled modes
    (:class:`seekopt.design.guard.GuardReport`); both are also in the profile's metadata.
    ``solve_time_s`` sums the QP solves of this design; ``objective`` is
    ``"min_settle/<worst|mean>"`` or ``"min_residual/<worst|mean>"``.  ``fallback_solves`` counts the
    QPs a fallback solver answered after the primary failed without proof; ``unresolved_solves``
    the QPs no solver decided (skipped).  ``settle_samples`` is the sample the nominal plant's band
    holds from, ``set_settle_samples`` the one every other plant of the set holds it from (the seek's
    length; later than ``settle_samples`` when the lexicographic design,
    :attr:`SeekProblem.nominal_first`, let the nominal plant settle first); ``set_min_settle_samples``
    the set's minimum (the first stage's), earlier than ``set_settle_samples`` by the worst-case slack the
    design spent for the nominal plant (:attr:`SeekProblem.worst_case_slack_s`).
    """

    profile: Profile
    metrics: SeekMetrics
    status: str
    solve_time_s: float
    solver: str
    objective: str
    settle_samples: int = 0
    n_solves: int = 0
    residual_band: float = float("nan")
    worst_metrics: SeekMetrics | None = None
    qp_status: str = ""
    build_time_s: float = 0.0
    fallback_solves: int = 0
    unresolved_solves: int = 0
    prediction: SetPrediction | None = None
    guard: GuardReport | None = None
    set_settle_samples: int = 0
    set_min_settle_samples: int = 0

    def __post_init__(self):
        if not self.set_settle_samples:
            self.set_settle_samples = self.settle_samples
        if not self.set_min_settle_samples:
            self.set_min_settle_samples = self.set_settle_samples


class SolveStats:
    """Per-design solve bookkeeping: solves, time, fallbacks, the lengths no solver decided."""

    def __init__(self, primary: str):
        self.primary = primary
        self.n, self.t, self.status, self.fallback, self.unresolved = 0, 0.0, "", 0, []
        self.unconfirmed = set()        # (structure, length) whose "infeasible" a search step took unproven

    def add(self, N: int, sol) -> None:
        self.n += 1
        self.t += sol.solve_time_s
        self.status = sol.status
        if sol.solver != self.primary and sol.outcome in (QPStatus.OPTIMAL, QPStatus.INFEASIBLE):
            self.fallback += 1
        if sol.outcome not in (QPStatus.OPTIMAL, QPStatus.INFEASIBLE):
            self.unresolved.append((N, " -> ".join(f"{a} {b} ({c})" for a, b, c in sol.attempts)))

    def why(self) -> str:
        return "; ".join(f"N = {n}: {a}" for n, a in self.unresolved[-3:])
