"""Joint output-error refit by simulation of the base and the accepted effects.

Every candidate is fitted by the fast engine (:mod:`identification.loop.fit_engine`) on the
*measured* position and velocity, and the effects already accepted are re-fitted one at a time
(backfitting).  That is exact for effects the measured signals reproduce (a bias table, Kt(p))
but not for friction: while the head sticks only the model's own state says which force holds
it, so a table, a torque constant or ``k0`` fitted with the friction force frozen from one
simulation is co-adapted with that simulation's sticking, and each effect re-fitted alone
cannot undo what the others absorbed.  :func:`joint_refit` re-fits them together on the fit
data by ``DiscretePlant`` simulation (:func:`identification.loop.residual.simulate`, the loop's
reference simulation): Levenberg-Marquardt on the output error, the Jacobian by forward
differences of simulations.

Coordinates (each scaled so that one unit is a small, resolvable change; the forward-difference
step is one unit): ``k0`` (relative), the constant ``bias_a``, the declared modes' gains
(relative), the Kt(p) coefficients, a correction of a position-bias table on
``settings.joint_table_knots`` coarse hats over the fitted positions, the friction's Coulomb
level (relative) and viscous coefficient (relative).  Units: tracks, A, s.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from identification.loop.fit_engine import Data, Fit, hats
from identification.loop.residual import simulate
from identification.model.effects import Friction, PositionBias, TorqueConstantVariation
from identification.model.plant import ModalPlant

__all__ = ["JointScales", "joint_refit", "needs_joint_refit", "held_base"]

#: effects whose force only the model's own state reproduces (fitted on frozen simulations)
STATE_HELD = (Friction,)


@dataclass(frozen=True)
class JointScales:
    """One coordinate unit of :func:`joint_refit` (also its forward-difference step).

    k0_rel : relative change of ``k0`` [-]
    bias_a : change of the constant bias and of each coarse table hat [A]
    gain_rel : relative change of a declared mode's gain [-]
    kt_coeff : change of a Kt(p) coefficient [-]
    coulomb_rel : relative change of the Coulomb level [-]
    viscous_rel : relative change of the viscous coefficient [-]
    """

    k0_rel: float = 2e-3
    bias_a: float = 2e-5
    gain_rel: float = 2e-2
    kt_coeff: float = 2e-3
    coulomb_rel: float = 2e-2
    viscous_rel: float = 0.1


def needs_joint_refit(plant: ModalPlant) -> bool:
    """True when ``plant`` has an effect whose force only its own simulation reproduces."""
    return any(isinstance(e, STATE_HELD) for e in plant.effects)


def _maker(plant: ModalPlant, data: Data, table_knots: int, sc: JointScales):
    """``(make(x) -> plant, number of coordinates)`` for the coordinates of the module notes."""
    eff = list(plant.effects)
    i_tab = [i for i, e in enumerate(eff) if isinstance(e, PositionBias)]
    i_kt = [i for i, e in enumerate(eff) if isinstance(e, TorqueConstantVariation)]
    i_fr = [i for i, e in enumerate(eff) if isinstance(e, Friction)]
    n_modes = len(plant.modes)
    H = None
    if i_tab and table_knots > 0:
        pos = data.log.position_track[data.windows.index()]
        coarse = np.linspace(float(pos.min()), float(pos.max()), max(int(table_knots), 2))
        H = np.array(hats(np.asarray(eff[i_tab[-1]].knots_track, float), coarse))     # (K, knots)
    sizes = [1, 1, n_modes, sum(len(eff[i].coeffs) for i in i_kt), 0 if H is None else len(H), 2 * len(i_fr)]

    def make(x):
        x = np.asarray(x, float)
        parts = np.split(x, np.cumsum(sizes)[:-1])
        modes = [replace(m, gain=m.gain * (1.0 + sc.gain_rel * float(xm))) for m, xm in zip(plant.modes, parts[2])]
        new = list(eff)
        j = 0
        for i in i_kt:
            e = eff[i]
            c = [float(v) + sc.kt_coeff * float(parts[3][j + k]) for k, v in enumerate(e.coeffs)]
            j += len(e.coeffs)
            new[i] = TorqueConstantVariation(c, e.center_track, e.scale_track)
        if H is not None:
            t = eff[i_tab[-1]]
            new[i_tab[-1]] = PositionBias(list(t.knots_track),
                                          [float(v) for v in np.asarray(t.bias_a, float) + sc.bias_a * (parts[4] @ H)])
        for k, i in enumerate(i_fr):
            f = eff[i]
            new[i] = Friction(float(max(f.coulomb_a * (1.0 + sc.coulomb_rel * parts[5][2 * k]), 0.0)),
                              float(max(f.viscous_a_per_tps * (1.0 + sc.viscous_rel * parts[5][2 * k + 1]), 0.0)))
        return plant.copy(k0=plant.k0 * (1.0 + sc.k0_rel * float(parts[0][0])),
                          bias_a=plant.bias_a + sc.bias_a * float(parts[1][0]), modes=modes, effects=new)
    return make, int(sum(sizes))


def joint_refit(plant: ModalPlant, data: Data, table_knots: int = 5, max_iters: int = 6,
                scales: JointScales = JointScales(), progress=None) -> ModalPlant:
    """Levenberg-Marquardt on the output error of ``data``'s windows (``DiscretePlant``
    simulation, one anchor pass) over the coordinates of the module notes; forward-difference
    Jacobian (one simulation per coordinate).  Returns ``plant`` itself when no step lowers the
    sum of squares.

    Parameters
    ----------
    plant : ModalPlant
        The plant with its accepted effects.
    data : Data
        Fit data (windows simulated from rest at each seek start, re-anchored per window).
    table_knots : int
        Coarse knots of a position-bias table's correction (0: table kept).
    max_iters : int
        Jacobian evaluations at most.
    scales : JointScales
        One unit of each coordinate [units of the parameter].
    """
    make, n = _maker(plant, data, table_knots, scales)

    def res(x):
        return simulate(make(x), data.log, data.windows, passes=1, continuous=False, grid=data.grid,
                        cache=data.cache).e
    x = np.zeros(n)
    r = res(x)
    f = float(r @ r)
    f_start = f_prev = f
    mu = 1e-3
    say = progress or (lambda *a: None)
    for it in range(max_iters):
        J = np.column_stack([res(x + np.eye(n)[j]) - r for j in range(n)])        # unit steps
        g, A = J.T @ r, J.T @ J
        d = np.sqrt(np.maximum(np.diag(A), 1e-30 * max(np.max(np.diag(A)), 1e-300)))
        As, gs = A / np.outer(d, d), g / d
        moved = False
        for _ in range(4):
            dx = -np.linalg.solve(As + mu * np.eye(n), gs) / d
            rn = res(x + dx)
            fn = float(rn @ rn)
            if fn < f:
                x, r, f, moved = x + dx, rn, fn, True
                mu = max(mu / 3.0, 1e-6)
                break
            mu *= 8.0
        say(f"joint refit iteration {it + 1}: rms {np.sqrt(f / len(r)):.4g} track (mu {mu:.2g})")
        if not moved or f > (1.0 - 1e-3) * f_prev:
            break
        f_prev = f
    return make(x) if f < f_start else plant


def held_base(F, plant: ModalPlant, fit: Data):
    """A candidate fitted on top of a plant whose effects only its own simulation reproduces
    (friction, :func:`needs_joint_refit`): the fast engine re-fits the base (``k0``, bias, mode
    gains, Kt coefficients) against the friction force frozen from one simulation, which does
    not follow the sticking those changes cause, so after a joint refit by simulation that
    re-fit can undo it.  The candidate's effect on the base as it was is the alternative; the
    one with the lower output error on the fit data (simulated) is kept.  Only for candidates
    that add effects and leave the modes and the delay alone."""
    if len(F.plant.modes) != len(plant.modes) or F.plant.delay_s != plant.delay_s:
        return F
    have = [e for e in plant.effects]
    eff = []
    for e in F.plant.effects:
        same = [h for h in have if h.name == e.name]
        if same:
            eff.append(same[0])
            have.remove(same[0])
        else:
            eff.append(e)
    if have or len(eff) == len(plant.effects):
        return F
    alt = plant.copy(effects=eff)

    def sse(p):
        e = simulate(p, fit.log, fit.windows, continuous=False, grid=fit.grid, cache=fit.cache).e
        return float(e @ e)
    if sse(alt) < sse(F.plant):
        return Fit(F.effect, alt, F.n_params, F.params, (F.note + "; " if F.note else "") + "base kept")
    return F
