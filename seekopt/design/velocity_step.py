"""The velocity step of a long seek (:mod:`seekopt.design.longseek`) and its QP.

A velocity step of ``d`` tracks per sample is a feedforward ``u_A`` over ``N`` samples and a reference ``r_A``
that leave the 2DOF loop on its ramp equilibrium: from ``N`` on the reference is the rigid body's affine
asymptote ``c (k - tau/Ts - j - 1/2)`` summed over the step (``c = k0 Ts^2``, ``tau`` the input delay), the head
moves at ``d`` with zero current, the modes at rest, zero error.  :class:`StepQP` is the condensed QP on the
closed-loop maps of a plant set (:class:`seekopt.design.qp.LoopMaps`, from the one simulator), built once
for steps of at most ``nmax`` samples and solved per ``N`` through the problem's solver chain
(:class:`seekopt.design.solvers.SolverChain`); :class:`VelocityStep` is the designed step and how two of them
make a seek.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

__all__ = ["VelocityStep", "StepQP"]


@dataclass
class VelocityStep:
    """A designed velocity step (module notes): from rest to ``track_per_sample`` on the ramp equilibrium.

    Attributes
    ----------
    current_a : ndarray
        ``u_A`` [A], ``N`` samples (zero afterwards).
    reference_track : ndarray
        ``r_A`` [track] for ``k <= N``; afterwards the ramp ``r_A[-1] + d (k - N)``.
    track_per_sample : float
        ``d`` [track/sample] (velocity ``d fs`` track/s).
    settle_samples : int
        Samples from the start of a step until ``|e_A| <= band`` for good (nominal linear loop): the
        arrival of a seek settles this long after its decelerating step starts.
    min_coast_samples : int
        Smallest step spacing ``m`` from which every seek ``m' >= m`` settles by ``m' + settle_samples``
        within Imax (nominal linear loop; every design is still simulated).
    """

    current_a: np.ndarray
    reference_track: np.ndarray
    track_per_sample: float
    sample_rate_hz: float
    imax_a: float
    settle_track: float
    settle_samples: int
    min_coast_samples: int
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.current_a)

    @property
    def velocity_track_s(self) -> float:
        return self.track_per_sample * self.sample_rate_hz

    @property
    def min_tracks(self) -> float:
        """Shortest seek that coasts with this step (``m >= min_coast_samples``)."""
        return (self.min_coast_samples - 1) * self.track_per_sample + 1e-9

    def extended(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(u_A, r_A)`` over ``n`` samples with the zero feedforward and the ramp continuation."""
        u = np.zeros(n); u[:min(n, self.n)] = self.current_a[:n]
        nr = len(self.reference_track)
        r = self.reference_track[-1] + self.track_per_sample * (np.arange(n) - (nr - 1))
        r[:min(n, nr)] = self.reference_track[:n]
        return u, r

    def coast_samples(self, tracks: float) -> int:
        """Step spacing ``m = ceil(|K| / d)``."""
        return int(math.ceil(abs(tracks) / self.track_per_sample - 1e-12))

    def compose(self, tracks: float) -> tuple[np.ndarray, np.ndarray, int, float]:
        """``(u, r, m, s)`` of the seek of ``tracks`` (module notes); ``r`` ends at ``tracks`` exactly."""
        m = self.coast_samples(tracks)
        s = abs(tracks) / (m * self.track_per_sample)
        n = m + max(self.n, len(self.reference_track))
        u, r = self.extended(n)
        u2, r2 = np.zeros(n), np.zeros(n)
        u2[m:], r2[m:] = u[:n - m], r[:n - m]
        sign = math.copysign(1.0, tracks)
        uu, rr = sign * s * (u - u2), sign * s * (r - r2)
        rr[-1] = float(tracks)       # s (r_A(k) - r_A(k-m)) = s m d = K on the ramp; exact end
        return uu, rr, m, s

    def to_dict(self) -> dict:
        return {"current_a": [float(x) for x in self.current_a],
                "reference_track": [float(x) for x in self.reference_track],
                "track_per_sample": self.track_per_sample, "sample_rate_hz": self.sample_rate_hz,
                "imax_a": self.imax_a, "settle_track": self.settle_track, "settle_samples": self.settle_samples,
                "min_coast_samples": self.min_coast_samples, "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> "VelocityStep":
        return cls(np.asarray(d["current_a"], float), np.asarray(d["reference_track"], float),
                   float(d["track_per_sample"]), float(d["sample_rate_hz"]), float(d["imax_a"]),
                   float(d["settle_track"]), int(d["settle_samples"]), int(d["min_coast_samples"]),
                   dict(d.get("meta") or {}))


class StepQP:
    """Condensed QP of a velocity step for steps of at most ``nmax`` samples (built once, solved per ``N``).

    ``x = [v, w]``: ``u = Imax v`` (``N`` samples), ``r = Ramp u + sigma w`` (``w`` on ``k < N``, 0 after).
    """

    def __init__(self, maps, nmax, horizon, k0, fs, delay_samples, imax, band, bias, hf, nlo,
                 settings, rho=1e-2, rho_w=1e-3, quiet=0.2, quiet_after=32):
        from seekopt.design.profiles import rigid_position_kernel
        from seekopt.design.loop_maps import toeplitz_rows
        from seekopt.design.qp_samples import pes_row_samples
        from seekopt.design.solvers import SolverChain
        t0 = time.perf_counter()
        N, H, L = int(nmax), int(horizon), maps[0].L
        self.N, self.H, self.imax, self.band, self.bias = N, H, float(imax), float(band), abs(float(bias))
        self.quiet, self.quiet_after = float(quiet), int(quiet_after)
        self.c = k0 / fs ** 2                      # track per (A sample^2)
        # reference base: the ZOH rigid response (with the delay), on its affine asymptote
        # c (k - tau - j - 1/2) from ``ceil(tau)`` samples after the step ends
        self.ramp = toeplitz_rows(rigid_position_kernel(H, delay_samples, self.c), np.arange(H), N)
        self.k_extra = int(math.ceil(delay_samples - 1e-12))
        self.sigma = 1.0                                   # scale of the reference correction w [track]
        self.wmax = self.c * imax * N * N                  # |w| bound: loose (the objective keeps w small)
        E = np.eye(H, N)
        ks_set = pes_row_samples(N, H)
        ks_set = ks_set[ks_set >= nlo]
        blocks, kinds = [], []
        for i, mp in enumerate(maps):               # settle band: e_i(k) = y_i(k) - r(k), k >= N
            # the nominal plant's quiet tail bounds what one step adds to the other's arrival: every sample
            ks = np.arange(nlo, H) if i == 0 else ks_set
            Tyu = toeplitz_rows(mp.y_u, ks, N)
            Tyr = toeplitz_rows(mp.y_r, ks, H)
            a = np.hstack([imax * (Tyu + Tyr @ self.ramp - self.ramp[ks]), self.sigma * (Tyr @ E - E[ks])]) / band
            blocks.append(a); kinds += [("pes", i, int(k)) for k in ks]
        ncur = min(H, N + 40)
        for i, mp in enumerate(maps):               # total current, every sub-step
            rows = np.arange(ncur if i == 0 else min(H, N + 8))
            Tiu, Tir = toeplitz_rows(mp.i_u, rows, N), toeplitz_rows(mp.i_r, rows, H)
            blocks.append(np.hstack([Tiu + Tir @ self.ramp, Tir[:, :N] * (self.sigma / imax)]))
            kinds += [("cur", i, int(k)) for k in np.repeat(rows, L)]
        if hf is not None:                          # unmodelled-mode residual, nominal sub-step currents
            G = hf
            Tiu, Tir = toeplitz_rows(maps[0].i_u, np.arange(H), N), toeplitz_rows(maps[0].i_r, np.arange(H), H)
            blocks.append(np.hstack([imax * G @ (Tiu + Tir @ self.ramp), self.sigma * G @ Tir @ E]) / band)
            kinds += [("hf", 0, j) for j in range(G.shape[0])]
        cum = np.tril(np.ones((N, N))) / N          # rigid velocity within [0, d]; and = d at the end
        blocks.append(np.hstack([cum, np.zeros((N, N))])); kinds += [("vel", 0, j) for j in range(N)]
        A = np.vstack(blocks)
        self.A = A
        self.kind = np.array([k[0] for k in kinds]); self.sample = np.array([k[2] for k in kinds])
        self.plant = np.array([k[1] for k in kinds])
        D = np.eye(N) - np.eye(N, k=-1)
        P = np.zeros((2 * N, 2 * N))
        P[:N, :N] = 2 * rho * D.T @ D
        P[N:, N:] = 2 * rho_w * D.T @ D
        tail = np.nonzero((self.kind == "pes") & (self.sample >= N))[0]
        if tail.size:
            P += 2.0 / tail.size * A[tail].T @ A[tail]
        P += 2e-9 * np.eye(2 * N)
        self._H = P                      # numpy data: the chain's zero-copy path (no DM round trip)
        self.m = A.shape[0]
        self.solver = SolverChain(2 * N, self.m, settings.chain, settings.options)
        self.violation_tol = float(settings.violation_tol)
        self.build_time_s = time.perf_counter() - t0

    def solve(self, d: float, nseek: int, beta: float, gamma: float, hf_tol: float | None, x0=None):
        N, m = self.N, self.m
        lba, uba = np.full(m, -np.inf), np.full(m, np.inf)
        pes = (self.kind == "pes") & (self.sample >= nseek)
        lba[pes], uba[pes] = -beta, beta
        far = pes & (self.sample >= nseek + self.quiet_after) & (self.plant == 0)   # the accelerating
        # step's tail adds to the arrival's error: quiet it on the nominal plant (short coasts)
        lba[far], uba[far] = -self.quiet * beta, self.quiet * beta
        cur = self.kind == "cur"
        lim = (gamma * self.imax - self.bias) / self.imax
        lba[cur], uba[cur] = -lim, lim
        hf = self.kind == "hf"
        if hf_tol is not None:
            lba[hf], uba[hf] = -hf_tol, hf_tol
        vel = self.kind == "vel"
        V = d / (self.c * self.imax * N)
        # within [0, d]: the seek's arrival runs at s (d - v_A), so a velocity below 0 (a back-swing at the
        # start) would carry the seek above the limit
        lba[vel], uba[vel] = 0.0, V * (1 + 1e-9)
        last = vel & (self.sample == nseek - 1)      # one equality row (the rows after it repeat it)
        lba[last] = uba[last] = V
        uba[vel & (self.sample >= nseek)] = np.inf
        lbx, ubx = np.zeros(2 * N), np.zeros(2 * N)
        lbx[:nseek], ubx[:nseek] = -1.0, 1.0
        lbx[N:N + nseek], ubx[N:N + nseek] = -self.wmax, self.wmax
        from seekopt.design.solvers import constraint_violation

        def check(x):                              # never trust a status alone
            if not np.all(np.isfinite(x)):
                return "non-finite answer"
            viol = constraint_violation(self.A, x, lba, uba, lbx, ubx)
            return f"constraint violation {viol:.2g}" if viol > self.violation_tol else ""
        # numerical trouble moves on to the fallback solvers before anything is called infeasible
        return self.solver.solve(self._H, np.zeros(2 * N), self.A, lba, uba, lbx, ubx, x0=x0, check=check)

    def unpack(self, x, nseek):
        """``(u [A], w [track])`` over ``nseek`` samples; ``r = reference(u, w)``."""
        return self.imax * x[:nseek], self.sigma * x[self.N:self.N + nseek]

    def reference(self, u, w):
        """``r`` [track] up to the first sample on the ramp asymptote (``len(u) + ceil(tau)``)."""
        n = len(u)
        r = self.ramp[:n + 1 + self.k_extra, :n] @ u
        r[:n] += w
        return r
