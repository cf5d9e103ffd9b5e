"""The seek QP's rows as an operator (seekopt.design.qp_rows.SeekRows): the blind-band rows derived from a
band row and a shared row, never stored, give the same products and rows as written out."""
from __future__ import annotations

import numpy as np

from seekopt.design.ocp import SeekDesigner
from seekopt.design.qp_rows import SeekRows
from seekopt.design.solvers import constraint_violation
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant


def test_derived_rows_match_the_rows_written_out():
    des = SeekDesigner(default_truth_plant(), Controller.nss(), 0.3)
    qp = des._structure(8, False)
    r = qp.rows
    assert r.p.size > 0 and qp.m == r.m_b + r.p.size              # the blind-band rows are derived
    assert np.all(qp.kind[r.m_b:] == "bpes") and not np.any(qp.kind[:r.m_b] == "bpes")
    K = 37.0
    A0, A1 = SeekRows.expand(r.A0, r.A1, r.D0, r.D1, r.p, r.d, r.s)
    A = A0 + K * A1                                                 # every row written out
    op = qp.row_operator(K)
    x = np.random.default_rng(3).uniform(-1, 1, qp.n)
    ax = A @ x
    assert np.allclose(op.matvec(x), ax, rtol=0, atol=1e-9 * np.max(np.abs(ax)))
    rows = np.r_[0, 7, r.m_b - 1, r.m_b, qp.m - 1]
    cols = np.arange(0, qp.n, 3)
    assert np.allclose(op.take(rows, cols), A[np.ix_(rows, cols)], rtol=1e-12, atol=1e-12)
    assert np.allclose(op.dense(), A, rtol=1e-12, atol=1e-12)
    # term sizes: exact on the explicit rows, an upper bound (|a| + |d|) on the derived ones
    size, exact = op.abs_matvec(np.abs(x)), np.abs(A) @ np.abs(x)
    assert np.allclose(size[:r.m_b], exact[:r.m_b], rtol=1e-12)
    assert np.all(size >= exact * (1 - 1e-12))
    # the re-check: the same verdict as on the rows written out, no looser than there
    g, lba, uba, lbx, ubx = qp.bounds(K, 8, des.beta, des.gamma, des.hf_tol, None)
    v_op, v_dense = qp.violation(x, K, lba, uba, lbx, ubx), constraint_violation(A, x, lba, uba, lbx, ubx)
    assert v_dense > 0 and v_op <= v_dense * (1 + 1e-9) and v_op > 0.5 * v_dense
    H, Am = qp.matrices(K)
    assert np.array_equal(Am, op.dense()) and H is qp.hessian(K)
