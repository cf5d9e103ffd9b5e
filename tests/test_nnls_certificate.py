"""Farkas certificates by non-negative least squares (seekopt.design.certificates.nnls_certificate) and the
one BLAS limiter (seekopt.design.blas)."""
from __future__ import annotations

import numpy as np
import pytest

from seekopt.design.certificates import nnls_certificate, phase1_daqp, phase1_lp, proves_infeasible
from tests.qp_cases import two_conflicting_rows


def _system(seed: int, infeasible: bool):
    """Random two-sided rows around a point inside the box; ``infeasible``: row 0 repeated with a band
    that misses its own (no x satisfies both)."""
    rng = np.random.default_rng(seed)
    n = 8
    A = rng.standard_normal((40, n))
    x_in = rng.uniform(-0.5, 0.5, n)
    r = A @ x_in
    lba, uba = r - 0.1, r + 0.1
    if infeasible:
        A = np.vstack([A, A[:1]])
        lba, uba = np.append(lba, uba[0] + 0.05), np.append(uba, np.inf)
    return A, lba, uba, -np.ones(n), np.ones(n)


@pytest.mark.parametrize("seed", range(6))
def test_nnls_certificate_proves_infeasible_rows_and_nothing_else(seed):
    """From every row: a verified certificate exactly when the rows have no solution (the phase-1 LP
    agrees); from a feasible system never one."""
    for infeasible in (False, True):
        A, lba, uba, lbx, ubx = _system(seed, infeasible)
        lam = nnls_certificate(A, lba, uba, lbx, ubx, np.arange(len(A)))
        assert (lam is not None) == infeasible
        assert (phase1_lp(A, lba, uba, lbx, ubx)[0] is not None) == infeasible
        if lam is not None:
            assert proves_infeasible(A, lba, uba, lbx, ubx, lam)


@pytest.mark.parametrize("seed", range(6))
def test_phase1_daqp_proves_infeasible_rows_and_nothing_else(seed):
    """daqp's phase-1 QP: verified multipliers exactly when the rows have no solution (as the phase-1 LP),
    and always the added row (without it the rows have a solution)."""
    for infeasible in (False, True):
        A, lba, uba, lbx, ubx = _system(seed, infeasible)
        lam, named = phase1_daqp(A, lba, uba, lbx, ubx)
        assert named is not None
        assert (lam is not None) == infeasible
        if lam is not None:
            assert proves_infeasible(A, lba, uba, lbx, ubx, lam)
            assert lam[-1] != 0


def test_nnls_certificate_cuts_in_the_rows_the_named_ones_lack():
    """Named rows feasible on their own: the rows their least-norm point violates join (cutting planes)
    until the certificate holds -- on the two rows that conflict, out of 202."""
    A, lba, uba, lbx, ubx = two_conflicting_rows()
    lam = nnls_certificate(A, lba, uba, lbx, ubx, [0])
    assert lam is not None and proves_infeasible(A, lba, uba, lbx, ubx, lam)
    assert set(np.flatnonzero(lam)) == {0, 101}
    assert nnls_certificate(A, lba, uba, lbx, ubx, [0], max_rounds=1) is None    # row a alone proves nothing
    lba[[0, 101]] = 0.5                                           # now feasible: no certificate
    assert nnls_certificate(A, lba, uba, lbx, ubx, [0, 101]) is None


def test_one_blas_limiter():
    """The sweep engines, the command line and the designer limit BLAS through one module."""
    from threadpoolctl import threadpool_info

    from seekopt.design import blas
    from seekopt.evaluate import engines
    assert engines.limit_blas is blas.limit_blas
    with blas.blas_limit(1):
        assert all(p["num_threads"] == 1 for p in threadpool_info() if p["user_api"] == "blas")
    with blas.blas_limit(None):        # no limit asked: the pools are left alone
        pass
