"""The steps a :class:`~seekopt.design.longseek.LongSeekDesigner` designs once and keeps: velocity steps
(:mod:`seekopt.design.velocity_step`) and the acceleration step (:mod:`seekopt.design.accel_step`), each
designed by a bisection of small QPs on the problem's set and checked on the nominal linear loop.

The composition of seeks from them and the dispatch rule: :mod:`seekopt.design.longseek` (module notes).
"""
from __future__ import annotations

import math
import time

import numpy as np

from seekopt.design import guard as _guard
from seekopt.design.predict import set_loop_maps
from seekopt.design.accel_step import AccelStep, AccelStepQP
from seekopt.design.longseek_spec import I0_FRACTION, LongSeekError
from seekopt.design.search import bisect_length
from seekopt.design.velocity_step import StepQP, VelocityStep

#: The acceleration step's error bound on the nominal plant from ``min_accel_samples()`` samples after the step
#: (32, or 14 with ``compare_below_long``: where a composition's older terms begin), as a fraction of the band
#: margin (:class:`~seekopt.design.accel_step.AccelStepQP` ``quiet``).
ACCEL_QUIET = 0.1
#: Samples after the acceleration step's end from which the other plants of the set are held in the band
#: (:class:`~seekopt.design.accel_step.AccelStepQP` ``set_lag``; the nominal from the end on).  A seek sees
#: the four-term sum of the step's error, not one step's: on the set's gain corners the older terms' slow
#: tails already put the seek's set settle 18-20 samples after the nominal (robust bundled drive, 1e4-1e5
#: tracks at 2e6 track/s), so holding each step's set error in the band from its end on cost 7 samples of
#: the nominal arrival (step 46 -> 39 samples) and bought no set settle: measured with 10, the seeks'
#: predicted set settle moved by -3..+3 samples over 311-1e5 tracks (16: up to +28), the nominal 7 sooner.
ACCEL_SET_LAG = 10

__all__ = ["StepDesigns", "ACCEL_QUIET", "ACCEL_SET_LAG"]


