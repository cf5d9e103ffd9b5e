"""The friction fit refines a position-bias table's shape by simulation (issue 10, item 6).

A head held by friction does not feel a change of the bias table, so a table fitted before
friction was modelled keeps what sticking made of it and its own linear fit cannot move it
where the head dwells (measured on kt_bias_friction of the independent 50.4 kHz drive: 0.65 ...
0.80 mA too high at the top of the fit range).  :func:`sim_refine_table` searches the table's
shape (coarse hats) and the Coulomb level by simulation.  The log comes from the independent
test drive (``tests/drives``), the wrong table is the truth's with a bump added.
"""
from __future__ import annotations

import numpy as np

from identification.loop.fit_engine import Data
from identification.loop.friction import sim_refine_table
from identification.loop.residual import simulate
from identification.loop.windows import seek_windows
from identification.model.effects import Friction, PositionBias
from tests.drives import Schedule, make_log, modal_plant, nss_drive

KNOTS = [0.0, 5000.0, 10000.0, 15000.0, 20000.0]
TABLE = [-0.004, -0.001, 0.001, 0.002, 0.0025]


def _log():
    eff = [{"effect": "position_bias", "params": {"knots_track": KNOTS, "bias_a": TABLE}},
           {"effect": "friction", "params": {"coulomb_a": 0.0015, "viscous_a_per_tps": 1e-9}}]
    drive = nss_drive(seed=3, runout=False)
    drive = drive.with_plant(drive.plant.with_effects(eff))
    return make_log(drive, Schedule(n_seeks=16, seed=3), noise_seed=3), modal_plant(drive)


def test_table_shape_is_refined_by_simulation_under_friction():
    log, truth = _log()
    data = Data(log, seek_windows(log))
    pos = log.position_track[data.windows.index()]
    lo, hi = float(pos.min()), float(pos.max())
    table = next(e for e in truth.effects if isinstance(e, PositionBias))
    fine = np.linspace(lo, hi, 40)
    fine_knots = np.linspace(min(lo, 0.0), max(hi, 20000.0), 33)
    bump = 0.8e-3 * np.clip(1 - np.abs(fine_knots - hi) / (0.4 * (hi - lo)), 0, None)   # 0.8 mA at the top
    wrong = PositionBias(list(fine_knots), list(np.interp(fine_knots, table.knots_track, table.bias_a) + bump))
    model = truth.copy(effects=[wrong if isinstance(e, PositionBias) else e for e in truth.effects])

    def rms(p):
        e = simulate(p, log, data.windows, continuous=False, grid=data.grid, cache=data.cache).e
        return float(np.sqrt(np.mean(e ** 2)))

    def table_err(p):
        t = next(e for e in p.effects if isinstance(e, PositionBias))
        return float(np.max(np.abs(t.force(fine, 0.0) - table.force(fine, 0.0))))
    out = sim_refine_table(model, data, knots=5, max_evals=150)
    fr = next(e for e in out.effects if isinstance(e, Friction))
    r0, r1, t0, t1 = rms(model), rms(out), table_err(model), table_err(out)
    assert r1 < 0.5 * r0, (r0, r1)
    assert t1 < 0.5 * t0, (t0, t1)
    assert abs(fr.coulomb_a - 0.0015) < 0.3e-3, fr.coulomb_a
    assert sim_refine_table(model, data, knots=0) is model
