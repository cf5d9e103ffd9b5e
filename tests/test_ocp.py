"""Optimal seek design: rest-to-rest, current limit, infeasibility, solver reuse, failure handling.

Fast tests design on a perturbed copy of the truth (modes +-2 % / +-20 %, delay +3 us, no modes
above 0.45 fs) and check on the design plant and on the truth with the one simulator.  The
acceptance runs over K in {1, 10, 50, 200, 1000} are marked slow.
"""
import math

import numpy as np
import pytest

from seekopt.design.solver_settings import BASE_FALLBACKS

from seekopt.design import solvers as solvmod
from seekopt.design.baselines import baseline_profile
from seekopt.evaluate.bench import perturbed_plant
from seekopt.drive.controller import Controller
from seekopt.design.metrics import evaluate_profile, simulate_profile
from identification.model.plant import Mode
from seekopt.design.designer import DesignError, DesignInfeasible, DesignResult, SeekDesigner, design_seek
from seekopt.design.problem import SeekProblem, SolverSettings
from seekopt.design.robust import RobustSpec, seek_induced
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
    d = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    for K in (40.0, 45.0, 50.0, -40.0):
        d.design(K)
    builds, solvers = d.builds, sum(d.solver_builds.values())
    assert builds >= 1 and solvers >= builds          # a full-size solver per structure, plus working-set buckets
    for K in (40.0, 45.0, 50.0, -40.0, 42.0):    # same size class: no new structure, no new solver
        d.design(K)
    assert d.builds == builds and sum(d.solver_builds.values()) == solvers


def test_failed_solve_is_never_returned(setup, monkeypatch):
    truth, ctrl, design = setup
    d = SeekDesigner(SeekProblem(design, ctrl, IMAX, solver=SolverSettings(max_samples=32)))

    def failing(self, *a, **k):
        return solvmod.QPSolution(np.full(self.n, np.nan), np.zeros(self.m), np.zeros(self.n), False,
                                  "solver crashed", 0.0, 0.0)

    monkeypatch.setattr(solvmod.ConicQP, "solve", failing)
    monkeypatch.setattr(solvmod.DaqpQP, "solve", failing)
    monkeypatch.setattr(solvmod.PiqpQP, "solve", failing)      # every solver of the chain
    with pytest.raises(DesignError, match="solver crashed"):
        d.design(10.0)
    with pytest.raises(DesignError, match="solver crashed"):
        d.design(10.0, seek_samples=20)

    def lying(self, *a, **k):       # claims success with a useless answer
        return solvmod.QPSolution(np.zeros(self.n), np.zeros(self.m), np.zeros(self.n), True, "1", 0.0, 0.0)

    monkeypatch.setattr(solvmod.ConicQP, "solve", lying)
    monkeypatch.setattr(solvmod.DaqpQP, "solve", lying)
    with pytest.raises(DesignError, match="violation"):
        d.design(10.0)
    with pytest.raises(DesignError, match="violation"):
        d.design(10.0, seek_samples=20)


def test_ipopt_path_agrees_with_qp(setup):
    truth, ctrl, design = setup
    a = SeekDesigner(SeekProblem(design, ctrl, IMAX, hf_guard=None)).design(10.0, seek_samples=12)
    b = SeekDesigner(SeekProblem(design, ctrl, IMAX, hf_guard=None, solver=SolverSettings("ipopt", fallbacks=()))
                     ).design(10.0, seek_samples=12)
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
    res = SeekDesigner(SeekProblem(design, ctrl, IMAX, robust="freq=3,gain=25,zeta=30,delay=3e-6,n=2")).design(50.0)
    m = evaluate_profile(truth, ctrl, res.profile)
    base = min(evaluate_profile(truth, ctrl, baseline_profile(design, fs, k, 50.0, IMAX)).settle_time_s
               for k in ("sine", "windowed_sine"))
    assert m.settled and m.settle_time_s <= 0.5 * base
    assert m.peak_current_a <= IMAX * 1.02


