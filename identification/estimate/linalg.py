"""The shared linear algebra of the estimators: one least-squares solver, one covariance family,
one per-seek initial-condition projector.

* :func:`lstsq` -- column-scaled, rank-revealing (SVD, singular values below ``rcond`` times the
  largest are dropped) least squares, optionally with bounds (:func:`scipy.optimize.lsq_linear`).
  Every LS solve in :mod:`identification` goes through it.
* :func:`white_cov`, :func:`sandwich_cov`, :func:`cluster_cov`, :func:`floored_cov`, :func:`wald` --
  covariance of LS estimates: Gauss-Newton ``s^2 (J^T J)^-1`` for white residuals, the Newey-West
  and cluster sandwiches for correlated ones, a sandwich whose variances are floored at the
  Gauss-Newton ones, and the Wald statistic of a coefficient block.
* :class:`SegmentProjector` -- removes each seek's initial position and velocity (a per-segment
  polynomial in time) by orthogonal projection: the one place where per-seek ``p0 + v0 t`` is
  taken out of the data and the regressors (variable projection of linear nuisance parameters).

All routines scale the columns to unit norm before factorising, so parameters of very different
units (``k0`` in track/(A s^2) next to a bias in A) do not lose digits to one another.
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.optimize import lsq_linear

__all__ = ["lstsq", "white_cov", "sandwich_cov", "cluster_cov", "floored_cov", "wald", "SegmentProjector"]


def _column_scale(A: np.ndarray) -> np.ndarray:
    s = np.linalg.norm(A, axis=0)
    s[s == 0] = 1.0
    return s


def lstsq(A, b, *, rcond: float | None = None, bounds=None) -> np.ndarray:
    """Least-squares coefficients ``x`` minimising ``||A x - b||`` (real or complex).

    The columns of ``A`` are scaled to unit norm, the scaled problem is solved by SVD
    (:func:`numpy.linalg.lstsq`: singular values below ``rcond`` times the largest count as zero,
    so a rank-deficient ``A`` gives the minimum-norm solution) and the scale is undone.

    Parameters
    ----------
    A : array_like, shape (m, n)
        Regressors (any units; each column's unit is the inverse of its coefficient's).
    b : array_like, shape (m,) or (m, k)
        Data; several right-hand sides are solved at once.
    rcond : float, optional
        Relative singular-value cut-off of the scaled problem [-]; None: machine precision times
        ``max(m, n)`` (numpy's default).
    bounds : (array_like, array_like), optional
        Lower and upper bounds on ``x`` (real problems, 1-D ``b`` only).

    Returns
    -------
    ndarray, shape (n,) or (n, k)
    """
    A = np.asarray(A)
    b = np.asarray(b)
    if A.shape[1] == 0:
        return np.zeros((0,) + b.shape[1:], dtype=np.result_type(A, b))
    s = _column_scale(A)
    if bounds is None:
        x = np.linalg.lstsq(A / s, b, rcond=rcond)[0]
    else:
        lo, hi = (np.broadcast_to(np.asarray(v, dtype=float), s.shape) * s for v in bounds)
        x = lsq_linear(A / s, b, bounds=(lo, hi)).x
    return x / s if x.ndim == 1 else x / s[:, None]


def _scaled_inverse(J: np.ndarray):
    """``(s, B)`` with ``s`` the column norms of ``J`` and ``B = pinv(Js^T Js)``, ``Js = J / s``."""
    s = _column_scale(J)
    Js = J / s
    return s, Js, np.linalg.pinv(Js.T @ Js)


def white_cov(J, r=None, *, dof: int | None = None, sigma2: float | None = None) -> np.ndarray:
    """Covariance ``s^2 (J^T J)^-1`` of LS estimates with white residuals (pseudo-inverse on the
    column-scaled normal matrix).

    Parameters
    ----------
    J : array_like, shape (m, n)
        Regressors, or the Jacobian of the residual (Gauss-Newton).
    r : array_like, shape (m,), optional
        Residual; ``s^2 = r.r / dof``.
    dof : int, optional
        Degrees of freedom of ``s^2`` (default ``m - n``, at least 1).
    sigma2 : float, optional
        The residual variance when it is known (then ``r`` is not needed).
    """
    J = np.asarray(J, dtype=float)
    s, _, B = _scaled_inverse(J)
    if sigma2 is None:
        r = np.asarray(r, dtype=float)
        sigma2 = float(r @ r) / max(len(r) - J.shape[1] if dof is None else dof, 1)
    return B * sigma2 / np.outer(s, s)


def _cluster_meat(G: np.ndarray, labels: np.ndarray):
    """``sum_c G_c G_c^T`` with ``G_c`` the sum of the rows of ``G`` in cluster ``c``; and the number of clusters."""
    _, idx = np.unique(labels, return_inverse=True)
    Gs = np.zeros((int(idx.max()) + 1 if len(idx) else 0, G.shape[1]))
    np.add.at(Gs, idx, G)
    return Gs.T @ Gs, len(Gs)


def cluster_cov(J, r, labels) -> np.ndarray:
    """Cluster-robust covariance of LS estimates: any correlation within a cluster, none across.

    ``B M B * c/(c-1) * m/(m-n)``, ``B = (J^T J)^-1``, ``M = sum_c G_c G_c^T``, ``G_c = sum_{i in c}
    r_i J_i`` over the ``c`` clusters (``labels[i]`` the cluster of row ``i``, e.g. its seek); needs
    many more clusters than parameters.
    """
    return _sandwich(np.asarray(J, dtype=float), np.asarray(r, dtype=float), labels=np.asarray(labels))[0]


def sandwich_cov(J, r, bounds, lags: int = 32, kind: str = "newey-west"):
    """Covariance of LS estimates with serially correlated residuals: ``B M B``, ``B = (J^T J)^-1``.

    ``J`` (rows x params) and ``r`` are stacked segments with row ``bounds`` (``bounds[i]:bounds[i+1]``
    is segment ``i``).  ``kind="newey-west"``: ``M = sum_{|l| <= lags} (1 - |l|/(lags+1)) sum_i g_i
    g_{i+l}^T`` over pairs within a segment (``g_i = r_i J_i``, Bartlett weights); ``kind="cluster"``:
    :func:`cluster_cov` with one cluster per segment.  Both are scaled by ``m / (m - n)``.

    Returns
    -------
    (cov, cov_white)
        The sandwich and the plain Gauss-Newton covariance ``s^2 (J^T J)^-1``
        (:func:`white_cov`), for the inflation ratio.
    """
    J, r = np.asarray(J, dtype=float), np.asarray(r, dtype=float)
    bounds = np.asarray(bounds, dtype=int)
    if kind == "cluster":
        return _sandwich(J, r, labels=np.repeat(np.arange(len(bounds) - 1), np.diff(bounds)))
    if kind != "newey-west":
        raise ValueError(f"covariance kind must be 'newey-west' or 'cluster', got {kind!r}")
    return _sandwich(J, r, bounds=bounds, lags=lags)


def _sandwich(J, r, labels=None, bounds=None, lags: int = 0):
    s, Js, B = _scaled_inverse(J)
    dof = max(len(r) - J.shape[1], 1)
    cov_white = B * float(r @ r) / dof
    G = Js * r[:, None]
    if labels is not None:
        M, k = _cluster_meat(G, labels)
        cov = B @ M @ B * (k / max(k - 1, 1)) * len(r) / dof
        return cov / np.outer(s, s), cov_white / np.outer(s, s)
    M = G.T @ G
    inner = bounds[1:-1]
    for lag in range(1, lags + 1):
        w = 1.0 - lag / (lags + 1.0)
        C = G[:-lag].T @ G[lag:]
        # remove the pairs (i, i + lag) that straddle a segment boundary
        idx = (inner[:, None] - np.arange(1, lag + 1)[None, :]).ravel()
        idx = np.unique(idx[(idx >= 0) & (idx + lag < len(r))])
        if len(idx):
            C -= G[idx].T @ G[idx + lag]
        M += w * (C + C.T)
    cov = B @ M @ B * len(r) / dof
    return cov / np.outer(s, s), cov_white / np.outer(s, s)


def floored_cov(cov, floor) -> np.ndarray:
    """``cov`` with every variance at least ``floor``'s, its correlations kept: ``S cov S`` with
    ``S = diag(max(1, sqrt(floor_ii / cov_ii)))`` (a congruence: positive semi-definite when ``cov`` is).

    Use: a sandwich built from the estimate's own residuals is biased low when few independent
    blocks carry a parameter's information (the residuals are orthogonal to the Jacobian, so the
    scores summed over all rows vanish: the more lags or the larger the clusters, the more of the
    score's variance the estimate loses); the Gauss-Newton covariance of the whitened problem is the
    floor where the noise model has whitened the residual.  Measured on the 36 kHz drive
    (``studies/std_calibration.py``, 20 seeds, the same fits): RMS of the gains' normalised errors
    1.11 with the Gauss-Newton covariance, 1.24 / 1.27 / 1.32 with Newey-West at 32 / 96 / 256 lags,
    1.43 with one cluster per seek."""
    cov = np.asarray(cov, dtype=float)
    d, f = np.diag(cov), np.diag(np.asarray(floor, dtype=float))
    s = np.sqrt(np.maximum(1.0, np.where(d > 0, f / np.where(d > 0, d, 1.0), 1.0)))
    return cov * np.outer(s, s)


def wald(theta, cov) -> float:
    """Wald statistic ``theta^T cov^-1 theta`` (chi^2 with ``len(theta)`` degrees of freedom under
    ``theta = 0``); a singular ``cov`` is handled by :func:`lstsq`."""
    theta = np.asarray(theta, dtype=float)
    return float(theta @ lstsq(np.asarray(cov, dtype=float), theta))


# ------------------------------------------------------------------------------ per-seek projector
class SegmentProjector:
    """Orthogonal projection that removes a per-segment polynomial ``p0 + v0 t (+ ...)``.

    The rows are the concatenation of the index ranges ``segments`` (half-open, into the log);
    ``t`` is the local sample index from each segment's *start* (``offsets`` shifts it when only
    part of a segment is used, so that ``t`` still counts from the seek start).  Projecting the
    data and every regressor removes the per-segment initial position and velocity exactly
    (variable projection of linear nuisance parameters).  :meth:`polynomial` evaluates the fitted
    per-segment polynomial at other local times (e.g. over the whole seek when it was fitted on
    its settle window).

    Parameters
    ----------
    segments : sequence of (int, int)
    offsets : sequence of int, optional
        Local time [samples] of each range's first row (default 0).
    degree : int
        Polynomial degree of the nuisance (1: initial position and velocity).
    """

    def __init__(self, segments, offsets=None, degree: int = 1):
        pairs = [(int(a), int(b), o) for (a, b), o in
                 zip(segments, [0] * len(segments) if offsets is None else list(offsets)) if b > a]
        if not pairs:
            raise ValueError("SegmentProjector: no non-empty segment")
        segs = [(a, b) for a, b, _ in pairs]
        self.offsets = np.array([o for _, _, o in pairs], dtype=float)
        self.segments = segs
        self.lengths = np.array([b - a for a, b in segs])
        self.rows = np.concatenate([np.arange(a, b) for a, b in segs])
        self.seg_id = np.repeat(np.arange(len(segs)), self.lengths)
        self.bounds = np.r_[0, np.cumsum(self.lengths)][:len(segs) + 1]
        t = np.concatenate([np.arange(n, dtype=float) + o for n, o in zip(self.lengths, self.offsets)])
        # orthonormal per-segment polynomial basis: Gram-Schmidt on 1, t, t^2 .. within each segment;
        # T[s] holds the monomial coefficients of each basis function (for :meth:`polynomial`)
        self.degree = int(degree)
        w, nseg = self.degree + 1, len(segs)
        self._tscale = np.maximum(self.lengths, 1).astype(float)
        tt = t / self._tscale[self.seg_id]
        Q, T = [], []
        starts = self.bounds[:-1]
        for d in range(w):
            v, cv = tt ** d, np.zeros((nseg, w))
            cv[:, d] = 1.0
            for _ in range(2):                       # twice is enough (re-orthogonalisation)
                for q, cq in zip(Q, T):
                    dot = np.add.reduceat(q * v, starts)
                    v = v - q * dot[self.seg_id]
                    cv = cv - cq * dot[:, None]
            nrm = np.sqrt(np.add.reduceat(v * v, starts))
            ok = nrm > 1e-9 * np.sqrt(self.lengths)  # segments too short for this degree get 0
            inv = np.where(ok, 1.0 / np.where(ok, nrm, 1.0), 0.0)
            Q.append(v * inv[self.seg_id])
            T.append(cv * inv[:, None])
        self.Q = np.column_stack(Q)
        self._T = np.stack(T, axis=2)                # (segment, monomial, basis function)
        self.t = t
        # the projection as sparse products: coefficients S x (one row per segment and basis
        # function), fit S^T (S x)
        n = len(self.rows)
        self._S = sparse.csr_matrix((self.Q.T.ravel(), (np.repeat(np.arange(w), n) * nseg + np.tile(self.seg_id, w),
                                                        np.tile(np.arange(n), w))), shape=(w * nseg, n))
        self._ST = self._S.T.tocsr()

    @property
    def n_rows(self) -> int:
        return len(self.rows)

    @property
    def n_nuisance(self) -> int:
        return int(sum(min(self.degree + 1, n) for n in self.lengths))

    def take(self, x) -> np.ndarray:
        """Rows of a log-length array (or the rows of each column of a 2-D array)."""
        return np.asarray(x)[self.rows]

    def fitted(self, x) -> np.ndarray:
        """The per-segment polynomial LS fit of rows ``x`` (1-D, or 2-D with one column per signal)."""
        x = np.asarray(x, dtype=float)
        return self._ST @ (self._S @ x)

    def project(self, x) -> np.ndarray:
        """``x`` minus its per-segment polynomial fit (``x`` already restricted to the rows)."""
        return np.asarray(x, dtype=float) - self.fitted(x)

    def polynomial(self, x, t_local) -> list:
        """Each segment's LS polynomial fit of rows ``x`` (1-D) evaluated at local times
        ``t_local[j]`` [samples from the seek start, as ``offsets``]: a list of arrays."""
        coef = (self._S @ np.asarray(x, dtype=float)).reshape(self.degree + 1, len(self.segments))
        out = []
        for j, tl in enumerate(t_local):
            V = np.vander(np.asarray(tl, dtype=float) / self._tscale[j], self.degree + 1, increasing=True)
            out.append(V @ (self._T[j] @ coef[:, j]))
        return out
