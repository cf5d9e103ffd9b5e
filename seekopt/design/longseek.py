"""Full-stroke seeks: accelerate - coast - arrive, under an optional velocity limit.

A drive's stroke is hundreds of thousands of tracks; above a few thousand the VCM's back-EMF caps the
velocity and the seek coasts.  Designing such a seek as one rest-to-rest QP makes the problem grow with
the coast; here the coast is free and only one short segment is optimised.

The velocity step
-----------------
A *velocity step* of ``d`` tracks per sample is a feedforward ``u_A`` over ``N`` samples and a reference
``r_A`` that leave the 2DOF loop ``u = u_ff + C(r - y)`` on its ramp equilibrium::

    r_A(k) = ramp(k) = k0 Ts^2 sum_j u_A(j) (k - tau/Ts - j - 1/2)      for k >= N   (ZOH rigid body with
    k0 Ts^2 sum_j u_A(j) = d                                                          input delay tau)

(the head moving at ``d`` track/sample with zero current, the modes at rest, zero error: the loop with a
double-integrator plant and an integrating controller is type 3, so it tracks the ramp with zero error).
It is designed by a QP on the condensed linear loop (:class:`seekopt.design.qp.LoopMaps`, from the one
simulator) over the same plant set, current limit, unmodelled-mode guard and solver chain as
:class:`seekopt.design.designer.SeekDesigner` (one :class:`seekopt.design.problem.SeekProblem`): minimum ``N`` such that ``|y_i(k) - r_A(k)| <= beta band`` for
``k >= N`` on every plant ``i`` of the set, the total current within ``gamma Imax - |bias|`` (so that the
mirrored step, ``-u_A``, with the hold current is within ``gamma Imax`` too), the rigid velocity within ``[0, d]``
(the arrival's mirrored step runs at ``d - v_A``), and the guard's residual within half its tolerance (the two steps of a seek add).

The seek
--------
The loop is linear and time-invariant, so a seek of ``K`` tracks is the difference of two steps::

    m = ceil(K / d),  s = K / (m d) <= 1
    u(k) = s (u_A(k) - u_A(k - m)),   r(k) = s (r_A(k) - r_A(k - m))

The head accelerates, coasts at ``s d`` with zero feedforward, and arrives with the mirror of the
acceleration; after both steps the reference is exactly ``s m d = K`` and the head is at rest there
(rest-to-rest exactness), and the position error is ``s (e_A(k) - e_A(k - m))`` with ``e_A = y_A - r_A``:
the arrival settles like the step settles onto its ramp.  The design cost is one small QP per velocity,
whatever the coast; every seek is checked on the full design plant by
:func:`seekopt.drive.simulator.simulate_2dof` (via :func:`seekopt.design.metrics.evaluate_profile`).
Shorter seeks (no room for a coast) go to :class:`seekopt.design.designer.SeekDesigner`; its peak rigid
velocity is checked against the limit.

Long seeks below the coast at ``vmax`` (or without a velocity limit): the acceleration step
-------------------------------------------------------------------------------------------
A velocity step per velocity would make the cost grow with the length (its QP grows with the velocity: a
step to 1.1e7 track/s, the bang-bang peak of 1e5 tracks, took 45 s CPU).  Instead one *acceleration step*
(:mod:`seekopt.design.accel_step`: from rest onto the constant-current parabola ``I0``, one bisection of
small QPs on the problem's set, kept) gives every such seek as four shifted copies,
``u = s (u_J(k) - u_J(k-n) - u_J(k-m) + u_J(k-m-n))``, rest-to-rest exact (``s c I0 n m = K``).

**The dispatch rule** (:meth:`LongSeekDesigner.design`, the rule of ``seekopt design``):

1. with ``vmax`` and a seek long enough to coast at it (:meth:`~LongSeekDesigner.needs_coast`): the velocity
   step to ``vmax`` and its mirror (above) on one plant; on a plant set the acceleration step of rule 2 with
   ``n`` capped at ``vmax`` (the velocity step only when that gives no plan): on the robust set the
   velocity step's QP (about 90 samples on every plant) took 13.9 s CPU and settled no sooner (1e4 and
   15849 tracks at 2e6 track/s: 8.64 / 11.59 ms against 8.56 / 11.55 ms; 0.04-0.6 ms later beyond,
   ``docs/results_longseek.md``), while on one plant it costs 0.6 s and settles 0.7 ms sooner;
2. else, from ``long_from_track = c I0 n_floor^2`` tracks on (``n_floor = 32`` samples at ``I0``: the older
   terms are on the step's quiet rows; below the step's length ``N_J`` the transitions overlap and a plan
   is kept only if its nominal current is within ``(1 + gamma) / 2 Imax`` with the hold, as the velocity
   step's compositions): the acceleration step with ``n <= m``, ``n`` within 3 of the bang-bang
   ``sqrt(K / (c I0))`` (capped at ``vmax / (fs c I0)``), the one whose four-term error settles first on
   every plant of the set (linear maps; ties: nominal settle, then ``m + n``); verified on the design plant
   by simulation (Imax, settled by the predicted sample); seeks up to ``LongSeekSpec.rest_to_rest_up_to_track``
   (``--rest-to-rest-up-to``) stay with the rest-to-rest QP, which settles sooner at a cost that grows
   with the length;
   with ``LongSeekSpec.compare_below_long`` (sweeps: on; ``seekopt design``: off, as a single design would
   pay the step and the reference first), from ``c I0 COMPOSE_FROM_SAMPLES^2`` (14 samples at ``I0``)
   to ``long_from_track`` the composition (``n >= 14``) is taken when its predicted settle is within
   ``SETTLE_RATIO = 1.15`` of
   ``T_bb + O - OVERHEAD_SPREAD``, ``O`` the settle overhead of the rest-to-rest design of
   ``compare_from_track`` tracks (one cheap design per designer, kept): the rest-to-rest overhead mostly
   grows with the length or stays flat (robust sweep set, samples: 200k TPI 27.6 at 10 samples at ``I0``,
   29.2 at 20, 27.6 at 25.5; 500k 36.6, 38.2, 40.2; 1000k 41.6, 49.8, 52.1, 50.3) but fell 3 samples at
   300k TPI (33.6 -> 30.65 at 2069 tracks), so ``T_bb + O - 3`` is a low estimate of the rest-to-rest
   settle on every cell measured.
   Why: the rest-to-rest QPs near ``n_floor`` have 80-110 samples, and robust ones at high track density
   took 5-282 s CPU each (``docs/results_sweep_scaling.md``), while the composition settles within
   1.00-1.08x of them there (``docs/results_longseek.md``);
3. else the rest-to-rest QP (:class:`~seekopt.design.designer.SeekDesigner`), its peak velocity checked
   against ``vmax``.

On the bundled drive ``long_from_track`` is 1627 tracks (``N_J`` = 30 nominal, 39 robust); when no plan
near the bang-bang ``n`` settles on every plant (none measured), the rest-to-rest QP designs the seek.

The velocity limit and the stroke from the plant's metadata: :mod:`seekopt.design.longseek_spec`.
"""
from __future__ import annotations

