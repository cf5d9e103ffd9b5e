"""The loop's joint output-error refit by simulation (identification/loop/joint.py) on a log of the
independent drive (tests/drives: its own RK4 plant, controller and noise).

The drive has friction and a kinked position-bias table; the refit starts from the truth's plant
with the Coulomb level 20 % high, k0 0.5 % low and a bump of 0.3 mA in the table at the middle
of the visited positions (what a fit co-adapted with a wrong sticking pattern leaves).  The
refit must lower the output error and bring each of them back towards the truth (measured:
output-error SSE 50157 -> 161 track^2, Coulomb level x k0 +20 % -> +7.6 %, k0 -0.5 % -> +0.04 %, table
error where the seeks dwell and pass 0.25 -> 0.06 mA; ~12 s of CPU).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from identification.loop.joint import joint_refit, needs_joint_refit
from identification.loop.settings import LoopSettings
from identification.loop.fit_engine import Data
from identification.loop.windows import seek_windows
from identification.loop.residual import simulate
from identification.model.effects import Friction, PositionBias
from tests.drives import Schedule, drive_50k, make_log, modal_plant, truth_50k

KNOTS = [0.0, 10000.0, 20000.0, 30000.0, 40000.0, 50000.0, 60000.0]
TABLE = [-0.012, -0.005, 0.001, 0.004, 0.003, 0.007, 0.016]
EFFECTS = [{"effect": "position_bias", "params": {"knots_track": KNOTS, "bias_a": TABLE}},
           {"effect": "friction", "params": {"coulomb_a": 0.0015, "viscous_a_per_tps": 1e-9}}]


@lru_cache(maxsize=None)
def _case():
    drive = drive_50k(truth_50k().with_effects(EFFECTS), seed=3, runout=False)
    log = make_log(drive, Schedule(n_seeks=14, seed=3, stroke_track=(0.0, 60000.0)))
    truth = modal_plant(drive)
    st = LoopSettings()
    return Data(log, seek_windows(log, st.window_s, st.min_window_samples), effect_step_s=st.effect_step_s), truth


def _sse(plant, data):
    e = simulate(plant, data.log, data.windows, passes=1, continuous=False, grid=data.grid, cache=data.cache).e
    return float(e @ e)


def _table(plant, x):
    tab = [e for e in plant.effects if isinstance(e, PositionBias)][0]
    return plant.k0 * (plant.bias_a + np.interp(x, tab.knots_track, tab.bias_a))


def test_joint_refit_undoes_a_co_adapted_friction_fit():
    fit, truth = _case()
    pos = fit.log.position_track[fit.windows.index()]
    mid = float(np.median(pos))
    fine = np.linspace(0.0, 60000.0, 121)
    tab = np.interp(fine, KNOTS, TABLE) + 3e-4 * np.maximum(1 - np.abs(fine - mid) / 6000.0, 0.0)
    start = truth.copy(k0=0.995 * truth.k0, effects=[PositionBias(list(fine), list(tab)),
                                                     Friction(0.0018, 1e-9)])
    assert needs_joint_refit(start) and not needs_joint_refit(truth.copy(effects=truth.effects[:1]))
    new = joint_refit(start, fit, table_knots=7, max_iters=4)
    assert _sse(new, fit) < 0.5 * _sse(start, fit)
    c_new = [e for e in new.effects if isinstance(e, Friction)][0].coulomb_a * new.k0
    c_start, c_true = 0.0018 * start.k0, 0.0015 * truth.k0
    assert abs(c_new - c_true) < 0.5 * abs(c_start - c_true), (c_new, c_true)
    assert abs(new.k0 / truth.k0 - 1) < 0.5 * abs(start.k0 / truth.k0 - 1), new.k0
    x = np.linspace(np.quantile(pos, 0.1), np.quantile(pos, 0.9), 9)      # where the seeks dwell and pass
    err_start = np.max(np.abs(_table(start, x) - _table(truth, x)))
    err_new = np.max(np.abs(_table(new, x) - _table(truth, x)))
    assert err_new < 0.5 * err_start, (err_new / truth.k0, err_start / truth.k0)
