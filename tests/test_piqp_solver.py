"""PIQP as a design QP solver (:class:`seekopt.design.piqp_solver.PiqpQP`): the daqp package's answers and
verdicts, "infeasible" with a verified Farkas certificate, the chain moving on from its trouble, and the
designer with PIQP as the first fallback designing the same lengths."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from seekopt.design import solvers as solvmod
from seekopt.design.designer import SeekDesigner
from seekopt.design.problem import SeekProblem, SolverSettings
from seekopt.design.solver_settings import BASE_FALLBACKS
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from tests.test_daqp_solver import _random_qps, _seek_qps

IMAX = 0.3
needs_piqp = pytest.mark.skipif(not solvmod.piqp_available(), reason="piqp not installed (a dependency; absent only where it could not be installed)")


@pytest.fixture(scope="module")
def plant_ctrl():
    return default_truth_plant(), Controller.nss()


@needs_piqp
def test_piqp_answers_and_proves_as_daqp(plant_ctrl):
    """Random QPs and the seek QP at the designed length and one sample short: the daqp package's
    outcome; optimal answers agree; every "infeasible" of the seek QP carries a verified certificate."""
    seek, _ = _seek_qps(*plant_ctrl)
    proven = 0
    for i, data in enumerate(_random_qps() + seek):
        n, m = data[0].shape[0], data[2].shape[0]
        a = solvmod.PiqpQP(n, m).solve(*data)
        b = solvmod.DaqpQP(n, m).solve(*data)
        assert a.outcome is b.outcome and a.solver == solvmod.PIQP
        if a.outcome is solvmod.QPStatus.OPTIMAL:
            assert solvmod.constraint_violation(data[2], a.x, *data[3:]) <= 1e-8
            f = lambda x: 0.5 * x @ data[0] @ x + data[1] @ x      # noqa: E731
            assert abs(f(a.x) - f(b.x)) <= 1e-7 * max(1.0, abs(f(b.x)))
        else:
            assert a.proven in (True, False)
            if a.proven:
                proven += 1
                assert solvmod.proves_infeasible(data[2], data[3], data[4], data[5], data[6], a.lam_a)
            else:
                assert not np.any(a.lam_a)       # unproven: no multipliers to mistake for a certificate
    short = solvmod.PiqpQP(1, 1).solve(*seek[1])                   # one sample short of the design
    assert short.outcome is solvmod.QPStatus.INFEASIBLE and short.proven is True
    assert proven >= 2


@needs_piqp
def test_chain_moves_on_from_piqp_trouble_and_piqp_proves_for_the_chain():
    """PIQP at its iteration limit proves nothing: the next solver answers.  As the second solver of a
    chain it proves what the first reported infeasible."""
    H, g, A = np.eye(3), np.ones(3), np.array([[1.0, 1.0, 0.0], [0.0, 1.0, -1.0]])
    ok = (H, g, A, np.array([-1.0, -0.5]), np.array([1.0, 0.5]), -np.ones(3), np.ones(3))
    bad = (H, g, A, np.array([2.5, -0.5]), np.array([3.0, 0.5]), -np.ones(3), np.ones(3))    # x0 + x1 <= 2
    chain = solvmod.SolverChain(3, 2, (solvmod.PIQP, solvmod.DAQP_PKG), options={solvmod.PIQP: {"max_iter": 1}})
    sol = chain.solve(*ok)
    assert sol.outcome is solvmod.QPStatus.OPTIMAL and sol.solver == solvmod.DAQP_PKG
    assert [a[0] for a in sol.attempts] == [solvmod.PIQP, solvmod.DAQP_PKG]
    assert sol.attempts[0][2] == solvmod.QPStatus.ITERATION_LIMIT.value
    chain = solvmod.SolverChain(3, 2, (solvmod.PIQP, solvmod.DAQP_PKG))
    sol = chain.solve(*bad, start=0)
    assert sol.outcome is solvmod.QPStatus.INFEASIBLE and sol.proven is True and sol.solver == solvmod.PIQP
    assert solvmod.proves_infeasible(A, *bad[3:], sol.lam_a)


@needs_piqp
def test_designer_with_piqp_first_fallback_designs_the_same(plant_ctrl):
    """PIQP as the first fallback of the one-plant designer (the default where the package is installed)
    replaces daqp's phase-1 proofs (none run), and the lengths are those of the chain without PIQP."""
    plant, ctrl = plant_ctrl
    base = SeekDesigner(SeekProblem(plant, ctrl, IMAX, solver=SolverSettings(fallbacks=BASE_FALLBACKS)))
    alt = SeekDesigner(SeekProblem(plant, ctrl, IMAX))
    assert alt.settings.chain[:2] == (solvmod.DAQP_PKG, solvmod.PIQP)
    for K in (50.0, 500.0):
        a, b = base.design(K), alt.design(K)
        assert a.settle_samples == b.settle_samples
        assert b.unresolved_solves == 0
    assert sum(ws.phase1_proofs for ws in alt._ws.values()) == 0
    assert sum(ws.phase1_proofs for ws in base._ws.values()) > 0


def test_piqp_missing_is_an_import_error(monkeypatch):
    """Without the optional package, asking for ``piqp`` fails loudly (never a silent other solver), and
    the default chain is the one without it."""
    monkeypatch.setitem(sys.modules, "piqp", None)
    with pytest.raises(ImportError):
        solvmod.make_qp_solver(3, 2, solvmod.PIQP)
    assert not solvmod.piqp_available() and not solvmod.piqp_installed()
    assert SolverSettings().fallbacks == BASE_FALLBACKS


