"""What the effect-aware designer (:class:`seekopt.design.nlp.EffectAwareDesigner`) returns and raises:
a design verified on the full plant (:class:`NLPDesignResult`), or one of its failures -- Ipopt failed, ran out
of time or no design passed the full-plant check (:class:`NLPDesignError`), or the drive's feedback cannot
hold the band at the target (:class:`DesignUnholdable`).  Never a profile that was not verified.
"""
from __future__ import annotations

from dataclasses import dataclass

from seekopt.design.metrics import SeekMetrics
from seekopt.design.profiles import Profile
from seekopt.design.result import DesignResult

__all__ = ["NLPDesignError", "DesignUnholdable", "NLPDesignResult"]


class NLPDesignError(RuntimeError):
    """Ipopt failed, ran out of time, or no design passed the full-plant check (never a profile)."""


class DesignUnholdable(ValueError):
    """The drive's feedback cannot hold the band at the target whatever the feedforward."""


@dataclass
class NLPDesignResult:
    """A verified effect-aware design, played on the full plant from ``start_track``.

    ``linear``: the QP design that warm-started it; ``linear_metrics``: that design played on the
    same full plant from the same start (what ignoring the effects costs)."""

    profile: Profile
    metrics: SeekMetrics
    start_track: float
    settle_samples: int
    solves: list
    linear: DesignResult
    linear_metrics: SeekMetrics
    build_time_s: float = 0.0

    @property
    def ipopt_iterations(self) -> int:
        return sum(s.iterations for s in self.solves)

    @property
    def ipopt_time_s(self) -> float:
        return sum(s.wall_s for s in self.solves)

    @property
    def ipopt_cpu_s(self) -> float:
        return sum(s.cpu_s for s in self.solves)