import math
import time

from seekopt.design.accel_step import AccelStep, plan_seek
from seekopt.design.guard_bands import plant_gain_curve, problem_bands
from seekopt.design.longseek_spec import (I0_FRACTION, LongSeekError, LongSeekSpec, stroke_from_plant,
                                          t_accel_coast_decel, vmax_from_plant)
from seekopt.design.longseek_build import SeekBuild, rigid_peak_velocity
from seekopt.design.longseek_steps import ACCEL_QUIET, ACCEL_SET_LAG, StepDesigns
from seekopt.design.velocity_step import VelocityStep

#: Bang-bang samples at ``I0`` of the reference rest-to-rest seek of the dispatch (module notes, rule 2):
#: its robust design is cheap at every track density of the sweep (0.2-3.9 s CPU at 200k-1000k TPI).
COMPARE_SAMPLES = 10
#: Fewest samples at ``I0`` of a composition below ``long_from_track``: shorter seeks stay rest-to-rest, whose
#: QPs are cheap there at every track density of the sweep (<= 1.4 s CPU robust, 200k-1000k TPI) and settle
#: 11-14 % sooner than the composition at 300k-500k TPI.
COMPOSE_FROM_SAMPLES = 14
#: Settle allowed to a composition below ``long_from_track`` against the rest-to-rest design (issue 12).
SETTLE_RATIO = 1.15
#: Samples by which a robust rest-to-rest design's overhead (settle - T_bb) may fall below the reference
#: design's (:meth:`LongSeekDesigner.rest_to_rest_overhead`) at a longer seek: the overhead is a settle counted
#: in whole samples less a fractional T_bb, and the set's arrival (gain corners, delay) does not grow it
#: monotonically with the length.  Largest drop measured on the robust sweep set: 300k TPI, 33.6 samples at
#: 10 samples at ``I0`` against 30.65 at 2069 tracks (600k: 37.6 against 37.5; 200k/500k/1000k: none).
OVERHEAD_SPREAD = 3.0

