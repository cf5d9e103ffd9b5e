"""The log as the linear part of a plant sees it, given the plant's effects.

Used by closing the loop to re-identify the linear plant (rigid body, modes, bias, delay:
what :func:`identification.estimate.identify.identify` models) once effects are accepted:
:func:`compensate` removes the effects from the data, :func:`reidentified` says which effects
survive a re-identification and which it estimates itself.  Units: tracks, A, s.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from identification.logs.seeklog import SeekLog
from identification.loop.grid import Grid, eval_forces, eval_inputs, eval_outputs
from identification.model.effects import AmplifierLag, ExtraMode, InputDelay
from identification.model.plant import ModalPlant

__all__ = ["compensate", "reidentified"]


def reidentified(plant: ModalPlant) -> tuple:
    """``(kept, absorbed)`` effects of ``plant`` when its linear part is identified again.

    An extra mode is part of what the identification estimates (its modes): absorbed.  Every
    other effect is kept and compensated in the data by :func:`compensate`: ``input``,
    ``force`` and ``output`` effects, pure delays, an amplifier lag (a filter on the current:
    left in the data, the identification would absorb it as delay and a damped "mode"), and
    structural effects that change the rigid body's own dynamics (a pivot spring), which the
    identification cannot represent."""
    kept, absorbed = [], []
    for e in plant.effects:
        (absorbed if isinstance(e, ExtraMode) else kept).append(e)
    return kept, absorbed


def _lag_average(u: np.ndarray, bandwidth_hz: float, h: float) -> np.ndarray:
    """Mean over each step ``h`` [s] of a first-order lag's output, for an input held over each
    step (exact integral; the lag starts in steady state)."""
    wa = 2 * math.pi * bandwidth_hz
    a = math.exp(-wa * h)
    g = (1.0 - a) / (wa * h)
    u = np.asarray(u, dtype=float)
    x = lfilter([0.0, 1.0 - a], [1.0, -a], u, zi=[u[0]])[0]     # lag state at the start of each step
    return u + (x - u) * g


def compensate(plant: ModalPlant, log: SeekLog, res=None, effect_step_s: float | None = None) -> SeekLog:
    """The log as the linear part of ``plant`` (rigid body, modes, bias, delay ``plant.delay_s``)
    sees it, given its effects.

    The current as the plant receives it (``SeekLog.input_current``: every sub-step of a
    multirate log) is mapped through the ``input`` effects at the measured position (on the
    grid of :class:`identification.loop.grid.Grid`), through the amplifier lag (mean output
    over each sub-step) and delayed by the extra delay of the ``input_delay`` effects; the
    current-equivalent of the state-dependent forces beyond the constant bias (bias table,
    friction, the pivot's rest force, stiffness and damping: the terms structural effects add
    to the rigid body's row of ``ModalPlant.state_space``), advanced by ``plant.delay_s`` (it
    enters undelayed), is added; ``output`` effects are subtracted from the position.  Effects
    are evaluated on the measured position and on the rigid-body velocity of the reference
    simulation ``res`` (``simulate(..., record=True)`` of ``plant``, which reproduces the
    model's own sticking in dwell) where it ran, else on the velocity estimated from the
    position.  ``current_a`` of the result is the mean of its sub-step columns."""
    t = log.time_s
    y = log.position_track - eval_outputs(plant.effects, t)
    grid = Grid(log, effect_step_s)
    v = grid.velocity[:, 0]
    if res is not None and res.state is not None:
        v = np.where(np.isfinite(res.state[:, 1]), res.state[:, 1], v)
    grid.position, grid.velocity = grid.interpolate(y), grid.interpolate(v)
    L, h = grid.L, log.dt / grid.L
    A = plant.state_space()[0]
    rest = plant.copy(bias_a=0.0)
    f = eval_forces(rest, grid.position, grid.velocity) + (A[1, 0] * grid.position + A[1, 1] * grid.velocity) / plant.k0
    f = grid.substep_mean(f).reshape(-1)
    k = np.arange(log.n * L, dtype=float)
    f = np.interp(k + plant.delay_s / h, k, f)
    cmd = grid.substep_mean(eval_inputs(plant.effects, grid.u_fine(), grid.position)).reshape(-1)
    for e in plant.effects:
        if isinstance(e, AmplifierLag):
            cmd = _lag_average(cmd, e.bandwidth_hz, h)
    extra = sum(e.delay_s for e in plant.effects if isinstance(e, InputDelay)) / h
    if extra:
        cmd = np.interp(k - extra, k, cmd)
    cur = (cmd + f).reshape(log.n, L)
    extra_cols = dict(log.extra)
    if L > 1:
        for j in range(L):
            extra_cols[f"current_sub{j + 1}_a"] = cur[:, j].copy()
    return SeekLog(t.copy(), cur.mean(axis=1), y, log.target_track.copy(), log.sample_rate_hz,
                   log.track_pitch_nm, dict(log.metadata), {kk: np.array(vv, copy=True) for kk, vv in extra_cols.items()},
                   log.source)
