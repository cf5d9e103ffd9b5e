"""Optimal seek design: rest-to-rest, current limit, infeasibility, solver reuse, failure handling.

Fast tests design on a perturbed copy of the truth (modes +-2 % / +-20 %, delay +3 us, no modes
above 0.45 fs) and check on the design plant and on the truth with the one simulator.  The
acceptance runs over K in {1, 10, 50, 200, 1000} are marked slow.
"""
import math

import numpy as np
import pytest

from seekopt.design import qp as qpmod
from seekopt.evaluate.bench import baseline_profile, perturbed_plant
from seekopt.drive.controller import Controller
from seekopt.design.metrics import evaluate_profile, simulate_profile
from identification.model.plant import Mode
from seekopt.design.ocp import (DesignError, DesignInfeasible, DesignResult, RobustSpec, SeekDesigner,
                         design_seek, seek_induced)
from seekopt.drive.presets import SEEK_MODES, default_truth_plant
from seekopt.design.profiles import Profile, rigid_endpoint_matrix, t_bang_bang

IMAX = 0.3


@pytest.fixture(scope="module")
def setup():
    truth, ctrl = default_truth_plant(), Controller.nss()
    design = perturbed_plant(truth, ctrl.sample_rate_hz)
    return truth, ctrl, design


@pytest.fixture(scope="module")
def nominal(setup):
    truth, ctrl, design = setup
    return SeekDesigner(design, ctrl, IMAX)


def _check_profile(prof: Profile, plant, ctrl, K):
    fs = ctrl.sample_rate_hz
    M = rigid_endpoint_matrix(prof.n, plant.k0, 1 / fs)
    pos, vel = M @ prof.current_a
    assert abs(pos - K) <= 1e-6 and abs(vel) <= 1e-6          # ZOH rigid model at rest at K
    assert np.max(np.abs(prof.current_a)) <= IMAX
    assert prof.reference_track[-1] == pytest.approx(K, abs=1e-6)
    sim = simulate_profile(plant, ctrl, prof)
    assert sim.peak_current_a <= IMAX * (1 + 1e-9)            # total current, every sub-step


def test_robust_spec_parsing_and_plants(setup):
    truth, ctrl, design = setup
    s = RobustSpec.from_string("freq=5,zeta=30,gain=30,delay=2e-6,n=3")
    assert (s.freq_pct, s.zeta_pct, s.gain_pct, s.delay_s, s.n_samples, s.objective) == (5, 30, 30, 2e-6, 3, "worst")
    assert RobustSpec.from_string("default") == RobustSpec()
    assert RobustSpec.from_string(s.to_string()) == s
    assert RobustSpec.from_string(RobustSpec().to_string()) == RobustSpec()
    for bad in ("freq", "speed=3", "freq=x", "objective=best", "gain=-1"):
        with pytest.raises(ValueError):
            RobustSpec.from_string(bad)
    plants = s.plants(design)
    assert plants[0] is design and len(plants) == 1 + 2 * 2 + 2 + 3     # nominal, freq x delay, gain +-, array
    f0 = np.array([m.freq_hz for m in design.modes])
    seek = np.array([seek_induced(m) for m in design.modes])
    assert seek.any() and not seek.all()
    for p in plants[1:]:
        rel = np.abs(np.array([m.freq_hz for m in p.modes]) / f0 - 1)
        assert np.all(rel[seek] <= 0.05 + 1e-12) and np.all(rel[~seek] <= 0.01 + 1e-12)   # 1 %: other modes
        assert abs(p.delay_s - design.delay_s) <= 2e-6 + 1e-15
    assert np.isclose(max(np.max(np.abs(np.array([m.freq_hz for m in p.modes]) / f0 - 1)[seek]) for p in plants), 0.05)
    assert RobustSpec(n_samples=2, seed=1).plants(design)[-1].modes != RobustSpec(n_samples=2, seed=2).plants(design)[-1].modes


def test_robust_ranges_floor_at_reported_std(setup):
    """Every range is at least n_sigma reported std; modes near Nyquist are not varied."""
    truth, ctrl, design = setup
    m0 = Mode(1000.0, 0.01, 0.5, std={"freq_hz": 50.0, "zeta": 0.0, "gain": 0.0})    # std 5 %: 15 % range
    hf = Mode(0.47 * ctrl.sample_rate_hz, 0.01, 1.0)
    p = design.copy(modes=[m0, hf], std={"delay_s": 1e-6})
    f, z, g, d, k = RobustSpec().ranges(p)
    assert f[0] == pytest.approx(0.15) and f[1] == 0 and g[1] == 0
    assert g[0] == pytest.approx(0.08) and d == pytest.approx(3e-6) and k == 0


