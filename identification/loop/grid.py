"""The log on the plant's sub-step grid, and the plant's effects evaluated on it.

A drive holds ``L`` currents per log sample (a multirate controller; ``L = 1`` for a
single-rate log) and its plant evolves continuously in between, so an effect that depends on
the head's position or velocity (position bias, torque-constant variation, friction) changes
*within* a sample: during a 20 000-track seek the head moves by hundreds of tracks per sample.
Evaluated once per sample at its start, a 60 mA bias slope over the stroke then acts a
fraction of a sample late: a force error proportional to the velocity that the rigid body
integrates to tracks over one window.  So the loop evaluates state-dependent effects ``M``
times per sub-step (``M`` from :attr:`LoopSettings.effect_step_s`), on the position
interpolated between the measured samples, and averages them over each sub-step; the
reference simulation (:func:`identification.loop.residual.simulate`) steps ``DiscretePlant`` at
the same ``dt / (L M)``.

Units: position [track], velocity [track/s], current and current-equivalent force [A].
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import savgol_filter

from identification.logs.seeklog import SeekLog
from identification.model.effects import CurrentSaturation, PivotSpringDamper
from identification.model.ops import NUMPY, SmoothingSettings, numpy_ops
from identification.model.plant import ModalPlant

__all__ = ["Grid", "velocity_estimate", "eval_inputs", "eval_forces", "eval_outputs", "has_state_effects"]


def velocity_estimate(log: SeekLog, window: int = 9) -> np.ndarray:
    """Head velocity [track/s] from the measured position (Savitzky-Golay derivative)."""
    w = max(5, min(window | 1, log.n - (1 - log.n % 2)))
    return savgol_filter(log.position_track, w, 2, deriv=1, delta=log.dt)


def has_state_effects(plant: ModalPlant) -> bool:
    """True when the plant has effects evaluated on its state: ``force`` effects and ``input``
    effects other than a current saturation (which depends on the current only)."""
    return any(e.kind == "force" or (e.kind == "input" and not isinstance(e, CurrentSaturation))
               for e in plant.effects)


class Grid:
    """The log on a grid of ``S = L M`` points per sample (``L`` held currents, ``M`` effect
    evaluations per held current).

    Attributes
    ----------
    L, M, S : int
    u : ndarray ``(n, L)``
        Current per sub-step [A] (``SeekLog.input_current``).
    position, velocity : ndarray ``(n, S)``
        Measured position [track] and velocity estimate [track/s] interpolated linearly to
        ``t_k + j dt / S``, ``j = 0..S-1`` (the start of each evaluation step).
    """

    def __init__(self, log: SeekLog, effect_step_s: float | None = None, velocity: np.ndarray | None = None):
        u = log.input_current()
        self.u = u.reshape(log.n, -1)
        self.L = self.u.shape[1]
        h = log.dt / self.L
        self.M = max(1, math.ceil(h / effect_step_s - 1e-9)) if effect_step_s else 1
        self.S = self.L * self.M
        self.n = log.n
        v = velocity_estimate(log) if velocity is None else velocity
        self.position = self.interpolate(log.position_track)
        self.velocity = self.interpolate(v)

    def interpolate(self, x: np.ndarray) -> np.ndarray:
        """Per-sample ``x`` -> ``(n, S)`` linearly interpolated (held after the last sample)."""
        x = np.asarray(x, float)
        nxt = np.r_[x[1:], x[-1]]
        frac = np.arange(self.S) / self.S
        return x[:, None] + (nxt - x)[:, None] * frac[None, :]

    def u_fine(self) -> np.ndarray:
        """``(n, S)`` current at every evaluation step (each sub-step current held ``M`` times)."""
        return np.repeat(self.u, self.M, axis=1) if self.M > 1 else self.u

    def substep_mean(self, x: np.ndarray) -> np.ndarray:
        """``(n, S)`` -> ``(n, L)``: mean over the ``M`` evaluations of each sub-step."""
        return x.reshape(self.n, self.L, self.M).mean(axis=2) if self.M > 1 else x


# ---------------------------------------------------------------- vectorised effects
def eval_inputs(effects, u: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Apply ``input`` effects (in order) to currents [A] at ``position`` [track] (same shapes): each
    effect's own :meth:`~identification.model.effects.Effect.input_map` on arrays."""
    for e in effects:
        if e.kind == "input":
            u = e.input_map(u, position)
    return u


def eval_forces(plant: ModalPlant, position: np.ndarray, velocity: np.ndarray,
                v_scale: float = 0.0) -> np.ndarray:
    """Undelayed current-equivalent force [A]: bias, pivot rest offset, ``force`` effects (each
    effect's own :meth:`~identification.model.effects.Effect.force` on arrays).

    ``v_scale`` [track/s] smooths ``sign(v)`` as ``tanh(v / v_scale)`` (velocity estimated
    from a noisy position: near zero velocity its sign is unknown)."""
    ops = numpy_ops(SmoothingSettings(friction_velocity_tps=v_scale)) if v_scale > 0 else NUMPY
    f = np.full(np.shape(position), float(plant.bias_a))
    for e in plant.effects:
        if isinstance(e, PivotSpringDamper):
            f += e.rest_force_a(plant.k0)
        elif e.kind == "force":
            f += e.force(position, velocity, ops)
    return f


def eval_outputs(effects, t: np.ndarray) -> np.ndarray:
    """Sum of ``output`` effects [track] at times ``t`` [s]."""
    out = np.zeros(len(t))
    for e in effects:
        if e.kind == "output":
            out += e.output(t)
    return out
