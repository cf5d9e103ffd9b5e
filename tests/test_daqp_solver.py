"""The ``daqp`` package as the design QP solver (:class:`seekopt.design.solvers.DaqpQP`): the same
answers and verdicts as casadi's daqp, warm starts that change nothing but the work, and casadi's
daqp still selectable through :class:`SolverSettings`."""
from __future__ import annotations

import numpy as np
import pytest

from seekopt.design import solvers as solvmod
from seekopt.design.designer import SeekDesigner
from seekopt.design.problem import SeekProblem, SolverSettings
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from seekopt.evaluate.bench import perturbed_plant

IMAX = 0.3


@pytest.fixture(scope="module")
def plant_ctrl():
    truth, ctrl = default_truth_plant(), Controller.nss()
    return perturbed_plant(truth, ctrl.sample_rate_hz), ctrl


def _random_qps(seed: int = 3, count: int = 12):
    """Strictly convex QPs with box and row bounds (one equality row), some infeasible."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(count):
        n, m = rng.integers(4, 12), rng.integers(3, 15)
        M = rng.standard_normal((n, n))
        H = M @ M.T + 0.5 * np.eye(n)
        g, A = rng.standard_normal(n), rng.standard_normal((m, n))
        lba, uba = -rng.uniform(0.1, 1.0, m), rng.uniform(0.1, 1.0, m)
        lba[0] = uba[0] = 0.2 * rng.standard_normal()
        if i % 3 == 2:                         # a row pushed beyond what the box allows: infeasible
            lba[1] = uba[1] = 2.0 * np.abs(A[1]).sum()
        out.append((H, g, A, lba, uba, -np.ones(n), np.ones(n)))
    return out


def _seek_qps(plant, ctrl, K=200.0):
    """The nominal seek QP at a feasible and an infeasible length (full rows, numpy)."""
    d = SeekDesigner(SeekProblem(plant, ctrl, IMAX))
    res = d.design(K)
    qp = d._structure(d._classes(res.settle_samples)[0], False)
    return [qp.numeric(K, n, d.beta, d.gamma, d.hf_tol if d.guard_bands else None, d.slew)
            for n in (res.settle_samples, res.settle_samples - 1)], res


def test_daqp_package_answers_as_casadi_daqp(plant_ctrl):
    plant, ctrl = plant_ctrl
    seek, _ = _seek_qps(plant, ctrl)
    verdicts = []
    for data in _random_qps() + seek:
        n, m = data[0].shape[0], data[2].shape[0]
        a = solvmod.DaqpQP(n, m).solve(*data)
        b = solvmod.ConicQP(n, m, "daqp").solve(*data)
        assert a.outcome is b.outcome
        verdicts.append(a.outcome)
        if a.outcome is solvmod.QPStatus.OPTIMAL:
            scale = max(1.0, float(np.max(np.abs(b.x))))
            assert np.max(np.abs(a.x - b.x)) <= 1e-6 * scale
            assert np.allclose(a.lam_a, b.lam_a, atol=1e-6 * max(1.0, float(np.max(np.abs(b.lam_a)))))
            assert solvmod.constraint_violation(data[2], a.x, *data[3:]) <= 1e-8
        else:   # an "infeasible" is a verified certificate or marked unproven -- never proof by status
            assert a.proven in (True, False)
            if a.proven:
                assert solvmod.proves_infeasible(data[2], data[3], data[4], data[5], data[6], a.lam_a)
    assert solvmod.QPStatus.OPTIMAL in verdicts and solvmod.QPStatus.INFEASIBLE in verdicts


def test_warm_start_gives_the_cold_answer(plant_ctrl):
    """Started from the active set of the neighbouring length (and from a deliberately wrong one),
    daqp gives the cold answer and verdict."""
    plant, ctrl = plant_ctrl
    d = SeekDesigner(SeekProblem(plant, ctrl, IMAX))
    res = d.design(300.0)
    qp = d._structure(d._classes(res.settle_samples)[0], False)
    hf = d.hf_tol if d.guard_bands else None
    q = solvmod.DaqpQP(qp.n, qp.m)
    prev = q.solve(*qp.numeric(300.0, res.settle_samples + 2, d.beta, d.gamma, hf, d.slew))
    assert prev.outcome is solvmod.QPStatus.OPTIMAL
    rng = np.random.default_rng(0)
    wrong = (rng.choice([-1.0, 0.0, 1.0], qp.m, p=[0.1, 0.8, 0.1]), np.zeros(qp.n))
    for n in (res.settle_samples + 1, res.settle_samples, res.settle_samples - 1):
        data = qp.numeric(300.0, n, d.beta, d.gamma, hf, d.slew)
        cold = q.solve(*data)
        for lam0 in ((prev.lam_a, prev.lam_x), wrong):
            warm = q.solve(*data, lam_a0=lam0[0], lam_x0=lam0[1])
            assert warm.outcome is cold.outcome
            if cold.outcome is solvmod.QPStatus.OPTIMAL:
                assert np.max(np.abs(warm.x - cold.x)) <= 1e-7 * max(1.0, float(np.max(np.abs(cold.x))))
    assert cold.outcome is solvmod.QPStatus.INFEASIBLE       # one sample short of the design


def test_designer_warm_and_cold_design_the_same(plant_ctrl):
    """The working set's warm starts (default) against cold solves: same lengths, same currents."""
    plant, ctrl = plant_ctrl
    ks = (30.0, 120.0, 400.0)
    warm = SeekDesigner(SeekProblem(plant, ctrl, IMAX, robust="n=2"))
    cold = SeekDesigner(SeekProblem(plant, ctrl, IMAX, robust="n=2"))
    make = cold._working_set

    def no_warm(qp):
        ws = make(qp)
        ws.warm = False
        return ws
    cold._working_set = no_warm
    for K in ks:
        a, b = warm.design(K), cold.design(K)
        assert a.settle_samples == b.settle_samples
        assert np.allclose(a.profile.current_a, b.profile.current_a, atol=1e-6 * IMAX)
        assert a.unresolved_solves == b.unresolved_solves == 0


