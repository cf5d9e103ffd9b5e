"""Friction candidate of closing the loop: Coulomb + viscous, with sticking.

Fitted in two stages: a fast model on the measured signals (a head at rest holds while the
applied force is below the Coulomb level), then the bias and the Coulomb level refined by
``DiscretePlant`` simulation -- when the head sticks only the model's own state reproduces
the friction force, and the rigid body turns a 1e-6 A bias error into a visible position
error.  With a position-bias table in the plant its shape is refined by simulation too
(:func:`sim_refine_table`): a head held by friction does not feel a change of the table, so
the table's own (linear, penalised) fit cannot correct where the head dwells, and a table
fitted before friction was modelled keeps what sticking made of it.  Units: tracks, A, s.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from identification.loop.fit_engine import Data, Engine, Fit, hats, linear_fit, rebase, refit_base
from identification.loop.residual import simulate
from identification.loop.stats import lstsq
from identification.model.effects import Friction, PositionBias
from identification.model.plant import ModalPlant

__all__ = ["fit_friction", "sim_refine", "sim_refine_table", "polish"]


def _friction_force(c, vis, bias, u_del, v, moving, other=0.0):
    """Fast friction model from measured signals [A]: ``-c sign(v) - vis v`` while moving,
    and while stuck the force that holds the head, ``-clip(u + bias + other, -c, c)``: everything
    else that pushes it -- the delivered command ``u`` (input effects applied), the constant bias
    and the plant's other forces at the measured position ``other`` (a position-bias table)."""
    return np.where(moving, -c * np.sign(v) - vis * v, -np.clip(u_del + bias + other, -c, c))


def fit_friction(plant, data, settings):
    g = data.grid
    v = data.on_grid(g.velocity)                                   # (n, L)
    ap, (c, vis), _, w = linear_fit(plant, data, [data.on_grid(-np.tanh(g.velocity / data.v_scale)), -v],
                                    bounds=([0, 0], [np.inf, np.inf]))
    if w < settings.min_wald_chi2:
        return None
    # 1. fast model with sticking (a head at rest stays while |u + bias| < c), base jointly
    eng = Engine(plant, data)
    m = eng.lm.m                                                   # delay in sub-steps
    u = eng.cmd.reshape(-1)
    u_del = np.r_[np.full(m + 1, u[0]), u[:len(u) - m - 1]].reshape(eng.cmd.shape)
    moving = np.abs(v) > 2 * data.v_scale
    other = eng.force - plant.bias_a           # the plant's forces beyond its constant bias (bias table, pivot)
    base = eng.base_cols()
    B = eng.project(*[base[i] for i in range(len(base)) if i != 1])
    c0, v0 = max(c / (1 + ap.k), 1e-6), max(vis / (1 + ap.k), 1e-12)

    def fast(x):
        cc, bb, vv = abs(c0 * (1 + x[0])), plant.bias_a + c0 * x[1], abs(v0 * (1 + x[2]))
        col = eng.resp(force=_friction_force(cc, vv, bb, u_del, v, moving, other) + bb - plant.bias_a)
        th, sse = lstsq(eng.project(eng.target() - col)[:, 0], B)
        return sse, th, (cc, bb, vv)
    x = minimize(lambda x: fast(x)[0], np.zeros(3), method="Nelder-Mead",
                 options={"maxiter": 150, "xatol": 2e-3, "initial_simplex": np.vstack([np.zeros(3), 0.2 * np.eye(3)])}).x
    _, th, (cc, bb, vv) = fast(x)
    full = np.r_[th[0], 0.0, th[1:]]
    p = rebase(plant.copy(bias_a=bb), full, eng.setters, effects=plant.effects + [Friction(float(cc), float(vv))])
    # 2. bias and Coulomb level by simulation (the rigid body integrates 1e-6 A errors visibly)
    sub = data.subset(settings.search_samples)
    p = sim_refine(p, sub)
    p = sim_refine_table(p, sub, settings.friction_table_knots, settings.friction_table_evals)
    p = polish(p, data, 1, bias=False)
    return Fit("friction", p, 2, p.effects[-1].params,
               "fast sticking model, then bias and Coulomb level refined by DiscretePlant simulation")


