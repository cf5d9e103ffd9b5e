"""Fallback solvers that cannot hang, whole-row failures that move the search on, the design check by the
linear play, and the guard rows shared by the designers of one plant (issue 12)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from seekopt.design import guard as guardmod
from seekopt.design.designer import SeekDesigner
from seekopt.design.metrics import evaluate_profile
from seekopt.design.problem import SeekProblem, SolverSettings
from seekopt.design.profiles import t_bang_bang
from seekopt.design.qp_status import QPSolution, QPStatus
from seekopt.design.solvers import ConicQP, SolverChain, make_qp_solver
from seekopt.design.working_set import WorkingSetQP
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from seekopt.evaluate.bench import perturbed_plant

IMAX = 0.3


def _box_qp(n: int = 30, seed: int = 0):
    """A strictly convex QP whose optimum has many active rows (the unconstrained optimum far outside)."""
    rng = np.random.default_rng(seed)
    Q = rng.standard_normal((n, n))
    H = Q @ Q.T + n * np.eye(n)
    g = -50.0 * rng.standard_normal(n) * n
    A = rng.standard_normal((2 * n, n))
    return H, g, A, -np.ones(2 * n), np.ones(2 * n), -np.ones(n), np.ones(n)


def test_qpoases_fallback_stops_at_its_working_set_limit():
    """qpOASES is built with a working-set limit (casadi's ``CPUtime`` is not honoured): a limit too small
    for the QP ends in ``iteration_limit`` (no proof), not a wait; the default limit solves it."""
    data = _box_qp()
    n, m = data[0].shape[0], data[2].shape[0]
    ref = make_qp_solver(n, m, "daqp_pkg").solve(*data)
    assert ref.outcome is QPStatus.OPTIMAL
    short = ConicQP(n, m, "qpoases", {"nWSR": 2}).solve(*data)
    assert short.outcome is QPStatus.ITERATION_LIMIT and not short.success
    default = ConicQP(n, m, "qpoases")
    assert 0 < default.options["nWSR"] < math.inf
    assert 0 < ConicQP(n, m, "highs").options["highs"]["time_limit"] < math.inf
    full = default.solve(*data)
    assert full.outcome is QPStatus.OPTIMAL
    assert np.allclose(full.x, ref.x, atol=1e-6)


def test_proximal_daqp_answers_an_ill_conditioned_qp_like_the_package():
    """``daqp_prox`` (the package with proximal iterations, a fallback of the default chain after
    casadi's daqp) gives the package's optimum on a well-posed QP and on a Hessian with condition ~1e11."""
    H, g, A, lba, uba, lbx, ubx = _box_qp(seed=1)
    n, m = H.shape[0], A.shape[0]
    U, _ = np.linalg.qr(np.random.default_rng(2).standard_normal((n, n)))
    Hill = U @ np.diag(np.geomspace(1e-5, 1e6, n)) @ U.T
    for Hq in (H, Hill):
        a = make_qp_solver(n, m, "daqp_pkg").solve(Hq, g, A, lba, uba, lbx, ubx)
        b = make_qp_solver(n, m, "daqp_prox").solve(Hq, g, A, lba, uba, lbx, ubx)
        assert b.solver == "daqp_prox" and b.outcome is QPStatus.OPTIMAL
        fa = 0.5 * a.x @ Hq @ a.x + g @ a.x
        fb = 0.5 * b.x @ Hq @ b.x + g @ b.x
        assert fb <= fa + 1e-6 * abs(fa)
    chain = SolverSettings().chain
    assert chain.index("daqp") < chain.index("daqp_prox") < chain.index("qpoases")


class _Failing:
    """A solver that always ends in numerical trouble (counts its calls)."""
    warm_duals = False

    def __init__(self, name):
        self.name, self.calls = name, 0

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None):
        self.calls += 1
        n = H.shape[0]
        return QPSolution(np.full(n, np.nan), np.zeros(len(A)), np.zeros(n), False, "-2", 0.0, 0.0,
                          QPStatus.NUMERICAL, self.name)


@pytest.fixture(scope="module")
def setup():
    truth, ctrl = default_truth_plant(), Controller.nss()
    return truth, ctrl, perturbed_plant(truth, ctrl.sample_rate_hz)


def test_whole_row_failure_is_returned_without_solving_the_same_full_qp(setup):
    """A nominal structure's QP on its free variables with every row (screen=False) IS the full QP: when
    every solver fails on it, the answer is that failure (numerical, no proof) and the full QP is not
    solved again (which ran the whole chain a second time: minutes of qpOASES at nominal K = 3888)."""
    _, ctrl, design = setup
    des = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    qp = des._structure(32, False)
    made = []

    def chain(n, m):
        c = SolverChain(n, m, ("daqp_pkg", "daqp"))
        c._solvers = {name: _Failing(name) for name in c.names}
        made.append(c)
        return c
    ws = WorkingSetQP(qp, chain, pad=False)
    n = int(math.ceil(t_bang_bang(150.0, design.k0, IMAX) * ctrl.sample_rate_hz)) + 4
    sol = ws.solve(150.0, n, des.beta, des.gamma, des.hf_tol if des.guard_bands else None, des.slew, screen=False)
    assert sol.outcome is QPStatus.NUMERICAL and not sol.success
    assert ws.full_solves == 0
    assert [a[0] for a in sol.attempts] == ["daqp_pkg", "daqp"]
    assert sum(s.calls for c in made for s in c._solvers.values()) == 2


def test_design_check_by_linear_play_equals_the_simulator(setup):
    """A plant whose loop superposes is checked by the linear play of the designer's maps: the metrics
    the result carries are the simulator's (settle time exactly, peak current to rounding)."""
    truth, ctrl, _ = setup
    des = SeekDesigner(SeekProblem(truth, ctrl, IMAX))
    for K in (10.0, 300.0):
        res = des.design(K)
        sim = evaluate_profile(truth, ctrl, res.profile)
        assert res.metrics.settle_time_s == sim.settle_time_s
        assert abs(res.metrics.peak_current_a - sim.peak_current_a) <= 1e-9 * IMAX
        assert res.metrics.settle_time_s * ctrl.sample_rate_hz <= res.settle_samples + 1 + 1e-9


def test_guard_rows_are_shared_by_the_designers_of_one_plant(setup, monkeypatch):
    """The nominal and robust designers of one plant build a size class's guard rows once (the same
    read-only arrays); another plant's designer builds its own."""
    from seekopt.design.robust import RobustSpec
    truth, ctrl, design = setup
    guardmod._GUARD_CACHE.clear()
    built = []
    orig = guardmod.build_guard_rows
    monkeypatch.setattr(guardmod, "build_guard_rows", lambda *a, **k: built.append(a[3]) or orig(*a, **k))
    a = SeekDesigner(SeekProblem(truth, ctrl, IMAX))
    b = SeekDesigner(SeekProblem(truth, ctrl, IMAX, robust=RobustSpec()))
    assert a.guard_bands
    qa, qb = a._structure(32, False), b._structure(32, False)
    assert len(built) == 1
    G = qa_rows = guardmod._GUARD_CACHE[next(iter(guardmod._GUARD_CACHE))][0]
    assert not G.flags.writeable and qa_rows.shape[1] > 0
    c = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    c._structure(32, False)
    assert len(built) == 2
    # the shared rows give the same designs as rows built afresh
    guardmod._GUARD_CACHE.clear()
    fresh = SeekDesigner(SeekProblem(truth, ctrl, IMAX))
    assert np.array_equal(fresh._structure(32, False).A0, qa.A0)
    assert qb.m > qa.m


def test_package_daqp_retries_a_stuck_solve_with_proximal_iterations():
    """A ``daqp_pkg`` solve that ends at the iteration limit (or cycling) is retried once with proximal
    iterations (``PROX_OPTIONS``) before the chain's fallbacks are asked: here the limit is made tiny."""
    from seekopt.design.daqp_solver import DaqpQP
    data = _box_qp(seed=3)
    n, m = data[0].shape[0], data[2].shape[0]
    ref = DaqpQP(n, m).solve(*data)
    stuck = DaqpQP(n, m, {"iter_limit": 2})
    sol = stuck.solve(*data)
    assert stuck.prox_retries == 1
    assert sol.outcome is QPStatus.OPTIMAL and np.allclose(sol.x, ref.x, atol=1e-6)
    assert DaqpQP(n, m).prox_retries == 0