# ------------------------------------------------------------------------- problem as data, solver reuse
def test_seek_problem_json_round_trip_designs_identically(setup, tmp_path):
    truth, ctrl, design = setup
    prob = SeekProblem(design, ctrl, IMAX, 0.1, robust=RobustSpec(n_samples=2, freq_pct=3), slew_a_per_s=2000.0,
                       band_margin=0.85, solver=SolverSettings(fallbacks=("qpoases", "proxqp"), max_samples=256))
    prob.to_json(tmp_path / "problem.json")
    back = SeekProblem.from_json(tmp_path / "problem.json")
    assert back == prob and back.to_dict() == prob.to_dict()
    assert back.plant.hash() == design.hash() and back.controller.hash() == ctrl.hash()
    assert back.robust == prob.robust and back.solver == prob.solver
    assert SeekProblem.from_json(prob.to_json()) == prob
    assert back != SeekProblem(design, ctrl, IMAX)
    a, b = SeekDesigner(prob).design(30.0), SeekDesigner.from_problem(back).design(30.0)
    assert a.settle_samples == b.settle_samples
    assert np.array_equal(a.profile.current_a, b.profile.current_a)
    assert np.array_equal(a.profile.reference_track, b.profile.reference_track)


def test_designer_built_once_designs_20_lengths_without_rebuilding(setup):
    truth, ctrl, design = setup
    d = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    lengths = np.round(np.geomspace(1.0, 300.0, 20), 1)
    first = [d.design(K).settle_samples for K in lengths]
    builds, maps, solvers = d.builds, d.map_builds, dict(d.solver_builds)
    assert builds == len(d._qps) <= 6            # one structure per size class used, not one per length
    assert maps <= 2
    again = [d.design(K).settle_samples for K in lengths[::-1]][::-1]
    assert again == first
    assert [SeekDesigner(SeekProblem(design, ctrl, IMAX)).design(K).settle_samples for K in lengths[::4]] == first[::4]
    assert (d.builds, d.map_builds) == (builds, maps)
    # reduced problems (working set): one small solver per (free variables, row bucket), built once and
    # kept -- never one per solve
    chains = sum(len(w._chains) for w in d._ws.values()) + sum(q._solver is not None for q in d._qps.values())
    primary = d.settings.qp_solver
    assert d.solver_builds[primary] == chains
    assert d.solver_builds[primary] - solvers[primary] <= 8


# ------------------------------------------------------------------------- solver statuses
@pytest.mark.parametrize("solver,raw,success,expected", [
    ("daqp", 1, True, "optimal"), ("daqp", "2", True, "optimal"), ("daqp", -1, False, "infeasible"),
    ("daqp", -2, False, "numerical"), ("daqp", "-3", False, "numerical"), ("daqp", -4, False, "iteration_limit"),
    ("daqp", -5, False, "numerical"), ("daqp", -6, False, "numerical"), ("daqp", 1, False, "optimal"),
    ("highs", "Optimal", True, "optimal"), ("highs", "Infeasible", False, "infeasible"),
    ("highs", "Time limit reached", False, "iteration_limit"), ("highs", "Unknown", False, "numerical"),
    ("qpoases", "Successful return.", True, "optimal"),
    ("qpoases", "Premature homotopy termination because QP is infeasible.", False, "infeasible"),
    ("qpoases", "Maximum number of working set recalculations performed.", False, "iteration_limit"),
    ("proxqp", "PROXQP_SOLVED", True, "optimal"), ("proxqp", "PROXQP_PRIMAL_INFEASIBLE", False, "infeasible"),
    ("proxqp", "PROXQP_MAX_ITER_REACHED", False, "iteration_limit"),
    ("osqp", "primal infeasible inaccurate", False, "numerical"), ("osqp", "solved inaccurate", False, "numerical"),
    ("ipopt", "Infeasible_Problem_Detected", False, "infeasible"),
    ("ipopt", "Maximum_Iterations_Exceeded", False, "iteration_limit"),
    ("ipopt", "Restoration_Failed", False, "numerical")])
