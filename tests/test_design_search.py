"""The seek-length search and the reduced QP solves behind it: which lengths the search probes (and
with which confirmation), the predicted start, the nominal QP solved on its free variables, and
infeasibility certificates found by cutting-plane phase-1 LPs."""
import math
from dataclasses import dataclass

import numpy as np
import pytest

from seekopt.design.certificates import proves_infeasible
from seekopt.design.designer import SeekDesigner
from seekopt.design.problem import SeekProblem, SolverSettings
from seekopt.design.profiles import t_bang_bang
from seekopt.design.search import bisect_length, gallop_length, prior_length, predict_length
from seekopt.design.working_set import WorkingSetQP
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from seekopt.evaluate.bench import perturbed_plant
from tests.qp_cases import two_conflicting_rows

IMAX = 0.3


@dataclass
class _Answer:
    success: bool
    x: np.ndarray


class _Lengths:
    """Feasible from ``n_star`` on; records every probe ``(n, confirm)``; an infeasible probe made
    without confirmation is 'unconfirmed' (as the designer's working set reports it)."""

    def __init__(self, n_star):
        self.n_star, self.calls, self._unconfirmed = n_star, [], set()

    def probe(self, n, warm=None, confirm=True):
        self.calls.append((n, bool(confirm)))
        ok = n >= self.n_star
        if not ok and not confirm:
            self._unconfirmed.add(n)
        return _Answer(ok, np.full(2, float(n)))

    def unconfirmed(self, n):
        found = n in self._unconfirmed
        self._unconfirmed.discard(n)
        return found


@pytest.mark.parametrize("n_star", [3, 9, 17, 30, 31])
@pytest.mark.parametrize("n0", [2, 8, 9, 10, 16, 29, 32])
def test_gallop_and_bisection_find_the_shortest_length_and_confirm_only_below_it(n_star, n0):
    lo, nmax = 1, 32
    s = _Lengths(n_star)
    found = gallop_length(s.probe, lo, n0, nmax)
    assert found is not None
    hi, _ = bisect_length(s.probe, *found, s.unconfirmed, floor=lo)
    assert hi == n_star
    # the length the answer rests on is solved with confirmation (once), no other infeasible one is
    confirmed_inf = [n for n, c in s.calls if c and n < n_star]
    assert confirmed_inf == ([n_star - 1] if n_star - 1 > lo else [])
    assert len(s.calls) == len(set(s.calls))            # no probe repeated with the same flag
    if n0 == n_star and n_star - 1 > lo:    # exact prediction: two solves, the second confirmed at once
        assert s.calls == [(n_star, False), (n_star - 1, True)]


def test_gallop_stops_at_an_infeasible_class_top_after_one_probe():
    s = _Lengths(40)
    assert gallop_length(s.probe, 20, 32, 32) is None
    assert s.calls == [(32, True)]          # the class's longest seek: confirmed at once (one probe)
    s = _Lengths(40)
    assert gallop_length(s.probe, 20, 30, 32) is None
    assert s.calls == [(30, False), (31, False), (32, True)]


def test_prior_length_starts_a_first_search_near_the_designed_lengths():
    # designed lengths of the bundled plants (nominal): n_rigid 2 -> 6, 11 -> 19, 49 -> 64
    assert prior_length(2) == 7 and prior_length(11) == 18 and prior_length(49) == 66
    assert prior_length(0) == prior_length(1) == 6


def test_predicted_length_is_the_neighbours_settle_overhead():
    assert predict_length({40: 55, 60: 75}, 50) == 65          # overhead 15 interpolated
    assert predict_length({40: 55, 60: 79}, 50) == 67          # 15 .. 19
    assert predict_length({40: 55}, 50) == 65                  # one neighbour: its overhead
    assert predict_length({40: 55}, 100) is None               # no neighbour within 1.5x
    assert predict_length({}, 10) is None


@pytest.fixture(scope="module")
def setup():
    truth, ctrl = default_truth_plant(), Controller.nss()
    return ctrl, perturbed_plant(truth, ctrl.sample_rate_hz)


def test_nominal_qp_on_its_free_variables_answers_as_the_full_qp(setup):
    """The nominal structures are solved on their free variables with every bounded row
    (WorkingSetQP screen=False): the full QP's answer and verdict, and the same designs."""
    ctrl, design = setup
    full = SeekDesigner(SeekProblem(design, ctrl, IMAX, solver=SolverSettings(working_set=False)))
    red = SeekDesigner(SeekProblem(design, ctrl, IMAX))
    for K in (20.0, 150.0):
        a, b = full.design(K), red.design(K)
        assert a.settle_samples == b.settle_samples
        assert np.allclose(a.profile.current_a, b.profile.current_a, atol=1e-4 * IMAX)
    assert red._ws and all(w.rounds >= 1 and w.full_solves == 0 for w in red._ws.values())
    qp = red._structure(32, False)
    ws = WorkingSetQP(qp, lambda n, m: qp._make_solver(n, m))
    n_rigid = int(math.ceil(t_bang_bang(150.0, design.k0, IMAX) * ctrl.sample_rate_hz))
    verdicts = set()
    for n in (n_rigid, 22, 28, 32):
        args = (150.0, n, red.beta, red.gamma, red.hf_tol if red.guard_bands else None, red.slew)
        f = qp.solver.solve(*qp.numeric(*args))
        r = ws.solve(*args, screen=False)
        assert (f.outcome, f.success) == (r.outcome, r.success)
        verdicts.add(f.success)
        if f.success:
            assert np.allclose(f.x, r.x, atol=1e-6)
            assert np.all(r.x[n + qp.input_tail:qp.nin] == 0.0)   # pinned samples past the inputs (settle + tail)
    assert verdicts == {True, False}


def test_cutting_plane_certificate_proves_on_few_rows():
    """WorkingSetQP._certificate: the rows the solver names are feasible on their own; the rows the
    phase-1 LP's point violates join until the LP proves infeasibility -- a verified certificate on
    a few rows of many (never the whole set's LP when the cuts suffice)."""
    A, lba, uba, lbx, ubx = two_conflicting_rows()
    named = np.zeros(len(A)); named[0] = -1.0                     # the solver names row a only
    lam = WorkingSetQP._certificate(A, lba, uba, lbx, ubx, len(A), named)
    assert lam is not None and proves_infeasible(A, lba, uba, lbx, ubx, lam)
    assert set(np.flatnonzero(lam)) == {0, 101}
    lba[[0, 101]] = 0.5                                           # now feasible: no certificate
    assert WorkingSetQP._certificate(A, lba, uba, lbx, ubx, len(A), named) is None
