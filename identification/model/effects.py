"""Effects beyond the linear modal plant: what a real drive does that eq. (1) does not say.

Each effect is a small dataclass with a name (its key in the plant JSON,
``{"effect": name, "params": {...}}``) and acts on the plant in one of four
ways, so that :class:`identification.model.plant.DiscretePlant` can step any
combination of them with the one discretisation:

``structural``
    changes the linear continuous-time dynamics before discretisation
    (extra input delay, amplifier lag, pivot spring/damper, an extra mode).
``input``
    maps the commanded current before it enters the delay line
    (current saturation, torque-constant variation with position).
``force``
    adds a current-equivalent force that depends on the state, undelayed
    (position-dependent bias, friction, the pivot's rest-position offset).
``output``
    adds a known signal to the measured position (periodic disturbance,
    i.e. repeatable run-out at spindle harmonics).

Units: position in tracks, velocity in track/s, current in A; a *force* is
expressed as the current that would produce it (force / torque constant).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar

import numpy as np

__all__ = [
    "Effect", "InputDelay", "AmplifierLag", "PivotSpringDamper", "ExtraMode",
    "CurrentSaturation", "TorqueConstantVariation", "PositionBias", "Friction",
    "PeriodicDisturbance", "EFFECTS", "effect_from_dict",
]


class Effect:
    """Base class; subclasses are dataclasses whose fields are the parameters."""

    name: ClassVar[str] = ""
    kind: ClassVar[str] = ""

    @property
    def params(self) -> dict:
        return {k: (list(v) if isinstance(v, (list, tuple, np.ndarray)) else v)
                for k, v in asdict(self).items()}

    def to_dict(self) -> dict:
        return {"effect": self.name, "params": self.params}

    # Hooks; each subclass overrides the one(s) of its kind.
    def input_map(self, u: float, position: float) -> float:
        return u

    def force(self, position: float, velocity: float) -> float:
        return 0.0

    def output(self, t: np.ndarray | float) -> np.ndarray | float:
        return 0.0 * np.asarray(t, dtype=float)


# --- structural (linear) ---------------------------------------------------------
@dataclass
class InputDelay(Effect):
    """Extra pure input delay ``delay_s`` [s] (fractional samples allowed)."""

    delay_s: float
    name: ClassVar[str] = "input_delay"
    kind: ClassVar[str] = "structural"


@dataclass
class AmplifierLag(Effect):
    """First-order current-amplifier lag ``1/(1 + s/(2 pi bandwidth_hz))``."""

    bandwidth_hz: float
    name: ClassVar[str] = "amplifier_lag"
    kind: ClassVar[str] = "structural"


@dataclass
class PivotSpringDamper(Effect):
    """Pivot bearing stiffness and damping: the rigid body becomes
    ``k0 / (s^2 + 2 zeta w s + w^2)`` with ``w = 2 pi freq_hz``, centred on
    ``rest_track`` (the position where the spring exerts no force)."""

    freq_hz: float
    zeta: float
    rest_track: float = 0.0
    name: ClassVar[str] = "pivot_spring_damper"
    kind: ClassVar[str] = "structural"

    def force(self, position: float, velocity: float) -> float:
        return 0.0  # the offset is handled exactly in the linear model (see plant.py)


@dataclass
class ExtraMode(Effect):
    """A mode the identified model did not contain: ``k0 g / (s^2 + 2 zeta w s + w^2)``."""

    freq_hz: float
    zeta: float
    gain: float
    name: ClassVar[str] = "extra_mode"
    kind: ClassVar[str] = "structural"


# --- input maps (nonlinear) ------------------------------------------------------
@dataclass
class CurrentSaturation(Effect):
    """The amplifier delivers at most ``limit_a`` [A] in either direction."""

    limit_a: float
    name: ClassVar[str] = "current_saturation"
    kind: ClassVar[str] = "input"

    def input_map(self, u: float, position: float) -> float:
        return min(max(u, -self.limit_a), self.limit_a)


@dataclass
class TorqueConstantVariation(Effect):
    """Torque constant that varies over the stroke:
    ``Kt(p)/Kt0 = 1 + sum_i coeffs[i] * x**(i+1)``, ``x = (p - center_track)/scale_track``."""

    coeffs: list
    center_track: float = 0.0
    scale_track: float = 10000.0
    name: ClassVar[str] = "torque_constant_variation"
    kind: ClassVar[str] = "input"

    def factor(self, position):
        x = (np.asarray(position, dtype=float) - self.center_track) / self.scale_track
        return 1.0 + sum(c * x ** (i + 1) for i, c in enumerate(self.coeffs))

    def input_map(self, u: float, position: float) -> float:
        return u * float(self.factor(position))


# --- state-dependent forces (nonlinear) --------------------------------------------
@dataclass
class PositionBias(Effect):
    """Bias force that varies with position (flex-cable preload, windage), as a
    piecewise-linear table ``bias_a`` [A] at ``knots_track``, held constant
    beyond the ends.  Added to the plant's constant ``bias_a``."""

    knots_track: list
    bias_a: list
    name: ClassVar[str] = "position_bias"
    kind: ClassVar[str] = "force"

    def force(self, position: float, velocity: float) -> float:
        return float(np.interp(position, self.knots_track, self.bias_a))


@dataclass
class Friction(Effect):
    """Pivot friction: ``-coulomb_a * sign(v) - viscous_a_per_tps * v`` with
    ``v`` in track/s (current-equivalent force)."""

    coulomb_a: float
    viscous_a_per_tps: float = 0.0
    name: ClassVar[str] = "friction"
    kind: ClassVar[str] = "force"

    def force(self, position: float, velocity: float) -> float:
        return -self.coulomb_a * float(np.sign(velocity)) - self.viscous_a_per_tps * velocity


# --- output signals ----------------------------------------------------------------
@dataclass
class PeriodicDisturbance(Effect):
    """Repeatable run-out: ``sum_h cos_track[h] cos(2 pi h f t) + sin_track[h] sin(2 pi h f t)``
    at harmonics ``harmonics`` of the spindle frequency ``spindle_hz``, added to
    the measured position (t from the start of the log)."""

    spindle_hz: float
    harmonics: list
    cos_track: list
    sin_track: list
    name: ClassVar[str] = "periodic_disturbance"
    kind: ClassVar[str] = "output"

    def output(self, t):
        t = np.asarray(t, dtype=float)
        out = np.zeros_like(t)
        for h, a, b in zip(self.harmonics, self.cos_track, self.sin_track):
            ph = 2 * np.pi * h * self.spindle_hz * t
            out = out + a * np.cos(ph) + b * np.sin(ph)
        return out


EFFECTS: dict[str, type[Effect]] = {
    cls.name: cls for cls in (
        InputDelay, AmplifierLag, PivotSpringDamper, ExtraMode, CurrentSaturation,
        TorqueConstantVariation, PositionBias, Friction, PeriodicDisturbance)
}


def effect_from_dict(d: dict) -> Effect:
    """Build an effect from ``{"effect": name, "params": {...}}``."""
    try:
        cls = EFFECTS[d["effect"]]
    except KeyError as exc:
        raise ValueError(f"unknown effect {d.get('effect')!r}; known: {sorted(EFFECTS)}") from exc
    return cls(**d.get("params", {}))
