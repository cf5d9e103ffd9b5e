"""Statistics of closing the loop: least squares, clustered covariance, Wald test, BIC.

The residual of an output-error simulation is coloured (force noise integrated by the rigid
body, flutter, run-out) and correlated within a seek, so

* significance uses a covariance robust to any correlation within a seek (the clusters are
  the seeks: :func:`cluster_cov`, :func:`wald`);
* the information criterion counts an *effective* number of independent samples
  (:func:`effective_n`, :func:`bic`).

``windows`` arguments are :class:`identification.loop.windows.Windows`; residuals are
concatenated over their samples.
"""
from __future__ import annotations

import math

import numpy as np

from identification.estimate.linalg import cluster_cov as _cluster_cov, lstsq as _ls, wald

__all__ = ["lstsq", "smooth_lstsq", "cluster_cov", "wald", "effective_n", "bic", "segments"]


def lstsq(r: np.ndarray, Z: np.ndarray, bounds=None):
    """Least squares ``r ~ Z theta`` (optionally bounded): ``(theta, sse)``
    (:func:`identification.estimate.linalg.lstsq`: columns scaled, relative cut-off 1e-9)."""
    th = _ls(Z, r, rcond=1e-9, bounds=bounds)
    e = r - Z @ th
    return th, float(e @ e)


def segments(windows, e: np.ndarray) -> list:
    """Split concatenated window samples into per-window arrays."""
    cuts = np.cumsum([b - a for a, b in windows.bounds])[:-1]
    return np.split(e, cuts)


def cluster_cov(Z: np.ndarray, e: np.ndarray, windows) -> np.ndarray:
    """Covariance of LS coefficients robust to any correlation within a seek (clusters: the
    windows' groups; :func:`identification.estimate.linalg.cluster_cov`)."""
    return _cluster_cov(Z, e, np.repeat(windows.groups, [b - a for a, b in windows.bounds]))


def effective_n(e: np.ndarray, windows, max_lag: int = 100) -> float:
    """Effective number of independent samples of a residual: ``N / (1 + 2 sum rho(k))``,
    ``rho`` its autocorrelation pooled within windows, summed up to its first drop below
    0.05; at least one per seek [-]."""
    segs = segments(windows, e)
    den = sum(float(s @ s) for s in segs) or 1e-300
    tau = 0.0
    for k in range(1, max_lag + 1):
        rho = sum(float(s[k:] @ s[:-k]) for s in segs if len(s) > k) / den
        if rho < 0.05:
            break
        tau += rho
    return max(len(e) / (1.0 + 2.0 * tau), float(len(set(windows.groups))))


def bic(e: np.ndarray, k: float, n_eff: float) -> float:
    """Bayesian information criterion of an output-error residual ``e`` with ``k`` parameters,
    on ``n_eff`` effective samples (:func:`effective_n` of the reference model's residual):
    ``n_eff log(SSE / N) + k log(n_eff)``.  (An AR noise model fitted to each residual would
    reward a large, smooth -- hence predictable -- misfit.)  ``k`` may be negative for a model
    with fewer parameters than the reference."""
    return float(n_eff * math.log(max(float(e @ e) / len(e), 1e-300)) + k * math.log(n_eff))