def test_solver_status_classification(solver, raw, success, expected):
    assert solvmod.classify_status(solver, raw, success).value == expected


class _Fake:
    """Scripted solver: returns the given raw statuses in turn (daqp flags)."""

    def __init__(self, name, flags, n=2, m=1):
        self.name, self.flags, self.n, self.m, self.calls = name, list(flags), n, m, 0

    def solve(self, *data, x0=None):
        flag = self.flags[min(self.calls, len(self.flags) - 1)]
        self.calls += 1
        out = solvmod.classify_status("daqp", flag, flag in (1, 2))
        return solvmod.QPSolution(np.ones(self.n), np.zeros(self.m), np.zeros(self.n), flag in (1, 2), str(flag),
                                  0.001, 0.001, out, self.name)


@pytest.mark.parametrize("primary,fallback,outcome,n_attempts", [
    ([1], [1], "optimal", 1),               # no retry on success
    ([-1], [1], "infeasible", 1),           # a proof ends the chain
    ([-2], [1], "optimal", 2),              # cycling: the fallback answers
    ([-4], [-1], "infeasible", 2),          # iteration limit, then proven infeasible
    ([-2], [-5], "numerical", 2),           # nobody decides: never called infeasible
])
def test_solver_chain_retries_only_without_proof(primary, fallback, outcome, n_attempts, monkeypatch):
    fakes = {"daqp": _Fake("daqp", primary), "qpoases": _Fake("qpoases", fallback)}
    monkeypatch.setattr(solvmod, "make_qp_solver", lambda n, m, name, opts=None: fakes[name])
    built = []
    chain = solvmod.SolverChain(2, 1, ("daqp", "qpoases"), builds=built.append)
    assert built == ["daqp"]                 # the fallback is built on first need only
    sol = chain.solve(None, None, None, None, None, None, None)
    assert sol.outcome.value == outcome and len(sol.attempts) == n_attempts
    assert sol.infeasible == (outcome == "infeasible") and sol.success == (outcome == "optimal")
    assert built == ["daqp", "qpoases"][:n_attempts]
    bad = solvmod.SolverChain(2, 1, ("daqp", "qpoases"))     # an answer failing the re-check is not optimal
    sol = bad.solve(None, None, None, None, None, None, None, check=lambda x: "constraint violation 1")
    if primary == [1] and fallback == [1]:
        assert sol.outcome.value == "numerical" and "violation" in sol.status and len(sol.attempts) == 2


def test_cycling_primary_falls_back_and_designs_the_same(setup, monkeypatch):
    """daqp (the package and casadi's) forced to report cycling (-2) on every solve: the fallback
    (qpoases) designs, the bisection finds the same length as daqp alone, and no length is called
    infeasible on a cycling status.  Without the blind-band PES rows: with them (10 more rows per band row here)
    qpOASES reaches its working-set cap (``QPOASES_NWSR_PER_DIM``) on 11 of 17 solves and HiGHS, next in
    the chain, designs the same length (measured: 24 samples either way)."""
    truth, ctrl, design = setup
    ref = SeekDesigner(SeekProblem(design, ctrl, IMAX, blind_pes_points=0)).design(50.0)
    real, real_pkg = solvmod.ConicQP.solve, solvmod.DaqpQP.solve

    def cycle(sol, name):
        return solvmod.QPSolution(sol.x, sol.lam_a, sol.lam_x, False, "-2", sol.solve_time_s, sol.cpu_time_s,
                                  solvmod.classify_status(name, -2, False), name)

    def cycling(self, *a, **k):
        sol = real(self, *a, **k)
        return cycle(sol, "daqp") if self.plugin == "daqp" else sol

    monkeypatch.setattr(solvmod.ConicQP, "solve", cycling)
    monkeypatch.setattr(solvmod.DaqpQP, "solve", lambda self, *a, **k: cycle(real_pkg(self, *a, **k), "daqp_pkg"))
    # the chain without PIQP (the default's first fallback where installed, tests/test_piqp_solver.py): qpOASES next
    d = SeekDesigner(SeekProblem(design, ctrl, IMAX, blind_pes_points=0,
                                 solver=SolverSettings(fallbacks=BASE_FALLBACKS)))
    res = d.design(50.0)
    assert res.settle_samples == ref.settle_samples
    assert res.fallback_solves == res.n_solves and res.unresolved_solves == 0
    assert d.solver_builds["qpoases"] >= 1 and "highs" not in d.solver_builds     # built on need only


