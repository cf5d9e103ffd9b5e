"""Closing the loop on logs with undeclared effects (identification.closing, candidates, loop_report).

The "identified model" is the truth plant without the undeclared effect, slightly perturbed
(``studies/closing_the_loop.standin_model``); effect strengths are random (seeded) from the
study's ranges (``random_effect``), never the synthetic drive's defaults.  The default run
keeps a representative subset; the full per-effect matrix is ``@pytest.mark.slow``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "studies"))
import closing_the_loop as study  # noqa: E402

from identification.closing import close_loop  # noqa: E402
from identification.logs import write_log  # noqa: E402
from identification.loop_report import write_report  # noqa: E402
from identification.plant import ModalPlant  # noqa: E402
from seekopt.synth import SynthConfig, synthesize  # noqa: E402

#: parameter tolerances (see param_error in the study for the definitions)
TOL = {
    "input_delay": {"delay_error_us": 1.0},
    "amplifier_lag": {"bandwidth_rel_error": 0.15},
    "pivot_spring_damper": {"freq_rel_error": 0.10, "zeta_error": 0.10},
    "position_bias": {"bias_max_error_mA": 0.35},
    "friction": {"coulomb_rel_error": 0.25},
    "torque_constant_variation": {"gain_max_rel_error": 0.01},
    "current_saturation": {"limit_rel_error": 0.03},
    "periodic_disturbance": {"spindle_error_hz": 0.5, "h1_amplitude_rel_error": 0.25},
    "extra_mode": {"freq_rel_error": 0.05, "gain_rel_error": 0.35},
}


def _check_single(row, effect):
    assert row["first"] == effect, (row["accepted"], row["unexplained"])
    assert row["ratio"] <= 0.7, row
    for k, tol in TOL[effect].items():
        assert abs(row["error"][k]) <= tol, (k, row["error"], row["declared"])


# ------------------------------------------------------------------------ fast
@pytest.fixture(scope="module")
def clean():
    log, truth = synthesize(SynthConfig(n_seeks=50, seed=7, rro=False))
    return close_loop(log, study.standin_model(truth, 7))


def test_clean_log_accepts_nothing(clean):
    assert clean.accepted == []
    assert clean.error_after["rms_track"] <= clean.error_before["rms_track"] + 1e-12
    assert not any(u.startswith("residual depends on") for u in clean.unexplained)


def test_report_json_has_the_exact_keys(clean, tmp_path):
    rep = write_report(clean, tmp_path / "r.json", tmp_path / "figs")
    d = json.loads((tmp_path / "r.json").read_text())
    assert list(d) == ["plant", "error_before", "error_after", "steps", "unexplained"] == list(rep)
    for k in ("error_before", "error_after"):
        assert set(d[k]) == {"rms_track", "fit_percent"}
    assert all(set(s) == {"effect", "params", "evidence", "rms_before", "rms_after", "accepted"} for s in d["steps"])
    assert all(isinstance(u, str) and "\n" not in u for u in d["unexplained"])
    ModalPlant.from_dict(d["plant"])                     # a valid plant
    md = (tmp_path / "figs" / "loop_report.md").read_text()
    assert "## Unexplained" in md and "residual_seeks.png" in md
    assert (tmp_path / "figs" / "spectra.png").stat().st_size > 10000


def test_benchmark_rro_alone_gives_periodic_disturbance():
    log, truth = synthesize(SynthConfig(n_seeks=50, seed=8))          # default: benchmark RRO on
    R = close_loop(log, study.standin_model(truth, 8))
    assert R.accepted == ["periodic_disturbance"], R.unexplained
    pd = R.plant.effects[-1]
    assert abs(pd.spindle_hz - 120.0) < 1.0 and 1 in pd.harmonics
    assert R.error_after["rms_track"] < 0.95 * R.error_before["rms_track"]


@pytest.mark.parametrize("effect", ["current_saturation", "input_delay"])
def test_single_effect_fast(effect):
    _check_single(study.run_case(effect, 2000 + study.EFFECTS.index(effect), 50), effect)


def test_effect_outside_the_library_is_not_claimed():
    row = study.run_case("dead_zone", 3001, 50)
    assert row["accepted"] == []
    assert any(u.startswith("residual depends on current") for u in row["unexplained"]), row["unexplained"]


def test_cli_loop(tmp_path, monkeypatch):
    import identification.identify as ident
    from seekopt.cli import main
    log, truth = synthesize(SynthConfig(n_seeks=24, seed=9, rro=False,
                                        effects=[study.random_effect("current_saturation", np.random.default_rng(9))]))
    vlog, _ = synthesize(SynthConfig(n_seeks=16, seed=10, rro=False, effects=[e.to_dict() for e in truth.effects]))
    write_log(log, tmp_path / "a.csv"); write_log(vlog, tmp_path / "b.npz")

    class Stub:
        plant = study.standin_model(truth.copy(effects=[]), 9)
    monkeypatch.setattr(ident, "identify", lambda log, method="robust": Stub())
    rc = main(["loop", str(tmp_path / "a.csv"), "--validate", str(tmp_path / "b.npz"),
               "--report", str(tmp_path / "rep.json"), "--figures", str(tmp_path / "f")])
    assert rc == 0
    d = json.loads((tmp_path / "rep.json").read_text())
    assert [s["effect"] for s in d["steps"] if s["accepted"]][:1] == ["current_saturation"]
    assert d["error_after"]["rms_track"] < d["error_before"]["rms_track"]
    assert (tmp_path / "f" / "loop_report.md").exists()
    assert main(["loop", str(tmp_path / "missing.csv"), "--report", str(tmp_path / "x.json")]) == 2


# ------------------------------------------------------------------------ slow
@pytest.mark.slow
@pytest.mark.parametrize("effect", study.EFFECTS)
def test_each_effect(effect):
    _check_single(study.run_case(effect, 1000 + 17 * study.EFFECTS.index(effect), 80), effect)


@pytest.mark.slow
def test_two_effects_both_accepted():
    row = study.run_case("two", 1000 + 17 * (study.EFFECTS + study.OTHER).index("two"), 80)
    assert set(row["accepted"]) == {"friction", "torque_constant_variation"}, row
    assert row["ratio"] <= 0.7


@pytest.mark.slow
def test_time_varying_gain_is_not_claimed():
    row = study.run_case("time_varying_gain", 1000 + 17 * (study.EFFECTS + study.OTHER).index("time_varying_gain"), 80)
    assert row["accepted"] == [], row
    assert any(u.startswith("residual depends on time") for u in row["unexplained"]), row["unexplained"]


@pytest.mark.slow
def test_separate_validation_log_rephases_rro_and_finds_friction():
    eff = [study.random_effect("friction", np.random.default_rng(5))]
    log, truth = synthesize(SynthConfig(n_seeks=60, seed=51, effects=eff))
    vlog, _ = synthesize(SynthConfig(n_seeks=40, seed=52, effects=eff))
    R = close_loop(log, study.standin_model(truth.copy(effects=[]), 51), validation=vlog)
    assert R.accepted[0] == "friction" and "periodic_disturbance" in R.accepted, R.accepted
    assert R.error_after["rms_track"] <= 0.7 * R.error_before["rms_track"]
