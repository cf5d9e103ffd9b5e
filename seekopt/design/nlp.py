"""Effect-aware seek design: a CasADi NLP over the full closed loop, solved by Ipopt.

When the plant carries nonlinear effects (torque constant ``Kt(x)``, position bias, friction,
saturation; :mod:`identification.model.effects`), the closed loop is no longer a convolution and
the linear designer (:mod:`seekopt.design.ocp`) designs for the wrong drive.  Here the loop is
stepped symbolically, exactly as the simulator steps it numerically::

    y(k)    = measure(x(k))                              plant (effects, delay line) at the servo rate
    e(k)    = r(k) - y(k)
    i(k, l) = u_ff(k) + u_hold + C_l x_c(k) + D_l e(k)   l = 0..L-1 sub-step currents (lifted controller)
    x       <- transition(x, hist, i(k, l))              L times: the multirate sub-step hold
    x_c(k+1) = A x_c(k) + B e(k)

``transition``/``measure`` are the plant's one stepping engine
(:class:`identification.model.discrete.DiscretePlant`) on CasADi symbols (``casadi_ops``, smoothed
kinks); ``A, B, C, D`` are :meth:`seekopt.drive.controller.Controller.lifted_ss` (the runtime's own
matrices).  ``u_hold`` holds the head at the start track (:func:`seekopt.design.feasibility.hold_current`).

The NLP for one seek length ``N`` (multiple shooting at the servo rate, states scaled to O(1))::

    min   w_t t^2 + rho |D v|^2 + rho_q |D q|^2 + w_e mean_{k >= N} e_k^2
    s.t.  state continuity z(k+1) = F(z(k), v_k, q_k)               (scaled: x = o + s z)
          -t <= (y(k) - T0 - K) / band <= t        k >= N            (settle-band epigraph)
          |i(k, l)| <= gamma Imax                  every sub-step    (total current)
          |G (i - u_hold)| <= hf_tol band                            (unmodelled-mode guard, as ocp)
          v_k = u_ff(k) / Imax in [-1, 1], q_k = (r(k) - K) / |K|,  both 0 for k >= N (rest at K)

A length is feasible when ``t* <= beta`` (band margin).  The minimum seek-settle time is a search
on ``N`` from the linear design's length (warm start: the linear QP design, rolled out through
the same sample function), then every candidate is played on the full plant by
:func:`seekopt.drive.simulator.simulate_2dof` and the length stepped up until one settles.
One NLP (``nlpsol`` with parameters ``K, T0, Imax, u_hold``, the scaling and the tail weights;
``N`` enters through the bounds) is built per size class and plant structure and called many
times; Ipopt gets the exact Hessian CasADi derives.  Ipopt failures, time-outs and designs that
fail the simulator check raise :class:`NLPDesignError`; nothing is returned as a profile.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from identification.model.ops import casadi_ops
from identification.model.plant import ModalPlant

import seekopt.design.qp as _qp
from seekopt.design.feasibility import (hold_check, hold_current, nonlinear_effects, play_seek,
                                        resolve_start)
from seekopt.design.metrics import SeekMetrics
from seekopt.design.ocp import SIZE_CLASSES, DesignResult, SeekDesigner
from seekopt.design.profiles import Profile

__all__ = ["NLPSettings", "NLPDesignError", "DesignUnholdable", "NLPSolve", "NLPDesignResult",
           "closed_loop_sample", "close_sample", "SeekNLP", "EffectAwareDesigner", "needs_nlp", "BUILD_COUNT"]

#: NLP constructions so far (reuse is visible here, as ``seekopt.design.qp.BUILD_COUNT`` for QPs).
BUILD_COUNT = {"nlp": 0}


class NLPDesignError(RuntimeError):
    """Ipopt failed, ran out of time, or no design passed the full-plant check (never a profile)."""


class DesignUnholdable(ValueError):
    """The drive's feedback cannot hold the band at the target whatever the feedforward."""


def needs_nlp(plant: ModalPlant) -> bool:
    """True when the plant has input or force effects (the linear design would ignore them)."""
    return bool(nonlinear_effects(plant))


