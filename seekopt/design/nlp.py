"""Effect-aware seek design: minimum seek-settle time on a plant with effects, Ipopt over the full loop.

When the plant carries input or force effects (torque constant ``Kt(x)``, position bias, friction,
saturation; :mod:`identification.model.effects`), the closed loop is no longer a convolution and
the linear designer (:mod:`seekopt.design.designer`) designs for another drive.  The
:class:`EffectAwareDesigner` designs for the plant as it is:

1. the start track (:func:`seekopt.design.feasibility.resolve_start`; never outside the range the
   effects were fitted on) and the hold check at the target: when the drive's feedback cannot hold
   the band there whatever the feedforward (a friction limit cycle, run-out), :class:`DesignUnholdable`
   names the effect and the residual;
2. the linear design (QP, :class:`~seekopt.design.designer.SeekDesigner` on ``plant.linear_part()``, the
   same robust set), passed through the plant's input map and forces along its planned run
   (:func:`seekopt.design.feasibility.compensate`; redone at a lower current limit when the effects need
   current the limit does not leave): the warm start and the first seek length;
3. a search on the seek length ``N`` (secant steps on the NLP's worst residual, bisection; at most
   ``max_nlps`` NLPs once a feasible length is known) with the NLP of :mod:`seekopt.design.nlp_problem`
   at each length: the full closed loop on CasADi symbols, one NLP per size class called many times,
   Ipopt with the exact Hessian; the robust set as a smooth maximum of its first-order spread;
4. candidates played on the full plant (output effects aside: the hold check has them) from the start
   track by the one simulator (:func:`seekopt.design.feasibility.play_seek`); the first that settles by
   ``N`` within ``Imax`` is the design.

Ipopt failures, time-outs and designs that fail the full-plant check raise :class:`NLPDesignError`:
nothing is returned (or written) as a profile.
"""
from __future__ import annotations

import copy
import math
import time

import numpy as np

from identification.model.plant import ModalPlant

from seekopt.design import guard as _guard
from seekopt.design.designer import DesignResult, SeekDesigner
from seekopt.design.feasibility import (compensate, hold_check, hold_current, kt_scaled, nonlinear_effects,
                                        play_seek, resolve_start)
from seekopt.design.metrics import SeekMetrics
from seekopt.design.predict import set_loop_maps
from seekopt.design.nlp_result import DesignUnholdable, NLPDesignError, NLPDesignResult
from seekopt.design.nlp_search import _search_length, _verified_samples, _warm_for
from seekopt.design.nlp_problem import (BUILD_COUNT, NLPSettings, NLPSolve, RobustSpread, SeekNLP,
                                        close_sample, closed_loop_sample)
from seekopt.design.problem import SeekProblem
from seekopt.design.profiles import Profile

__all__ = ["NLPSettings", "NLPDesignError", "DesignUnholdable", "NLPSolve", "NLPDesignResult",
           "closed_loop_sample", "close_sample", "SeekNLP", "EffectAwareDesigner", "needs_nlp", "BUILD_COUNT"]


#: Ipopt statuses of a time-out (a length not shown feasible, the search moves on)
_TIMEOUTS = ("Maximum_WallTime_Exceeded", "Maximum_CpuTime_Exceeded")


class _Budget(Exception):
    """The NLP budget of one design is spent (a feasible length is known)."""