def test_iteration_limit_of_real_daqp_is_retried(setup):
    truth, ctrl, design = setup
    ref = SeekDesigner(SeekProblem(design, ctrl, IMAX)).design(20.0)
    tight = SolverSettings(options={"daqp_pkg": {"iter_limit": 2}, "daqp": {"daqp": {"iter_limit": 2}}})
    res = SeekDesigner(SeekProblem(design, ctrl, IMAX, solver=tight)).design(20.0)
    assert res.fallback_solves >= 1 and res.unresolved_solves == 0
    assert abs(res.settle_samples - ref.settle_samples) <= 1


def test_working_set_option_designs_as_the_full_qp(setup):
    """SolverSettings(working_set=True): the same optimum on a working set of the rows."""
    truth, ctrl, design = setup
    full = SeekDesigner(SeekProblem(design, ctrl, IMAX, robust="n=2", solver=SolverSettings(working_set=False)))
    ws = SeekDesigner(SeekProblem(design, ctrl, IMAX, robust="n=2", solver=SolverSettings(working_set=True)))
    for K in (20.0, 150.0):
        a, b = full.design(K), ws.design(K)
        assert a.settle_samples == b.settle_samples
        assert np.allclose(a.profile.current_a, b.profile.current_a, atol=1e-3 * IMAX)
    a, b = full.design(50.0, seek_samples=24), ws.design(50.0, seek_samples=24)
    assert b.residual_band == pytest.approx(a.residual_band, rel=1e-3, abs=1e-6)
    wsq = next(iter(ws._ws.values()))
    assert wsq.rounds > 0


def test_set_predictions_from_the_simulators_responses_equal_the_simulator(setup):
    """predict_on_set(maps=...) plays linear plants by superposing the one simulator's impulse
    responses: the same settle times and peak currents as simulate_2dof on every plant; the guard
    report from those currents equals the simulated one."""
    from seekopt.design import guard as gmod
    from seekopt.design.predict import play_linear, predict_on_set, superposes
    truth, ctrl, design = setup
    des = SeekDesigner(SeekProblem(design.copy(bias_a=0.01), ctrl, IMAX, robust="n=3"))
    res = des.design(150.0)
    prof = res.profile
    n = prof.n + int(round(0.015 * ctrl.sample_rate_hz))
    maps = des._loop_maps(n)
    assert all(superposes(p) for p in des.plants)
    fast = predict_on_set(des.plants, ctrl, prof, des.settle, design.k0, maps=maps)
    slow = predict_on_set(des.plants, ctrl, prof, des.settle, design.k0)
    for a, b in zip(fast.metrics, slow.metrics):
        assert a.settle_time_s == b.settle_time_s
        assert a.peak_current_a == pytest.approx(b.peak_current_a, rel=1e-9)
        assert a.peak_pes_after_track == pytest.approx(b.peak_pes_after_track, rel=1e-7, abs=1e-12)
    _, cur = play_linear(maps[0], prof, n)
    g1 = gmod.guard_report(des.plant, ctrl, prof, des.guard_bands, des.settle, curve=des.guard_curve)
    g2 = gmod.guard_report(des.plant, ctrl, prof, des.guard_bands, des.settle, curve=des.guard_curve,
                           current_sub=cur)
    assert g2.worst_band == pytest.approx(g1.worst_band, rel=1e-7)
    assert play_linear(maps[0], prof, maps[0].horizon + 1) is None