@dataclass
class NLPSettings:
    """Settings of the effect-aware design (times in s, fractions of band / Imax).

    ``tail_s``: time after the seek carrying band rows in the NLP (the simulator check runs
    ``check_tail_s``); ``band_margin``/``current_margin``: ``beta``/``gamma`` as in
    :class:`seekopt.design.ocp.SeekDesigner`; ``hf_*``: its unmodelled-mode guard; ``rho``,
    ``rho_q``, ``w_e``, ``w_t``: cost weights (smoothness of ``u_ff`` and ``r``, tail energy,
    worst residual); ``nlp_wall_s``: Ipopt wall-time limit per solve; ``design_wall_s``: for the
    whole search; ``smoothing``: ``identification.model.ops.SmoothingSettings`` for the kinks
    (None: the engine's default)."""

    tail_s: float = 0.004
    band_margin: float = 0.8
    current_margin: float = 0.97
    hf_guard: tuple | None = (0.45, 0.65)
    hf_gain: float = 1.0
    hf_tol: float = 0.1
    hf_extra: int = 16
    rho: float = 1e-2
    rho_q: float = 1e-3
    w_e: float = 1.0
    w_t: float = 10.0
    max_iter: int = 300
    tol: float = 1e-7
    nlp_wall_s: float = 120.0
    design_wall_s: float = 1200.0
    check_tail_s: float = 0.015
    max_samples: int = 512
    robust_slots: int = 4
    max_swaps: int = 2
    expand: bool = True
    smoothing: object = None
    ipopt: dict = field(default_factory=dict)
    nlpsol: dict = field(default_factory=dict)


@dataclass
class NLPSolve:
    """One Ipopt call: seek length, status, iterations, wall time [s], worst residual [band]."""

    n_seek: int
    status: str
    success: bool
    iterations: int
    wall_s: float
    residual: float

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class NLPDesignResult:
    """A verified effect-aware design, played on the full plant from ``start_track``.

    ``linear``: the QP design that warm-started it; ``linear_metrics``: that design played on the
    same full plant from the same start (what ignoring the effects costs)."""

    profile: Profile
    metrics: SeekMetrics
    start_track: float
    settle_samples: int
    solves: list
    linear: DesignResult
    linear_metrics: SeekMetrics
    build_time_s: float = 0.0

    @property
    def ipopt_iterations(self) -> int:
        return sum(s.iterations for s in self.solves)

    @property
    def ipopt_time_s(self) -> float:
        return sum(s.wall_s for s in self.solves)


# ------------------------------------------------------------------------------- the loop
def closed_loop_sample(plant: ModalPlant, controller, ops=None) -> tuple:
    """One servo sample of the 2DOF loop on the full plant as a CasADi ``Function``.

    ``F(x, hist, xc, u, r, t, i) -> (x+, hist+, xc+, y, i_loop)``: plant state and delay line
    (:class:`DiscretePlant` at the sub-step ``1 / (L fs)``), controller state (lifted), the
    feedforward current incl. hold ``u`` [A] and the reference ``r`` [track] of the sample, its
    time ``t`` [s]; ``y`` the measured position at the start of the sample and ``i_loop`` the ``L``
    sub-step currents the loop commands, ``u + C_l x_c + D_l (r - y)``.  The plant is stepped with
    the currents ``i`` given as an input: the loop is closed by ``i = i_loop`` (an equality of the
    NLP, or :func:`close_sample` for simulation), so the effects' curvature couples only the head's
    position and velocity with the current (a sparse exact Hessian).
    Returns ``(F, (nx, nh, nc), dp)``.
    """
    ops = casadi_ops() if ops is None else ops
    fs, L = float(controller.sample_rate_hz), int(controller.fast_multiple)
    dt = 1.0 / (fs * L)
    dp = plant.discretize(dt)
    A, B, C, D = (np.asarray(a, dtype=float) for a in controller.lifted_ss())
    nc = A.shape[0]
    nx, nh = dp.n, dp.m + 1
    x0, h0, xc = ca.SX.sym("x", nx), ca.SX.sym("hist", nh), ca.SX.sym("xc", nc)
    u, r, t, i = ca.SX.sym("u"), ca.SX.sym("r"), ca.SX.sym("t"), ca.SX.sym("i", L)
    y = dp.measure(x0, t, ops)
    e = r - y
    i_loop = u + ca.mtimes(ca.DM(C), xc) + ca.DM(D) * e
    xcn = ca.mtimes(ca.DM(A), xc) + ca.DM(B) * e
    x, h = x0, h0
    for j in range(L):
        x, h = dp.transition(x, h, i[j], t + j * dt, ops)
    F = ca.Function("servo_sample", [x0, h0, xc, u, r, t, i], [x, h, xcn, y, i_loop],
                    ["x", "hist", "xc", "u", "r", "t", "i"], ["x_next", "hist_next", "xc_next", "y", "i_loop"])
    return F, (nx, nh, nc), dp