def needs_nlp(plant: ModalPlant) -> bool:
    """True when the plant has input or force effects (the linear design would ignore them)."""
    return bool(nonlinear_effects(plant))


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
    robust : Drift, RobustSpec or None
        The design's uncertainty (as :class:`~seekopt.design.problem.SeekProblem`): the linear warm
        start holds the band on its set, the NLP on the same set to first order around the full-plant
        trajectory (:class:`~seekopt.design.nlp_problem.RobustSpread`).
    settings : NLPSettings, optional
    family : list of ModalPlant, optional
        Further members of the drive's family (as ``SeekProblem.family``).
    """

    def __init__(self, plant: ModalPlant, controller, imax: float, settle: float = 0.1, robust=None,
                 settings: NLPSettings | None = None, family=None):
        self.plant, self.controller = plant, controller
        self.imax, self.settle = float(imax), float(settle)
        self.settings = settings or NLPSettings()
        self.fs, self.L = float(controller.sample_rate_hz), int(controller.fast_multiple)
        self.nlp_plant = plant.copy(effects=[e for e in plant.effects if e.kind != "output"])
        self.robust = robust
        # the current headroom: the drive's torque constant may differ from the plant's by kt_u (a fraction);
        # the NLP holds its current rows, the full-plant check Imax, on the plant with its gain scaled so
        std_k0 = float((plant.std or {}).get("k0") or 0.0)
        self.kt_u = max(self.settings.kt_uncertainty, 3.0 * std_k0 / plant.k0) if self.settings.kt_uncertainty > 0 else 0.0
        self.kt_plants = [kt_scaled(self.nlp_plant, 1.0 + s * self.kt_u) for s in (-1.0, 1.0)] if self.kt_u > 0 else []
        tail = {} if self.settings.tail_s is None else {"tail_s": self.settings.tail_s}
        self.problem = SeekProblem(plant.linear_part(), controller, imax, settle,
                                   band_margin=self.settings.band_margin,
                                   current_margin=self.settings.current_margin, robust=robust,
                                   family=[f.linear_part() for f in (family or [])], **tail)
        self.linear = SeekDesigner(self.problem)
        self.sizes = self.problem.solver.size_classes
        # band rows after the seek: the linear designer's horizon (one rule, SeekProblem.band_tail_samples);
        # the full-plant acceptance holds the rows' margin over the same samples
        self.tail = self.accept_tail = self.linear.tail
        # the feedforward and reference may run input_tail samples past the settle sample (the linear designer's
        # rule, SeekProblem.input_tail_s): an NLP of n samples settles by n, at rest from n + tin
        self.tin = int(self.linear.input_tail)
        self._nlps: dict = {}
        self._spreads: dict = {}
        self._derated: dict = {}
        self.kt_peak_a = math.nan

    def _set_maps(self, c: int) -> list:
        """The robust set's closed-loop maps for the size class ``c``: the linear designer's
        (:meth:`SeekDesigner._loop_maps`, each plant with its drive's feedforward calibration), long
        enough for the NLP's horizon and tail and the linear designer's guard horizon."""
        need = max(c + 2 * self.tail + 1, c + self.linear.tail + 1)
        return self.linear._loop_maps(need)

    def _nlp(self, n: int):
        """``(SeekNLP, RobustSpread or None)`` of the size class of ``n`` samples (built on first use)."""
        c = next((c for c in self.sizes if c >= n + self.tin), None)   # the input runs input_tail samples more
        if c is None or c > self.settings.max_samples:
            raise NLPDesignError(f"seek of {n} samples is longer than the largest NLP "
                                 f"({self.settings.max_samples} samples)")
        if c not in self._nlps:
            maps = self._set_maps(c)
            # the torque-constant headroom: current rows only, on the linear loop with the gain scaled
            kt_maps = set_loop_maps([p.linear_part() for p in self.kt_plants], self.controller, maps[0].horizon) \
                if self.kt_plants else []
            if len(self.linear.plants) > 1 or kt_maps:
                # the shortest seek of this class settles at prev - tin + 1 (the class holds n + tin): the set's
                # band rows start there, not after the previous class's input length (that left up to tin
                # samples after such a seek without robust rows; the Kt drive's robust K = 200 from track 12000:
                # 5.28 -> 1.98 band at 45 samples, 2.35 band at 58 from the gap)
                prev = max([k for k in self.sizes if k < c], default=0) - self.tin
                self._spreads[c] = RobustSpread(maps + kt_maps, c, c + self.tail, self.settle, nmax_prev=max(prev, 0),
                                                stride=self.linear._stride(c), current_only=len(kt_maps))
            # the linear designer's unmodelled-mode guard: same bands, rows and horizon, on the nominal
            # linear loop
            guard, Hq = None, c + self.linear.tail
            rows = _guard.design_guard_rows(self.linear.guard_bands, self.plant.k0, self.fs, c, Hq, maps[0],
                                            curve=self.linear.guard_curve)
            if rows is not None:
                Tiu, Tir, sir = maps[0].current_rows(Hq, c)
                G = rows[0]
                guard = (np.hstack([G @ Tiu, G @ Tir]) / self.settle, G @ sir / self.settle)
            self._nlps[c] = SeekNLP(self.nlp_plant, self.controller, c, self.tail, self.settle, self.settings,
                                    spread=self._spreads.get(c), guard=guard, guard_tol=self.problem.hf_tol)
        return self._nlps[c], self._spreads.get(c)

    def design(self, tracks: float, start_track: float | None = None, progress=None,
               linear: DesignResult | None = None) -> NLPDesignResult:
        """Design the seek of ``tracks`` (signed) from ``start_track`` (default: middle of the fitted range).

        Raises :class:`~seekopt.design.feasibility.StartError` (start/end outside the fitted range),
        :class:`DesignUnholdable` (the loop cannot hold the band at the target), and
        :class:`NLPDesignError` (Ipopt failed / timed out / no design passed the full-plant check).
        ``linear``: the linear design of this seek if already made (warm start).
        """
        say = progress or (lambda msg: None)
        K = float(tracks)
        if not math.isfinite(K) or K == 0:
            raise ValueError(f"tracks must be a non-zero number, not {tracks!r}")
        T0 = resolve_start(self.plant, K, start_track)
        hc = hold_check(self.plant, self.controller, T0 + K, self.settle)
        if not hc.holds:
            raise DesignUnholdable(hc.message())
        t_begin = time.process_time()
        st = self.settings
        say(f"linear design (QP) for {K:g} tracks")
        lin = self.linear.design(K) if linear is None else linear
        # checks on the plant the NLP designs for: output effects (run-out) are the spindle's phase, not
        # the seek's, and no feedforward removes them (the hold check above includes them)
        lin_m, n_lin, _ = self._accept(lin.profile, K, T0)
        warm, comp, (g_w, o_w) = self._warm_start(K, T0, lin, say)
        dt = 1.0 / (self.fs * self.L)
        uh = hold_current(self.nlp_plant, T0, dt)
        dp = self.nlp_plant.discretize(dt)
        dp.reset(T0, 0.0, current=uh)
        x0 = np.r_[dp.x, dp.hist, np.zeros(self.controller.n_states)]
        # the search starts at the length the warm start was solved for: the one its whole set holds the band
        # from (set_settle_samples; its input runs input_tail samples more).  A robust design's nominal may
        # settle sooner (settle_samples): squeezed to that, the warm start of the Kt drive's robust K = 200
        # from track 12000 (nominal 45, set 46 samples) started the NLP 9.7 band off and it stopped at 1.98 band
        tin = self.tin
        n0 = max(int(warm.set_settle_samples), int(warm.settle_samples))
        # the whole warm start: the linear design's input runs input_tail samples past its settle sample (its
        # band rows hold from n0); cut at n0 (the former rule) it lost the end of the deceleration (up to
        # 0.17 A over 8 samples on the combination drive's K = 200): 4.7 band of guard residual, and the NLPs
        # started from it at other lengths stopped at residuals that rose with the length
        m_w = int(warm.profile.seek_samples)
        v_w, q_w = comp.current_a[:m_w] / self.imax, (warm.profile.reference_track[:m_w] - K) / abs(K)
        g_w, o_w = g_w[:m_w], o_w[:m_w]
        solves: list = []
        imaps: dict = {}                 # the guard's input map (gain, offset) each length's NLP used
        cache: dict = {}

        def feasible(n, checking=False):
            # ``max_nlps`` bounds the length search; the full-plant check's step-up (at most ``check_steps``
            # lengths above the search's answer) solves its own NLPs: a budget spent by the search must not
            # leave the step-up without candidates
            if n in cache:
                return cache[n][0]
            if time.process_time() - t_begin > st.design_cpu_s:
                raise NLPDesignError(f"design of {K:g} tracks from track {T0:g} ran out of time "
                                     f"({st.design_cpu_s:g} s CPU, {len(solves)} NLPs)")
            if not checking and len(solves) >= st.max_nlps and any(ok for ok, *_ in cache.values()):
                raise _Budget()
            nlp, spread = self._nlp(n)
            v0, q0, imap = _warm_for(n, nlp.N, tin, cache, imaps, (n0, v_w, q_w, (g_w, o_w)))
            imaps[n] = imap
            rec, v, q = nlp.solve(K, T0, n, self.imax, uh, x0, v0, q0, st.band_margin, st.current_margin, input_tail=tin,
                                  input_map=imap)
            solves.append(rec)
            # an Ipopt failure or time-out at one length shows nothing about it: that length is not shown
            # feasible (never a profile: its iterate is dropped) and the search moves on
            if rec.success and spread is not None:      # the whole set on every sample, first order
                _, e, i = nlp.rollout(x0, v, q, K, T0, self.imax, uh)
                dE, _ = spread.spread(v, q, K, self.imax)
                rec.residual = max(rec.residual, float(np.max(np.abs(e[n:] + np.vstack([0 * e, dE])[:, n:]))))
            say(f"  NLP N={n}: {rec.status}, {rec.iterations} it, {rec.wall_s:.2f} s ({rec.cpu_s:.2f} s CPU), residual {rec.residual:.3g} band, "
                f"current slack {rec.slack:.2g}, guard excess {rec.guard_excess:.2g} band")
            good = rec.success and rec.residual <= st.band_margin * (1 + 1e-6) and rec.slack <= st.slack_tol
            res = rec.residual if rec.slack <= st.slack_tol else max(rec.residual, st.band_margin * (1 + rec.slack))
            cache[n] = (good, v[:n + tin], q[:n + tin], res)
            return good

        # the linear design, accepted on the full plant by the same rule (_accept: the length from which it
        # holds the rows' margin), is a verified design too: the NLP searches only for shorter seeks, and when
        # it finds none the linear design is the answer (never a worse one)
        n_cap = st.max_samples if n_lin is None else min(st.max_samples, n_lin - 1)
        if n_cap < 1:
            return self._linear_result(lin, lin_m, K, T0, n_lin, solves, say)
        try:
            lo, hi = _search_length(feasible, lambda n: cache[n][3], min(n0, n_cap), st.band_margin, n_cap)
        except _Budget:
            hi = min(m for m, (ok, *_ ) in cache.items() if ok)
        if hi is None:
            if n_lin is not None:
                return self._linear_result(lin, lin_m, K, T0, n_lin, solves, say)
            late = sum(s.status in _TIMEOUTS for s in solves)
            raise NLPDesignError(f"no effect-aware design of {K:g} tracks from track {T0:g} within "
                                 f"{st.max_samples} samples ({len(solves)} NLPs"
                                 + (f", {late} timed out at {st.nlp_cpu_s:g} s CPU" if late else "")
                                 + f"; last: {solves[-1].status if solves else 'no NLP'})")
        # verify on the full plant; step up on failure
        tried = 0
        for n in sorted(m for m, (ok, *_ ) in cache.items() if ok and hi <= m <= n_cap) + \
                list(range(hi + 1, min(hi + st.check_steps, n_cap) + 1)):
            if tried >= st.check_steps:
                break
            if not feasible(n, checking=True):
                continue
            tried += 1
            _, v, q, _ = cache[n]
            prof = self._profile(v, q, K, T0, n, lin, solves)
            m, n_ok, held = self._accept(prof, K, T0, n)
            if n_ok == n:
                rec = next(s for s in reversed(solves) if s.n_seek == n)
                prof.meta.update(guard_excess_band=round(rec.guard_excess, 4),
                                 warm_start_imax_a=round(warm.profile.imax_a, 5),
                                 peak_current_kt_a=round(self.kt_peak_a, 5))
                prof.meta.update(design_status="verified", design_path="nlp", ipopt_iterations=sum(s.iterations for s in solves),
                                 ipopt_time_s=round(sum(s.wall_s for s in solves), 3),
                         ipopt_cpu_s=round(sum(s.cpu_s for s in solves), 3), n_nlp=len(solves))
                return NLPDesignResult(prof, m, T0, n, solves, lin, lin_m,
                                       sum(p.build_time_s for p in self._nlps.values()))
            say(f"  N={n}: full-plant check failed (settle {m.settle_time_s * 1e3:.3f} ms, "
                f"peak {m.peak_current_a:.4g} A ({self.kt_peak_a:.4g} A at Kt x(1 +- {self.kt_u:g})), peak |PES| "
                f"{held:.3g} band over the {self.accept_tail} samples after the seek, margin {st.band_margin:g})")
        if n_lin is not None:
            return self._linear_result(lin, lin_m, K, T0, n_lin, solves, say)
        raise NLPDesignError(f"no effect-aware design of {K:g} tracks from track {T0:g} passed the full-plant "
                             f"check ({tried} candidates from {hi} samples)")

    def _accept(self, prof: Profile, K: float, T0: float, n: int | None = None):
        """The one acceptance rule of a design (an NLP candidate or the linear fallback): played on the full
        plant (output effects aside) from ``T0`` by the one simulator, it is accepted at the length ``n``
        [samples] when its total current stays within Imax, it settles by ``n + 1`` samples and its ``|PES|``
        stays within the margin its band rows promise (``band_margin`` band) over the samples those rows
        cover, ``n .. n + accept_tail`` (:meth:`SeekProblem.band_tail_samples`) -- not merely the band.

        ``n`` given: ``(metrics, n or None, worst |PES| [band] over that window)``; ``n`` None: the shortest
        length at which the design is accepted (None if none within the play), for the linear fallback."""
        st, tail = self.settings, self.accept_tail
        horizon = max(st.check_tail_s, (tail + 2) / self.fs) if n is not None else st.check_tail_s + (tail + 2) / self.fs
        m, sim = play_seek(self.nlp_plant, self.controller, prof, T0, settle=self.settle, horizon_s=horizon)
        pes = np.abs(np.asarray(sim.true_position_track, float) - (T0 + K)) / self.settle
        ns = _verified_samples(m, self.fs, self.imax)
        if ns is None or not self._within_imax_on_kt(prof, T0):
            return m, None, math.inf
        last = len(pes) - tail - 1                 # the last length whose whole window was played
        lengths = [int(n)] if n is not None else range(max(ns - 1, 1), last + 1)
        held = math.inf
        for k in lengths:
            held = float(np.max(pes[k:k + tail + 1])) if k <= last else math.inf
            if k >= ns - 1 and held <= st.band_margin * (1 + 1e-6):
                return m, k, held
        return m, None, held

    def _within_imax_on_kt(self, prof: Profile, T0: float) -> bool:
        """The current headroom's check: ``prof`` played from ``T0`` on the design plant with its torque constant
        ``1 +- kt_u`` times the plant's (:func:`~seekopt.design.feasibility.kt_scaled`) stays within Imax on
        every sub-step; the worst peak [A] is kept in ``self.kt_peak_a`` (for the profile's metadata)."""
        peaks = [play_seek(p, self.controller, prof, T0, settle=self.settle, horizon_s=0.004)[0].peak_current_a
                 for p in self.kt_plants]
        self.kt_peak_a = max(peaks, default=math.nan)
        return all(pk <= self.imax * (1 + 1e-9) for pk in peaks)

    def _linear_result(self, lin: DesignResult, lin_m: SeekMetrics, K, T0, n_lin: int, solves, say):
        """The linear (QP) design as the answer: accepted on the full plant from ``T0`` by the rule every NLP
        design meets (:meth:`_accept`: within Imax, settled by ``n_lin + 1`` samples, the band margin held over
        the band rows' samples after ``n_lin``) and no effect-aware design was accepted sooner."""
        say(f"  no effect-aware design accepted before the linear design ({n_lin} samples on the full plant, "
            "band margin held): the linear design is the answer")
        prof = copy.deepcopy(lin.profile)
        prof.meta.update(start_track=T0, direction="outward" if K > 0 else "inward", design_status="verified",
                         design_path="linear (no effect-aware design settled sooner)",
                         effects_in_design="none", kt_uncertainty=round(self.kt_u, 6), design_settle_samples=n_lin, ipopt_iterations=sum(s.iterations for s in solves),
                         ipopt_time_s=round(sum(s.wall_s for s in solves), 3),
                         ipopt_cpu_s=round(sum(s.cpu_s for s in solves), 3), n_nlp=len(solves))
        return NLPDesignResult(prof, lin_m, T0, n_lin, solves, lin, lin_m,
                               sum(p.build_time_s for p in self._nlps.values()))

    def _warm_start(self, K, T0, lin, say):
        """``(DesignResult, compensated Profile, (gain, offset))``: the linear design whose feedforward, passed through
        the plant's input map and forces along its planned run (:func:`compensate`), stays within
        ``current_margin * Imax``; when it does not (a torque constant below 1, a bias the hold must
        carry), the linear design is redone for a lower current limit (cached per 1 % of Imax).
        ``(gain, offset)``: the input map along the plan (:func:`compensate`), for the NLP's guard."""
        limit = self.settings.current_margin * self.imax
        comp, peak, imap = compensate(self.nlp_plant, self.controller, lin.profile, T0, input_gain=True)
        for _ in range(3):
            if peak <= limit * (1 + 1e-6):
                return lin, comp, imap
            frac = math.floor(100.0 * lin.profile.imax_a / self.imax * limit / peak) / 100.0
            if frac < 0.3:
                break
            if frac not in self._derated:
                self._derated[frac] = SeekDesigner(SeekProblem(
                    self.plant.linear_part(), self.controller, frac * self.imax, self.settle,
                    band_margin=self.settings.band_margin, current_margin=self.settings.current_margin,
                    robust=self.robust, family=self.problem.family))
            say(f"linear design for {K:g} tracks at {frac:.2f} Imax (the effects need the rest)")
            lin = self._derated[frac].design(K)
            comp, peak, imap = compensate(self.nlp_plant, self.controller, lin.profile, T0, input_gain=True)
        return lin, comp, imap

    def _profile(self, v, q, K, T0, n, lin: DesignResult, solves) -> Profile:
        u = self.imax * np.asarray(v[:n + self.tin], float)      # input_tail samples past the settle sample
        r = K + abs(K) * np.asarray(q[:n + self.tin], float)
        meta = {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
                "design_objective": "min_settle/nlp", "solver": "ipopt", "reference": "free",
                "start_track": T0, "direction": "outward" if K > 0 else "inward",
                "effects_in_design": ";".join(e.name for e in self.nlp_plant.effects) or "none",
                "robust_warm_start": self.linear.robust.to_string() if self.linear.robust else "none",
                "band_margin": self.settings.band_margin, "current_margin": self.settings.current_margin,
                "kt_uncertainty": round(self.kt_u, 6),
                "design_settle_samples": n, "linear_settle_samples": lin.settle_samples}
        out = [e.name for e in self.plant.effects if e.kind == "output"]
        if out:
            meta["effects_not_in_design"] = ";".join(out)
        return Profile(np.r_[u, 0.0], np.r_[r, K], self.fs, K, self.imax, self.settle, "optimal-nlp", len(u), meta)