def test_farkas_check_and_zero_copy_solve():
    """proves_infeasible accepts a true certificate and rejects others; the numpy (buffer) path of
    ConicQP answers as the casadi.DM path."""
    A = np.array([[1.0, 1.0], [1.0, 1.0]])
    lba, uba = np.array([2.0, -np.inf]), np.array([np.inf, 1.0])
    lbx, ubx = -10 * np.ones(2), 10 * np.ones(2)
    assert solvmod.proves_infeasible(A, lba, uba, lbx, ubx, [-1.0, 1.0])
    assert not solvmod.proves_infeasible(A, lba, uba, lbx, ubx, [1.0, -1.0])
    assert not solvmod.proves_infeasible(A, lba, np.array([np.inf, 3.0]), lbx, ubx, [-1.0, 1.0])
    rng = np.random.default_rng(1)
    M = rng.standard_normal((6, 6)); H = M @ M.T + np.eye(6)
    g, B = rng.standard_normal(6), rng.standard_normal((5, 6))
    q = solvmod.ConicQP(6, 5, "daqp")
    a = q.solve(H, g, B, -np.ones(5), np.ones(5), -np.ones(6), np.ones(6))
    b = q.solve(solvmod.dm(H), g, solvmod.dm(B), -np.ones(5), np.ones(5), -np.ones(6), np.ones(6))
    assert a.outcome is b.outcome is solvmod.QPStatus.OPTIMAL
    assert np.allclose(a.x, b.x, atol=1e-9)
    bad = q.solve(H, g, B, np.full(5, 2.0), np.full(5, 3.0) * 0 + 1.0, -np.ones(6), np.ones(6))
    assert bad.outcome is not solvmod.QPStatus.OPTIMAL


def test_phase1_lp_certificate_proves_only_infeasible_rows():
    """farkas_certificate returns verified multipliers for rows with no solution (an infeasible
    subset of a larger row set proves the larger set infeasible) and None for feasible rows."""
    rng = np.random.default_rng(3)
    n = 8
    A = rng.standard_normal((30, n))
    x_in = rng.uniform(-0.5, 0.5, n)
    r = A @ x_in
    lba, uba = r - 0.1, r + 0.1                      # feasible: x_in satisfies them
    lbx, ubx = -np.ones(n), np.ones(n)
    assert solvmod.farkas_certificate(A, lba, uba, lbx, ubx) is None
    A2 = np.vstack([A, A[:1]])                       # row 0 again, bounded away from its band
    lb2, ub2 = np.append(lba, uba[0] + 0.05), np.append(uba, np.inf)
    lam = solvmod.farkas_certificate(A2, lb2, ub2, lbx, ubx)
    assert lam is not None and solvmod.proves_infeasible(A2, lb2, ub2, lbx, ubx, lam)
    big = np.vstack([A2, rng.standard_normal((50, n))])
    lam_big = np.zeros(len(big)); lam_big[:len(A2)] = lam
    assert solvmod.proves_infeasible(big, np.append(lb2, -np.ones(50) * np.inf), np.append(ub2, np.full(50, np.inf)),
                                     lbx, ubx, lam_big)


def test_blocked_mode_residuals_equal_the_phasor_matrix():
    """qp.mode_residuals (blocked sum, used by the guard report) equals mode_residual_phasors @ i."""
    from seekopt.design.qp import mode_residual_phasors, mode_residuals
    rng = np.random.default_rng(4)
    f, g = np.linspace(2e3, 4e4, 97), rng.uniform(0.1, 2.0, 97)
    for n in (1, 5, 64, 1237):
        i = rng.standard_normal(n)
        ref = mode_residual_phasors(3e5, 25e3, 4, n, f, g) @ i
        assert np.allclose(mode_residuals(3e5, 25e3, 4, i, f, g), ref, rtol=1e-11, atol=1e-12 * np.abs(ref).max())


