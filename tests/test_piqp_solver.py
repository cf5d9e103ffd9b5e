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
needs_piqp = pytest.mark.skipif(not solvmod.piqp_available(), reason="piqp not installed (optional)")


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
