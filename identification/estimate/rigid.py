"""Rigid-body gain, bias and delay from seek segments.

Two estimators:

* :func:`eq8_fit` -- the paper's eq. (8) (Section 3.1)::

      y(i) = sum_{j=0}^{i} sum_{k=0}^{j} ( b0 u(k) - b1 )

  LS for ``(b0, b1)`` through the 2x2 normal equations ``[U] [b0, b1]^T = [...]``, applied to each
  seek from its start to its end with the position relative to the start (the sample before the
  first sample of the seek, where eq. (8) has ``y(-1) = 0``), normal equations pooled over the
  seeks.  ``k0`` follows from ``b0`` (:func:`k0_from_b0`).

* :func:`rigid_fit` -- the fit the robust method starts from: the ZOH double integrator with
  fractional input delay of :mod:`identification.model.plant` (exactly how the plant is stepped),
  per-segment initial position and velocity as linear nuisance parameters, a bias force, and the
  delay estimated by a 1-D search.

Which discretisation (ERRATA item 5)
-----------------------------------
The code uses the double sum for eq. (8) (the paper's method) and the ZOH of plant.py everywhere
else.  They differ: ``sum_{j<=i} sum_{k<=j} u(k) = sum_{k<=i} (i - k + 1) u(k)``, whereas the ZOH
double integrator of plant.py (no delay) gives ``p(i) = k0 Ts^2 sum_{k<i} (i - k - 1/2) u(k)``.
Exactly, ``k0 Ts^2 sum_{j<=i} sum_{k<=j} u(k) = p((i + 3/2) Ts) - k0 Ts^2 u(i+1) / 8``: the double
sum is the ZOH position one and a half samples later (one sample from including ``u(i)`` in
``y(i)``, half a sample from the rectangle rule), with ``b0 = k0 Ts^2`` -- **not** ``k0 Ts^2 / 2``:
for a constant ``u``, ``b0 (i+1)(i+2)/2`` must grow like ``k0 (i Ts)^2 / 2``.  After a rest-to-rest
current the two end at the same position.  ``tests/test_rigid.py`` proves both.  The printed
``b0 = k0 Ts^2 / 2`` (and ERRATA item 5, which endorses it) would double ``k0``; :func:`k0_from_b0`
uses ``k0 = b0 / Ts^2`` and keeps the printed relation behind ``printed=True``.  The 1.5-sample
advance (plus the plant's own input delay) is an unmodelled lag for eq. (8): on ZOH data with the
benchmark's 10 us delay it biased ``k0`` by -0.9 % on short sine seeks (test) and -0.3 % on the
synthetic drive's logs (``docs/results_identification.md``).

The bias force from the whole log (:func:`whole_log_bias`): between two instants where the head is at
rest the rigid body's velocity change is ``k0`` times the integral of the total force, so the bias is
minus the mean current over the log plus a velocity correction -- the continuity of the velocity
from seek to seek, which a per-seek fit with free initial position and velocity throws away.

Two further misprints in Section 3.1 are handled as follows: the cost ``J`` uses
``sum_j sum_k 1 = (i+1)(i+2)/2`` as the regressor of ``b1`` while the printed normal equations use
``sum_{j=0}^{i} j = i(i+1)/2``; and the printed solution vector is the LS coefficient of ``+b1``
although eq. (8) subtracts ``b1``.  :func:`eq8_fit` uses the cost's regressor by default
(``bias_regressor="printed"`` selects the other) and returns ``b1`` with eq. (8)'s sign, so
``bias_a = -b1 / b0``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from identification.estimate.linalg import SegmentProjector, lstsq, white_cov
from identification.model.plant import ModalPlant

__all__ = ["double_sum", "Eq8Fit", "eq8_fit", "k0_from_b0", "zoh_rigid_response", "bias_response", "RigidFit",
           "rigid_fit", "BiasEstimate", "momentum_bias", "whole_log_bias", "SegmentProjector"]


# ------------------------------------------------------------------------------------ eq. (8)
def double_sum(x) -> np.ndarray:
    """``S(i) = sum_{j=0}^{i} sum_{k=0}^{j} x(k)`` (the double summation of eq. (8))."""
    return np.cumsum(np.cumsum(np.asarray(x, dtype=float)))


def k0_from_b0(b0: float, dt: float, printed: bool = False) -> float:
    """Rigid-body gain ``k0`` [track/(A s^2)] from eq. (8)'s ``b0`` [track/A].

    ``k0 = b0 / Ts^2`` for the double sum as written (see the module notes); ``printed=True``
    gives the paper's printed ``k0 = 2 b0 / Ts^2``, which is twice too large.
    """
    return (2.0 if printed else 1.0) * b0 / dt ** 2


@dataclass
class Eq8Fit:
    """Result of :func:`eq8_fit`.

    ``b0`` [track/A] and ``b1`` [track] as in eq. (8); ``k0`` [track/(A s^2)] (``b0 / Ts^2``);
    ``bias_a = -b1 / b0`` [A]; ``U`` the pooled 2x2 normal matrix and ``rhs`` its right-hand side;
    ``residual_rms`` [track]; ``n_seeks`` and ``n_samples`` used; ``cov`` the covariance of
    ``(b0, b1)`` for white residuals (:func:`identification.estimate.linalg.white_cov`).
    """
    b0: float
    b1: float
    k0: float
    bias_a: float
    U: np.ndarray
    rhs: np.ndarray
    residual_rms: float
    n_seeks: int
    n_samples: int
    cov: np.ndarray | None = None


def eq8_fit(current_a, position_track, segments, dt: float, bias_regressor: str = "cost") -> Eq8Fit:
    """The paper's eq. (8) rigid-body fit, pooled over seek segments.

    For each segment ``[i0, i1)`` (seek start to end): ``u(i) = current_a[i0 + i]``,
    ``y(i) = position_track[i0 + i] - position_track[i0 - 1]`` (relative to the last sample before
    the seek, where eq. (8) has ``y(-1) = 0``; ``position_track[0]`` if ``i0 = 0``),
    ``i = 0..M`` with ``M = i1 - i0 - 1``;
    regressors ``phi0(i) = sum_{j<=i} sum_{k<=j} u(k)`` and ``phi1(i) = -sum_{j<=i} sum_{k<=j} 1``
    (``bias_regressor="printed"``: ``-sum_{j<=i} j``).  The normal equations
    ``U [b0, b1]^T = [sum_i y phi0, sum_i y phi1]^T`` with
    ``U11 = sum_i phi0^2``, ``U12 = U21 = sum_i phi0 phi1``, ``U22 = sum_i phi1^2`` are summed over the
    segments and solved.

    Parameters
    ----------
    current_a, position_track : array_like
        Measured current [A] and head position [track] over the whole log.
    segments : sequence of (int, int)
        Half-open seek segments (e.g. ``(s.start, s.end)`` of :func:`identification.logs.seeklog.segment_seeks`).
    dt : float
        Sample period ``Ts`` [s].
    bias_regressor : {"cost", "printed"}
        Regressor of ``b1`` (see the module notes).

    Returns
    -------
    Eq8Fit
    """
    u_all = np.asarray(current_a, dtype=float)
    y_all = np.asarray(position_track, dtype=float)
    U, rhs, n, used = np.zeros((2, 2)), np.zeros(2), 0, 0
    blocks = []
    for i0, i1 in segments:
        if i1 - i0 < 3:
            continue
        u = u_all[i0:i1]
        y = y_all[i0:i1] - y_all[max(i0 - 1, 0)]
        i = np.arange(i1 - i0, dtype=float)
        one = (i + 1) * (i + 2) / 2 if bias_regressor == "cost" else i * (i + 1) / 2
        X = np.column_stack([double_sum(u), -one])
        U += X.T @ X
        rhs += X.T @ y
        blocks.append((X, y))
        n += i1 - i0
        used += 1
    if used == 0:
        raise ValueError("eq8_fit: no segment with at least 3 samples")
    b = lstsq(U, rhs)                       # the pooled normal equations of eq. (8)
    # the residual from the residuals themselves: yy - 2 b.rhs + b.U.b cancels catastrophically
    r = np.concatenate([y - X @ b for X, y in blocks])
    cov = white_cov(np.vstack([X for X, _ in blocks]), r)
    b0, b1 = float(b[0]), float(b[1])
    return Eq8Fit(b0, b1, k0_from_b0(b0, dt), -b1 / b0, U, rhs, float(np.sqrt(float(r @ r) / n)), used, n, cov)


# ------------------------------------------------------------------------------------ ZOH rigid body
def _rigid_block(dt: float, delay_s: float = 0.0):
    """``m, h, Gamma_new, Gamma_old, Gamma_f`` of the unit rigid body in the one discretisation
    (:class:`identification.model.discrete.DiscretePlant` of ``ModalPlant(k0=1, delay_s=delay_s)``):
    whole-sample delay ``m``, ``Phi = [[1, h], [0, 1]]`` (checked) and the input / force columns."""
    dp = ModalPlant(k0=1.0, delay_s=float(delay_s)).discretize(dt)
    Phi = dp.Phi[:2, :2]
    if not (Phi[0, 0] == Phi[1, 1] == 1.0 and Phi[1, 0] == 0.0):
        raise AssertionError("the rigid block of DiscretePlant is not a double integrator")
    return dp.m, float(Phi[0, 1]), dp.G_new[:2], dp.G_old[:2], dp.G_f[:2]


def _restarted_rigid(dp_in, dv_in, h: float, starts) -> np.ndarray:
    """Position of the rigid block ``p[k+1] = p[k] + h v[k] + dp_in[k]``, ``v[k+1] = v[k] + dv_in[k]``
    with ``p = v = 0`` at every index in ``starts`` and zero before the first: two cumulative
    sums, exact for ``Phi = [[1, h], [0, 1]]``."""
    n = len(dv_in)
    starts = np.asarray(sorted(set(int(s) for s in starts)), dtype=int)
    seg = np.zeros(n, dtype=int)
    seg[starts] = 1
    seg = np.cumsum(seg)        # segment number of each sample (0: before the first start)

    def restart_cumsum(x):      # y[k] = sum_{start <= j < k} x[j] within each segment
        c = np.r_[0.0, np.cumsum(x)][:n]
        base = np.r_[0.0, c[starts]]
        return c - base[seg]

    p = restart_cumsum(h * restart_cumsum(dv_in) + dp_in)
    p[seg == 0] = 0.0
    return p


def zoh_rigid_response(current_a, dt: float, delay_s: float, starts) -> np.ndarray:
    """Unit-``k0`` rigid-body position from the measured current, restarted at each start.

    The rigid block of :class:`identification.model.discrete.DiscretePlant` of
    ``ModalPlant(k0=1, delay_s=delay_s)`` (ZOH, fractional input delay: its ``Phi``, ``Gamma_new``,
    ``Gamma_old``), stepped by two cumulative sums -- exact, because that block is a double
    integrator, ``Phi = [[1, dt], [0, 1]]`` (checked)::

        v[k+1] = v[k] + Gn_v u[k-m] + Go_v u[k-m-1]
        p[k+1] = p[k] + dt v[k] + Gn_p u[k-m] + Go_p u[k-m-1]

    with ``p = v = 0`` at every index in ``starts`` (the delay line holds the measured current
    before it; before sample 0 the current is taken as ``current_a[0]``).  Between starts the
    response runs on; samples before the first start are zero.  Per-segment initial position and
    velocity are left to :class:`identification.estimate.linalg.SegmentProjector`.

    ``current_a`` of shape ``(n, L)`` is a multirate current (``L`` held sub-steps per sample,
    :meth:`identification.logs.seeklog.SeekLog.input_current`): the response is computed at ``dt / L`` and
    sampled at the log's instants.

    ``tests/test_rigid.py`` checks it against ``DiscretePlant`` stepping, fractional delays and the
    multirate sub-step hold included.

    Returns
    -------
    ndarray
        Position [track per track/(A s^2)], i.e. multiply by ``k0``.
    """
    u = np.asarray(current_a, dtype=float)
    if u.ndim == 2:
        L = u.shape[1]
        fine = zoh_rigid_response(u.reshape(-1), dt / L, delay_s, [L * int(s) for s in starts])
        return fine[::L]
    dp_in, dv_in, h = _increments(u, dt, delay_s)
    return _restarted_rigid(dp_in, dv_in, h, starts)


def _increments(u, dt: float, delay_s: float):
    """Per-sample position and velocity increments of the unit rigid block driven by the current
    ``u`` (1-D, held over each sample; before sample 0 it is ``u[0]``), and ``h``."""
    n = len(u)
    m, h, gn, go, _ = _rigid_block(dt, delay_s)
    pad = np.r_[np.full(m + 1, u[0]), u]
    un = pad[1:n + 1]          # u[k - m]
    uo = pad[:n]               # u[k - m - 1]
    return gn[0] * un + go[0] * uo, gn[1] * un + go[1] * uo, h


def bias_response(n: int, dt: float, starts) -> np.ndarray:
    """Unit-``k0`` position from a unit constant force (the undelayed force channel ``Gamma_f`` of
    the same rigid block), restarted at each start: ``(t - t_start)^2 / 2`` [s^2]."""
    _, h, _, _, gf = _rigid_block(dt)
    return _restarted_rigid(np.full(n, gf[0]), np.full(n, gf[1]), h, starts)


@dataclass
class RigidFit:
    """Result of :func:`rigid_fit`: ``k0`` [track/(A s^2)], ``bias_a`` [A], ``delay_s`` [s] with
    white-noise standard deviations ``std`` (dict), the fit residual rms [track] and the per-segment
    initial position/velocity coefficients (orthonormal basis of :class:`SegmentProjector`)."""
    k0: float
    bias_a: float
    delay_s: float
    residual_rms: float
    std: dict = field(default_factory=dict)
    delay_grid: np.ndarray | None = None
    delay_cost: np.ndarray | None = None


def _rigid_ls(u, y, dt, delay, proj, starts):
    R = proj.take(zoh_rigid_response(u, dt, delay, starts))
    B = proj.take(bias_response(len(u), dt, starts))
    X = proj.project(np.column_stack([R, B]))
    yp = proj.project(proj.take(y))
    c = lstsq(X, yp)
    r = yp - X @ c
    return c, r, X


def rigid_fit(current_a, position_track, segments, dt: float, delay_range=(0.0, 3.0), ngrid: int = 13) -> RigidFit:
    """ZOH rigid body + bias + fractional delay, per-segment initial position/velocity projected out.

    Model on each segment ``[i0, i1)`` (position in tracks)::

        y(i) = k0 R_delay(i) + (k0 bias_a) (i dt)^2 / 2 + p0_s + v0_s i dt

    with ``R_delay`` from :func:`zoh_rigid_response`.  ``(k0, k0 bias_a)`` by LS for each delay, the
    delay [s] by a grid over ``delay_range`` (in samples) refined by bounded scalar minimisation.

    Returns
    -------
    RigidFit
    """
    u = np.asarray(current_a, dtype=float)
    y = np.asarray(position_track, dtype=float)
    segments = [(a, b) for a, b in segments if b - a >= 4]
    starts = [a for a, _ in segments]
    proj = SegmentProjector(segments)

    def cost(d_samples):
        _, r, _ = _rigid_ls(u, y, dt, d_samples * dt, proj, starts)
        return float(r @ r)

    grid = np.linspace(delay_range[0], delay_range[1], ngrid)
    costs = np.array([cost(g) for g in grid])
    j = int(np.argmin(costs))
    lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, ngrid - 1)]
    d = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6}).x if hi > lo else lo
    c, r, X = _rigid_ls(u, y, dt, d * dt, proj, starts)
    dof = max(proj.n_rows - proj.n_nuisance - 2, 1)
    cov = white_cov(X, r, dof=dof)
    k0 = float(c[0])
    bias = float(c[1] / c[0])
    sb = np.sqrt(cov[1, 1] / k0 ** 2 + bias ** 2 * cov[0, 0] / k0 ** 2)
    return RigidFit(k0, bias, float(d * dt), float(np.sqrt(np.mean(r ** 2))),
                    {"k0": float(np.sqrt(cov[0, 0])), "bias_a": float(sb)}, grid * dt, costs)


@dataclass
class BiasEstimate:
    """Result of :func:`whole_log_bias`: ``bias_a`` [A] and its standard deviation ``std_a`` [A]
    (batch means over the chunks), the number of chunks and the time they span [s]."""
    bias_a: float
    std_a: float
    n_chunks: int
    span_s: float


def momentum_bias(current_a, instants, velocity, k0: float, dt: float, delay_s: float = 0.0) -> BiasEstimate:
    """The bias force from the whole log: the rigid body's momentum balance between instants where
    its velocity is known.

    Between consecutive instants ``k_j < k_{j+1}`` the velocity of the rigid block changes by
    ``k0`` times its response to the current (the same ZOH and delay as :func:`zoh_rigid_response`,
    multirate sub-steps included) plus ``k0 dt`` per sample of bias (the force channel), plus the
    unlogged force noise, so each chunk gives ``b_j = ((v_{j+1} - v_j) / k0 - dV_j) / (dt N_j)``
    (``dV_j`` the unit-``k0`` velocity change due to the current, ``N_j`` the samples).  The
    estimate is their time-weighted mean, in which the velocities telescope: only the first and the
    last velocity's errors remain, divided by ``k0`` times the whole span, and the force noise
    averages over the whole log.  Its standard deviation is the batch-means one of the ``b_j`` (it
    also counts the inner velocities' errors, which telescope away in the estimate itself: slightly
    conservative).

    Parameters
    ----------
    current_a : array_like, shape (n,) or (n, L)
        The current as the plant sees it [A] (:meth:`identification.logs.seeklog.SeekLog.input_current`).
    instants : sequence of int
        Sample indices, increasing (at least 3).
    velocity : sequence of float
        The rigid body's velocity at each instant [track/s].
    k0 : float
        Rigid-body gain [track/(A s^2)].
    dt, delay_s : float
        Sample period and input delay [s].
    """
    k_ = np.asarray(instants, dtype=int)
    v = np.asarray(velocity, dtype=float)
    if len(k_) < 3 or np.any(np.diff(k_) <= 0) or len(v) != len(k_):
        raise ValueError(f"momentum_bias: need at least 3 increasing instants with a velocity each, got {len(k_)}")
    u = np.asarray(current_a, dtype=float)
    L = u.shape[1] if u.ndim == 2 else 1
    _, dv_in, _ = _increments(u.reshape(-1), dt / L, delay_s)
    cs = np.r_[0.0, np.cumsum(dv_in)]
    dV = cs[L * k_[1:]] - cs[L * k_[:-1]]
    gf_v = _rigid_block(dt / L)[4][1] * L            # velocity per sample of a unit force [s]
    n = np.diff(k_).astype(float)
    bj = (np.diff(v) / k0 - dV) / (gf_v * n)
    w = n / n.sum()
    b = float(w @ bj)
    k = len(bj)
    std = float(np.sqrt(np.sum(w ** 2 * (bj - b) ** 2) * k / max(k - 1, 1)))
    return BiasEstimate(b, std, k, float(n.sum() * dt))


def whole_log_bias(current_a, position_track, rest_windows, k0: float, dt: float, delay_s: float = 0.0) -> BiasEstimate:
    """:func:`momentum_bias` with the velocity at the middle of each rest window (e.g. the settle
    windows) taken as the LS slope of the position over it -- model-free, exact for a uniformly
    accelerated head, approximate while it still settles.

    Parameters
    ----------
    position_track : array_like
        Measured head position [track].
    rest_windows : sequence of (int, int)
        Half-open index ranges where the head rests (at least 3 of them, 4 samples each).
    current_a, k0, dt, delay_s
        As :func:`momentum_bias`.
    """
    y = np.asarray(position_track, dtype=float)
    wins = sorted((int(a), int(b)) for a, b in rest_windows if b - a >= 4)
    if len(wins) < 3:
        raise ValueError(f"whole_log_bias: need at least 3 rest windows of 4 samples, got {len(wins)}")
    centres, v = [], []
    for a, b in wins:
        if (b - a) % 2 == 0:                         # an odd count: the middle is a sample
            a += 1
        t = (np.arange(b - a) - (b - a - 1) / 2) * dt
        v.append(np.polyfit(t, y[a:b], 1)[0])
        centres.append((a + b - 1) // 2)
    return momentum_bias(current_a, centres, v, k0, dt, delay_s)