def test_neighbouring_lengths_start_from_the_predicted_length(setup):
    """A sweep's next length starts from the settle/T_bb ratio of its neighbour and designs the same
    length as a fresh designer (class scan and bisection)."""
    truth, ctrl, design = setup
    warm = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    warm.design(100.0)
    assert warm._predict(int(math.ceil(t_bang_bang(120.0, design.k0, IMAX) * ctrl.sample_rate_hz))) is not None
    a = warm.design(120.0)
    b = SeekDesigner(SeekProblem(design, ctrl, IMAX)).design(120.0)
    assert a.settle_samples == b.settle_samples
    assert a.n_solves <= b.n_solves + 2


# ------------------------------------------------------------------------- early errors
def test_impossible_seeks_rejected_before_any_qp(setup):
    truth, ctrl, design = setup
    d = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    with pytest.raises(DesignInfeasible, match="beyond the longest design horizon"):
        d.design(1e9)
    with pytest.raises(DesignInfeasible, match="beyond the longest design horizon"):
        SeekDesigner(SeekProblem(design, ctrl, 1e-7)).design(200.0)
    with pytest.raises(DesignInfeasible, match="holding current"):
        SeekDesigner(SeekProblem(design.copy(bias_a=0.01), ctrl, 0.01)).design(1.0)
    assert d.builds == 0 and d.map_builds == 0


def test_unstable_closed_loop_rejected_at_once(setup):
    from seekopt.design.problem import ProblemError, check_closed_loop
    from seekopt.design.qp import LoopMaps
    truth, ctrl, design = setup
    for f in (1.0, 1.5, 2.0, 2.5, 3.0):          # the check agrees with the simulated closed loop
        p = truth.copy(k0=truth.k0 * f)
        try:
            check_closed_loop(p, ctrl)
            stable = True
        except ProblemError:
            stable = False
        try:
            with np.errstate(all="ignore"):
                LoopMaps(p, ctrl, 4000)
            simulated = True
        except ValueError:
            simulated = False
        assert stable == simulated, f
    with pytest.raises(ProblemError, match="unstable"):
        SeekDesigner(SeekProblem(truth.copy(k0=truth.k0 * 3), ctrl, IMAX))