def sim_refine(plant: ModalPlant, data: Data, rounds=("bias", "coulomb", "bias"), max_shifts: int = 4) -> ModalPlant:
    """Coordinate refinement (Brent, by ``DiscretePlant`` simulation) of ``bias_a`` and of the
    last effect's (friction) Coulomb level.  Each search runs on +-5 % (bias) / +-15 % (Coulomb)
    of the Coulomb level; when its optimum ends at an end of that interval, the interval is moved
    there (at most ``max_shifts`` times): the fast model's start can be further off than that
    (other effects the measured signals do not reproduce)."""
    for what in rounds:
        fr = plant.effects[-1]
        c = fr.coulomb_a
        if what == "bias":
            def make(x, p=plant):
                return p.copy(bias_a=p.bias_a + x)
            lo, hi = -0.05 * c, 0.05 * c
        else:
            def make(x, p=plant, fr=fr):
                return p.copy(effects=p.effects[:-1] + [Friction(max(fr.coulomb_a + x, 0.0), fr.viscous_a_per_tps)])
            lo, hi = -0.15 * c, 0.15 * c

        def cost(x):
            return _sim_sse(make(x), data)
        best, f0 = 0.0, cost(0.0)
        for _ in range(1 + max_shifts):     # an optimum at the end of the interval: the interval moves on
            a, b = best + lo, best + hi
            r = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 0.002 * c, "maxiter": 14})
            if not r.fun < f0:
                break
            best, f0 = float(r.x), float(r.fun)
            if min(best - a, b - best) > 0.05 * (b - a) or (what == "coulomb" and fr.coulomb_a + best <= 0.0):
                break
        if best:
            plant = make(best)
    return plant


def _sim_sse(plant: ModalPlant, data: Data) -> float:
    """Output-error sum of squares [track^2] of ``plant`` simulated (``DiscretePlant``, one pass) on
    ``data``'s windows: the cost both simulation refinements minimise."""
    e = simulate(plant, data.log, data.windows, passes=1, continuous=False, grid=data.grid, cache=data.cache).e
    return float(e @ e)


def sim_refine_table(plant: ModalPlant, data: Data, knots: int = 5, max_evals: int = 150) -> ModalPlant:
    """Shape of the plant's position-bias table and the last effect's (friction) Coulomb level,
    refined jointly by ``DiscretePlant`` simulation (Powell on the output-error sum of squares of
    ``data``).  The table gets a correction ``coulomb * sum_j x_j hat_j(p)`` on ``knots`` equally
    spaced coarse knots over the positions of ``data``'s windows (held constant beyond them), the
    Coulomb level a factor ``1 + x``.  Returns ``plant`` unchanged without a table, with
    ``knots`` 0, or when the search does not lower the cost."""
    idx = [i for i, e in enumerate(plant.effects) if isinstance(e, PositionBias)]
    if not idx or knots <= 0 or max_evals <= 0:
        return plant
    i_tab, tab, fr = idx[-1], plant.effects[idx[-1]], plant.effects[-1]
    c = fr.coulomb_a
    if c <= 0.0:
        return plant
    kn, v0 = np.asarray(tab.knots_track, float), np.asarray(tab.bias_a, float)
    pos = data.log.position_track[data.windows.index()]
    H = np.array(hats(kn, np.linspace(float(pos.min()), float(pos.max()), max(int(knots), 2))))   # (K, knots)
    K = len(H)

    def make(x):
        eff = list(plant.effects)
        eff[i_tab] = PositionBias([float(k) for k in kn], [float(b) for b in v0 + c * (x[:K] @ H)])
        eff[-1] = Friction(float(max(c * (1.0 + x[K]), 0.0)), fr.viscous_a_per_tps)
        return plant.copy(effects=eff)

    def cost(x):
        return _sim_sse(make(x), data)
    x0 = np.zeros(K + 1)
    f0 = cost(x0)
    r = minimize(cost, x0, method="Powell", options={"xtol": 2e-3, "ftol": 1e-4, "maxfev": int(max_evals)})
    return make(r.x) if r.fun < f0 else plant


def polish(plant: ModalPlant, data: Data, iters: int = 2, bias: bool = True) -> ModalPlant:
    """Base re-fit with the command and force sequences of the plant's own simulation
    (for effects the measured signals do not reproduce, e.g. friction sticking);
    ``bias=False`` keeps ``bias_a``."""
    for _ in range(iters):
        res = simulate(plant, data.log, data.windows, continuous=False, record=True, grid=data.grid,
                       cache=data.cache)
        new = refit_base(plant, data.freeze(plant, res), iters=1)
        plant = new if bias else new.copy(bias_a=plant.bias_a)
    return plant