def test_orthogonal_array_vertices_cover_all_sign_pairs(setup):
    """Default set: every pair of varied factors (frequency and gain of each mode, delay) takes all four
    sign combinations on the array's vertices."""
    truth, ctrl, design = setup
    spec = RobustSpec()
    plants = spec.plants(design)
    arr = plants[-spec.n_samples:]
    f0 = np.array([m.freq_hz for m in design.modes]); g0 = np.array([m.gain for m in design.modes])
    signs = np.array([np.r_[np.sign([m.freq_hz for m in p.modes] - f0), np.sign([m.gain for m in p.modes] / g0 - 1),
                            np.sign(p.delay_s - design.delay_s)] for p in arr])
    assert signs.shape[1] <= 15 and np.all(signs != 0)
    for i in range(signs.shape[1]):
        for j in range(i + 1, signs.shape[1]):
            pairs = {(a, b) for a, b in zip(signs[:, i], signs[:, j])}
            assert len(pairs) == 4


@pytest.mark.parametrize("K", [10.0, -50.0, 0.5])
def test_design_rest_to_rest_within_imax(setup, nominal, K):
    truth, ctrl, design = setup
    res = nominal.design(K)
    assert isinstance(res, DesignResult) and res.status == "verified"
    _check_profile(res.profile, design, ctrl, K)
    # settles on the design plant no later than the design said (sample grid)
    assert res.metrics.settled
    assert res.metrics.settle_time_s <= (res.settle_samples + 1) / ctrl.sample_rate_hz + 1e-12
    assert res.profile.meta["plant_hash"] == design.hash() and res.profile.meta["controller_hash"] == ctrl.hash()


def test_baselines_rest_to_rest_and_ff_within_imax(setup):
    truth, ctrl, design = setup
    for kind in ("sine", "windowed_sine"):
        for K in (1.0, 200.0):
            prof = baseline_profile(design, ctrl.sample_rate_hz, kind, K, IMAX)
            pos, vel = rigid_endpoint_matrix(prof.n, design.k0, 1 / ctrl.sample_rate_hz) @ prof.current_a
            assert abs(pos - K) <= 1e-6 and abs(vel) <= 1e-6
            assert np.max(np.abs(prof.current_a)) <= IMAX * (1 + 1e-12)


def test_too_short_seek_is_infeasible(setup, nominal):
    truth, ctrl, design = setup
    fs = ctrl.sample_rate_hz
    tbb_samples = t_bang_bang(200.0, design.k0, IMAX) * fs
    with pytest.raises(DesignInfeasible, match="shortest feasible seek time is") as e:
        nominal.design(200.0, seek_samples=int(tbb_samples) - 3)
    n_short = int(str(e.value).split("shortest feasible seek time is ")[1].split()[0])
    assert n_short >= math.floor(tbb_samples)
    assert "T_bb" in str(e.value)
    # the named time is feasible (minimum residual objective (a) for that seek time)
    res = nominal.design(200.0, seek_samples=n_short)
    assert res.profile.seek_samples == n_short
    _check_profile(res.profile, design, ctrl, 200.0)


def test_min_residual_objective_improves_with_time(setup, nominal):
    truth, ctrl, design = setup
    r = [nominal.design(50.0, seek_samples=n).residual_band for n in (16, 22, 30)]
    assert r[0] >= r[1] >= r[2] - 1e-6
    assert nominal.design(50.0, seek_samples=30).objective == "min_residual/worst"


def test_solver_built_once_and_reused(setup):
    truth, ctrl, design = setup
    d = SeekDesigner(design, ctrl, IMAX)
    before = sum(qpmod.BUILD_COUNT.values())
    d.design(40.0)
    builds, total = d.builds, sum(qpmod.BUILD_COUNT.values())
    assert builds >= 1 and total - before == builds
    for K in (40.0, 45.0, 50.0, -40.0):          # same size class: no new structure, no new solver
        d.design(K)
    assert d.builds == builds and sum(qpmod.BUILD_COUNT.values()) == total


def test_failed_solve_is_never_returned(setup, monkeypatch):
    truth, ctrl, design = setup
    d = SeekDesigner(design, ctrl, IMAX)

    def failing(self, *a, **k):
        return qpmod.QPSolution(np.full(self.n, np.nan), np.zeros(self.m), np.zeros(self.n), False,
                                "solver crashed", 0.0, 0.0)

    monkeypatch.setattr(qpmod.ConicQP, "solve", failing)
    with pytest.raises(DesignError, match="solver crashed"):
        d.design(10.0)
    with pytest.raises(DesignError, match="solver crashed"):
        d.design(10.0, seek_samples=20)

    def lying(self, *a, **k):       # claims success with a useless answer
        return qpmod.QPSolution(np.zeros(self.n), np.zeros(self.m), np.zeros(self.n), True, "1", 0.0, 0.0)

    monkeypatch.setattr(qpmod.ConicQP, "solve", lying)
    with pytest.raises(DesignError, match="violation"):
        d.design(10.0)
    with pytest.raises(DesignError, match="violation"):
        d.design(10.0, seek_samples=20)


