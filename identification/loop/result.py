"""What closing the loop returns: the candidates tried (:class:`Step`) and :class:`LoopResult`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from identification.loop.fit_engine import Data
from identification.loop.residual import Residual
from identification.loop.settings import LoopSettings
from identification.model.plant import ModalPlant

__all__ = ["Step", "LoopResult", "errors", "improved_fraction", "jsonable"]


def jsonable(x):
    """Numpy scalars and arrays -> plain Python (for JSON)."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


def errors(res: Residual) -> dict:
    """``{"rms_track", "fit_percent"}`` of a residual."""
    return {"rms_track": float(res.rms), "fit_percent": float(res.fit_percent)}


def improved_fraction(new: Residual, old: Residual, rate: bool = False) -> float:
    """Fraction of validation seeks whose squared error (``rate``: of the error's first
    difference, :meth:`Windows.rate`) the new model lowers [-]."""
    if rate:
        (en, wn), (eo, wo) = new.windows.rate(new.e), old.windows.rate(old.e)
        n, o = wn.per_group(en), wo.per_group(eo)
    else:
        n, o = new.windows.per_group(new.e), old.windows.per_group(old.e)
    return float(np.mean([n[g] < o[g] for g in n]))


@dataclass
class Step:
    """One candidate tried at one iteration (errors: validation RMS [track]).

    ``bic_drop`` is the drop of the output-error BIC on the fit data [nats] (NaN when the
    validation RMS did not qualify); ``n_params`` the change in the number of parameters;
    ``rate_before``/``rate_after`` [track/sample], ``rate_bic_drop`` [nats] and
    ``rate_improved_fraction`` [-] the same figures for the error's first difference
    (:meth:`identification.loop.windows.Windows.rate`; NaN when not computed)."""

    effect: str
    params: dict
    evidence: str
    rms_before: float
    rms_after: float
    accepted: bool
    iteration: int = 0
    bic_drop: float = float("nan")
    fit_percent_after: float = float("nan")
    improved_fraction: float = float("nan")
    n_params: float = 0.0
    note: str = ""
    plant: ModalPlant | None = field(default=None, repr=False)
    rate_before: float = float("nan")
    rate_after: float = float("nan")
    rate_bic_drop: float = float("nan")
    rate_improved_fraction: float = float("nan")

    def to_dict(self) -> dict:
        return {"effect": self.effect, "params": jsonable(self.params), "evidence": self.evidence,
                "rms_before": float(self.rms_before), "rms_after": float(self.rms_after),
                "accepted": bool(self.accepted)}


@dataclass
class LoopResult:
    """Outcome of :func:`identification.loop.closing.close_loop`.

    ``plant`` is the augmented plant (linear part + accepted effects; its ``meta`` records
    the log and ``position_range_track``, the range of positions [track] the fit log's seeks
    settled on, where the position-dependent effects were fitted and may be used); ``model`` the plant the loop started from; ``error_before`` / ``error_after``
    the validation RMS [track] and fit [%] on the validation seeks inside ``position_range_track``
    (``info["validation_outside_range"]``: the seeks left out and their RMS); ``info`` how the loop ran (simulation protocol,
    validation data, base re-fit, re-identifications); ``stage_s`` the wall time per stage [s]."""

    plant: ModalPlant
    model: ModalPlant
    error_before: dict
    error_after: dict
    steps: list
    unexplained: list
    res_before: Residual
    res_after: Residual
    fit: Data
    val: Data
    analysis_before: dict
    analysis_after: dict
    runtime_s: float
    notes: list = field(default_factory=list)
    info: dict = field(default_factory=dict)
    settings: LoopSettings = field(default_factory=LoopSettings)
    stage_s: dict = field(default_factory=dict)

    @property
    def accepted(self) -> list:
        """Accepted effects in order of first acceptance (those still in the final plant: an
        extra mode is re-estimated by a kept re-identification as part of the linear plant)."""
        have = {e.name for e in self.plant.effects}
        return list(dict.fromkeys(s.effect for s in self.steps if s.accepted and s.effect in have))

    def report(self) -> dict:
        """The JSON report: ``plant`` (ModalPlant JSON, accepted effects included),
        ``error_before``/``error_after`` (validation RMS [track], fit [%]), ``steps``,
        ``unexplained``."""
        return {"plant": jsonable(self.plant.to_dict()), "error_before": self.error_before,
                "error_after": self.error_after, "steps": [s.to_dict() for s in self.steps],
                "unexplained": list(self.unexplained)}

    def augmented_plant(self) -> ModalPlant:
        """The augmented plant alone (what ``seekopt loop -o`` writes; ``ModalPlant.load`` reads it)."""
        return self.plant.copy()
