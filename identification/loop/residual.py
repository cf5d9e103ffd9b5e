"""Output-error residual of a plant model on a seek log: the loop's reference simulation.

The model is simulated from the *measured* current with the one discretisation
(:class:`identification.model.discrete.DiscretePlant`, effects included) on the windows of
:mod:`identification.loop.windows`: each seek from rest at its start (previous current held),
re-anchored at every window start, where the rigid-body position and velocity are fitted by
least squares (linear nuisance parameters).  ``residual = measured - simulated`` [track].

The plant is stepped at the drive's sub-step ``dt / L`` with the logged sub-step currents
(``SeekLog.input_current``), and, when it has state-dependent effects, ``M`` times per sub-step
(:class:`identification.loop.grid.Grid`): the effects then follow the head within a sample as
they do on the drive.  The fast engine used for fitting is :mod:`identification.loop.linear`;
the statistics of the residual are in :mod:`identification.loop.analysis`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identification.logs.seeklog import SeekLog
from identification.loop.grid import Grid, eval_forces, eval_inputs, eval_outputs, has_state_effects
from identification.loop.hybrid import flexible_response, step_seeks
from identification.loop.linear import LinearModel
from identification.loop.windows import Windows, seek_windows
from identification.model.plant import ModalPlant

__all__ = ["Residual", "simulate", "residual", "fit_percent", "rms"]


def rms(e: np.ndarray) -> float:
    """Root mean square [same unit as ``e``]."""
    return float(np.sqrt(np.mean(np.square(e)))) if len(e) else float("nan")


@dataclass
class Residual:
    """Measured minus simulated position on a set of windows.

    Attributes
    ----------
    windows : Windows
    e : ndarray
        Residual [track] on the window samples (concatenated, see ``windows.index()``).
    y_sim : ndarray
        Simulated position [track], anchored, full log length (NaN outside windows).
    log : SeekLog
    cmd, force : ndarray or None
        With ``simulate(..., record=True)``: ``(n, L)`` command after ``input`` effects and net
        undelayed force (bias + ``force`` effects) the simulation applied, mean over each
        sub-step [A] (NaN where not simulated).
    state : ndarray or None
        With ``record=True``: ``(n, 2)`` rigid-body position [track] and velocity [track/s]
        of the simulation at each sample (NaN where not simulated).
    """

    windows: Windows
    e: np.ndarray
    y_sim: np.ndarray
    log: SeekLog
    cmd: np.ndarray | None = None
    force: np.ndarray | None = None
    state: np.ndarray | None = None

    @property
    def rms(self) -> float:
        return rms(self.e)

    @property
    def rate_rms(self) -> float:
        """RMS of the residual's first difference within each window [track/sample]
        (:meth:`Windows.rate`: the part of the error the fast dynamics set)."""
        return rms(self.windows.rate(self.e)[0])

    @property
    def fit_percent(self) -> float:
        return fit_percent(self.log, self.windows, self.e)

    def full(self) -> np.ndarray:
        """Residual on the full log grid (NaN outside windows)."""
        out = np.full(self.log.n, np.nan)
        out[self.windows.index()] = self.e
        return out


def fit_percent(log: SeekLog, windows: Windows, e: np.ndarray) -> float:
    """NRMSE fit ``100 (1 - |e| / |y - mean_w(y)|)`` [%], ``mean_w`` the per-window mean."""
    y = log.position_track
    den = np.concatenate([y[a:b] - y[a:b].mean() for a, b in windows.bounds])
    return float(100.0 * (1.0 - np.linalg.norm(e) / max(np.linalg.norm(den), 1e-300)))


def _anchor(y, ysim, windows, basis):
    """Per-window least-squares anchors: ``(residual on the window samples, anchored simulation,
    {window start: (position, velocity) corrections})``."""
    e_parts, ys, corr = [], np.full(len(y), np.nan), {}
    for a, b in windows.bounds:
        B = basis(b - a)
        r = y[a:b] - ysim[a:b]
        c, *_ = np.linalg.lstsq(B, r, rcond=None)
        ys[a:b] = ysim[a:b] + B @ c
        e_parts.append(r - B @ c)
        corr[a] = c
    return (np.concatenate(e_parts) if e_parts else np.zeros(0)), ys, corr


def _simulate_filter(plant, log, windows, continuous, record, grid, cache):
    """The exact linear engine for plants without state-dependent effects (equal to stepping
    ``DiscretePlant``; ``tests/test_residual.py`` checks it)."""
    lm = LinearModel(plant, log.dt, grid.L, cache)
    cmd = eval_inputs(plant.effects, grid.u, None)
    force = np.broadcast_to(eval_forces(plant, np.zeros(1), np.zeros(1))[0], cmd.shape)
    ysim = lm.response(cmd, force, windows, restart=not continuous) + eval_outputs(plant.effects, log.time_s)
    e, ys, _ = _anchor(log.position_track, ysim, windows, lm.free_basis)
    if not record:
        return Residual(windows, e, ys, log)
    inside = np.zeros(log.n, bool)
    inside[windows.index()] = True
    cmd_r = np.where(inside[:, None], cmd, np.nan)
    f_r = np.where(inside[:, None], force, np.nan)
    return Residual(windows, e, ys, log, cmd_r, f_r, None)


def simulate(plant: ModalPlant, log: SeekLog, windows: Windows, passes: int | None = None,
             continuous: bool = True, record: bool = False, grid: Grid | None = None,
             engine: str = "auto", cache: dict | None = None) -> Residual:
    """Reference simulation: ``DiscretePlant`` stepped from the measured current, rigid
    states re-anchored at each window start, anchors fitted by least squares.

    Parameters
    ----------
    plant : ModalPlant
        Model, effects included.
    log : SeekLog
    windows : Windows
    passes : int, optional
        Anchor passes; default 1 for plants whose effects do not depend on the state,
        else 2 (the second starts from the anchors fitted by the first).
    continuous : bool
        True: step the whole log (modes, amplifier and delay line carry over between
        windows).  False: step each seek only, from rest at its start
        (``DiscretePlant.reset`` with the previous current held before it).
    record : bool
        Also record the command and force sequences applied (last pass) and, when stepped,
        the rigid-body state.
    grid : Grid, optional
        Sub-step currents and the evaluation steps of state-dependent effects (default
        ``Grid(log)``: the logged sub-steps, one evaluation each).
    engine : str
        ``"step"``: step ``DiscretePlant``; ``"filter"``: the exact linear engine
        (:class:`identification.loop.linear.LinearModel`), only for plants without
        state-dependent effects; ``"hybrid"``: the rigid body stepped for all seeks at once and
        the modes filtered (:mod:`identification.loop.hybrid`), only per seek
        (``continuous=False``); ``"auto"``: the filter, else the hybrid where they apply.  All
        equal ``"step"`` to round-off.
    cache : dict, optional
        Filters of the linear engine (held by the caller).
    """
    grid = grid or Grid(log)
    state_dep = has_state_effects(plant)
    if engine == "filter" and state_dep:
        raise ValueError("the linear engine cannot simulate state-dependent effects")
    if engine in ("auto", "filter") and not state_dep:
        return _simulate_filter(plant, log, windows, continuous, record, grid, cache)
    y, dt = log.position_track, log.dt
    passes = passes or (2 if state_dep else 1)
    M = grid.M if state_dep else 1
    steps = grid.L * M                    # DiscretePlant steps per log sample
    U = np.repeat(grid.u, M, axis=1) if M > 1 else grid.u
    v = grid.velocity[:, 0]
    anchors = {a: (y[a], v[a]) for a, _ in windows.bounds}
    basis = LinearModel(plant.linear_part(), dt, 1, cache).free_basis

    def per_substep(x):
        return x.reshape(log.n, grid.L, M).mean(axis=2) if M > 1 else x
    if engine in ("auto", "hybrid") and not continuous:
        y_out = eval_outputs(plant.effects, log.time_s)
        for _ in range(passes):
            yr, cmd_s, f_s, state, hist = step_seeks(plant, dt, U, windows.spans(), anchors)
            ysim = yr + flexible_response(plant, dt, cmd_s, f_s, windows, hist, cache) + y_out
            e, ys, corr = _anchor(y, ysim, windows, basis)
            for a, c in corr.items():
                anchors[a] = (anchors[a][0] + c[0], anchors[a][1] + c[1])
        if not record:
            return Residual(windows, e, ys, log)
        inside = np.zeros(log.n, bool)
        inside[windows.index()] = True
        return Residual(windows, e, ys, log, np.where(inside[:, None], per_substep(cmd_s), np.nan),
                        np.where(inside[:, None], per_substep(f_s), np.nan), state)
    starts = set(anchors)
    spans = [(0, log.n)] if continuous else windows.spans()
    for _ in range(passes):
        dp = plant.discretize(dt / steps)
        if continuous:
            dp.reset(y[0], 0.0, current=U[0, 0], t0=log.time_s[0])
        ysim = np.full(log.n, np.nan)
        step, output = dp.step, dp.output
        xs = np.full((log.n, steps, 2), np.nan) if record else None
        for a0, b0 in spans:
            if not continuous:   # from rest at the seek start; time keeps the log's origin
                dp.reset(*anchors[a0], current=U[max(a0 - 1, 0), -1], t0=log.time_s[0])
                dp.k = a0 * steps
            for k in range(a0, b0):
                if k in starts:
                    dp.x[0], dp.x[1] = anchors[k]
                ysim[k] = output()
                if record:
                    for j in range(steps):
                        xs[k, j] = dp.x[:2]
                        step(U[k, j])
                else:
                    for j in range(steps):
                        step(U[k, j])
        e, ys, corr = _anchor(y, ysim, windows, basis)
        for a, c in corr.items():
            anchors[a] = (anchors[a][0] + c[0], anchors[a][1] + c[1])
    if not record:
        return Residual(windows, e, ys, log)
    # what the steps applied, from the recorded rigid states (the effects' own definitions)
    cmd_r = per_substep(eval_inputs(plant.effects, U, xs[:, :, 0]))
    f_r = per_substep(eval_forces(plant, xs[:, :, 0], xs[:, :, 1]))
    return Residual(windows, e, ys, log, cmd_r, f_r, xs[:, 0, :].copy())


def residual(plant: ModalPlant, log: SeekLog, windows: Windows | None = None) -> Residual:
    """:func:`simulate` on :func:`identification.loop.windows.seek_windows` by default."""
    return simulate(plant, log, windows or seek_windows(log))

