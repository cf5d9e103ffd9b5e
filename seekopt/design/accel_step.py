"""The acceleration step of a long seek (:mod:`seekopt.design.longseek`) and its QP.

An *acceleration step* is a feedforward ``u_J`` that rises from 0 to a constant current ``I0`` within ``N``
samples and stays there, with a reference ``r_J`` that leaves the 2DOF loop on its constant-acceleration
equilibrium: from ``N`` on ``r_J`` is the rigid response (ZOH, input delay) of ``u_J`` plus a constant
``delta`` (the QP's choice: e.g. the modes' static deflection), and the position error is within the band.
The loop is linear and time-invariant with a type-3 open loop (double integrator and an integrating
controller), so it tracks that parabola with zero steady error on every plant of a set, also with a gain
or delay error; after ``N`` the error only decays.

Four shifted copies make a seek of any length (``s <= 1``; ``n <= m`` the samples at ``+I0`` and the spacing
of the acceleration and the deceleration)::

    u(k) = s (u_J(k) - u_J(k - n) - u_J(k - m) + u_J(k - m - n)),   r(k) likewise

The rigid velocity is ``s c I0 n`` per sample after the acceleration (``c = k0 Ts^2``) and the second
difference of the rigid parabola is exact: the reference ends at ``s c I0 n m = K`` and the rigid body at
rest there (rest-to-rest exactness); the error is the same four-term sum of ``e_J`` (the arrival settles as
the step settles, the three older terms are quiet).  So one QP per designer serves every length and velocity.

:class:`AccelStepQP` is the condensed QP on the set's closed-loop maps (:func:`seekopt.design.predict.set_loop_maps`),
built for at most ``nmax`` samples and solved per ``N`` through the problem's solver chain:

* settle band: ``|e_0(k)| <= beta band`` for ``k >= N`` on the nominal plant, ``<= quiet beta band`` from
  ``N + quiet_after`` on (the older terms of the sum; the seek is verified on the design plant by
  simulation); ``|e_i(k)| <= beta band`` from ``N + set_lag`` on the other plants of the set (a seek's
  error is the four-term sum, whose older terms' slow tails on the set's gain corners already hold the
  set's settle later than the nominal's: :data:`seekopt.design.longseek_steps.ACCEL_SET_LAG`; the plan
  predicts every plant's settle of the sum);
* total current (every sub-step, every plant): within ``[(S_i - lim) / 2, (S_i + lim) / 2]`` with ``S_i =
  I0 k0 / k0_i`` the plant's steady current and ``lim = gamma Imax - |bias|``: a transition, its mirror and
  the doubled one of a seek without coast (``n = m``) then stay within ``lim``;
* feedforward within ``[(I0 - Imax) / 2, (I0 + Imax) / 2]`` (the doubled transition within ``Imax``).

* the unmodelled-mode guard (:func:`seekopt.design.guard.design_guard_rows`) on the one-sample differences
  ``i(k) - i(k-1)`` of the nominal sub-step currents (finite: the current settles at ``S``): a mode at
  ``f`` keeps ``X(f) = dX(f) / (1 - e^{-j w})`` of a transition and a seek four of them, ``|z_seek| <=
  4 |dX| / (2 sin(pi f / fs))``, so the rows are bounded by ``hf_tol 2 min_f sin(pi f / fs) / 4``.  The seek's
  guard residual is measured after the design (:func:`seekopt.design.guard.guard_report`).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from seekopt.design.profiles import rigid_position_kernel

__all__ = ["AccelStep", "AccelStepQP", "rigid_position_kernel"]


@dataclass
class AccelStep:
    """A designed acceleration step (module notes).

    Attributes
    ----------
    current_a : ndarray
        ``u_J`` [A] over ``N`` samples; ``i0_a`` afterwards.
    i0_a : float
        Constant current [A] after the step.
    reference_offset_track : ndarray
        ``r_J - R`` [track] (``R`` the rigid response of ``u_J``) for ``k < N``; ``delta_track`` afterwards.
    delta_track : float
    settle_samples : int
        First sample from which the nominal linear loop's ``|e_J| <= band`` for good.
    error_track : ndarray
        ``e_J`` [track] on the nominal linear loop over a horizon in which it has died out (zero after).
    set_error_track : ndarray
        ``(plants - 1, horizon)``: ``e_J`` on the other plants of the design's set (calibrated maps).
    current_sub_a : ndarray
        Total sub-step currents ``(horizon, L)`` [A] on the nominal linear loop (``i0`` times the steady
        ratio after).
    """

    current_a: np.ndarray
    i0_a: float
    reference_offset_track: np.ndarray
    delta_track: float
    c_track_per_a: float
    delay_samples: float
    sample_rate_hz: float
    settle_samples: int = 0
    error_track: np.ndarray = field(default_factory=lambda: np.zeros(0))
    current_sub_a: np.ndarray = field(default_factory=lambda: np.zeros((0, 1)))
    set_error_track: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.current_a)

    @property
    def accel_track(self) -> float:
        """``c I0`` [track/sample^2]: the rigid acceleration after the step."""
        return self.c_track_per_a * self.i0_a

    def extended(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(u_J, r_J)`` over ``n`` samples (the constant current and the parabola continued)."""
        u = np.full(n, self.i0_a)
        u[:min(n, self.n)] = self.current_a[:n]
        R = np.convolve(u, rigid_position_kernel(n, self.delay_samples, self.c_track_per_a))[:n]
        off = np.full(n, self.delta_track)
        off[:min(n, self.n)] = self.reference_offset_track[:n]
        return u, R + off

    def compose(self, tracks: float, n: int, m: int) -> tuple[np.ndarray, np.ndarray, float]:
        """``(u, r, s)`` of the seek of ``tracks`` with ``n`` samples at ``I0`` and spacing ``m`` (module notes);
        ``r`` ends at ``tracks`` exactly and ``u`` is zero from ``m + n + N`` on."""
        n, m = sorted((int(n), int(m)))
        s = abs(tracks) / (self.accel_track * n * m)
        if not 0 < s <= 1 + 1e-12:
            raise ValueError(f"{tracks:g} tracks do not fit n = {n}, m = {m} (s = {s:g})")
        L = m + n + self.n + int(math.ceil(self.delay_samples)) + 2
        uj, rj = self.extended(L)
        sign = math.copysign(s, tracks)
        u, r = sign * self.four_term(uj, n, m, L), sign * self.four_term(rj, n, m, L)
        u[m + n + self.n:] = 0.0                  # exactly zero (the four constants cancel)
        r[-1] = float(tracks)                     # exact end (s c I0 n m = K on the parabola)
        return u, r, s

    def four_term(self, x: np.ndarray, n: int, m: int, length: int) -> np.ndarray:
        """``x(k) - x(k-n) - x(k-m) + x(k-m-n)`` over ``length`` samples for a response ``x`` of the step
        (``x`` held at its last value beyond its horizon: the error at 0, the current at its steady value)."""
        x = np.asarray(x, float)
        ext = np.concatenate([x, np.repeat(x[-1:], max(length - len(x), 0), axis=0)])[:length]
        y = ext.copy()
        for sh, sg in ((n, -1), (m, -1), (m + n, 1)):
            if sh < length:
                y[sh:] += sg * ext[:length - sh]
        return y