def close_sample(F) -> ca.Function:
    """``F`` with the loop closed (``i = i_loop``): ``(x, hist, xc, u, r, t) -> (x+, hist+, xc+, y, i)``."""
    x, h, xc = (ca.SX.sym(n, F.size1_in(k)) for k, n in enumerate(("x", "hist", "xc")))
    u, r, t = ca.SX.sym("u"), ca.SX.sym("r"), ca.SX.sym("t")
    i = F(x, h, xc, u, r, t, ca.SX.zeros(F.size1_in(6)))[4]
    return ca.Function("closed_sample", [x, h, xc, u, r, t], list(F(x, h, xc, u, r, t, i)[:4]) + [i])


class SeekNLP:
    """The effect-aware seek NLP for seeks of at most ``nmax`` samples (one size class).

    Built once (``nlpsol``, Ipopt, exact Hessian); :meth:`solve` is called per ``(K, T0, N)``.
    Decision vector ``[v (nmax), q (nmax), t, i (L H), z (nz x H)]``, ``H = nmax + tail``: scaled
    feedforward and reference, the residual epigraph, the sub-step currents [Imax] and the scaled
    loop states.  Parameters ``[K, |K|, T0, Imax, u_hold, o (nz), s (nz), w (H + 1)]``: initial
    state ``o``, state scale ``s`` (``x = o + s z``), tail-energy weights ``w``.

    ``robust_plants`` (linear plants, nominal first): the robust set of the linear designer.  Each
    other plant ``j`` adds band and current rows ``e + dT_j [u_ff; r]``: the nominal full-plant
    response plus the difference of the two linear loops' responses
    (:class:`seekopt.design.qp.LoopMaps`), i.e. the set's parametric spread to first order around
    the effect-aware trajectory.
    """

    def __init__(self, plant: ModalPlant, controller, nmax: int, tail: int, band: float,
                 settings: NLPSettings, robust_slots: int = 0, nmax_prev: int = 0):
        t_build = time.perf_counter()
        self.settings, self.band = settings, float(band)
        self.fs, self.L = float(controller.sample_rate_hz), int(controller.fast_multiple)
        ops = casadi_ops() if settings.smoothing is None else casadi_ops(smooth=settings.smoothing)
        F, (nx, nh, nc), self.dp = closed_loop_sample(plant, controller, ops)
        self.F, self.dims = F, (nx, nh, nc)
        nz = nx + nh + nc
        N, H, L = int(nmax), int(nmax) + int(tail), self.L
        self.N, self.H, self.nz = N, H, nz
        # one scaled servo sample: z -> z+ with x = o + s z (o: rest state at the start, s: scale)
        zs, os_, ss = ca.SX.sym("z", nz), ca.SX.sym("o", nz), ca.SX.sym("s", nz)
        us, rs, ts = ca.SX.sym("u"), ca.SX.sym("r"), ca.SX.sym("t")
        xs = os_ + ss * zs
        isub = ca.SX.sym("i", L)
        xn, hn, xcn, ys, is_ = F(xs[:nx], xs[nx:nx + nh], xs[nx + nh:], us, rs, ts, isub)
        S = ca.Function("scaled_sample", [zs, us, rs, ts, isub, os_, ss],
                        [(ca.vertcat(xn, hn, xcn) - os_) / ss, ys, is_])
        Meas = ca.Function("measure", [zs, ts, os_, ss], [self.dp.measure(xs[:nx], ts, ops)])
        Kp, aK, T0, imax, uh = (ca.MX.sym(n) for n in ("K", "absK", "T0", "imax", "uhold"))
        o, s, w = ca.MX.sym("o", nz), ca.MX.sym("s", nz), ca.MX.sym("w", H + 1)
        V, Q, tt = ca.MX.sym("v", N), ca.MX.sym("q", N), ca.MX.sym("t")
        Iv, Z = ca.MX.sym("i", L * H), ca.MX.sym("z", nz, H)
        Zprev = ca.horzcat(ca.MX.zeros(nz, 1), Z[:, :H - 1])
        U = ca.horzcat(imax * V.T + uh, ca.repmat(uh, 1, H - N))
        R = ca.horzcat(T0 + Kp + aK * Q.T, ca.repmat(T0 + Kp, 1, H - N))
        Zn, Y, Icur = S.map(H)(Zprev, U, R, ca.DM(np.arange(H) / self.fs).T,
                               imax * ca.reshape(Iv, L, H), o, s)
        yH = Meas(Z[:, H - 1], H / self.fs, o, s)
        Ev = ca.MX.sym("e", H + 1)                                  # PES [band], samples 0..H
        E = Ev
        rows, self.blocks = [], {}

        def add(name, expr, sample=None):
            self.blocks[name] = (sum(r.numel() for r in rows), expr.numel(),
                                 None if sample is None else np.asarray(sample, int))
            rows.append(expr)

        ks = np.arange(H + 1)
        add("dyn", ca.vec(Zn - Z))
        add("pes", Ev - (ca.vertcat(Y.T, yH) - T0 - Kp) / band)
        add("pes_hi", E - tt, ks)
        add("pes_lo", E + tt, ks)
        add("cur", Iv - ca.vec(Icur) / imax)                       # (k, l) sample-major
        if settings.hf_guard:
            lo, hi = settings.hf_guard
            nsub = min(H, N + settings.hf_extra) * L              # the seek's sub-steps and a few more
            G, _ = _qp.hf_guard_matrix(plant.k0, self.fs, L, nsub, lo * self.fs, hi * self.fs,
                                       settings.hf_gain, spacing_hz=max(self.fs / (2 * N), 50.0))
            add("hf", ca.mtimes(ca.DM(G), imax * Iv[:nsub] - uh) / band)
        self.n_slots, self.rob_params = int(robust_slots), []
        if self.n_slots:
            for name, expr, smp in self._robust_rows(self.n_slots, nmax_prev, E, V, Q, Iv, Kp, aK, imax):
                add(name, expr - tt if name == "rob_hi" else expr + tt if name == "rob_lo" else expr, smp)
        dV = ca.diff(ca.vertcat(0, V, 0))
        dQ = ca.diff(ca.vertcat(0, Q, 0))
        f = (settings.w_t * tt ** 2 + settings.rho * ca.sumsqr(dV) + settings.rho_q * ca.sumsqr(dQ)
             + ca.dot(w, E ** 2))
        x = ca.vertcat(V, Q, tt, Iv, Ev, ca.vec(Z))
        p = ca.vertcat(Kp, aK, T0, imax, uh, o, s, w, *[ca.vec(a) for a in self.rob_params])
        g = ca.vertcat(*rows)
        self.nx_dec, self.ng = x.numel(), g.numel()
        ipopt = {"print_level": 0, "sb": "yes", "max_iter": settings.max_iter, "tol": settings.tol,
                 "acceptable_tol": 1e-5, "acceptable_iter": 10, "mu_strategy": "adaptive",
                 "max_wall_time": float(settings.nlp_wall_s), "hessian_approximation": "exact",
                 "mumps_pivot_order": 2}
        ipopt.update(settings.ipopt)
        self.solver = ca.nlpsol("seek_nlp", "ipopt", {"x": x, "f": f, "g": g, "p": p},
                                {"ipopt": ipopt, "print_time": False, "error_on_fail": False,
                                 "expand": bool(settings.expand), **settings.nlpsol})
        # numeric roll-out of the same sample function (warm start and state scaling)
        xs, us = ca.SX.sym("xs", nz), ca.SX.sym("us", 3)
        out = close_sample(F)(xs[:nx], xs[nx:nx + nh], xs[nx + nh:], us[0], us[1], us[2])
        step = ca.Function("step", [xs, us], [ca.vertcat(*out[:3]), out[4]])
        self._rollout = step.mapaccum("rollout", H)
        BUILD_COUNT["nlp"] += 1
        self.build_time_s = time.perf_counter() - t_build

    def _robust_rows(self, nslots, nmax_prev, E, V, Q, Iv, Kp, aK, imax):
        """Band and current rows of ``nslots`` other plants of the robust set, first order around the
        nominal full-plant trajectory: ``e_j = e + (dT_yu^j u_ff + dT_yr^j r) / band`` with the
        differences of the linear loops' responses as parameters (the plants are chosen per call,
        :meth:`robust_data`).  Band rows on samples that can follow a seek of this class
        (``k > nmax_prev``): every sample up to ``nmax + 16``, every 2nd to ``nmax + 48``, every 4th
        after (the slow closed-loop tail; the simulator re-checks every sample); current rows on
        every sub-step of ``k < nmax + 8``."""
        N, H, L, band = self.N, self.H, self.L, self.band
        kb = np.concatenate([np.arange(nmax_prev + 1, min(N + 16, H + 1)),
                             np.arange(N + 16, min(N + 48, H + 1), 2), np.arange(N + 48, H + 1, 4)])
        self.rob_kb = kb = np.unique(kb[kb <= H]).astype(int)
        self.rob_kc = kc = np.arange(min(H, N + 8))
        nb, ni = len(kb) * nslots, len(kc) * L
        DY, dy = ca.MX.sym("dY", nb, 2 * N), ca.MX.sym("dy", nb)
        DI, di = ca.MX.sym("dI", ni * nslots, 2 * N), ca.MX.sym("di", ni * nslots)
        wy = ca.vertcat(imax * V, aK * Q)
        Er = ca.repmat(E[kb.tolist()], nslots, 1) + (ca.mtimes(DY, wy) + Kp * dy) / band
        Ir = ca.repmat(Iv[:ni], nslots, 1) + (ca.mtimes(DI, wy) + Kp * di) / imax
        self.rob_params = [DY, dy, DI, di]
        return [("rob_hi", Er, np.tile(kb, nslots)), ("rob_lo", Er, np.tile(kb, nslots)), ("rob_cur", Ir, None)]

    def _pes(self, X, K, T0) -> np.ndarray:
        """PES [band] of the rolled-out states ``X`` (numeric measure of the plant's engine)."""
        nx = self.dims[0]
        y = [float(self.dp.measure(X[:nx, k], k / self.fs)) for k in range(X.shape[1])]
        return (np.asarray(y) - T0 - K) / self.band

    def set_residuals(self, maps: list, x0, v, q, K, T0, imax, uh, nseek) -> np.ndarray:
        """Worst ``|PES|`` [band] after sample ``nseek`` on every plant of the robust set (``maps``,
        nominal first) to first order: the nominal loop rolled out plus each plant's linear spread."""
        N, H = self.N, self.H
        X, _ = self.rollout(x0, v, q, K, T0, imax, uh)
        e = self._pes(X, K, T0)
        ks = np.arange(nseek, H + 1)
        w = np.r_[imax * np.asarray(v[:N]), abs(K) * np.asarray(q[:N])]
        Yu0, Yr0, y0 = maps[0].position_rows(ks, N)
        out = [np.max(np.abs(e[ks]))]
        for m in maps[1:]:
            Yu, Yr, yj = m.position_rows(ks, N)
            out.append(np.max(np.abs(e[ks] + (np.hstack([Yu - Yu0, Yr - Yr0]) @ w + K * (yj - y0)) / self.band)))
        return np.array(out)

    def robust_data(self, maps: list, slots: list) -> np.ndarray:
        """Parameter values for the robust rows: ``maps`` the :class:`~seekopt.design.qp.LoopMaps`
        of the robust set (nominal first, horizon > H), ``slots`` the indices of the plants to use."""
        N, kb, kc = self.N, self.rob_kb, self.rob_kc
        (Y0u, Y0r, y0), (I0u, I0r, i0) = maps[0].position_rows(kb, N), maps[0].current_rows(len(kc), N)
        DY, dy, DI, di = [], [], [], []
        for j in slots:
            (Yu, Yr, y), (Iu, Ir, i) = maps[j].position_rows(kb, N), maps[j].current_rows(len(kc), N)
            DY.append(np.hstack([Yu - Y0u, Yr - Y0r])); dy.append(y - y0)
            DI.append(np.hstack([Iu - I0u, Ir - I0r])); di.append(i - i0)
        return np.concatenate([np.vstack(DY).T.ravel(), np.concatenate(dy), np.vstack(DI).T.ravel(),
                               np.concatenate(di)])

    # ------------------------------------------------------------------ per call
    def rollout(self, x0, v, q, K, T0, imax, uh):
        """States ``(nz, H + 1)`` and sub-step currents ``(L, H)`` [A] of the loop (the same sample
        function) for scaled inputs ``v, q``."""
        N, H = self.N, self.H
        u = np.full(H, uh); u[:N] += imax * np.asarray(v)[:N]
        r = np.full(H, T0 + K); r[:N] += abs(K) * np.asarray(q)[:N]
        X, Icur = self._rollout(x0, np.vstack([u, r, np.arange(H) / self.fs]))
        return np.column_stack([x0, np.asarray(X)]), np.asarray(Icur)

    def solve(self, K: float, T0: float, nseek: int, imax: float, uh: float, x0: np.ndarray,
              v0: np.ndarray, q0: np.ndarray, beta: float, gamma: float, robust=None):
        """Solve for a seek of ``K`` tracks from ``T0`` in ``nseek`` samples, warm-started from
        ``v0, q0`` (scaled feedforward and reference, length ``nmax``) rolled out through the loop.
        Returns ``(NLPSolve, v, q)``; ``NLPSolve.residual`` is the worst ``|PES|`` after the seek in
        bands (over the robust set when it has one)."""
        N, H, st = self.N, self.H, self.settings
        if not 0 < nseek <= N:
            raise ValueError(f"seek length {nseek} outside 1..{N}")
        live = (np.arange(N) < nseek).astype(float)
        v0 = np.where(live > 0, np.clip(v0[:N], -1, 1), 0.0)
        q0 = np.where(live > 0, np.clip(q0[:N], -2, 2), 0.0)
        X, Icur = self.rollout(x0, v0, q0, K, T0, imax, uh)
        dev = np.abs(X - x0[:, None])
        s = np.maximum(dev.max(axis=1), 1e-9 * max(dev.max(), 1e-12))
        s[0] = max(s[0], abs(K))
        w = np.zeros(H + 1); w[nseek:] = st.w_e / (H + 1 - nseek)
        if self.n_slots and robust is None:
            raise ValueError("this NLP has robust rows: give robust=robust_data(...)")
        p = np.r_[K, abs(K), T0, imax, uh, x0, s, w, [] if robust is None else robust]
        e0 = self._pes(X, K, T0)
        t0 = float(np.max(np.abs(e0[nseek:])))
        xw = np.r_[v0, q0, t0, Icur.T.ravel() / imax, e0, ((X[:, 1:] - x0[:, None]) / s[:, None]).T.ravel()]
        ni = H * self.L
        nfree = self.nx_dec - 2 * N - 1 - ni
        lbx = np.r_[-1.0 * live, -2.0 * live, 0.0, np.full(ni, -gamma), np.full(nfree, -np.inf)]
        ubx = np.r_[1.0 * live, 2.0 * live, np.inf, np.full(ni, gamma), np.full(nfree, np.inf)]
        lbg = np.full(self.ng, -np.inf); ubg = np.full(self.ng, np.inf)
        for name, (off, n, smp) in self.blocks.items():
            sl = slice(off, off + n)
            if name in ("dyn", "cur", "pes"):
                lbg[sl] = ubg[sl] = 0.0
            elif name in ("pes_hi", "rob_hi"):
                ubg[sl] = np.where(smp >= nseek, 0.0, np.inf)           # e - t <= 0 after the seek
            elif name in ("pes_lo", "rob_lo"):
                lbg[sl] = np.where(smp >= nseek, 0.0, -np.inf)          # e + t >= 0 after the seek
            elif name == "rob_cur":
                lbg[sl], ubg[sl] = -gamma, gamma
            elif name == "hf":
                lbg[sl], ubg[sl] = -st.hf_tol, st.hf_tol
        t_start = time.perf_counter()
        sol = self.solver(x0=xw, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        wall = time.perf_counter() - t_start
        stats = self.solver.stats()
        xo = np.asarray(sol["x"], dtype=float).ravel()
        status = str(stats.get("return_status", "?"))
        ok = (bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level") \
            and bool(np.all(np.isfinite(xo)))
        rec = NLPSolve(int(nseek), status, ok, int(stats.get("iter_count", 0)), wall,
                       float(xo[2 * N]) if ok else math.inf)
        return rec, xo[:N], xo[N:2 * N]


# ------------------------------------------------------------------------------- designer
class EffectAwareDesigner:
    """Minimum seek-settle design on a plant with effects; build once, design many seeks.

    Parameters
    ----------
    plant : ModalPlant
        Design plant with its effects (e.g. the loop's augmented plant).  Output effects
        (run-out) are left out of the NLP (the seek's phase to the spindle is unknown) and kept in
        every check.
    controller : Controller
    imax, settle : float
        Current limit [A] (total current, every sub-step) and settle band [track].
    robust : RobustSpec, optional
        Robust set of the linear warm-start design (QP).
    settings : NLPSettings, optional
    """

    def __init__(self, plant: ModalPlant, controller, imax: float, settle: float = 0.1, robust=None,
                 settings: NLPSettings | None = None):
        self.plant, self.controller = plant, controller
        self.imax, self.settle = float(imax), float(settle)
        self.settings = settings or NLPSettings()
        self.fs, self.L = float(controller.sample_rate_hz), int(controller.fast_multiple)
        self.nlp_plant = plant.copy(effects=[e for e in plant.effects if e.kind != "output"])
        self.robust = robust
        self.linear = SeekDesigner(plant.linear_part(), controller, imax, settle, robust,
                                   band_margin=self.settings.band_margin,
                                   current_margin=self.settings.current_margin)
        self.tail = max(int(round(self.settings.tail_s * self.fs)), 16)
        self._nlps: dict = {}
        self._loop_maps = None

    def _nlp(self, n: int) -> SeekNLP:
        c = next((c for c in SIZE_CLASSES if c >= n), None)
        if c is None or c > self.settings.max_samples:
            raise NLPDesignError(f"seek of {n} samples is longer than the largest NLP "
                                 f"({self.settings.max_samples} samples)")
        if c not in self._nlps:
            prev = max([k for k in SIZE_CLASSES if k < c], default=0)
            self._nlps[c] = SeekNLP(self.nlp_plant, self.controller, c, self.tail, self.settle, self.settings,
                                    robust_slots=self._slots, nmax_prev=prev)
        return self._nlps[c]

    @property
    def _slots(self) -> int:
        return min(self.settings.robust_slots, len(self.linear.plants) - 1)

    def _maps(self, horizon: int) -> list:
        """Linear loop maps of the robust set (nominal first), horizon at least ``horizon``."""
        if self._loop_maps is None or self._loop_maps[0].horizon < horizon:
            h = max(horizon, 2 * (self._loop_maps[0].horizon if self._loop_maps else 0))
            self._loop_maps = [_qp.LoopMaps(p, self.controller, h) for p in self.linear.plants]
        return self._loop_maps

    def _worst_plants(self, u, r, K, n) -> list:
        """Indices of the robust set's plants (not the nominal) with the largest residual after sample
        ``n`` for the linear-loop response to ``(u_ff, r)`` (relative reference), worst first."""
        maps = self._maps(n + self.tail + 2)
        H = maps[0].horizon
        uu = np.zeros(H); uu[:len(u)] = u[:H]
        rr = np.full(H, K); rr[:len(r)] = r[:H]
        res = [np.max(np.abs(np.convolve(m.y_u, uu)[n:H] + np.convolve(m.y_r, rr)[n:H] - K)) for m in maps]
        return [int(j) for j in np.argsort(res[1:])[::-1] + 1]

    def design(self, tracks: float, start_track: float | None = None, progress=None) -> NLPDesignResult:
        """Design the seek of ``tracks`` (signed) from ``start_track`` (default: middle of the fitted range).

        Raises :class:`~seekopt.design.feasibility.StartError` (start/end outside the fitted range),
        :class:`DesignUnholdable` (the loop cannot hold the band at the target), and
        :class:`NLPDesignError` (Ipopt failed / timed out / no design passed the full-plant check).
        """
        say = progress or (lambda msg: None)
        K = float(tracks)
        if not math.isfinite(K) or K == 0:
            raise ValueError(f"tracks must be a non-zero number, not {tracks!r}")
        T0 = resolve_start(self.plant, K, start_track)
        hc = hold_check(self.plant, self.controller, T0 + K, self.settle)
        if not hc.holds:
            raise DesignUnholdable(hc.message())
        t_begin = time.perf_counter()
        say(f"linear warm start (QP) for {K:g} tracks")
        lin = self.linear.design(K)
        lin_m, _ = play_seek(self.plant, self.controller, lin.profile, T0, settle=self.settle,
                             horizon_s=self.settings.check_tail_s)
        uh = hold_current(self.nlp_plant, T0, 1.0 / (self.fs * self.L))
        dp = self.nlp_plant.discretize(1.0 / (self.fs * self.L))
        dp.reset(T0, 0.0, current=uh)
        nc = self.controller.n_states
        x0 = np.r_[dp.x, dp.hist, np.zeros(nc)]
        n_lin = int(lin.settle_samples)
        u_lin, r_lin = lin.profile.current_a[:n_lin], lin.profile.reference_track[:n_lin]
        st = self.settings
        solves: list = []
        cache: dict = {}
        slots = self._worst_plants(u_lin, r_lin, K, n_lin) if self._slots else []

        def feasible(n):
            if n in cache:
                return cache[n][0]
            if time.perf_counter() - t_begin > st.design_wall_s:
                raise NLPDesignError(f"design of {K:g} tracks from track {T0:g} ran out of time "
                                     f"({st.design_wall_s:g} s, {len(solves)} NLPs)")
            nlp = self._nlp(n)
            ok_prev = [m for m, (ok, *_ ) in cache.items() if ok]
            if ok_prev:       # warm start: the nearest feasible design, else the linear one
                m = min(ok_prev, key=lambda m: abs(m - n))
                v0, q0 = _stretch(cache[m][1], m, n), _stretch(cache[m][2], m, n)
            else:
                v0, q0 = _stretch(u_lin / self.imax, n_lin, n), _stretch((r_lin - K) / abs(K), n_lin, n)
            v0 = np.r_[v0, np.zeros(nlp.N - n)]; q0 = np.r_[q0, np.zeros(nlp.N - n)]
            maps = self._maps(nlp.H + 2) if nlp.n_slots else None
            for _ in range(st.max_swaps + 1):
                rob = nlp.robust_data(maps, slots[:nlp.n_slots]) if nlp.n_slots else None
                rec, v, q = nlp.solve(K, T0, n, self.imax, uh, x0, v0, q0, st.band_margin, st.current_margin, rob)
                solves.append(rec)
                if not rec.success and rec.status in ("Maximum_WallTime_Exceeded", "Maximum_CpuTime_Exceeded"):
                    raise NLPDesignError(f"Ipopt timed out ({st.nlp_wall_s:g} s) for {K:g} tracks in {n} samples")
                swapped = ""
                if rec.success and nlp.n_slots:       # the whole set, first order: swap in a violator
                    res = nlp.set_residuals(maps, x0, v, q, K, T0, self.imax, uh, n)
                    rec.residual = max(rec.residual, float(res.max()))
                    out = [j for j in np.argsort(res)[::-1] if j and j not in slots[:nlp.n_slots]]
                    if out and res[out[0]] > st.band_margin and rec.residual > st.band_margin:
                        weakest = min(slots[:nlp.n_slots], key=lambda j: res[j])
                        iw, io = slots.index(weakest), slots.index(out[0])
                        slots[iw], slots[io] = out[0], weakest
                        swapped = f"; set plant {out[0]} at {res[out[0]]:.3g} band swapped in"
                say(f"  NLP N={n}: {rec.status}, {rec.iterations} it, {rec.wall_s:.2f} s, "
                    f"residual {rec.residual:.3g} band{swapped}")
                if not swapped:
                    break
                v0, q0 = v, q
            good = rec.success and rec.residual <= st.band_margin * (1 + 1e-6)
            cache[n] = (good, v[:n], q[:n])
            return good

        # exponential search from the linear design's length, then bisection
        hi = lo = None
        n = n_lin
        step = max(1, n_lin // 16)
        if feasible(n):
            hi = n
            while lo is None:
                m = max(hi - step, 1)
                if m == hi or not feasible(m):
                    lo = m if m < hi else hi - 1
                else:
                    hi, step = m, 2 * step
        else:
            lo = n
            while hi is None:
                m = lo + step
                if m > st.max_samples:
                    raise NLPDesignError(f"no effect-aware design of {K:g} tracks from track {T0:g} "
                                         f"within {st.max_samples} samples ({solves[-1].status})")
                if feasible(m):
                    hi = m
                else:
                    lo, step = m, 2 * step
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if feasible(mid):
                hi = mid
            else:
                lo = mid
        # verify on the full plant; step up on failure
        for n in range(hi, min(hi + 12, st.max_samples) + 1):
            if not feasible(n):
                continue
            _, v, q = cache[n]
            prof = self._profile(v, q, K, T0, n, lin, solves)
            m, _ = play_seek(self.plant, self.controller, prof, T0, settle=self.settle,
                             horizon_s=st.check_tail_s)
            if m.peak_current_a <= self.imax * (1 + 1e-9) and m.settle_time_s * self.fs <= n + 1 + 1e-9:
                prof.meta.update(design_status="verified", ipopt_iterations=sum(s.iterations for s in solves),
                                 ipopt_time_s=round(sum(s.wall_s for s in solves), 3), n_nlp=len(solves))
                return NLPDesignResult(prof, m, T0, n, solves, lin, lin_m,
                                       sum(p.build_time_s for p in self._nlps.values()))
            say(f"  N={n}: full-plant check failed (settle {m.settle_time_s * 1e3:.3f} ms, "
                f"peak {m.peak_current_a:.4g} A)")
        raise NLPDesignError(f"no effect-aware design of {K:g} tracks from track {T0:g} passed the full-plant "
                             f"check up to {min(hi + 12, st.max_samples)} samples")

    def _profile(self, v, q, K, T0, n, lin: DesignResult, solves) -> Profile:
        u = self.imax * np.asarray(v[:n], float)
        r = K + abs(K) * np.asarray(q[:n], float)
        meta = {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
                "design_objective": "min_settle/nlp", "solver": "ipopt", "reference": "free",
                "start_track": T0, "direction": "outward" if K > 0 else "inward",
                "effects_in_design": ";".join(e.name for e in self.nlp_plant.effects) or "none",
                "robust_warm_start": self.linear.robust.to_string() if self.linear.robust else "none",
                "band_margin": self.settings.band_margin, "current_margin": self.settings.current_margin,
                "design_settle_samples": n, "linear_settle_samples": lin.settle_samples}
        out = [e.name for e in self.plant.effects if e.kind == "output"]
        if out:
            meta["effects_not_in_design"] = ";".join(out)
        return Profile(np.r_[u, 0.0], np.r_[r, K], self.fs, K, self.imax, self.settle, "optimal-nlp", n, meta)


def _stretch(a: np.ndarray, m: int, n: int) -> np.ndarray:
    """Resample a length-``m`` sequence to length ``n`` (time-stretched warm start)."""
    a = np.asarray(a, float)[:m]
    if m == n:
        return a.copy()
    return np.interp((np.arange(n) + 0.5) * m / n - 0.5, np.arange(m), a)
