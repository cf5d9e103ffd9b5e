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


def _random_rows(rng, m_b=300, n=41, nd=12, nv=500):
    """Explicit rows on disjoint column sets (part 0: columns 0..19 and the last, part 1: 20..39, one of
    them all zero) and derived rows, as a seek QP's."""
    A0, A1 = np.zeros((m_b, n)), np.zeros((m_b, n))
    A0[:, :20], A0[:, -1] = rng.standard_normal((m_b, 20)), rng.standard_normal(m_b)
    A1[:, 20:40] = rng.standard_normal((m_b, 20))
    A0[:, 5] = 0.0                                   # a column with no entry: left out of the products
    D0, D1 = np.zeros((nd, n)), np.zeros((nd, n))
    D0[:, :20], D1[:, 20:40] = rng.standard_normal((nd, 20)), rng.standard_normal((nd, 20))
    p, d, s = rng.integers(0, m_b, nv), rng.integers(0, nd, nv), rng.choice([-1.0, 1.0], nv)
    return A0, A1, D0, D1, p, d, s


def test_rows_from_parts_equal_the_rows_from_full_arrays():
    """SeekRows.from_parts (the seek QP's: each part on its own columns, the full arrays never written) gives
    bitwise the products and rows of SeekRows(A0, A1), for rows in any order, explicit and derived mixed,
    columns in runs or not, and after |K| changes (kept shared rows and column maps renewed)."""
    rng = np.random.default_rng(5)
    A0, A1, D0, D1, p, d, s = _random_rows(rng)
    n = A0.shape[1]
    full = SeekRows(A0, A1, D0, D1, p, d, s)
    c0, c1 = np.r_[np.arange(20), n - 1], np.arange(20, 40)
    parts = SeekRows.from_parts(n, (c0, np.asfortranarray(A0[:, c0])), (c1, np.asfortranarray(A1[:, c1])),
                                D0, D1, p, d, s)
    assert np.array_equal(parts.A0, A0) and np.array_equal(parts.A1, A1)
    written = lambda K: np.vstack([A0 + K * A1, (A0 + K * A1)[p] + s[:, None] * (D0 + K * D1)[d]])  # noqa: E731
    for K in (3.0, 3.0, 250.0, 0.5):
        a, b = full.at(K), parts.at(K)
        x = rng.uniform(-1, 1, n)
        assert np.array_equal(a.matvec(x), b.matvec(x))
        assert np.array_equal(a.abs_matvec(np.abs(x)), b.abs_matvec(np.abs(x)))
        for rows, cols in ((np.arange(0, full.m, 3), np.arange(n)),                     # sorted, all columns
                           (rng.permutation(full.m)[:200], np.arange(3, 30)),           # any order, a run
                           (np.r_[full.m - 1, 0, 7, full.m_b], np.r_[40, 0, 5, 22, 21])):  # scattered
            ref = written(K)[np.ix_(rows, cols)]
            assert np.array_equal(a.take(rows, cols), ref) and np.array_equal(b.take(rows, cols), ref)
        Aw = written(K)
        assert np.allclose(b.matvec(x), Aw @ x, rtol=0, atol=1e-12 * np.max(np.abs(Aw @ x)))


def test_bounds_of_the_last_arguments_are_kept_read_only():
    """SeekQP.bounds returns the same arrays for the same arguments (the designer's re-check and the working
    set ask twice per solve), read-only so that no caller can change them for the next; other arguments
    give other bounds."""
    des = SeekDesigner(default_truth_plant(), Controller.nss(), 0.3)
    qp = des._structure(8, False)
    args = (37.0, 8, des.beta, des.gamma, des.hf_tol, None)
    first = qp.bounds(*args)
    again = qp.bounds(*args)
    assert all(a is b for a, b in zip(first, again))
    for a in first:
        assert not a.flags.writeable
    other = qp.bounds(37.0, 7, des.beta, des.gamma, des.hf_tol, None)
    assert not np.array_equal(other[1], first[1])        # the band rows of sample 7 now bound
    assert all(np.array_equal(a, b) for a, b in zip(qp.bounds(*args), first))
