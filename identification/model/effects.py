"""Effects beyond the linear modal plant: what a real drive does that eq. (1) does not say.

Each effect is a small dataclass with a name (its key in the plant JSON,
``{"effect": name, "params": {...}}``) and acts on the plant in one of four
ways, so that :class:`identification.model.discrete.DiscretePlant` can step any
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

Each formula is written once and evaluates on numbers and on CasADi symbols: every hook
takes a backend ``ops`` (:mod:`identification.model.ops`; default :data:`~identification.model.ops.NUMPY`,
``casadi_ops(smooth)`` for the design NLP) and uses only its functions::

    input_map(u, position, ops=NUMPY) -> current [A]      (kind "input")
    force(position, velocity, ops=NUMPY) -> force [A]     (kind "force")
    output(t, ops=NUMPY) -> position [track]              (kind "output")

On numpy the hooks are vectorised (arrays in, arrays out).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import ClassVar

import numpy as np

from identification.model.ops import NUMPY

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
    def input_map(self, u, position, ops=NUMPY):
        """Command current [A] after this effect, at head position ``position`` [track]."""
        return u

    def force(self, position, velocity, ops=NUMPY):
        """Undelayed current-equivalent force [A] at ``position`` [track], ``velocity`` [track/s]."""
        return 0.0 * velocity

    def output(self, t, ops=NUMPY):
        """Signal added to the measured position [track] at time ``t`` [s]."""
        return 0.0 * ops.asarray(t)


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

    def rest_force_a(self, k0: float) -> float:
        """Constant force [A] of the rest offset: the spring ``-w^2 (p - rest)`` is the linear
        ``-w^2 p`` (in the state matrix) plus ``w^2 rest / k0`` as a current-equivalent force."""
        return (2.0 * np.pi * self.freq_hz) ** 2 * self.rest_track / k0


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

    def __post_init__(self):
        if not self.limit_a > 0:
            raise ValueError(f"current_saturation: limit_a must be > 0 (got {self.limit_a})")

    def input_map(self, u, position, ops=NUMPY):
        return ops.clip(u, -self.limit_a, self.limit_a)


@dataclass
class TorqueConstantVariation(Effect):
    """Torque constant that varies over the stroke:
    ``Kt(p)/Kt0 = 1 + sum_i coeffs[i] * x**(i+1)``, ``x = (p - center_track)/scale_track``."""

    coeffs: list
    center_track: float = 0.0
    scale_track: float = 10000.0
    name: ClassVar[str] = "torque_constant_variation"
    kind: ClassVar[str] = "input"

    def factor(self, position, ops=NUMPY):
        """``Kt(p) / Kt0`` [-] at ``position`` [track]."""
        x = (ops.asarray(position) - self.center_track) / self.scale_track
        return 1.0 + ops.sum([float(c) * x ** (i + 1) for i, c in enumerate(self.coeffs)] or [0.0 * x])

    def input_map(self, u, position, ops=NUMPY):
        return u * self.factor(position, ops)


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

    def __post_init__(self):
        k = np.asarray(self.knots_track, dtype=float)
        if k.ndim != 1 or len(k) < 1 or len(k) != len(self.bias_a):
            raise ValueError("position_bias: knots_track and bias_a must be equal-length, non-empty lists")
        if np.any(np.diff(k) <= 0):
            raise ValueError("position_bias: knots_track must be strictly increasing")

    def force(self, position, velocity, ops=NUMPY):
        return ops.interp(position, self.knots_track, self.bias_a)


@dataclass
class Friction(Effect):
    """Pivot friction: ``-coulomb_a * sign(v) - viscous_a_per_tps * v`` with
    ``v`` in track/s (current-equivalent force)."""

    coulomb_a: float
    viscous_a_per_tps: float = 0.0
    name: ClassVar[str] = "friction"
    kind: ClassVar[str] = "force"

    def force(self, position, velocity, ops=NUMPY):
        return -self.coulomb_a * ops.sign(velocity) - self.viscous_a_per_tps * velocity


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

    def output(self, t, ops=NUMPY):
        t = ops.asarray(t)
        terms = [0.0 * t]
        for h, a, b in zip(self.harmonics, self.cos_track, self.sin_track):
            ph = float(2 * np.pi * h * self.spindle_hz) * t
            terms.append(float(a) * ops.cos(ph) + float(b) * ops.sin(ph))
        return ops.sum(terms)


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
