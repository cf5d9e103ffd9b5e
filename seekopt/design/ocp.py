"""Former home of the seek designer, kept as a thin re-export so existing imports keep working.

The code lives in one module per concept: :mod:`seekopt.design.problem` (SeekProblem),
:mod:`seekopt.design.solver_settings` (SolverSettings), :mod:`seekopt.design.robust` (RobustSpec), :mod:`seekopt.design.designer`
(SeekDesigner, DesignResult, errors), :mod:`seekopt.design.qp` (LoopMaps, SeekQP) and
:mod:`seekopt.design.solvers` (QP solvers and status classification).
"""
from seekopt.design.designer import DesignError, DesignInfeasible, DesignResult, SeekDesigner, design_seek
from seekopt.design.problem import ProblemError, SeekProblem, check_closed_loop
from seekopt.design.solver_settings import SIZE_CLASSES, SolverSettings
from seekopt.design.robust import RobustSpec, seek_induced

__all__ = ["DesignInfeasible", "DesignError", "RobustSpec", "seek_induced", "DesignResult", "SeekDesigner",
           "design_seek", "SIZE_CLASSES", "SeekProblem", "SolverSettings", "ProblemError", "check_closed_loop"]
