"""The loop's reference simulation of a plant with state-dependent effects, all seeks at once.

``DiscretePlant`` evaluates every effect on the *rigid-body* state (position ``x[0]``, velocity
``x[1]``) and its ``Phi`` is block diagonal: the modes never feed back into the rigid body or
into the effects.  The nonlinear feedback therefore runs through the rigid block alone, with
the amplifier lag and the delay line between the command and the rigid body.  So:

1. the rigid block, the lag and the delay line of ``plant.discretize(h)`` (the same ``Phi`` and
   ``Gamma`` entries) are stepped for every seek in parallel (numpy arrays over seeks; each seek
   from rest at its start as ``DiscretePlant.reset``, re-anchored at each window start), the
   effects evaluated on that state (:func:`identification.loop.grid.eval_inputs`,
   :func:`identification.loop.grid.eval_forces`), recording the command and force they apply;
2. the modes are the linear engine's response to those recorded sequences
   (:class:`identification.loop.linear.LinearModel`, flexible blocks, each seek restarted).

The sum equals stepping ``DiscretePlant`` seek by seek (``tests/test_residual.py`` checks it)
and is ~50x faster: stepping costs one numpy update per time step for all seeks instead of one
``DiscretePlant.step`` per seek and step.
"""
from __future__ import annotations

import numpy as np

from identification.loop.grid import eval_forces, eval_inputs
from identification.loop.linear import LinearModel
from identification.model.plant import ModalPlant

__all__ = ["step_seeks", "flexible_response"]


def step_seeks(plant: ModalPlant, dt: float, U: np.ndarray, spans: list, anchors: dict):
    """Simulate ``plant`` over the runs ``spans`` (``[(a, b)]`` samples), ``U`` ``(n, S)`` the command
    current [A] held over each of the ``S`` steps of a sample, ``anchors`` ``{sample: (position,
    velocity)}`` where the rigid state is set (each run's start must be one).

    Returns ``(y, cmd, force, state, hist)``: the rigid body's position at the samples of the runs
    [track] (NaN elsewhere), ``(n, S)`` command after input effects and net undelayed force [A]
    applied at each step, ``(n, 2)`` rigid position and velocity at the samples, the command
    held before each run [A]."""
    n, S = U.shape
    h = dt / S
    dp = plant.discretize(h)
    m = dp.m
    lag = dp.lag
    P, gn, go, gf = dp.Phi[:2, :2], dp.G_new[:2], dp.G_old[:2], dp.G_f[:2]
    pl = dp.Phi[:2, lag] if lag is not None else None
    A0 = np.array([a for a, _ in spans]); lens = np.array([b - a for a, b in spans])
    R, width = len(spans), int(lens.max()) * S
    Uf = U.reshape(-1)
    x = np.array([anchors[a] for a in A0], float)                        # (R, 2) rigid state
    c_hist = eval_inputs(plant.effects, U[np.maximum(A0 - 1, 0), -1], x[:, 0])   # current held before each run
    c_ext = np.empty((R, width + m + 1))
    c_ext[:, :m + 1] = c_hist[:, None]                                    # the delay line, full of it
    xl = c_hist.copy()                                                    # the lag in steady state
    f_rec = np.zeros((R, width))
    y_rec = np.full((R, width // S), np.nan)
    v_rec = np.full((R, width // S), np.nan)
    starts = {}
    for a in anchors:
        r = int(np.searchsorted(A0, a, side="right")) - 1
        if 0 <= r < R and a < A0[r] + lens[r]:
            starts.setdefault((a - A0[r]) * S, []).append((r, anchors[a]))
    for j in range(width):
        if j in starts:
            for r, (p0, v0) in starts[j]:
                x[r] = (p0, v0)
        if j % S == 0:
            y_rec[:, j // S] = x[:, 0]
            v_rec[:, j // S] = x[:, 1]
        u = Uf[np.minimum(A0 * S + j, n * S - 1)]
        cmd = eval_inputs(plant.effects, u, x[:, 0])
        f = eval_forces(plant, x[:, 0], x[:, 1])
        c_ext[:, j + m + 1] = cmd
        un, uo = c_ext[:, j + 1], c_ext[:, j]
        xn = x @ P.T + un[:, None] * gn + uo[:, None] * go + f[:, None] * gf
        if lag is not None:
            xn += xl[:, None] * pl
            xl = dp.Phi[lag, lag] * xl + dp.G_new[lag] * un + dp.G_old[lag] * uo
        x = xn
        f_rec[:, j] = f
    # back to the log's grid
    cmd = np.zeros(n * S); force = np.zeros(n * S)
    y = np.full(n, np.nan); state = np.full((n, 2), np.nan)
    for r, (a, L) in enumerate(zip(A0, lens)):
        cmd[a * S:(a + L) * S] = c_ext[r, m + 1:m + 1 + L * S]
        force[a * S:(a + L) * S] = f_rec[r, :L * S]
        y[a:a + L] = y_rec[r, :L]
        state[a:a + L] = np.column_stack([y_rec[r, :L], v_rec[r, :L]])
    return y, cmd.reshape(n, S), force.reshape(n, S), state, c_hist


def flexible_response(plant: ModalPlant, dt: float, cmd: np.ndarray, force: np.ndarray, windows, hist,
                      cache=None):
    """The modes' (and lag's) contribution [track] at the samples to the recorded ``(n, S)``
    command and force, each seek restarted from ``hist`` (:meth:`LinearModel.response`)."""
    lm = LinearModel(plant, dt, cmd.shape[1], cache)
    return lm.response(cmd, force, windows, with_rigid=False, hist_cmd=hist)