class StepDesigns:
    """The velocity steps and the acceleration step of a :class:`~seekopt.design.longseek.LongSeekDesigner`
    (a mixin: the problem's data, the caches ``_steps``, ``_accel``, ``_maps``, ``_nominal``,
    ``accel_quiet`` and ``accel_set_lag`` are set by its constructor)."""

    # ------------------------------------------------------------------ velocity steps
    def _shortest_step(self, build, lo: int, nmax: int, cap: int, what: str):
        """The fewest samples of a step QP: ``build(nmax, lo) -> (qp, solve)`` makes the QP for steps of at
        most ``nmax`` samples (``solve(n, warm)`` solves it at ``n``); ``nmax`` grows 1.5x from the given
        one until feasible (at most ``cap``), then :func:`~seekopt.design.search.bisect_length` (the step
        QP decides on the whole problem: feasibility is monotone in ``n``, no confirmation).  Returns
        ``(n, solution, qp, QP solves)``."""
        best, n_solves = None, 0
        while nmax <= cap:
            qp, solve = build(nmax, lo)
            sol = solve(nmax); n_solves += 1
            if sol.success:
                best = sol
                break
            lo, nmax = nmax, int(math.ceil(1.5 * nmax))
        if best is None:
            raise LongSeekError(f"no {what} within {cap} samples")
        solves = []

        def probe(n, warm=None, confirm=True):
            solves.append(n)
            return solve(n, warm)
        hi, best = bisect_length(probe, lo, nmax, best, lambda n: False)
        return hi, best, qp, n_solves + len(solves)

    def _loop_maps(self, horizon):
        """The set's closed-loop maps as the linear designer's (:func:`~seekopt.design.predict.set_loop_maps`:
        each plant with its drive's feedforward calibration), at least ``horizon`` samples long (kept)."""
        if self._maps is None or self._maps_h < horizon:
            h = max(horizon, int(1.5 * self._maps_h))
            self._maps = set_loop_maps(self.plants, self.controller, h)
            self._maps_h = h
        return self._maps

    def _nominal_maps(self, horizon):
        """The nominal plant's maps over at least ``horizon`` samples: the set's first map when the set's maps
        are that long (one simulation of the nominal loop), else the nominal's alone (kept)."""
        if self._maps is not None and self._maps_h >= horizon:
            return self._maps[0]
        if self._nominal is None or self._nominal.horizon < horizon:
            self._nominal = set_loop_maps(self.plants[:1], self.controller, 2 * horizon)[0]
        return self._nominal

    def _guard_rows(self, nmax, maps):
        """The linear designer's unmodelled-mode guard rows (:func:`~seekopt.design.guard.design_guard_rows`:
        Nyquist band, controller notches, the plant's blind bands) for steps of at most ``nmax`` samples
        over ``nmax + tail`` samples; None without a band."""
        rows = _guard.design_guard_rows(self.guard_bands, self.plant.k0, self.fs, nmax, nmax + self.tail, maps[0],
                                        curve=self.guard_curve)
        return None if rows is None else rows[0]

    def _qp(self, nmax, nlo):
        H = nmax + self.tail
        maps = self._loop_maps(H)
        hf = self._guard_rows(nmax, maps)
        return StepQP(maps, nmax, H, self.plant.k0, self.fs, self.plant.total_delay_s * self.fs, self.imax,
                       self.settle, self.plant.bias_a, hf, nlo, self.problem.solver)

    def velocity_step(self, velocity_track_s: float) -> VelocityStep:
        """The shortest verified velocity step to ``velocity_track_s`` [track/s] (cached)."""
        d = float(velocity_track_s) / self.fs
        key = round(d, 12)
        if key in self._steps:
            return self._steps[key]
        t0 = time.process_time()
        c = self.plant.k0 / self.fs ** 2
        gam = self.gamma - abs(self.plant.bias_a) / self.imax
        n_rigid = int(math.ceil(d / (c * gam * self.imax) - 1e-9))
        lo = max(n_rigid - 1, 1)
        hf_tol = 0.5 * self.hf_tol if self.guard_bands else None
        nmax = max(16, int(math.ceil(1.3 * n_rigid + 12)))
        self._loop_maps(int(1.5 * nmax) + self.tail)     # once for the first two size classes

        def build(nmax, lo):
            qp = self._qp(nmax, lo)
            return qp, lambda n, warm=None: qp.solve(d, n, self.beta, self.gamma, hf_tol, x0=warm)
        hi, best, qp, n_solves = self._shortest_step(build, lo, nmax, 4096,
                                                     f"velocity step to {velocity_track_s:g} track/s")
        u, w = qp.unpack(best.x, hi)
        u = np.clip(u, -self.imax, self.imax)
        u += (d / c - u.sum()) / hi                  # exact velocity (least-norm correction, ~1e-12 A)
        r = qp.reference(u, w)
        step = VelocityStep(u, r, d, self.fs, self.imax, self.settle, 0, 0,
                            {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
                             "robust": self.robust.to_string() if self.robust else "none",
                             "design_samples": hi, "qp_solves": n_solves})
        step.settle_samples, step.min_coast_samples = self._arrival(step)
        step.meta["design_cpu_s"] = time.process_time() - t0
        self._steps[key] = step
        return step

    def _arrival(self, step: VelocityStep) -> tuple[int, int]:
        """Settle of the step's error and the smallest spacing from which compositions are clean
        (nominal linear loop: error ``e_A(k) - e_A(k-m)`` in the band after ``m + settle``, current within
        ``(1 + gamma) / 2 Imax`` with the hold in both directions, for every ``m`` up to the length where ``e_A`` and the
        currents have died out; ``m < N`` overlaps the steps)."""
        from seekopt.design.metrics import settle_index
        H = step.n + 4 * self.tail
        mp = self._nominal_maps(H)
        u, r = step.extended(H)
        y, i = mp.response(u, r, H)
        e = y - r
        S = max(settle_index(e, self.settle) or 0, step.n)
        if np.max(np.abs(e[-self.tail:])) > 0.01 * self.settle:
            raise LongSeekError(f"velocity step to {step.velocity_track_s:g} track/s: the loop has not caught "
                                f"the ramp {H} samples later")
        hold = abs(self.plant.bias_a)
        ez, iz = np.r_[e, np.zeros(H)], np.vstack([i, np.zeros_like(i)])   # e_A, i_A = 0 beyond the horizon
        if np.max(np.abs(i)) + hold > self.imax:
            raise LongSeekError(f"velocity step to {step.velocity_track_s:g} track/s exceeds Imax on the design plant")
        lim = self._composition_limit()    # compositions may use half the QP's current margin
        m_ok = H
        for m in range(H - 1, 0, -1):     # arrival error e_A(m + j) - e_A(j), scanned down in m (m < N: overlap)
            k = settle_index(ez[m:m + H] - e, self.settle)
            im = np.vstack([i[:m], iz[m:m + H] - i])
            if k is None or k > S or np.max(np.abs(im)) > lim:
                break
            m_ok = m
        return int(S), int(m_ok)

    # ------------------------------------------------------------------ the acceleration step
    def _lim(self) -> float:
        """The seek's current limit without the hold, ``gamma Imax - |bias|`` [A]."""
        return self.gamma * self.imax - abs(self.plant.bias_a)

    def _composition_limit(self) -> float:
        """A composition's total current limit, ``(1 + gamma) / 2 Imax - |bias|`` [A]: half the QP's current
        margin (the velocity steps' overlap and :func:`~seekopt.design.accel_step.plan_seek`'s plans)."""
        return 0.5 * (1 + self.gamma) * self.imax - abs(self.plant.bias_a)

    def accel_step(self) -> AccelStep:
        """The shortest acceleration step (:mod:`seekopt.design.accel_step`) on the problem's set, designed
        once (one bisection of small QPs) and kept: every seek from :meth:`long_from_track` on is built
        from it.  ``I0 = I0_FRACTION lim / max(1, max_i k0 / k0_i)`` so that every plant's steady current is within
        ``lim``."""
        if self._accel is not None:
            return self._accel
        from seekopt.design.metrics import settle_index
        t0 = time.process_time()
        lim = self._lim()
        k0s = [float(q.k0) for q in self.plants]
        i0 = I0_FRACTION * lim / max(1.0, max(self.plant.k0 / k for k in k0s))
        nmax = 48
        self._loop_maps(nmax + 4 * self.tail)     # once: the QPs and the set's error tracks below (N <= 48)

        def build(nmax, lo):
            H = nmax + self.tail
            maps = self._loop_maps(H)
            rows = _guard.design_guard_rows(self.guard_bands, self.plant.k0, self.fs, nmax, H, maps[0],
                                            curve=self.guard_curve)
            hf_tol = None
            if rows is not None:        # accel_step notes: four transitions, one-sample differences
                hf_tol = self.hf_tol * 2 * float(np.min(np.abs(np.sin(np.pi * rows[1] / self.fs)))) / 4
            qp = AccelStepQP(maps, k0s, nmax, H, self.plant.k0, self.fs, self.plant.total_delay_s * self.fs,
                             self.imax, i0, self.settle, lo, self.problem.solver,
                             hf=None if rows is None else rows[0], quiet=self.accel_quiet,
                             quiet_after=self.min_accel_samples(), set_lag=self.accel_set_lag)
            return qp, lambda n, warm=None: qp.solve(n, self.beta, lim, hf_tol, x0=warm)
        hi, best, qp, n_solves = self._shortest_step(build, 1, nmax, 512, "acceleration step")
        u, off, delta = qp.unpack(best.x, hi)
        st = AccelStep(u, i0, off, delta, qp.c, qp.delay, self.fs,
                       meta={"design_samples": hi, "qp_solves": n_solves})
        Hc = hi + 4 * self.tail        # the nominal linear loop: error and currents until they die out
        mp = self._nominal_maps(Hc)
        uu, rr = st.extended(Hc)
        y, st.current_sub_a = mp.response(uu, rr, Hc)
        e = y - rr
        if np.max(np.abs(e[-self.tail:])) > 0.01 * self.settle:
            raise LongSeekError(f"acceleration step: the loop has not caught the parabola {Hc} samples later")
        st.error_track = np.r_[e, 0.0]
        if len(self.plants) > 1:      # every plant of the set (calibrated maps), for the plan's worst case
            es = [q.response(uu, rr, Hc, currents=False)[0] - rr for q in self._loop_maps(Hc)[1:]]
            st.set_error_track = np.vstack([np.r_[x, 0.0] for x in es])
        st.settle_samples = int(max(settle_index(e, self.settle) or 0, hi))
        st.meta["design_cpu_s"] = time.process_time() - t0
        self._accel = st
        return st