class AccelStepQP:
    """Condensed QP of an acceleration step of at most ``nmax`` samples (built once, solved per ``N``).

    ``x = [v, w, delta]``: ``u = Imax v`` for ``k < N`` and ``I0`` after; ``r = R(u) + w + delta`` (``w`` on
    ``k < N``).  ``set_lag`` [samples]: the set's plants (all but the first map) are held in the band from
    ``N + set_lag`` on (module notes).
    """

    def __init__(self, maps, k0s, nmax, horizon, k0, fs, delay_samples, imax, i0, band, nlo, settings,
                 rho=1e-2, rho_w=1e-3, quiet=0.1, quiet_after=32, hf=None, set_lag=0):
        from seekopt.design.loop_maps import toeplitz_rows
        from seekopt.design.qp_samples import pes_row_samples
        from seekopt.design.solvers import SolverChain
        t0 = time.perf_counter()
        N, H, L = int(nmax), int(horizon), maps[0].L
        self.N, self.H, self.imax, self.i0, self.band = N, H, float(imax), float(i0), float(band)
        self.quiet, self.quiet_after = float(quiet), int(quiet_after)
        self.set_lag = int(set_lag)
        self.c = k0 / fs ** 2
        self.delay = float(delay_samples)
        self.steady = np.array([i0 * k0 / k for k in k0s])        # S_i [A]
        F = toeplitz_rows(rigid_position_kernel(H, delay_samples, self.c), np.arange(H), H)
        Fv, Ff = F[:, :N], F[:, N:].sum(axis=1)
        E, one = np.eye(H, N), np.ones(H)
        ks_set = pes_row_samples(N, H)
        ks_set = ks_set[ks_set >= nlo]
        blocks, offs, kinds = [], [], []
        for i, mp in enumerate(maps):               # settle band: e_i(k) = y_i(k) - r(k)
            ks = np.arange(nlo, H) if i == 0 else ks_set
            Tyu, Tyr = toeplitz_rows(mp.y_u, ks, H), toeplitz_rows(mp.y_r, ks, H)
            a = np.hstack([imax * (Tyu[:, :N] + Tyr @ Fv - Fv[ks]), Tyr @ E - E[ks], (Tyr @ one - 1.0)[:, None]])
            b = i0 * (Tyu[:, N:].sum(axis=1) + Tyr @ Ff - Ff[ks])
            blocks.append(a / band); offs.append(b / band); kinds += [("pes", i, int(k)) for k in ks]
        ncur = min(H, N + 40)
        for i, mp in enumerate(maps):               # total current, every sub-step
            rows = np.arange(ncur)
            Tiu, Tir = toeplitz_rows(mp.i_u, rows, H), toeplitz_rows(mp.i_r, rows, H)
            a = np.hstack([imax * (Tiu[:, :N] + Tir @ Fv), Tir @ E, (Tir @ one)[:, None]])
            b = i0 * (Tiu[:, N:].sum(axis=1) + Tir @ Ff)
            blocks.append(a / imax); offs.append(b / imax); kinds += [("cur", i, int(k)) for k in np.repeat(rows, L)]
        if hf is not None:      # guard rows on the one-sample differences of the nominal sub-step currents
            G = np.asarray(hf, float)
            GD = G.copy()
            GD[:, :-L] -= G[:, L:]
            rows = np.arange(H)
            Tiu, Tir = toeplitz_rows(maps[0].i_u, rows, H), toeplitz_rows(maps[0].i_r, rows, H)
            a = np.hstack([imax * GD @ (Tiu[:, :N] + Tir @ Fv), GD @ Tir @ E, (GD @ (Tir @ one))[:, None]])
            b = i0 * GD @ (Tiu[:, N:].sum(axis=1) + Tir @ Ff)
            blocks.append(a / band); offs.append(b / band); kinds += [("hf", 0, j) for j in range(G.shape[0])]
        A, self.b = np.vstack(blocks), np.concatenate(offs)
        self.A = A
        self.kind = np.array([k[0] for k in kinds]); self.sample = np.array([k[2] for k in kinds])
        self.plant = np.array([k[1] for k in kinds])
        nv = 2 * N + 1
        D = np.eye(N) - np.eye(N, k=-1)
        P = np.zeros((nv, nv))
        P[:N, :N] = 2 * rho * D.T @ D
        P[N:2 * N, N:2 * N] = 2 * rho_w * D.T @ D
        self._tail = np.nonzero((self.kind == "pes") & (self.plant == 0))[0]
        self._P0 = P + 2e-9 * np.eye(nv)      # numpy data: the chain's zero-copy path (no DM round trip)
        self.m = A.shape[0]
        self.solver = SolverChain(nv, self.m, settings.chain, settings.options)
        self.violation_tol = float(settings.violation_tol)
        self.build_time_s = time.perf_counter() - t0

    def solve(self, nseek: int, beta: float, lim_a: float, hf_tol: float | None = None, x0=None):
        """The step of ``nseek`` samples (``lim_a``: the seek's current limit ``gamma Imax - |bias|`` [A];
        ``hf_tol``: bound of the guard rows on the current's one-sample differences, in bands)."""
        from seekopt.design.solvers import constraint_violation
        N, m, b = self.N, self.m, self.b
        lba, uba = np.full(m, -np.inf), np.full(m, np.inf)
        pes = (self.kind == "pes") & (self.sample >= nseek)
        pes &= (self.plant == 0) | (self.sample >= nseek + self.set_lag)
        lba[pes], uba[pes] = -beta, beta
        far = pes & (self.sample >= nseek + self.quiet_after) & (self.plant == 0)
        lba[far], uba[far] = -self.quiet * beta, self.quiet * beta
        cur = self.kind == "cur"
        S = self.steady[self.plant[cur]]
        lba[cur], uba[cur] = 0.5 * (S - lim_a) / self.imax, 0.5 * (S + lim_a) / self.imax
        hf = self.kind == "hf"
        if hf_tol is not None:
            lba[hf], uba[hf] = -hf_tol, hf_tol
        lba, uba = lba - b, uba - b
        tail = self._tail[self.sample[self._tail] >= nseek]
        At = self.A[tail]
        P = self._P0 + 2.0 / max(tail.size, 1) * At.T @ At
        g = 2.0 / max(tail.size, 1) * At.T @ b[tail]
        nv = 2 * N + 1
        lbx, ubx = np.zeros(nv), np.zeros(nv)
        lbx[:N] = ubx[:N] = self.i0 / self.imax
        lbx[:nseek], ubx[:nseek] = 0.5 * (self.i0 / self.imax - 1.0), 0.5 * (self.i0 / self.imax + 1.0)
        wmax = self.c * self.imax * N * N
        lbx[N:N + nseek], ubx[N:N + nseek] = -wmax, wmax
        lbx[-1], ubx[-1] = -wmax, wmax

        def check(x):                              # never trust a status alone
            if not np.all(np.isfinite(x)):
                return "non-finite answer"
            viol = constraint_violation(self.A, x, lba, uba, lbx, ubx)
            return f"constraint violation {viol:.2g}" if viol > self.violation_tol else ""
        return self.solver.solve(P, g, self.A, lba, uba, lbx, ubx, x0=x0, check=check)

    def unpack(self, x, nseek):
        """``(u [A], reference offset [track] over ``nseek`` samples, delta [track])``."""
        N = self.N
        return self.imax * x[:nseek], x[N:N + nseek] + x[-1], float(x[-1])


