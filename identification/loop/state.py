"""The loop's model under test: its reference residual on fit or validation data, its state, and
the backfit of one accepted effect and the joint refit of all (:func:`identification.loop.closing.close_loop`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identification.loop.candidates import fit_candidate
from identification.loop.fit_engine import Data
from identification.loop.joint import joint_refit
from identification.loop.residual import Residual, simulate
from identification.loop.result import Step, improved_fraction
from identification.loop.settings import LoopSettings
from identification.loop.stats import bic, effective_n, lstsq
from identification.model.plant import ModalPlant

__all__ = ["evaluate"]


# ----------------------------------------------------------------------- evaluation
def _harmonic_nuisance(res: Residual, plant: ModalPlant) -> np.ndarray:
    """For a separate validation log: the periodic disturbance's phase at the log start is
    unknown, so its cos/sin coefficients are re-estimated on one half of the windows and
    applied to the other (2-fold, halves in time) -- the error stays out of sample."""
    from identification.model.effects import PeriodicDisturbance
    pd = [e for e in plant.effects if isinstance(e, PeriodicDisturbance)]
    if not pd:
        return res.e
    t = res.log.time_s
    idx = res.windows.index()
    cols = []
    for e in pd:
        for h in e.harmonics:
            ph = 2 * np.pi * h * e.spindle_hz * t[idx]
            cols += [np.cos(ph), np.sin(ph)]
    X = np.column_stack(cols)
    half = np.zeros(len(idx), bool)
    half[:len(idx) // 2] = True
    e = res.e.copy()
    for a, b in ((half, ~half), (~half, half)):
        th = lstsq(res.e[a], X[a])[0]
        e[b] = res.e[b] - X[b] @ th
    return e


def evaluate(plant: ModalPlant, data: Data, same_log: bool = True, record: bool = False) -> Residual:
    """Reference residual of ``plant`` on ``data`` (per-seek simulation).  On a log other than
    the fit log, output effects (periodic disturbance) are re-phased out of sample."""
    if same_log:
        return simulate(plant, data.log, data.windows, continuous=False, record=record, grid=data.grid,
                        cache=data.cache)
    keep = [e for e in plant.effects if e.kind != "output"]
    res = simulate(plant.copy(effects=keep), data.log, data.windows, continuous=False, record=record,
                   grid=data.grid, cache=data.cache)
    return Residual(res.windows, _harmonic_nuisance(res, plant), res.y_sim, res.log, res.cmd, res.force, res.state)


# ------------------------------------------------------------------------------ state
@dataclass
class _State:
    """The current model and its residuals (fit and validation) with the fit data's BIC."""

    plant: ModalPlant
    fit: Residual
    val: Residual
    n_eff: float = 0.0
    bic: float = 0.0
    n_eff_rate: float = 0.0     #: the same for the error's first difference (:meth:`Windows.rate`)
    bic_rate: float = 0.0

    def rescore(self, fit: Data) -> "_State":
        self.n_eff = effective_n(self.fit.e, fit.windows)
        self.bic = bic(self.fit.e, 0, self.n_eff)
        r, w = fit.windows.rate(self.fit.e)
        self.n_eff_rate = effective_n(r, w)
        self.bic_rate = bic(r, 0, self.n_eff_rate)
        return self


def _backfit(name: str, cur: _State, fit: Data, val: Data, same: bool, it: int, why: str, st: LoopSettings):
    """Re-fit the (last) accepted effect ``name`` with the others in place; ``(Step, new state)``
    if the validation error drops, else ``(None, cur)``."""
    plant = cur.plant
    idx = [i for i, e in enumerate(plant.effects) if e.name == name]
    if not idx:
        return None, cur
    base = plant.copy(effects=[e for i, e in enumerate(plant.effects) if i != idx[-1]])
    try:
        F = fit_candidate(name, base, fit.freeze(base, evaluate(base, fit, record=True)), st)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None, cur
    if F is None:
        return None, cur
    rv = evaluate(F.plant, val, same, record=True)
    if rv.rms >= cur.val.rms:
        return None, cur
    step = Step(name, F.params, f"re-fitted {why} (backfitting)", cur.val.rms, rv.rms, True, it,
                float("nan"), rv.fit_percent, improved_fraction(rv, cur.val), 0, F.note, F.plant)
    return step, _State(F.plant, evaluate(F.plant, fit, record=True), rv)


def _joint(cur: _State, fit: Data, val: Data, same: bool, it: int, st: LoopSettings, say):
    """Joint output-error refit by simulation of the base and every accepted effect
    (:func:`identification.loop.joint.joint_refit`); ``(Step, new state)`` if the validation
    error drops, else ``(None, cur)``."""
    p = joint_refit(cur.plant, fit, st.joint_table_knots, st.joint_iters, progress=say)
    if p is cur.plant:
        return None, cur
    rv = evaluate(p, val, same, record=True)
    if rv.rms >= cur.val.rms:
        say(f"  joint refit: validation rms {rv.rms:.4g} (not below {cur.val.rms:.4g}): not kept")
        return None, cur
    step = Step("joint_refit", {}, "accepted effects and base re-fitted together by simulation", cur.val.rms, rv.rms,
                True, it, float("nan"), rv.fit_percent, improved_fraction(rv, cur.val), 0,
                "Levenberg-Marquardt on the output error of DiscretePlant simulations", p)
    return step, _State(p, evaluate(p, fit, record=True), rv)