__all__ = ["LongSeekSpec", "VelocityStep", "AccelStep", "LongSeekDesigner", "LongSeekError", "vmax_from_plant",
           "stroke_from_plant", "t_accel_coast_decel", "I0_FRACTION", "OVERHEAD_SPREAD", "rigid_peak_velocity"]


class LongSeekDesigner(StepDesigns, SeekBuild):
    """Long seeks for one :class:`seekopt.design.problem.SeekProblem` (module notes); build once, design many.

    ``LongSeekDesigner(problem, spec)``, or the keyword form ``LongSeekDesigner(plant, controller, imax,
    settle, robust, spec, **options)`` (:meth:`SeekProblem.from_options`).  The velocity step uses the
    problem's plant set, margins, unmodelled-mode guard, tail and solver chain.

    Parameters
    ----------
    problem : SeekProblem
    spec : LongSeekSpec, optional
        Velocity limit and stroke (default :meth:`LongSeekSpec.from_plant`).
    short_designer : object, optional
        Designer for seeks without a coast (default ``SeekDesigner(problem)``, built on first use).
    """

    def __init__(self, problem, *args, spec: LongSeekSpec | None = None, short_designer=None, **options):
        from seekopt.design.problem import SeekProblem
        if not isinstance(problem, SeekProblem):
            pos = (problem,) + args
            if len(pos) < 3:
                raise TypeError("LongSeekDesigner(problem, spec) or (plant, controller, imax[, settle, robust, spec])")
            if len(pos) > 5:
                spec = pos[5]
            problem = SeekProblem.from_options(*pos[:5], **options)
        elif len(args) == 1 and spec is None:
            spec = args[0]
        elif args or options:
            raise TypeError("LongSeekDesigner(problem, spec) takes no further arguments")
        self.problem = p = problem
        self.plant, self.controller = p.plant, p.controller
        self.imax, self.settle, self.robust = p.imax_a, p.settle_band_track, p.robust
        self.spec = spec if spec is not None else LongSeekSpec.from_plant(p.plant, p.imax_a)
        self.fs, self.L = p.sample_rate_hz, int(p.controller.fast_multiple)
        self.beta, self.gamma = p.band_margin, p.current_margin
        self.hf_tol = p.hf_tol
        self.guard_bands = problem_bands(p)     # Nyquist, controller notches, blind bands
        self.guard_curve = plant_gain_curve(p.plant)
        self.solver = p.solver.qp_solver
        if abs(p.plant.bias_a) >= self.gamma * self.imax:
            raise LongSeekError(f"bias {p.plant.bias_a:g} A leaves no current for a seek at Imax {self.imax:g} A")
        self.plants = p.plants()
        self.tail = p.band_tail_samples()
        self._short = short_designer
        self._steps: dict = {}
        self._accel: AccelStep | None = None
        self.accel_quiet, self.accel_set_lag = ACCEL_QUIET, ACCEL_SET_LAG
        self._maps, self._maps_h = None, 0
        self._nominal = None
        self._r2r_over = None

    # ------------------------------------------------------------------ steps (StepDesigns) and dispatch
    def n_floor(self) -> int:
        """Fewest samples at ``I0`` of a built seek: the quiet rows' delay (32 samples; shorter than the step,
        the transitions overlap: :func:`~seekopt.design.accel_step.plan_seek` checks the current)."""
        return 32

    def long_from_track(self) -> float:
        """Shortest seek built from the acceleration step: ``c I0 n_floor^2`` [track] (``n = m = n_floor``)."""
        return self.accel_step().accel_track * self.n_floor() ** 2

    def _is_long(self, K: float) -> bool:
        """May the acceleration step build this seek (module notes, rule 2)?  From ``COMPOSE_FROM_SAMPLES``
        samples at ``I0`` on with ``compare_below_long``, else from :meth:`long_from_track`; unless
        ``rest_to_rest_up_to_track`` keeps it (cheap test first: below :meth:`_long_lower_bound` no step
        is designed)."""
        if abs(K) < self._long_lower_bound():
            return False
        r2r = self.spec.rest_to_rest_up_to_track
        if r2r is not None and abs(K) <= r2r:
            return False
        if not self.spec.compare_below_long:
            return abs(K) >= self.long_from_track()
        return abs(K) >= self.accel_step().accel_track * COMPOSE_FROM_SAMPLES ** 2

    def min_accel_samples(self) -> int:
        """Fewest samples at ``I0`` of any composition of this designer: ``COMPOSE_FROM_SAMPLES`` with
        ``LongSeekSpec.compare_below_long``, else :meth:`n_floor`.  The older terms of a composition's error
        are at least this many samples older than its arrival: the acceleration step's nominal quiet rows
        start there (:class:`~seekopt.design.accel_step.AccelStepQP` ``quiet_after``)."""
        return COMPOSE_FROM_SAMPLES if self.spec.compare_below_long else self.n_floor()

    def _long_lower_bound(self) -> float:
        """``c I0_FRACTION lim n^2`` [track] (``n``: ``COMPOSE_FROM_SAMPLES`` with
        ``LongSeekSpec.compare_below_long``, else :meth:`n_floor`): no shorter seek is built from the step
        (``I0 <= I0_FRACTION lim``)."""
        n = self.min_accel_samples()
        return self.plant.k0 / self.fs ** 2 * I0_FRACTION * self._lim() * n ** 2

    def compare_from_track(self) -> float:
        """``c I0 COMPARE_SAMPLES^2`` [track]: the reference rest-to-rest seek; longer seeks below
        :meth:`long_from_track` take the composition when it settles within ``SETTLE_RATIO`` of the
        rest-to-rest settle predicted from it (:meth:`rest_to_rest_overhead`)."""
        return self.accel_step().accel_track * COMPARE_SAMPLES ** 2

    def rest_to_rest_overhead(self) -> tuple:
        """Settle overheads [samples] ``(nominal, set)`` (settle - T_bb) of the rest-to-rest design of
        :meth:`compare_from_track` tracks (designed once by the short designer, kept): the design plant's
        (its simulated settle) and the set's (the sample every plant of the set holds the band from,
        ``DesignResult.set_settle_samples``; equal to the nominal's on one plant).  The overhead of the
        rest-to-rest designs grows with the length or stays flat (robust sweep set, module notes), so
        ``T_bb + overhead`` is a low estimate of a longer seek's rest-to-rest settle.  ``(-inf, -inf)``
        when the reference does not design (no composition below :meth:`long_from_track`)."""
        if self._r2r_over is None:
            from seekopt.design.profiles import t_bang_bang
            from seekopt.design.result import DesignError, DesignInfeasible
            K = self.compare_from_track()
            try:
                res = self.short_designer().design(K)
            except (DesignError, DesignInfeasible):      # nothing to compare with: no composition below
                self._r2r_over = (-math.inf, -math.inf)  # long_from_track
            else:
                tbb = t_bang_bang(K, self.plant.k0, self.imax) * self.fs
                self._r2r_over = (res.metrics.settle_time_s * self.fs - tbb, res.set_settle_samples - tbb)
        return self._r2r_over

    def _plan(self, K: float):
        """The composition's plan (:func:`~seekopt.design.accel_step.plan_seek`) under the dispatch rule
        (module notes, rule 2), or None: from :meth:`long_from_track` on any plan; below it, a plan whose
        predicted settle is within ``SETTLE_RATIO (T_bb + overhead - OVERHEAD_SPREAD)`` of the rest-to-rest
        design on the design plant AND over the set (its predicted worst against the reference's set
        overhead, :meth:`rest_to_rest_overhead`): a robust composition whose worst case arrives much later
        than a rest-to-rest design's would buy its speed with the drives the set stands for."""
        if abs(K) >= self.long_from_track():
            return self._plan_from(K, self.n_floor())
        plan = self._plan_from(K, COMPOSE_FROM_SAMPLES)
        if plan is None:
            return None
        from seekopt.design.profiles import t_bang_bang
        tbb = t_bang_bang(K, self.plant.k0, self.imax) * self.fs
        o_nom, o_set = self.rest_to_rest_overhead()
        ok = (plan[2] <= SETTLE_RATIO * (tbb + o_nom - OVERHEAD_SPREAD)
              and plan[3] <= SETTLE_RATIO * (tbb + o_set - OVERHEAD_SPREAD))
        return plan if ok else None

    def _plan_from(self, K: float, n_lo: int):
        """:func:`~seekopt.design.accel_step.plan_seek` of ``K`` tracks with at least ``n_lo`` samples at ``I0``,
        ``n`` capped at ``vmax``, within the composition's current limit."""
        return plan_seek(self.accel_step(), K, n_lo, self._n_vmax(), self.settle,
                         current_limit_a=self._composition_limit())

    def _n_vmax(self) -> float:
        v = self.spec.vmax_track_s
        return math.inf if v is None else v / self.fs / self.accel_step().accel_track

    # ------------------------------------------------------------------ seeks
    def needs_coast(self, tracks: float) -> bool:
        """True when a velocity limit is set and the seek is long enough to coast at it."""
        v = self.spec.vmax_track_s
        if v is None:
            return False
        a = self.plant.k0 * self.imax
        if abs(tracks) < 0.9 * v * v / a:          # cheap: far below the bang-bang peak velocity
            return False
        return abs(tracks) >= self.velocity_step(v).min_tracks

    def step_for(self, tracks: float) -> VelocityStep:
        """The fastest velocity step (at most ``vmax``, 3 % apart) with which ``tracks`` coasts."""
        K, v = abs(float(tracks)), self.spec.vmax_track_s
        if v is None:
            v = math.sqrt(K * self.plant.k0 * self.imax)
        st = self.velocity_step(v)
        if K >= st.min_tracks:
            return st
        v *= min(0.97, math.sqrt(K / st.min_tracks))    # min_tracks grows about as v^2
        for _ in range(200):
            st = self.velocity_step(v)
            if K >= st.min_tracks:
                return st
            v *= 0.97
        raise LongSeekError(f"no velocity step lets {K:g} tracks coast")

    def short_designer(self):
        if self._short is None:
            from seekopt.design.designer import SeekDesigner
            self._short = SeekDesigner(self.problem)
        return self._short

    def check_seek(self, tracks: float) -> float:
        """Reject at once (before any QP) a seek longer than the stroke, or one that neither coasts nor fits the
        rest-to-rest designer's horizon (:meth:`SeekDesigner.check_seek`).  Returns ``tracks`` as float."""
        K = float(tracks)
        if not math.isfinite(K) or K == 0:
            raise LongSeekError(f"tracks must be a non-zero number, not {tracks!r}")
        if self.spec.stroke_track is not None and abs(K) > self.spec.stroke_track:
            raise LongSeekError(f"seek of {K:g} tracks is longer than the stroke ({self.spec.stroke_track:g} tracks)")
        v = self.spec.vmax_track_s
        if abs(K) < self._long_lower_bound() and (
                v is None or abs(K) < 0.9 * v * v / (self.plant.k0 * self.imax)):
            self.short_designer().check_seek(K)      # only the rest-to-rest designer can take it
        return K

    def design(self, tracks: float):
        """Design the seek of ``tracks`` tracks -> :class:`seekopt.design.designer.DesignResult`.

        The dispatch rule of the module notes: a coast at ``vmax``: the velocity step at ``vmax`` and its
        mirror; else from :meth:`long_from_track` on: four copies of the acceleration step; else (or when no
        plan settles on every plant) the rest-to-rest designer, its rigid peak velocity checked against
        ``vmax``.  Every long seek is verified by simulation on the design plant.
        """
        from seekopt.design.designer import DesignError
        K = self.check_seek(tracks)
        t0 = time.process_time()
        vmax = self.spec.vmax_track_s
        on_set = len(self.plants) > 1        # rule 1 on a plant set: the acceleration step capped at vmax
        coast = not on_set and self.needs_coast(K)
        fresh = self._accel is None          # the step's QPs count for the design that builds it
        if not coast and self._is_long(K):
            plan = self._plan(K)
            if plan is not None:
                try:
                    return self._design_accel(K, *plan, t0=t0, fresh=fresh)
                except DesignError:
                    if on_set and self.needs_coast(K):
                        coast = True         # the velocity step to vmax, as on one plant
                    elif abs(K) >= self.long_from_track():
                        raise
                    # below long_from_track the rest-to-rest designer takes the seek (below)
        if on_set and not coast:
            coast = self.needs_coast(K)      # no plan (e.g. vmax below the step's floor): velocity step
        if not coast:
            res = self.short_designer().design(K)
            if vmax is None:
                return res
            vpk = rigid_peak_velocity(res.profile.current_a, self.plant.k0, self.fs)
            res.profile.meta["peak_rigid_velocity_track_s"] = vpk
            if vpk <= vmax * (1 + 1e-9):
                return res
            step = self.step_for(K)       # too fast and too short to coast at vmax: coast slower
        else:
            step = self.velocity_step(vmax)
        return self._design_velocity(K, step, t0)

    def design_velocity_step(self, tracks: float):
        """The seek of ``tracks`` from the velocity step to ``vmax`` and its mirror (rule 1 on one plant),
        whatever the dispatch; ``vmax`` must be set and the seek long enough to coast at it."""
        K = self.check_seek(tracks)
        if not self.needs_coast(K):
            raise LongSeekError(f"seek of {K:g} tracks does not coast at vmax (or no vmax is set)")
        return self._design_velocity(K, self.velocity_step(self.spec.vmax_track_s), time.process_time())

    def design_accel_step(self, tracks: float):
        """The seek of ``tracks`` from four acceleration steps (rule 2, ``n`` capped at ``vmax``, from
        ``n_floor`` samples at ``I0`` on), whatever the dispatch."""
        K = self.check_seek(tracks)
        t0, fresh = time.process_time(), self._accel is None
        plan = self._plan_from(K, self.n_floor())
        if plan is None:
            raise LongSeekError(f"no acceleration-step plan settles the seek of {K:g} tracks on every plant")
        return self._design_accel(K, *plan, t0=t0, fresh=fresh)