def plan_seek(step: AccelStep, tracks: float, n_lo: int, n_vmax: float, band: float, spread: int = 3,
              current_limit_a: float = math.inf):
    """``(n, m, predicted nominal settle sample, predicted worst settle sample over the set)`` of the seek of
    ``tracks`` (the rule of :mod:`seekopt.design.longseek`): ``n <= m``, ``n >= n_lo``, ``n <= n_vmax`` (the
    velocity limit), ``s c I0 n m = |K|`` with ``s <= 1``; among ``n`` within ``spread`` of the bang-bang
    ``sqrt(|K| / (c I0))`` (or ``n_vmax`` when that is lower) the one whose four-term error on the linear
    loop settles first on every plant of the set (ties: the earlier nominal settle, then the earlier last
    transition ``m + n``); with ``n`` shorter than the step the transitions overlap and the plan is kept only
    if its nominal total current (:attr:`AccelStep.current_sub_a`, four terms) is within ``current_limit_a``.
    None when no ``n`` qualifies."""
    from seekopt.design.metrics import settle_index
    P = abs(tracks) / step.accel_track
    top = int(math.floor(min(math.sqrt(P), n_vmax) + 1e-9))
    best = None
    for n in range(max(n_lo, top - spread), top + spread + 1):
        if n > n_vmax:
            break
        m = int(math.ceil(P / n - 1e-9))
        if m < n:
            continue
        s = P / (n * m)
        length = m + n + len(step.error_track)
        if n < step.n and np.max(np.abs(s * step.four_term(step.current_sub_a, n, m, length))) > current_limit_a:
            continue
        k = settle_index(s * step.four_term(step.error_track, n, m, length), band)
        ks = [settle_index(s * step.four_term(e, n, m, length), band) for e in step.set_error_track]
        if k is None or None in ks:
            continue
        kw = max([k] + ks)
        key = (kw, k, m + n)
        if best is None or key < best[0]:
            best = (key, n, m, k, kw)
    return None if best is None else best[1:]