def test_ipopt_path_agrees_with_qp(setup):
    truth, ctrl, design = setup
    a = SeekDesigner(design, ctrl, IMAX, hf_guard=None).design(10.0, seek_samples=12)
    b = SeekDesigner(design, ctrl, IMAX, hf_guard=None, solver="ipopt").design(10.0, seek_samples=12)
    assert b.solver == "ipopt"
    assert np.allclose(a.profile.current_a, b.profile.current_a, atol=2e-3 * IMAX)
    assert b.residual_band == pytest.approx(a.residual_band, rel=2e-2, abs=1e-3)


def test_design_seek_and_model_reference(setup):
    truth, ctrl, design = setup
    res = design_seek(design, ctrl, 20.0, IMAX, reference="model")
    _check_profile(res.profile, design, ctrl, 20.0)
    # model reference: the profile is long enough for the firmware's hold (model at rest at K)
    assert abs(res.profile.reference_track[-1] - 20.0) <= 1e-6


def test_robust_design_beats_baselines_on_truth(setup):
    """K = 50: designed on the perturbed plant, played on the truth."""
    truth, ctrl, design = setup
    fs = ctrl.sample_rate_hz
    res = SeekDesigner(design, ctrl, IMAX, robust="freq=3,gain=25,zeta=30,delay=3e-6,n=2").design(50.0)
    m = evaluate_profile(truth, ctrl, res.profile)
    base = min(evaluate_profile(truth, ctrl, baseline_profile(design, fs, k, 50.0, IMAX)).settle_time_s
               for k in ("sine", "windowed_sine"))
    assert m.settled and m.settle_time_s <= 0.5 * base
    assert m.peak_current_a <= IMAX * 1.02


# ------------------------------------------------------------------------- acceptance (slow)
#: The one robust setting of the acceptance: the ``RobustSpec`` defaults (the CLI's ``--robust``).
IDENT_ROBUST = RobustSpec()


@pytest.fixture(scope="module")
def identified():
    """The plant identified from a synthetic log (seed 0, 120 seeks), by the current code (about 20 s)."""
    from identification.estimate.identify import identify
    from seekopt.evaluate.synth import SynthConfig, synthesize
    log, _ = synthesize(SynthConfig(n_seeks=120, seed=0))
    plant = identify(log).plant
    return plant


def _best_baseline(plant_for_design, truth, ctrl, K):
    fs = ctrl.sample_rate_hz
    return min(evaluate_profile(truth, ctrl, baseline_profile(plant_for_design, fs, k, K, IMAX)).settle_time_s
               for k in ("sine", "windowed_sine"))


@pytest.fixture(scope="module")
def ident_designer(setup, identified):
    truth, ctrl, design = setup
    return SeekDesigner(identified, ctrl, IMAX, robust=IDENT_ROBUST)


@pytest.mark.slow
@pytest.mark.parametrize("K", [1.0, 10.0, 50.0, 200.0, 1000.0])
def test_acceptance_half_the_better_baseline(setup, identified, ident_designer, K):
    truth, ctrl, design = setup
    res = ident_designer.design(K)
    _check_profile(res.profile, identified, ctrl, K)
    m = evaluate_profile(truth, ctrl, res.profile, k0_for_tbb=identified.k0)
    assert m.settled and m.settle_time_s <= 0.5 * _best_baseline(identified, truth, ctrl, K)
    assert m.peak_current_a <= IMAX * 1.01
    if K == 200.0:
        assert m.ratio_tbb <= 2.0


@pytest.mark.slow
@pytest.mark.parametrize("shift", [-0.05, 0.05])
def test_acceptance_robust_to_seek_mode_shift(setup, identified, shift):
    truth, ctrl, design = setup
    seek = {m.freq_hz for m in SEEK_MODES}
    shifted = truth.copy(modes=[type(m)(m.freq_hz * (1 + shift) if m.freq_hz in seek else m.freq_hz, m.zeta, m.gain)
                                for m in truth.modes])
    for plant in (identified, design):          # identified plant and the perturbed stand-in
        res = SeekDesigner(plant, ctrl, IMAX, robust=IDENT_ROBUST).design(200.0)
        m = evaluate_profile(shifted, ctrl, res.profile)
        assert m.settled and m.settle_time_s <= 0.7 * _best_baseline(plant, shifted, ctrl, 200.0)
