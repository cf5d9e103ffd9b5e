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
from scipy.optimize import lsq_linear

__all__ = ["lstsq", "cluster_cov", "wald", "effective_n", "bic", "segments"]


def lstsq(r: np.ndarray, Z: np.ndarray, bounds=None):
    """Least squares ``r ~ Z theta`` (columns scaled; optionally bounded): ``(theta, sse)``."""
    if Z.shape[1] == 0:
        return np.zeros(0), float(r @ r)
    s = np.linalg.norm(Z, axis=0); s[s == 0] = 1.0
    if bounds is None:
        th = np.linalg.lstsq(Z / s, r, rcond=1e-9)[0]
    else:
        th = lsq_linear(Z / s, r, bounds=(np.asarray(bounds[0]) * s, np.asarray(bounds[1]) * s)).x
    th = th / s
    e = r - Z @ th
    return th, float(e @ e)


def segments(windows, e: np.ndarray) -> list:
    """Split concatenated window samples into per-window arrays."""
    cuts = np.cumsum([b - a for a, b in windows.bounds])[:-1]
    return np.split(e, cuts)


def cluster_cov(Z: np.ndarray, e: np.ndarray, windows) -> np.ndarray:
    """Covariance of LS coefficients robust to any correlation within a seek (clusters)."""
    Zi = np.linalg.pinv(Z.T @ Z)
    scores = {}
    i = 0
    for (a, b), g in zip(windows.bounds, windows.groups):
        scores[g] = scores.get(g, 0.0) + Z[i:i + b - a].T @ e[i:i + b - a]
        i += b - a
    meat = sum(np.outer(v, v) for v in scores.values())
    m = len(scores)
    return Zi @ meat @ Zi * m / max(m - 1, 1)


def wald(th: np.ndarray, cov: np.ndarray) -> float:
    """``th' cov^-1 th`` (chi^2 with len(th) degrees of freedom)."""
    return float(th @ np.linalg.lstsq(cov, th, rcond=None)[0])


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
