"""The effect-aware seek NLP: the full closed loop on CasADi symbols, built once per size class.

One servo sample of the 2DOF loop (:func:`closed_loop_sample`)::

    y(k)     = measure(x(k))                              plant (effects, delay line) at the servo rate
    e(k)     = r(k) - y(k)
    i(k, l)  = u_ff(k) + u_hold + C_l x_c(k) + D_l e(k)   l = 0..L-1 (lifted controller)
    x       <- transition(x, hist, i(k, l))               L times: the multirate sub-step hold
    x_c(k+1) = A x_c(k) + B e(k)

``transition``/``measure`` are the plant's one stepping engine
(:class:`identification.model.discrete.DiscretePlant`) on CasADi symbols (``casadi_ops``, smoothed
kinks), ``A, B, C, D`` the controller's :meth:`~seekopt.drive.controller.Controller.lifted_ss` (the
matrices its runtime steps with).

The NLP for one seek length ``N`` (:class:`SeekNLP`; multiple shooting at the servo rate, every
variable O(1): states scaled by their warm-start excursion, currents in Imax, PES in bands)::

    min   w_t t^2 + rho |D v|^2 + rho_q |D q|^2 + sum_{k >= N} w_k e_k^2
    s.t.  z(k+1) = F(z(k), v_k, q_k, i(k))                      state continuity (x = o + s z)
          i(k, l) = loop current of sample k                    (the loop closed by an equality)
          e_k = (y(k) - T0 - K) / band
          e_k + hi_k <= t,  e_k + lo_k >= -t          k >= N     settle band, robust envelope
          i_lo <= i(k, l) <= i_hi                                total current, robust envelope
          |G_v [g u_ff + o; r - K] + K g| <= hf_tol band        unmodelled-mode guard (the linear designer's
                                                                  rows on the nominal linear loop, applied to the
                                                                  force the feedforward delivers: g, o the input
                                                                  map linearised along the plan, e.g. g = Kt(x))
          v = u_ff / Imax in [-1, 1], q = (r - K) / |K| in [-2, 2], both 0 for k >= N + input_tail (rest at K; the band from N)

The plant is driven by the current variables ``i``, so the effects' curvature couples only the
head's position, velocity and the current: the exact Hessian is sparse and cheap.  ``N``, the
robust envelopes and the warm start enter as bounds and parameters: the solver is built once.

Robust set (:class:`RobustSpread`): the linear designer's plants differ from the nominal by their
modes; their PES and currents are the nominal full-plant ones plus the difference of the linear
loops' responses (first order around the effect-aware trajectory).  The difference is linear in
``(u_ff, r)``; the designer freezes it at the current design, gives the NLP its envelope over the
set (``hi_k = max_j d_jk``, ``lo_k = min_j d_jk``, nominal 0 included) and iterates until the
design meets the band on every plant of the set.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from identification.model.ops import SmoothingSettings, casadi_ops
from identification.model.plant import ModalPlant

from seekopt.design.nlp_basis import correction_knots, hat_basis
from seekopt.design.nlp_loop import close_sample, closed_loop_sample
from seekopt.design.nlp_spread import RobustSpread

__all__ = ["NLPSettings", "NLPSolve", "nlp_smoothing", "closed_loop_sample", "close_sample", "RobustSpread", "SeekNLP",
           "BUILD_COUNT"]

#: NLP constructions so far (reuse is visible here, as ``seekopt.design.qp.BUILD_COUNT`` for QPs).
BUILD_COUNT = {"nlp": 0}


@dataclass
class NLPSettings:
    """Settings of the effect-aware design (times in s, fractions of band / Imax).

    ``tail_s``: the problem's ``tail_s`` (:class:`seekopt.design.problem.SeekProblem`; None: its
    default) -- the NLP's band rows, the linear warm start's and the full-plant acceptance cover the same
    samples after the seek, :meth:`~seekopt.design.problem.SeekProblem.band_tail_samples` (the simulator
    check runs at least ``check_tail_s``); ``band_margin``/``current_margin``: ``beta``/``gamma`` as in
    :class:`seekopt.design.problem.SeekProblem` (the unmodelled-mode guard is the problem's);
    ``rho``, ``rho_q``, ``w_e``, ``w_t``: cost weights
    (smoothness of ``u_ff`` and ``r``, tail energy, worst residual); ``w_slack``: weight of the elastic
    slacks on the current and guard rows (exact penalty: the NLP is feasible at every length, a length
    is feasible when the current slack ends below ``slack_tol``; the guard's excess is recorded -- the
    NLP's smooth feedforward correction cannot always shape the spectrum as the QP's free samples do); ``nlp_cpu_s``: Ipopt CPU-time
    limit per solve (``max_cpu_time``: CPU, not wall, so that a design does not depend on the machine's load);
    ``design_cpu_s``: the process CPU time for a whole design; ``check_steps``: how many candidates
    the full-plant check tries (the seek lengthened on failure); ``max_nlps``: NLPs of the length search
    once a feasible length is known; ``kappa_band``, ``kappa_current``:
    sharpness of the smooth maximum over the robust set (log-sum-exp, over-estimates the maximum by
    at most ``log(n) / kappa``: 0.02 band and 0.005 Imax for 22 plants); ``per_sample_samples``, ``arrival_samples``, ``knot_spacing``: the corrections' knots
    (:func:`seekopt.design.nlp_basis.correction_knots`: every sample of seeks up to 32 samples; beyond, every
    sample of the last 32 -- the arrival, which sets the residual -- and one knot per 4 samples of the run
    before; a shorter seek's unused columns are fixed at 0).  Measured on the Kt study drive (K = 200,
    loop-fitted plant, nominal): from 50 %, per sample up to 48 samples cost 2-6 s per Ipopt iteration at
    94-96 columns (309 s for the design), 32/24/4 0.5-0.65 s at 60-62 columns (74 s), both 48 samples; from
    20 %, an arrival of 24 samples ended at 64 samples (2.424 ms on the drive), 32 at 50 (1.970 ms, 104 s);
    the former rule (per sample to 48, then 24 uniform hats) gave 11.33 / 6.63 / 2.08 ms from 20 / 50 / 80 %
    with 344 / 356 / 728 s of Ipopt (:mod:`seekopt.design.nlp_basis`); 64 hats on a 71-sample seek with
    friction took 4.9 s per iteration (24: 0.55 s); ``expand``: evaluate the NLP as SX (slower build, ~10x faster
    derivatives); ``smoothing``: :class:`~identification.model.ops.SmoothingSettings` of the kinks in
    the NLP (friction sign over at least 20 track/s, saturation corners 2 mA, bias-table corners 5 tracks;
    the full-plant check is exact: the smoothed corner's error decays only as ``w^2 / distance`` and adds up
    over a fitted table's knots -- on the combination drive's loop-fitted bias (64 knots 838 tracks apart) the
    NLP's model of a K = 200 seek from 50 % was 0.0138 track (0.14 band) off the plant at 50 tracks, enough
    for every candidate the NLP put at the 0.8-band margin to fail the full-plant check at 0.935 band; at 5 tracks
    1.4e-4 track, at 1 track 5.5e-6); ``friction_step``: the friction sign is smoothed at least over the
    velocity one sub-step of Coulomb force gives, divided by this (:func:`nlp_smoothing`); ``ipopt``:
    extra Ipopt options.

    ``kt_uncertainty`` [fraction of the torque constant]: the current headroom of effect-aware designs.  The
    drive's torque constant may differ from the design plant's by this much (the loop reports no
    uncertainty of its fitted ``Kt(x)``; on the study's combination drive the fitted ``Kt`` differed from
    the truth by up to 4 % at the seeks' starts, and a design at 0.97 Imax on the loop's plant drew 0.3010 A
    of 0.3 A on the truth).  The NLP holds its current rows (``current_margin`` Imax, every sub-step) also
    on the design plant's linear loop with its gain scaled by ``1 +- u`` (first order around the full-plant
    trajectory, as the robust set: :class:`RobustSpread` ``current_only``), and the full-plant check plays
    every candidate on the design plant with its gain scaled so (within Imax).  ``u`` is the larger of
    this and 3 standard deviations of the plant's reported ``k0``; 0 turns the headroom off."""

    tail_s: float | None = None
    band_margin: float = 0.8
    current_margin: float = 0.97
    kt_uncertainty: float = 0.05
    rho: float = 1e-2
    w_slack: float = 1e3
    slack_tol: float = 1e-4
    rho_q: float = 1e-3
    w_e: float = 1.0
    w_t: float = 10.0
    max_iter: int = 300
    tol: float = 1e-7
    nlp_cpu_s: float = 300.0
    design_cpu_s: float = 1800.0
    check_tail_s: float = 0.015
    check_steps: int = 6
    max_nlps: int = 6
    max_samples: int = 512
    per_sample_samples: int = 32
    arrival_samples: int = 32
    knot_spacing: int = 4
    friction_step: float = 0.5
    kappa_band: float = 150.0
    kappa_current: float = 600.0
    expand: bool = False
    smoothing: SmoothingSettings = field(default_factory=lambda: SmoothingSettings(
        friction_velocity_tps=20.0, saturation_width_a=0.002, table_width_track=5.0))
    ipopt: dict = field(default_factory=dict)
    nlpsol: dict = field(default_factory=dict)


@dataclass
class NLPSolve:
    """One Ipopt call: seek length, status, iterations, wall time [s], worst residual [band]
    (over the robust set when there is one), the elastic slack left on the current rows [Imax] (above
    ``slack_tol`` the length is infeasible) and the unmodelled-mode guard's excess over its tolerance
    [band] (elastic: penalised, recorded in the profile, not a feasibility condition); ``cpu_s`` the
    process CPU time of the call [s] (wall time depends on the machine's load)."""

    n_seek: int
    status: str
    success: bool
    iterations: int
    wall_s: float
    residual: float
    slack: float = 0.0
    guard_excess: float = 0.0
    cpu_s: float = 0.0

    def to_dict(self) -> dict:
        return dict(self.__dict__)


# ------------------------------------------------------------------------------- the loop's kinks
# (the loop's servo sample: seekopt.design.nlp_loop; the robust set: seekopt.design.nlp_spread)
def nlp_smoothing(plant: ModalPlant, controller, settings: NLPSettings) -> SmoothingSettings:
    """The kinks' smoothing in the NLP of ``plant``: ``settings.smoothing`` with the friction sign
    smoothed over at least ``k0 c dt / friction_step`` [track/s] (``c`` the Coulomb level [A], ``dt``
    the sub-step [s]).  The plant is stepped explicitly, so near rest the smoothed sign is a damper of
    rate ``k0 c / v_s`` [1/s]; over a sub-step it must take away less than the velocity (``friction_step``
    < 1), else the velocity flips sign every sub-step in the NLP's model (0.5 mA, 20 track/s on the
    bundled drive: 1.86 per sub-step) and Ipopt needs 4.5x the iterations (259 against 58 at 80 track/s,
    measured on a 71-sample seek) for the same design: the full-plant check is exact either way."""
    sm = settings.smoothing
    c = sum(abs(float(e.coulomb_a)) for e in plant.effects if e.name == "friction")
    if c <= 0 or sm.friction_velocity_tps <= 0:
        return sm
    dt = 1.0 / (float(controller.sample_rate_hz) * int(controller.fast_multiple))
    need = float(plant.k0) * c * dt / float(settings.friction_step)
    return replace(sm, friction_velocity_tps=max(sm.friction_velocity_tps, need))


# ------------------------------------------------------------------------------- the NLP
class SeekNLP:
    """The effect-aware seek NLP for seeks of at most ``nmax`` samples (one size class).

    Condensed like the linear QP (:class:`seekopt.design.qp.SeekQP`): the decision vector is
    ``[v (nmax), c (nb), t]``: the feedforward [Imax], the reference offset ``q = (r - K) / |K| =
    q_base + B c`` (the warm start's reference plus a correction on the piecewise-linear hats of
    :func:`~seekopt.design.nlp_basis.correction_knots`, as the feedforward's) and the worst residual [band];
    the PES and sub-step currents over ``H = nmax + tail`` samples are those of the nominal
    full-plant loop rolled out from the rest state (``mapaccum`` of the servo-sample function; the
    closed loop is stable, so single shooting is well conditioned).  Parameters
    ``[K, |K|, T0, Imax, u_hold, x0, w (H + 1), v_base, Bv, q_base (nmax), B (nmax x nb), g_in, o_in
    (nmax)]`` (``w``: tail-energy weights; ``g_in, o_in``: the input map along the plan, for the guard).  Built once
    (``nlpsol``, Ipopt, exact Hessian) and called per ``(K, T0, N)``.

    ``spread`` (:class:`RobustSpread`): the robust set, every plant ``j`` on its rows through one smooth
    maximum per row (``smax_j s = log(sum_j exp(kappa s_j)) / kappa``, nominal ``s_0 = 0``)::

        e_k + smax_j s_jk <= t,   -e_k + smax_j (-s_jk) <= t,   |i| + smax_j (+-di_j) <= gamma

    with ``s_jk = D_jk [Imax v; |K| q] + K d_jk`` linear: two rows per sample whatever the set's
    size (a row per plant and sample made Ipopt's dense KKT 5-10 times slower).
    """

    def __init__(self, plant: ModalPlant, controller, nmax: int, tail: int, band: float,
                 settings: NLPSettings, spread: "RobustSpread | None" = None, guard=None,
                 guard_tol: float = 0.1):
        t_build = time.perf_counter()
        self.settings, self.band = settings, float(band)
        self.fs, self.L = float(controller.sample_rate_hz), int(controller.fast_multiple)
        self.smoothing = nlp_smoothing(plant, controller, settings)
        ops = casadi_ops(self.smoothing)
        F, (nx, nh, nc), self.dp = closed_loop_sample(plant, controller, ops)
        self.dims, nz = (nx, nh, nc), nx + nh + nc
        N, H = int(nmax), int(nmax) + int(tail)
        self.N, self.H, self.nz = N, H, nz
        xr, ur = ca.SX.sym("x", nz), ca.SX.sym("u", 3)
        xn, hn, xcn, yr, ir = close_sample(F)(xr[:nx], xr[nx:nx + nh], xr[nx + nh:], ur[0], ur[1], ur[2])
        step = ca.Function("loop_step", [xr, ur], [ca.vertcat(xn, hn, xcn), yr, ir])
        self._rollout = step.mapaccum("rollout", H)
        self._measure = ca.Function("measure_x", [xr, ur[2]], [self.dp.measure(xr[:nx], ur[2], ops)])
        Kp, aK, T0, imax, uh = (ca.MX.sym(n) for n in ("K", "absK", "T0", "imax", "uhold"))
        x0, w = ca.MX.sym("x0", nz), ca.MX.sym("w", H + 1)
        # correction columns: the most any seek of this class uses (correction_knots); a shorter seek's unused
        # columns are fixed at 0 (Ipopt takes fixed variables out of its KKT system)
        nb = nv = self.nb = self.nv = max(len(correction_knots(n, settings)) for n in range(1, N + 1))
        A, CV, C, tt = ca.MX.sym("a"), ca.MX.sym("cv", nv), ca.MX.sym("c", nb), ca.MX.sym("t")
        sc, sg = ca.MX.sym("s_cur"), ca.MX.sym("s_guard")   # elastic slacks: the NLP is always feasible
        vb, Bv = ca.MX.sym("v_base", N), ca.MX.sym("Bv", N, nv)
        gin, oin = ca.MX.sym("g_in", N), ca.MX.sym("o_in", N)   # the input map along the plan (guard)
        qb, Bq = ca.MX.sym("q_base", N), ca.MX.sym("B", N, nb)
        V = (1 + A) * vb + ca.mtimes(Bv, CV)  # feedforward: the warm start scaled plus a smooth correction
        Q = qb + ca.mtimes(Bq, C)             # reference offset: a base plus a smooth correction
        U = ca.vertcat(ca.horzcat(imax * V.T + uh, ca.repmat(uh, 1, H - N)),
                       ca.horzcat(T0 + Kp + aK * Q.T, ca.repmat(T0 + Kp, 1, H - N)),
                       ca.DM(np.arange(H) / self.fs).T)
        X, Y, Iloop = self._rollout(x0, U)
        E = (ca.vertcat(Y.T, self._measure(X[:, H - 1], H / self.fs)) - T0 - Kp) / band   # PES [band]
        I = ca.vec(Iloop) / imax                                     # sub-step currents [Imax], (k, l)
        rows, self.blocks = [], {}

        def add(name, expr, samples=None):
            self.blocks[name] = (sum(r.numel() for r in rows), expr.numel(),
                                 np.arange(expr.numel()) if samples is None else np.asarray(samples, int))
            rows.append(expr)

        add("ff", V)
        add("pes_hi", E - tt)
        add("pes_lo", E + tt)
        add("cur_hi", I - sc)
        add("cur_lo", I + sc)
        self.guard_tol = float(guard_tol)
        if guard is not None:               # residual of unmodelled modes [band]: linear rows on (u_ff, r)
            Gm, g0 = (np.asarray(a, dtype=float) for a in guard)
            # on the current-equivalent force the feedforward delivers (gain * u + offset: the plant's
            # input map linearised along the warm start's plan, e.g. Kt(x) u), which is what excites
            # the modes: the compensated warm start then meets the guard exactly as the linear design
            z = ca.mtimes(ca.DM(Gm), ca.vertcat(imax * gin * V + oin, aK * Q)) + Kp * ca.DM(g0)
            add("hf_hi", z - sg)
            add("hf_lo", z + sg)
        if spread is not None and spread.n:     # every plant of the set: smooth max over the set per row
            DY, dy, DI, di = spread.rows()
            wy = ca.vertcat(imax * V, aK * Q)
            kb, kc = spread.band_samples, spread.current_substeps
            for name, D, d, base, kap, scale in (("rob_e", DY, dy, E[kb.tolist()], settings.kappa_band, 1.0),
                                                 ("rob_i", DI, di, I[kc.tolist()], settings.kappa_current, imax)):
                if D is None:                                         # current-only plants: no band rows
                    continue
                n, m = D.shape[0], D.shape[1]
                Sp = ca.reshape(ca.mtimes(ca.DM(D.reshape(n * m, -1, order="C")), wy) + Kp * ca.DM(d.ravel()),
                                m, n).T / scale                       # (plants, rows)
                Sp = ca.vertcat(ca.MX.zeros(1, m), Sp)                # the nominal plant: spread 0
                xs = ca.SX.sym("s", n + 1)
                lse = ca.Function("smooth_max", [xs], [ca.logsumexp(kap * xs) / kap]).map(m)
                up, dn = lse(Sp).T, lse(-Sp).T
                if name == "rob_e":
                    add("rob_hi", base + up - tt, kb)                # e + max_j s_j <= t
                    add("rob_lo", -base + dn - tt, kb)               # -e + max_j (-s_j) <= t
                else:
                    add("rob_ihi", base + up - sc, kc)               # i + max_j di_j <= gamma
                    add("rob_ilo", -base + dn - sc, kc)
        f = (settings.w_t * tt ** 2 + settings.rho * ca.sumsqr(ca.diff(ca.vertcat(0, V, 0)))
             + settings.rho_q * ca.sumsqr(ca.diff(ca.vertcat(0, Q, 0))) + ca.dot(w, E ** 2)
             + settings.w_slack * (sc + sg))
        x = ca.vertcat(A, CV, C, tt, sc, sg)
        p = ca.vertcat(Kp, aK, T0, imax, uh, x0, w, vb, ca.vec(Bv), qb, ca.vec(Bq), gin, oin)
        g = ca.vertcat(*rows)
        self.nx_dec, self.ng = x.numel(), g.numel()
        ipopt = {"print_level": 0, "sb": "yes", "max_iter": settings.max_iter, "tol": settings.tol,
                 "acceptable_tol": 1e-5, "acceptable_iter": 10, "mu_strategy": "adaptive",
                 "max_cpu_time": float(settings.nlp_cpu_s), "hessian_approximation": "exact"}
        ipopt.update(settings.ipopt)
        self.solver = ca.nlpsol("seek_nlp", "ipopt", {"x": x, "f": f, "g": g, "p": p},
                                {"ipopt": ipopt, "print_time": False, "error_on_fail": False,
                                 "expand": bool(settings.expand), **settings.nlpsol})
        BUILD_COUNT["nlp"] += 1
        self.build_time_s = time.perf_counter() - t_build

    # ------------------------------------------------------------------ per call
    def rollout(self, x0, v, q, K, T0, imax, uh):
        """The loop on the NLP's own model: states ``(nz, H + 1)`` (from ``x0``), PES [band]
        ``(H + 1,)`` and sub-step currents ``(L, H)`` [A] for scaled inputs ``v, q``."""
        N, H = self.N, self.H
        u = np.full(H, uh); u[:N] += imax * np.asarray(v)[:N]
        r = np.full(H, T0 + K); r[:N] += abs(K) * np.asarray(q)[:N]
        X, Y, I = self._rollout(x0, np.vstack([u, r, np.arange(H) / self.fs]))
        X = np.column_stack([x0, np.asarray(X)])
        yH = float(self._measure(X[:, -1], H / self.fs))
        return X, (np.r_[np.asarray(Y).ravel(), yH] - T0 - K) / self.band, np.asarray(I)

    def solve(self, K: float, T0: float, nseek: int, imax: float, uh: float, x0: np.ndarray,
              v0: np.ndarray, q0: np.ndarray, beta: float, gamma: float, input_map=None, input_tail: int = 0):
        """Solve for a seek of ``K`` tracks from ``T0`` settling in ``nseek`` samples from ``v0, q0`` (scaled
        feedforward and reference, length ``nmax``); ``input_map``: ``(gain, offset [A])`` of length
        ``nmax`` for the guard (default: 1, 0 -- the command is the force).  ``input_tail``: samples the
        feedforward and reference may go on after ``nseek`` (the linear designer's ``input_tail``, the
        problem's ``input_tail_s``: the band holds from ``nseek``, rest at ``K`` from ``nseek + input_tail``).
        Returns ``(NLPSolve, v, q)``; ``NLPSolve.residual`` is ``t*`` [band]."""
        N, H, st = self.N, self.H, self.settings
        n_in = int(nseek) + int(input_tail)
        if not (0 < nseek and n_in <= N):
            raise ValueError(f"seek length {nseek} + input tail {input_tail} outside 1..{N}")
        on = (np.arange(N) < n_in).astype(float)
        v0, q0 = on * np.clip(v0[:N], -1, 1), on * np.clip(q0[:N], -2, 2)
        ne = H + 1
        w = np.zeros(ne); w[nseek:] = st.w_e / (ne - nseek)
        p = np.r_[K, abs(K), T0, imax, uh, x0, w]
        _, e0, _ = self.rollout(x0, v0, q0, K, T0, imax, uh)
        knots = correction_knots(n_in, st)
        B = Bv = hat_basis(knots, N, self.nb)
        live = len(knots)
        gi, oi = (np.ones(N), np.zeros(N)) if input_map is None else \
            (np.r_[input_map[0], np.ones(N)][:N], np.r_[input_map[1], np.zeros(N)][:N] * on)
        p = np.r_[p, v0, Bv.T.ravel(), q0, B.T.ravel(), gi, oi]
        nd = 1 + self.nv + self.nb
        xw = np.r_[np.zeros(nd), float(np.max(np.abs(e0[nseek:]))), 0.1, 0.1]
        free = np.r_[np.arange(self.nv) < live, np.arange(self.nb) < live]
        lbx = np.r_[-0.5, np.where(free, -np.inf, 0.0), 0.0, 0.0, 0.0]
        ubx = np.r_[0.5, np.where(free, np.inf, 0.0), np.inf, np.inf, np.inf]
        lbg, ubg = np.full(self.ng, -np.inf), np.full(self.ng, np.inf)
        for name, (off, n, smp) in self.blocks.items():
            sl = slice(off, off + n)
            if name in ("pes_hi", "rob_hi", "rob_lo"):  # ... - t <= 0 after the seek
                ubg[sl] = np.where(smp >= nseek, 0.0, np.inf)
            elif name == "pes_lo":                      # e + t >= 0 after the seek
                lbg[sl] = np.where(smp >= nseek, 0.0, -np.inf)
            elif name == "ff":
                lbg[sl], ubg[sl] = -on, on
            elif name in ("cur_hi", "rob_ihi", "rob_ilo"):
                ubg[sl] = gamma
            elif name == "cur_lo":
                lbg[sl] = -gamma
            elif name == "hf_hi":
                ubg[sl] = self.guard_tol
            elif name == "hf_lo":
                lbg[sl] = -self.guard_tol
        t_start, c_start = time.perf_counter(), time.process_time()
        sol = self.solver(x0=xw, p=p, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        wall, cpu = time.perf_counter() - t_start, time.process_time() - c_start
        stats = self.solver.stats()
        xo = np.asarray(sol["x"], dtype=float).ravel()
        status = str(stats.get("return_status", "?"))
        ok = (bool(stats.get("success", False)) or status == "Solved_To_Acceptable_Level") \
            and bool(np.all(np.isfinite(xo)))
        self.last_slacks = (float(xo[nd + 1]), float(xo[nd + 2]))      # (current [Imax], guard [band])
        slack = float(xo[nd + 1]) if ok else math.inf
        guard_excess = float(xo[nd + 2]) if ok else math.inf
        rec = NLPSolve(int(nseek), status, ok, int(stats.get("iter_count", 0)), wall,
                       float(xo[nd]) if ok else math.inf, slack, guard_excess, cpu)
        v = (1 + xo[0]) * v0 + Bv @ xo[1:1 + self.nv]
        return rec, v, q0 + B @ xo[1 + self.nv:nd]