def test_cli_design_early_errors_exit_2(tmp_path, capsys):
    """Seeks longer than the stroke, a current limit that cannot hold the bias, an unstable loop: exit 2
    with one line before any QP.  (Without a stroke any length designs: long seeks are built from the
    acceleration step, seekopt.design.longseek.)"""
    from seekopt.app.cli import main
    from seekopt.drive.presets import default_truth_plant
    p = default_truth_plant()
    good, bad = tmp_path / "plant.json", tmp_path / "unstable.json"
    p.to_json(good)
    p.copy(k0=p.k0 * 3).to_json(bad)
    out = tmp_path / "p.csv"
    for args in (["--plant", str(good), "--tracks", "1e9", "--imax", "0.3", "--stroke", "1e6"],
                 ["--plant", str(good), "--tracks", "200", "--imax", "1e-7"],
                 ["--plant", str(bad), "--tracks", "200", "--imax", "0.3"]):
        assert main(["design", *args, "--robust", "none", "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "error" in err
    assert not out.exists()


def test_k500_nominal_designs_on_the_bundled_plant():
    """K = 500 nominal (issue 12: used to abort with 'QP solver daqp failed')."""
    from pathlib import Path
    from identification.model.plant import ModalPlant
    import seekopt
    plant = ModalPlant.load(Path(seekopt.__file__).parent / "data" / "sample_log.truth.json")
    res = SeekDesigner(SeekProblem(plant, Controller.nss(), IMAX)).design(500.0)
    assert res.metrics.settled and res.unresolved_solves == 0
    assert res.metrics.peak_current_a <= IMAX * (1 + 1e-9)


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
    return SeekDesigner(SeekProblem(identified, ctrl, IMAX, robust=IDENT_ROBUST))


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
        res = SeekDesigner(SeekProblem(plant, ctrl, IMAX, robust=IDENT_ROBUST)).design(200.0)
        m = evaluate_profile(shifted, ctrl, res.profile)
        assert m.settled and m.settle_time_s <= 0.7 * _best_baseline(plant, shifted, ctrl, 200.0)


@pytest.fixture(scope="module")
def bundled_plant():
    """The plant identified from the bundled sample log (the README's plant.json)."""
    from pathlib import Path
    import seekopt
    from identification.estimate.identify import identify
    from identification.logs.formats import read_log
    return identify(read_log(Path(seekopt.__file__).parent / "data" / "sample_log.npz")).plant


@pytest.mark.slow
@pytest.mark.parametrize("K,robust", [(500.0, None), (10000.0, RobustSpec())])
def test_issue12_false_aborts_design(bundled_plant, K, robust):
    """K = 500 nominal and K = 10000 robust (issue 12: aborted with 'QP solver daqp failed')."""
    res = SeekDesigner(SeekProblem(bundled_plant, Controller.nss(), IMAX, robust=robust)).design(K)
    assert res.metrics.settled and res.unresolved_solves == 0
    assert res.metrics.peak_current_a <= IMAX * (1 + 1e-9)
    assert res.metrics.settle_time_s * Controller.nss().sample_rate_hz <= res.settle_samples + 1


def test_finish_plays_a_loop_that_does_not_superpose_once(monkeypatch):
    """A plant whose loop does not superpose (a pivot spring's rest offset, seekopt.design.predict.superposes)
    is played once per verified design: the metrics and the unmodelled-mode guard read the same play, and
    both equal what the simulator and guard_report give on their own."""
    from identification.model.effects import PivotSpringDamper
    import seekopt.design.metrics as metmod
    import seekopt.drive.simulator as simmod
    from seekopt.design import guard as guardmod
    from seekopt.design.predict import superposes
    ctrl = Controller.nss()
    p = default_truth_plant().copy(effects=[PivotSpringDamper(30.0, 0.1, 3.0)])
    assert p.is_linear and not superposes(p)
    des = SeekDesigner(p, ctrl, IMAX)
    assert des.guard_bands
    import seekopt.design.designer as desmod
    sims, real_sim = [0], simmod.simulate_2dof
    plays = {"finish": [], "played": [], "packaged": []}     # simulator runs per call

    def counting(*a, **k):
        sims[0] += 1
        return real_sim(*a, **k)

    def counted(name, real):
        def call(*a, **k):
            before = sims[0]
            try:
                return real(*a, **k)
            finally:
                plays[name].append(sims[0] - before)
        return call
    monkeypatch.setattr(simmod, "simulate_2dof", counting)
    monkeypatch.setattr(metmod, "simulate_2dof", counting)
    monkeypatch.setattr(SeekDesigner, "_finish", counted("finish", SeekDesigner._finish))
    monkeypatch.setattr(desmod, "played_design", counted("played", desmod.played_design))
    monkeypatch.setattr(desmod, "packaged_design", counted("packaged", desmod.packaged_design))
    res = des.design(200.0)
    # a verified design: one play (the check, directly or through _finish); packaging plays nothing more
    assert plays["finish"] + plays["played"] and all(n == 1 for n in plays["finish"] + plays["played"]), plays
    assert all(n == 0 for n in plays["packaged"]), plays
    monkeypatch.undo()
    assert res.metrics == evaluate_profile(p, ctrl, res.profile, settle=0.1)
    g = guardmod.guard_report(p, ctrl, res.profile, des.guard_bands, 0.1, curve=des.guard_curve)
    assert (res.guard.worst_band, res.guard.worst_hz) == (g.worst_band, g.worst_hz)