def test_casadi_daqp_selected_in_solver_settings(plant_ctrl):
    """SolverSettings(qp_solver="daqp"): casadi's daqp designs alone (the package is never built),
    the same lengths as the default package solver."""
    plant, ctrl = plant_ctrl
    pkg = SeekDesigner(SeekProblem(plant, ctrl, IMAX))
    cas = SeekDesigner(SeekProblem(plant, ctrl, IMAX, solver=SolverSettings(qp_solver="daqp")))
    for K in (20.0, 250.0):
        a, b = pkg.design(K), cas.design(K)
        assert a.settle_samples == b.settle_samples
        assert a.profile.meta["solver"] == "daqp_pkg" and b.profile.meta["solver"] == "daqp"
    assert solvmod.DAQP_PKG not in cas.solver_builds and cas.solver_builds["daqp"] >= 1
    assert pkg.solver_builds[solvmod.DAQP_PKG] >= 1


def test_unproven_package_infeasible_is_rechecked_never_taken(monkeypatch):
    """A package "infeasible" whose multipliers prove nothing does not end a chain: the next solver
    decides, and without one it is not called infeasible."""
    H, g, A = np.eye(2), np.ones(2), np.array([[1.0, 1.0]])
    bad = (H, g, A, np.array([3.0]), np.array([5.0]), -np.ones(2), np.ones(2))     # infeasible
    good = (H, g, A, np.array([1.0]), np.array([3.0]), -np.ones(2), np.ones(2))
    real = solvmod.DaqpQP.solve

    def unproven(self, *a, **k):
        sol = real(self, *a, **k)
        if sol.outcome is solvmod.QPStatus.INFEASIBLE:
            sol.proven, sol.lam_a = False, np.zeros_like(sol.lam_a)
        return sol
    monkeypatch.setattr(solvmod.DaqpQP, "solve", unproven)
    alone = solvmod.SolverChain(2, 1, (solvmod.DAQP_PKG,))
    assert alone.solve(*bad).outcome is solvmod.QPStatus.NUMERICAL
    assert alone.solve(*bad, prove=False).outcome is solvmod.QPStatus.INFEASIBLE     # the caller proves it
    chain = solvmod.SolverChain(2, 1, (solvmod.DAQP_PKG, "daqp"))
    sol = chain.solve(*bad)
    assert sol.outcome is solvmod.QPStatus.INFEASIBLE and sol.solver == "daqp" and len(sol.attempts) == 2
    ok = chain.solve(*good)
    assert ok.outcome is solvmod.QPStatus.OPTIMAL and ok.solver == solvmod.DAQP_PKG
    # casadi solvers built for more rows take fewer (padded by the chain, multipliers trimmed)
    wide = solvmod.SolverChain(2, 4, ("daqp",))
    sol = wide.solve(*good)
    assert sol.outcome is solvmod.QPStatus.OPTIMAL and sol.lam_a.shape == (1,)
    assert np.allclose(sol.x, ok.x, atol=1e-9)


def test_qpoases_prints_no_banner(capfd):
    """qpOASES prints its licence banner when casadi makes its memory (first solve), not at
    construction: seekopt silences it there too, so sweeps and the CLI print nothing of it."""
    import numpy as np
    from seekopt.design.solvers import ConicQP
    q = ConicQP(2, 1, "qpoases")
    r = q.solve(np.eye(2), np.array([1.0, 1.0]), np.array([[1.0, 1.0]]), [-1.0], [1.0], [-5.0, -5.0], [5.0, 5.0])
    assert np.allclose(r.x, [-0.5, -0.5])
    assert "qpOASES" not in capfd.readouterr().out