@needs_piqp
def test_default_chain_asks_piqp_first_and_free_rows_change_nothing():
    """Where the package is installed PIQP is the first fallback.  Rows without bounds (the full QP's free
    rows) are left out of PIQP's problem: the same answer as without them, zero multipliers on them."""
    assert solvmod.piqp_installed() and SolverSettings().fallbacks == (solvmod.PIQP,) + BASE_FALLBACKS
    rng = np.random.default_rng(3)
    n = 6
    M = rng.standard_normal((n, n))
    H, g = M @ M.T + np.eye(n), rng.standard_normal(n)
    A = rng.standard_normal((4, n))
    lba, uba = np.array([-1.0, -0.2, 0.3, -0.5]), np.array([1.0, 0.2, 0.3, 0.5])     # an equality too
    box = (-np.ones(n), np.ones(n))
    a = solvmod.PiqpQP(n, 4).solve(H, g, A, lba, uba, *box)
    free = rng.standard_normal((3, n))
    b = solvmod.PiqpQP(n, 7).solve(H, g, np.vstack([A[:2], free, A[2:]]),
                                   np.r_[lba[:2], [-np.inf] * 3, lba[2:]], np.r_[uba[:2], [np.inf] * 3, uba[2:]], *box)
    assert a.outcome is b.outcome is solvmod.QPStatus.OPTIMAL
    assert np.allclose(a.x, b.x, atol=1e-9) and np.all(b.lam_a[2:5] == 0.0)
    assert np.allclose(b.lam_a[[0, 1, 5, 6]], a.lam_a, atol=1e-8)


@needs_piqp
def test_piqp_answer_keeps_only_the_active_rows_multipliers():
    """An interior-point answer's small multipliers on inactive rows are zeroed (they would start daqp from
    wrong rows); the active rows keep theirs and the optimality conditions still hold."""
    rng = np.random.default_rng(5)
    n, m = 8, 12
    M = rng.standard_normal((n, n))
    H, g = M @ M.T + np.eye(n), 3.0 * rng.standard_normal(n)
    A = rng.standard_normal((m, n))
    lba, uba, lbx, ubx = -0.3 * np.ones(m), 0.3 * np.ones(m), -np.ones(n), np.ones(n)
    a = solvmod.PiqpQP(n, m).solve(H, g, A, lba, uba, lbx, ubx)
    assert a.outcome is solvmod.QPStatus.OPTIMAL
    r = A @ a.x
    active = np.minimum(uba - r, r - lba) <= 1e-7
    assert active.any() and (~active).any()
    assert np.all(a.lam_a[~active] == 0.0) and np.all(a.lam_a[active] != 0.0)
    assert solvmod.kkt_holds(H, g, A, lba, uba, lbx, ubx, a.x, a.lam_a, a.lam_x)
    b = solvmod.DaqpQP(n, m).solve(H, g, A, lba, uba, lbx, ubx)        # the active-set solver's active rows
    assert np.array_equal(np.abs(b.lam_a) > 0, active)


@needs_piqp
def test_daqp_leaves_its_proximal_retry_to_piqp_when_piqp_is_next():
    assert solvmod.SolverChain(3, 2, (solvmod.DAQP_PKG, solvmod.PIQP)).get(solvmod.DAQP_PKG).prox_retry is False
    assert solvmod.SolverChain(3, 2, (solvmod.DAQP_PKG, "daqp")).get(solvmod.DAQP_PKG).prox_retry is True


class _FalselyInfeasible:
    """A primary that calls every QP infeasible without a certificate (as the ``daqp`` package did on
    ill-conditioned reduced QPs of long robust seeks)."""
    name, warm_duals = solvmod.DAQP_PKG, False

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None):
        n, m = len(g), len(A)
        return solvmod.QPSolution(np.full(n, np.nan), np.zeros(m), np.zeros(n), False, "-1", 0.0, 0.0,
                                  solvmod.QPStatus.INFEASIBLE, solvmod.DAQP_PKG, proven=False)


@needs_piqp
def test_a_search_step_with_a_second_opinion_is_not_ended_by_an_unproven_infeasible(plant_ctrl):
    """``WorkingSetQP.solve(confirm=False)``: the primary's unproven "infeasible" ends a search step as it
    is; with ``second_opinion=True`` the chain's next solver re-solves the reduced QP and its answer
    continues the rounds: the full QP's optimum."""
    from seekopt.design.working_set import WorkingSetQP
    plant, ctrl = plant_ctrl
    d = SeekDesigner(SeekProblem(plant, ctrl, IMAX))
    res = d.design(150.0)
    N = res.settle_samples
    qp = d._structure(d._classes(N)[0], False)
    args = (150.0, N, d.beta, d.gamma, d.hf_tol if d.guard_bands else None, d.slew)

    def chain(n, m):
        c = solvmod.SolverChain(n, m, (solvmod.DAQP_PKG, solvmod.PIQP))
        c._solvers[solvmod.DAQP_PKG] = _FalselyInfeasible()
        return c
    step = WorkingSetQP(qp, chain).solve(*args, confirm=False)
    assert step.outcome is solvmod.QPStatus.INFEASIBLE and step.unconfirmed
    second = WorkingSetQP(qp, chain).solve(*args, confirm=False, second_opinion=True)
    assert second.success and second.solver == solvmod.PIQP
    data = qp.numeric(*args)
    full = solvmod.DaqpQP(qp.n, qp.m).solve(*data)
    f = lambda x: 0.5 * x @ data[0] @ x + data[1] @ x      # noqa: E731  (the optimum's value: x itself is
    assert full.success and abs(f(second.x) - f(full.x)) <= 1e-7 * abs(f(full.x))   # ill-determined, cond(H))
    assert solvmod.constraint_violation(data[2], second.x, *data[3:]) <= 1e-8
