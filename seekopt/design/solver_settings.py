"""How the seek QPs are solved, not what is designed (:class:`SolverSettings`, part of a
:class:`~seekopt.design.problem.SeekProblem` and of its JSON form): the solver chain, the QP size classes
(:data:`SIZE_CLASSES`), the thinning of the set's rows, the answer re-check, the working set and the BLAS
threads.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

from seekopt.design.problem_checks import ProblemError
from seekopt.design.solvers import DAQP_PKG, PIQP, QP_SOLVERS, piqp_installed

__all__ = ["SolverSettings", "SIZE_CLASSES", "BASE_FALLBACKS", "default_fallbacks"]

#: Seek-length classes [samples]: one QP structure (and solver) per class, built on first use.  Above
#: 128 samples (seeks of about 2500 tracks and longer) the classes are 1/8 to 1/4 apart: the dense QP's
#: cost grows steeply with its size (K = 10000: class 256 took 45-75 s per solve, 224 about 25 s).
SIZE_CLASSES = (8, 16, 24, 32, 48, 64, 96, 128, 144, 160, 176, 192, 208, 224, 240, 256, 288, 320, 352, 384,
                448, 512)


#: The fallbacks without PIQP (the chain where the ``piqp`` package is not installed).
BASE_FALLBACKS = ("daqp", "daqp_prox", "qpoases", "highs")


def default_fallbacks() -> tuple:
    """:attr:`SolverSettings.fallbacks` by default: PIQP first when the package is installed
    (a dependency: absent only where it could not be installed), then :data:`BASE_FALLBACKS`.

    Why PIQP first: on the long robust rest-to-rest seeks of a sweep (80-110 samples, cond(H) 1e10-4e11) daqp
    cycles on some reduced QPs, and the rest of the chain was the cost -- casadi's daqp and ``daqp_prox``
    cycle too (the proximal iterations up to 19 s CPU), qpOASES stops at its recalculation limit, HiGHS at
    its time limit, and then the full QP (5392 rows) went through the chain again, qpOASES answering after
    32 s CPU.  PIQP solved each of those reduced QPs in 0.02-0.2 s (docs/results_sweep_scaling.md, session 9).
    As the first fallback it also re-checks daqp's unproven "infeasible" with a verifiable certificate
    (docs/results_speed.md, "QP solvers other than daqp")."""
    return ((PIQP,) if piqp_installed() else ()) + BASE_FALLBACKS


@dataclass
class SolverSettings:
    """How the seek QPs are solved (not what is designed).

    Parameters
    ----------
    qp_solver : str
        Primary solver -- the one place the QP solver is chosen: ``daqp_pkg`` (default: the ``daqp``
        package called directly, warm-started from the previous length's or round's active set;
        :class:`seekopt.design.solvers.DaqpQP`), a ``casadi.conic`` plugin (``daqp``: casadi's daqp,
        the former default, cold starts only; ``qpoases``, ``highs``, ...) or ``ipopt``.
    fallbacks : tuple of str
        Solvers tried, in order, on the same QP when the primary ends in numerical trouble (daqp
        cycling), an iteration limit or an answer that fails the constraint re-check -- before
        anything is called infeasible (:class:`seekopt.design.solvers.SolverChain`); default
        :func:`default_fallbacks` (``piqp`` first when the package is installed).  The first
        fallback also re-checks an "infeasible" of ``daqp_pkg`` that the answer rests on (the package
        returns no usable multipliers with it; :class:`seekopt.design.working_set.WorkingSetQP`);
        ``daqp_prox`` (the package with proximal iterations) answers where an ill-conditioned Hessian
        makes both daqps cycle; every fallback has an iteration or time limit (a failed fallback proves
        nothing: the length is skipped, never waited on).
    options : dict
        ``{solver name: plugin options}``.
    max_samples : int
        Longest seek considered [samples].
    size_classes : tuple of int
        QP size classes [samples] (:data:`SIZE_CLASSES`).
    thin_above_samples, thin_stride : int
        Classes above ``thin_above_samples`` carry the non-nominal plants' band rows on every
        ``thin_stride``-th sample only (nominal rows and current rows are never thinned: thinning
        current rows let set plants exceed Imax by 5-15 %; band stride 4 let the set's worst settle
        1.3 ms later at K = 3000).
    violation_tol : float
        Largest relative constraint violation accepted from a solver's answer.
    working_set : bool
        Solve each QP on its free variables and a working set of its rows, adding back violated rows
        (:class:`seekopt.design.working_set.WorkingSetQP`; the same optimum on far fewer rows).  A
        reduced "infeasible" stands only with a verified Farkas certificate or the fallbacks' proof on
        the reduced QP, else the full QP decides; search steps of the seek-length search take it
        unproven and the designer confirms the length its answer rests on (``studies/design_speed.py``).
    blas_threads : int or None
        BLAS threads while designing (``threadpoolctl``; None: leave as is).  The design's matrices
        are small: with 2 OpenBLAS threads on this 2-core machine three robust designs took 8-12 s
        CPU, with 1 thread 1.3-1.6 s (same designs).
    """

    qp_solver: str = DAQP_PKG
    fallbacks: tuple = field(default_factory=default_fallbacks)
    options: dict = field(default_factory=dict)
    max_samples: int = 512
    size_classes: tuple = SIZE_CLASSES
    thin_above_samples: int = 128
    thin_stride: int = 2
    violation_tol: float = 1e-3
    working_set: bool = True
    blas_threads: int | None = 1

    def __post_init__(self):
        self.fallbacks = tuple(self.fallbacks)
        self.size_classes = tuple(int(c) for c in self.size_classes)
        for name in (self.qp_solver,) + self.fallbacks:
            if name not in QP_SOLVERS:
                raise ProblemError(f"unknown QP solver {name!r} (choose from {', '.join(QP_SOLVERS)})")
        if self.max_samples < 2 or self.thin_stride < 1 or not self.violation_tol > 0:
            raise ProblemError("solver settings: max_samples >= 2, thin_stride >= 1, violation_tol > 0 required")

    @property
    def chain(self) -> tuple:
        """Primary, then fallbacks (duplicates dropped)."""
        return tuple(dict.fromkeys((self.qp_solver,) + self.fallbacks))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["fallbacks"], d["size_classes"] = list(self.fallbacks), list(self.size_classes)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SolverSettings":
        return cls(**d)