def smooth_lstsq(y: np.ndarray, X: np.ndarray, n_free: int, windows,
                 penalties=(("L2", 2), ("L2", 3), ("L1", 2), ("L0", 2)), lams=np.logspace(-6, 8, 29),
                 irls: int = 12, folds: int = 5):
    """Penalised least squares ``y ~ X theta`` whose last columns are a table along a coordinate:
    ``|y - X theta|^2 + lam P(D_k theta_table)``, ``D_k`` the k-th differences, the first
    ``n_free`` columns unpenalised, ``P`` the sum of squares (``"L2"``: a P-spline, smooth), of
    absolute values (``"L1"``: trend filtering, piecewise polynomial with few kinks) or a smooth
    count of the non-zero differences (``"L0"``: ``sum d^2 / (d^2 + eps^2)``, few kinks *without
    shrinking them*; L1 shrinks every kink by the same amount, which leaves a flex-cable bias
    table tens of micro-amperes off on both sides of a kink -- over a 10 ms window that is a
    track).  L1 and L0 are solved by iteratively reweighted least squares.  The penalty and
    ``lam`` are chosen by ``folds``-fold cross-validation over seeks (``windows.groups``; seek
    ``j`` held out in fold ``j mod folds``).  Not 2-fold: each half then trains on half the
    seeks, whose dwell positions leave gaps of several knots that the full fit does not have,
    and the score rewards the penalty that bridges such gaps smoothly (third differences) --
    which rounds off the kinks of a flex-cable table the full data do resolve (measured on a
    table with kinks at 20000 and 40000 track: 2-fold chose third differences, 0.40 mA off at
    the kink; 5- and 10-fold both chose L1/L0 second differences).

    Columns are scaled to unit norm and ``lam`` is relative to a typical table entry's data
    weight, so the grid ``lams`` means the same on any log.  Returns ``(theta, effective
    parameters of the table, penalty name, lam)``."""
    K = X.shape[1] - n_free
    s = np.linalg.norm(X, axis=0); s[s == 0] = 1.0
    Xs = X / s
    G, b = Xs.T @ Xs, Xs.T @ y
    ridge = 1e-12 * np.trace(G) * np.eye(len(G))
    lens = [bb - aa for aa, bb in windows.bounds]
    ids = {g: j for j, g in enumerate(dict.fromkeys(windows.groups))}
    nf = max(2, min(int(folds), len(ids)))
    fold = np.repeat([ids[g] % nf for g in windows.groups], lens)
    parts = []
    for j in range(nf):
        h = fold == j
        parts.append((G - Xs[h].T @ Xs[h], b - Xs[h].T @ y[h], Xs[h], y[h]))

    def penalty_matrix(D, w):
        R = np.zeros_like(G)
        R[n_free:, n_free:] = D.T @ (w[:, None] * D)
        return R

    def unit_penalty(D):
        """``(R, c)``: the unweighted penalty matrix of ``D`` and its scale (a typical entry's penalty ~ its
        data weight); one per ``D``, shared by every fold and ``lam``."""
        R = penalty_matrix(D, np.ones(len(D)))
        return R, 1.0 / max(float(np.median(np.diag(R)[n_free:])), 1e-300)

    def fit(Gi, bi, D, Rc, lam, kind):
        R, c = Rc
        A = Gi + lam * c * R + ridge
        phi = np.linalg.solve(A, bi)
        if kind in ("L1", "L0"):
            r0 = np.abs(D @ phi[n_free:])
            scale = float(np.median(r0)) or 1.0       # |d| / (|d| + eps) ~ L1 with weights in the L2 units
            eps = 1e-3 * max(float(r0.max()), 1e-300)
            for _ in range(irls):
                d = np.abs(D @ phi[n_free:])
                w = scale / (d + eps) if kind == "L1" else scale ** 2 / (d ** 2 + eps ** 2)
                A = Gi + lam * c * penalty_matrix(D, w) + ridge
                phi = np.linalg.solve(A, bi)
        return phi, A

    best = None
    for kind, k in penalties:
        D = np.diff(np.eye(K), k, axis=0) / s[n_free:]
        Rc = unit_penalty(D)
        for lam in lams:
            cv = sum(float(np.sum((yo - Xo @ fit(Gi, bi, D, Rc, lam, kind)[0]) ** 2)) for Gi, bi, Xo, yo in parts)
            if best is None or cv < best[0]:
                best = (cv, kind, k, lam, D, Rc)
    _, kind, k, lam, D, Rc = best
    phi, A = fit(G, b, D, Rc, lam, kind)
    edf = float(np.trace(np.linalg.solve(A, G)[n_free:, n_free:]))
    return phi / s, edf, f"{kind} difference-{k}", float(lam)
