"""Tests for identification.estimate.linalg: the one least-squares helper, the covariance family and
the per-seek initial-condition projector."""
import numpy as np
import pytest

from identification.estimate.linalg import SegmentProjector, cluster_cov, lstsq, sandwich_cov, wald, white_cov


def test_lstsq_scaled_rank_revealing_bounded_complex():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(200, 3)) * np.array([1e9, 1.0, 1e-4])      # wildly different column units
    x = np.array([2e-9, -0.5, 3e3])
    b = A @ x
    np.testing.assert_allclose(lstsq(A, b), x, rtol=1e-10)
    # several right-hand sides at once
    np.testing.assert_allclose(lstsq(A, np.column_stack([b, 2 * b])), np.column_stack([x, 2 * x]), rtol=1e-10)
    # rank deficient (a repeated column): the minimum-norm solution, no error
    Ad = np.column_stack([A[:, 1], A[:, 1]])
    np.testing.assert_allclose(lstsq(Ad, A[:, 1]), [0.5, 0.5], rtol=1e-10)
    # bounds are in the unscaled parameters
    xb = lstsq(A, b, bounds=([-np.inf, 0.0, -np.inf], [np.inf, np.inf, np.inf]))
    assert xb[1] >= 0.0
    # complex data
    Ac = A[:, 1:] * (1 + 0.5j)
    np.testing.assert_allclose(lstsq(Ac, Ac @ np.array([1 - 2j, 0.3j])), [1 - 2j, 0.3j], rtol=1e-9)
    assert lstsq(np.zeros((5, 0)), np.ones(5)).shape == (0,)


def test_white_cov_and_wald():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(500, 3)) * np.array([1e6, 1.0, 1e-3])
    r = rng.normal(size=500)
    ref = np.linalg.inv(X.T @ X) * (r @ r) / (500 - 3)
    np.testing.assert_allclose(white_cov(X, r), ref, rtol=1e-9)
    np.testing.assert_allclose(white_cov(X, sigma2=2.0), 2.0 * np.linalg.inv(X.T @ X), rtol=1e-9)
    th = np.array([1.0, -2.0])
    C = np.array([[2.0, 0.3], [0.3, 1.0]])
    assert wald(th, C) == pytest.approx(th @ np.linalg.solve(C, th), rel=1e-12)


def test_cluster_and_sandwich_covariances():
    rng = np.random.default_rng(2)
    n, k = 3000, 2
    J = rng.normal(size=(n, k))
    labels = np.repeat(np.arange(30), 100)
    r = rng.normal(size=n) + np.repeat(rng.normal(size=30), 100)     # correlated within a cluster
    # the textbook cluster sandwich with the CR1-like factors c/(c-1) n/(n-k)
    B = np.linalg.inv(J.T @ J)
    G = np.array([J[labels == c].T @ r[labels == c] for c in range(30)])
    ref = B @ (G.T @ G) @ B * 30 / 29 * n / (n - k)
    np.testing.assert_allclose(cluster_cov(J, r, labels), ref, rtol=1e-9)
    cov, cov_w = sandwich_cov(J, r, np.arange(0, n + 1, 100), kind="cluster")
    np.testing.assert_allclose(cov, ref, rtol=1e-9)
    np.testing.assert_allclose(cov_w, white_cov(J, r), rtol=1e-9)
    # Newey-West with no lags is the heteroscedasticity-robust (HC0 x n/(n-k)) sandwich
    nw0, _ = sandwich_cov(J, r, [0, n], lags=0)
    np.testing.assert_allclose(nw0, B @ (J.T * r ** 2) @ J @ B * n / (n - k), rtol=1e-9)
    with pytest.raises(ValueError, match="newey-west"):
        sandwich_cov(J, r, [0, n], kind="magic")


def test_segment_projector_polynomial_extrapolates_the_per_seek_fit():
    """The per-seek initial position and velocity fitted on part of each seek (here its tail,
    ``offsets`` counting from the seek start) and evaluated over the whole seek equals a plain LS
    line fitted on the same samples."""
    rng = np.random.default_rng(3)
    seeks = [(10, 80), (80, 200), (200, 230)]
    tails = [(50, 80), (150, 200), (220, 230)]
    x = rng.normal(size=300)
    P = SegmentProjector(tails, offsets=[ta - a for (a, _), (ta, _) in zip(seeks, tails)])
    got = P.polynomial(P.take(x), [np.arange(b - a) for a, b in seeks])
    for (a, b), (ta, tb), g in zip(seeks, tails, got):
        t = np.arange(ta - a, tb - a, dtype=float)
        c = np.polyfit(t, x[ta:tb], 1)
        np.testing.assert_allclose(g, np.polyval(c, np.arange(b - a)), atol=1e-10)
    # and the projection removes exactly that fit on the rows
    np.testing.assert_allclose(P.project(P.take(x)),
                               P.take(x) - np.concatenate([g[ta - a:tb - a] for (a, _), (ta, tb), g
                                                           in zip(seeks, tails, got)]), atol=1e-10)
