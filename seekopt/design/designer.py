"""Optimal seek-profile design: a designer built once from a :class:`SeekProblem`, called per length.

Problem (linear plant, one seek of ``K`` tracks, servo rate ``fs``, ``N`` seek samples)::

    find  u_ff(0..N-1) [A], r(0..N-1) [track]       (r = K and u_ff = 0 from N on)
    s.t.  |y_i(k) - K| <= beta * band     for k >= N_s, every plant i of the robust set
          |i_i(k, l)|  <= gamma * Imax    total current (feedforward + feedback + hold), all sub-steps
          |z_hf(f)|    <= hf_tol * band   residual of unmodelled modes, f in [0.45, 0.65] fs
          M u_ff = [K, 0]                 ZOH rigid model at rest at K (profiles.rigid_endpoint_matrix)
          |u_ff(k) - u_ff(k-1)| <= slew/fs   (optional)

``y_i`` and ``i_i`` are convolutions of ``u_ff`` and ``r`` with the closed-loop impulse responses of
plant ``i`` under the drive's controller (:class:`seekopt.design.qp.LoopMaps`, from the one
simulator).  Objectives:

(a) ``design(K, seek_samples=N)``: minimum residual vibration after the seek (``N_s = N``): the
    worst ``|PES|`` over the robust set (epigraph ``t``, ``objective="worst"``) or over the nominal
    plant with the tail energy averaged over the set (``objective="mean"``);
(b) ``design(K)``: minimum seek-settle time: bisection over ``N_s = N`` (feasibility is monotone in
    ``N``) with the band constraint, on the sample grid.

Solver statuses are classified (:mod:`seekopt.design.solvers`): only a solver's proof makes a length
infeasible; numerical trouble is retried with the fallback solvers first, and a length that no
solver decides is skipped like an infeasible one (the search moves on) and counted in
:attr:`DesignResult.unresolved_solves`.

The design sees the plant's *linear part*: nonlinear effects (friction, saturation, position bias)
are not modelled by the optimiser; every design is re-checked on the full plant by
:func:`seekopt.drive.simulator.simulate_2dof` and a design that fails the check is never returned.
"""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

from identification.model.plant import ModalPlant

from seekopt.design import blind_pes as _blind, guard as _guard, qp as _qp
from seekopt.design.blas import blas_limit
from seekopt.design.guard_bands import plant_gain_curve, problem_bands
from seekopt.design.predict import feedforward_scale, set_loop_maps
from seekopt.design.metrics import DEFAULT_TAIL_S
from seekopt.design.problem import ProblemError, SeekProblem, check_closed_loop
from seekopt.design.profiles import reference_from_model, t_bang_bang
from seekopt.design.result import DesignError, DesignInfeasible, DesignResult, SolveStats
from seekopt.design.settle_search import SettleSearch
from seekopt.design.solvers import DAQP_PKG, PIQP, SolverChain
from seekopt.design.verification import packaged_design, played_design, verified_design
from seekopt.design.working_set import WorkingSetQP

__all__ = ["DesignInfeasible", "DesignError", "DesignResult", "SeekDesigner", "design_seek"]


#: A design on one plant solves its structures whole below this many rows even with
#: ``SolverSettings.working_set``: a nominal QP (400-1400 rows) solves in one daqp call faster than in
#: working-set rounds (studies/design_speed.py: nominal median 0.74x of 37b8cdb's CPU with the working set
#: on every structure); designs over a plant set always use it (22 plants: 5000-11000 rows, 2-3x less
#: CPU; a 3-plant drift set at K = 1000: 3 s against 12.7 s CPU, where daqp failed on the whole QP and the
#: fallback solver took 11 s).
WORKING_SET_MIN_ROWS = 2500

#: Samples of closed-loop response computed beyond the first structure's need: the size classes up to
#: 128 samples then share the first map set (a rebuild re-simulates every plant of the set, ~0.4 s for
#: 22 plants, where the headroom costs ~0.07 s once; the responses' first samples are the same).
MAP_HEADROOM = 128


class SeekDesigner(SettleSearch):
    """Seek designer for one :class:`SeekProblem`; build once, design many times.

    ``SeekDesigner(problem)``; the former keyword form ``SeekDesigner(plant, controller, imax, settle,
    robust, **options)`` builds the problem with :meth:`SeekProblem.from_options`.  The designer holds
    what it builds (closed-loop maps, one QP structure and solver chain per seek-size class); the
    counters ``builds`` (QP structures), ``map_builds`` (closed-loop map sets) and
    ``solver_builds`` (solvers per name) show the reuse.

    Raises :class:`seekopt.design.problem.ProblemError` at once when the closed loop of a plant of the
    set under the controller is unstable.
    """

    def __init__(self, problem, *args, **options):
        if not isinstance(problem, SeekProblem):
            problem = SeekProblem.from_options(problem, *args, **options)
        elif args or options:
            raise TypeError("SeekDesigner(problem) takes no further arguments")
        self.problem = p = problem
        self.plant, self.controller = p.plant, p.controller
        self.imax, self.settle = p.imax_a, p.settle_band_track
        self.robust = p.robust
        self.fs = p.sample_rate_hz
        self.L = int(p.controller.fast_multiple)
        self.tail = p.band_tail_samples()
        self.reference = p.reference
        self.settings = p.solver
        self.solver_name = p.solver.qp_solver
        self.beta, self.gamma = p.band_margin, p.current_margin
        self.hf_guard, self.hf_gain, self.hf_tol = p.hf_guard, p.hf_gain, p.hf_tol
        self.guard_bands = problem_bands(p)     # Nyquist, controller notches, blind bands
        self.guard_curve = plant_gain_curve(p.plant)   # what the identification could have seen
        self.slew = p.slew_a_per_s
        # minimum seek-settle designs: the inputs may go on this many samples after the settle sample
        # (objective (a) and the shortest-feasible probe keep the seek length they are given)
        self.input_tail = max(int(round(p.input_tail_s * self.fs)), 0)
        self.check_robust = p.check_robust
        self.max_samples = int(p.solver.max_samples)
        self.thin_above, self.thin_stride = p.solver.thin_above_samples, p.solver.thin_stride
        self.plants = p.plants()
        for i, plant in enumerate(self.plants):        # before anything is built
            try:
                check_closed_loop(plant, self.controller)
            except ProblemError as exc:
                what = "design plant" if i == 0 else f"robust-set plant {i}"
                raise ProblemError(f"{what}: {exc}") from None
        self.objective_kind = self.robust.objective if self.robust else "worst"
        self.ignored_effects = [e.name for e in p.plant.effects if e.kind != "structural"]
        self._maps, self._maps_h = None, 0
        self._bpes, self._bpes_h = [], 0      # blind-band mode's PES maps (_blind_pes)
        self._qps: dict = {}
        self._ws: dict = {}             # working-set solver per structure
        self._history: dict = {}        # n_rigid -> designed settle samples (predicts the next length)
        self.check_tail = int(round(DEFAULT_TAIL_S * self.fs)) + 2   # samples the simulator check adds
        self.builds, self.map_builds = 0, 0
        self.solver_builds: Counter = Counter()

    @classmethod
    def from_problem(cls, problem: SeekProblem) -> "SeekDesigner":
        return cls(problem)

    # ------------------------------------------------------------------ structures
    def _loop_maps(self, horizon: int) -> list:
        """The set's closed-loop maps (:func:`~seekopt.design.predict.set_loop_maps`: a plant whose gain
        differs plays the profile through its drive's gain calibration), at least ``horizon`` samples
        long (kept; grown by doubling).  The effect-aware designer's robust set reads the same maps."""
        if self._maps is None or self._maps_h < horizon:
            h = max(horizon, 2 * self._maps_h)
            self._maps = set_loop_maps(self.plants, self.controller, h)
            self._maps_h = h
            self.map_builds += 1
        return self._maps

    def _blind_pes(self, horizon: int) -> list:
        """The blind-band mode's PES maps (:func:`seekopt.design.blind_pes.blind_pes_maps`) of the design
        plant, ``horizon`` samples long (kept with the loop maps' horizon)."""
        if self._bpes_h < horizon:
            f, g = _blind.blind_pes_freqs(self.guard_bands, self.problem.blind_pes_points)
            m0, base = (self._maps or [None])[0], None
            if (m0 is not None and m0.horizon >= horizon and feedforward_scale(self.plants[0]) == 1.0
                    and self.plants[0].hash() == self.plant.hash()):     # the design plant's own loop, already simulated
                base = {"y_uff": m0.y_u, "y_r": m0.y_r, "u_sub_uff": m0.i_u, "u_sub_r": m0.i_r}
            self._bpes = _blind.blind_pes_maps(self.plant, self.controller, horizon, f, g, base=base)
            self._bpes_h = horizon
        return self._bpes

    def _count_solver(self, name: str) -> None:
        self.solver_builds[name] += 1

    def _structure(self, nmax: int, epigraph: bool) -> _qp.SeekQP:
        key = (nmax, epigraph)
        if key not in self._qps:
            H = nmax + self.tail
            need = nmax + max(self.tail, self.check_tail)     # long enough for the checks too
            maps = self._loop_maps(need + (MAP_HEADROOM if self._maps is None else 0))
            R = None
            if self.reference != "free":
                imp = np.zeros(H); imp[0] = 1.0
                hm = reference_from_model(self._reference_model(), imp, self.fs, H)
                R = _qp.toeplitz_rows(hm, np.arange(H), H)
            in_tail = 0 if epigraph else self.input_tail
            # the grid follows the inputs' length: their spectrum's lobes are fs / (nmax + in_tail) wide
            hf = _guard.design_guard_rows(self.guard_bands, self.plant.k0, self.fs, nmax + in_tail, H, maps[0],
                                          curve=self.guard_curve)
            band_plants = range(len(self.plants)) if self.objective_kind == "worst" else [0]
            bpes_tol = self.problem.blind_pes_bound()
            bpes = self._blind_pes(self._maps_h) if bpes_tol is not None and not epigraph else None
            s = self.settings
            self._qps[key] = _qp.SeekQP(
                maps, nmax, H, self.imax, self.settle, self.fs, band_plants,
                lambda n, m: SolverChain(n, m, s.chain, s.options, builds=self._count_solver),
                epigraph=epigraph, R=R, hf=hf, slew=self.slew, stride=self._stride(nmax),
                input_tail=in_tail, bpes=bpes, bpes_tol=bpes_tol if bpes else None,
                bpes_plants=_blind.blind_pes_plants(self.plants))
            self.builds += 1
        return self._qps[key]

    def _reference_model(self) -> ModalPlant:
        return self.plant if self.reference == "model" else ModalPlant(k0=self.plant.k0,
                                                                      delay_s=self.plant.total_delay_s)

    def _stride(self, nmax: int) -> int:
        """Row stride of the non-nominal plants' band rows (1: every sample)."""
        return 1 if nmax <= self.thin_above else self.thin_stride

    def _classes(self, n_from: int):
        return [c for c in self.settings.size_classes if n_from <= c <= self.max_samples] or [self.max_samples]

    # ------------------------------------------------------------------ solving
    def _working_set(self, qp: _qp.SeekQP) -> WorkingSetQP:
        if qp not in self._ws:
            s = self.settings
            # daqp's own phase-1 proof first on sets of up to 3 plants (WorkingSetQP's phase1_first: measured
            # cheaper there, also warm; slower on 22-plant sets)
            self._ws[qp] = WorkingSetQP(qp, lambda n, m: SolverChain(n, m, s.chain, s.options,
                                                                     builds=self._count_solver),
                                        pad=s.qp_solver != DAQP_PKG,
                                        phase1_first=len(self.plants) <= 3 and s.chain[1:2] != (PIQP,))
        return self._ws[qp]

    def _solve(self, qp: _qp.SeekQP, K, n, beta, stats: SolveStats, warm=None, epigraph=False, confirm=True,
               nominal_from=None, second_opinion=False):
        hf_tol = self.hf_tol if self.guard_bands else None
        args = (K, n, None if epigraph else beta, self.gamma, hf_tol, self.slew, nominal_from)
        tol = self.settings.violation_tol
        bounds = qp.bounds(*args)

        def check(x, A=None):       # never trust a status alone: re-check the answer against the data
            viol = qp.violation(x, K, *bounds[1:], A=A)
            return f"constraint violation {viol:.2g}" if viol > tol else ""
        if self.settings.working_set:     # rows screened on a plant set and big structures, else all rows
            screen = len(self.plants) > 1 or qp.m >= WORKING_SET_MIN_ROWS
            sol = self._working_set(qp).solve(*args[:-1], x0=warm, check=check, confirm=confirm, screen=screen,
                                              nominal_from=nominal_from, second_opinion=second_opinion)
            if getattr(sol, "unconfirmed", False):
                stats.unconfirmed.add((id(qp), n))
        else:
            sol = qp.solver.solve(*qp.numeric(*args), x0=warm, check=check)
        stats.add(n, sol)
        return sol

    def check_seek(self, tracks: float) -> float:
        """Reject at once (before any QP is built) a seek no design can meet: non-finite or zero
        ``tracks``, a rigid-body bang-bang time ``T_bb`` beyond the longest design horizon, or a
        holding current above the design current limit.  Returns ``tracks`` as float."""
        K = float(tracks)
        if not math.isfinite(K) or K == 0:
            raise ProblemError(f"tracks must be a non-zero number, not {tracks!r}")
        tbb = t_bang_bang(K, self.plant.k0, self.imax)
        if tbb * self.fs > self.max_samples:
            raise DesignInfeasible(
                f"seek of {K:g} tracks at Imax {self.imax:g} A needs at least T_bb = {tbb * 1e3:.4g} ms = "
                f"{tbb * self.fs:.1f} samples, beyond the longest design horizon of {self.max_samples} samples "
                f"({self.max_samples / self.fs * 1e3:.4g} ms): raise Imax or the horizon (SolverSettings.max_samples)")
        if abs(self.plant.bias_a) >= self.gamma * self.imax:
            raise DesignInfeasible(f"holding current {abs(self.plant.bias_a):g} A (plant bias) leaves no current "
                                   f"within {self.gamma:g} x Imax = {self.gamma * self.imax:g} A")
        return K

    def shortest_feasible(self, tracks: float) -> int:
        """Fewest seek samples for which currents, guard and rest-to-rest can be met (no band);
        -1 when none within the horizon (lengths no solver decides count as not feasible)."""
        K = self.check_seek(tracks)
        with self._blas():
            return self._shortest_feasible(K)

    def _shortest_feasible(self, K: float) -> int:
        stats = SolveStats(self.solver_name)
        epi = True          # the structure objective (a) uses
        lo = max(int(math.floor(t_bang_bang(K, self.plant.k0, self.imax) * self.fs)) - 1, 0)
        for c in self._classes(lo + 1):
            qp = self._structure(c, epi)
            if self._solve(qp, K, c, None, stats, epigraph=epi).success:
                hi = c
                break
        else:
            return -1
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if self._solve(qp, K, mid, None, stats, epigraph=epi).success:
                hi = mid
            else:
                lo = mid
        return hi

    def _infeasible(self, K, n_req) -> DesignInfeasible:
        tbb = t_bang_bang(K, self.plant.k0, self.imax)
        n = self._shortest_feasible(K)
        what = (f"shortest feasible seek time is {n} samples ({n / self.fs * 1e3:.4g} ms)" if n > 0 else
                f"no feasible seek within {self.max_samples} samples")
        return DesignInfeasible(f"seek of {K:g} tracks in {n_req} samples ({n_req / self.fs * 1e3:.4g} ms) "
                                f"cannot be met at Imax {self.imax:g} A: {what}; "
                                f"T_bb = {tbb * 1e3:.4g} ms = {tbb * self.fs:.2f} samples")

    def _failed(self, K, what, stats: SolveStats) -> DesignError:
        return DesignError(f"QP solvers {'/'.join(self.settings.chain)} failed without proof for {K:g} tracks "
                           f"{what}: {stats.why()}")

    def _blas(self):
        """BLAS thread limit for a design (:attr:`SolverSettings.blas_threads`)."""
        return blas_limit(self.settings.blas_threads)

    def design(self, tracks: float, seek_samples: int | None = None) -> DesignResult:
        """Design the seek of ``tracks`` tracks.

        ``seek_samples=None``: minimum seek-settle time (objective (b)); an integer: minimum residual
        vibration for that seek length (objective (a)).  Raises :class:`DesignInfeasible` when the
        request cannot be met and :class:`DesignError` when no verified design is found.  Runs with
        at most :attr:`SolverSettings.blas_threads` BLAS threads.
        """
        K = self.check_seek(tracks)
        with self._blas():
            return self._design(K, seek_samples)

    def _design(self, K: float, seek_samples: int | None) -> DesignResult:
        stats = SolveStats(self.solver_name)
        n_rigid = int(math.ceil(t_bang_bang(K, self.plant.k0, self.imax) * self.fs - 1e-9))
        if seek_samples is not None:
            N = int(seek_samples)
            if N < max(n_rigid - 1, 1) or N > self.max_samples:
                raise self._infeasible(K, N)
            epi = True      # residual epigraph over the band plants (all: worst; nominal: mean)
            qp = self._structure(self._classes(N)[0], epi)
            sol = self._solve(qp, K, N, None, stats, epigraph=epi)
            if not sol.success:
                if sol.infeasible:
                    n_min = self._shortest_feasible(K)
                    if n_min < 0 or N < n_min:
                        raise self._infeasible(K, N)
                raise self._failed(K, f"in {N} samples", stats)
            return self._finish(qp, sol, K, N, stats, f"min_residual/{self.objective_kind}", strict=False)
        # (b) minimum seek-settle time: size class whose longest seek settles, then bisection
        lo = max(n_rigid - 2, 0)
        # long seeks settle no sooner than 1.25 T_bb (measured 1.37-1.58 for K = 1000-10000): skip the
        # hopeless big classes below that (lo stays at T_bb, so the bisection still covers them)
        first = max(n_rigid, 1) if n_rigid <= self.thin_above else int(math.ceil(1.25 * n_rigid))
        found = self._predicted_search(K, n_rigid, first, lo, stats)
        if found is not None:
            qp, c, hi, best = found
            return self._verify(qp, c, hi, best, K, stats, n_rigid)
        for c in self._classes(first):
            qp = self._structure(c, False)
            sol = self._solve(qp, K, c, self.beta, stats)
            if sol.success:
                break
            if sol.infeasible:      # proven: every shorter seek is infeasible too
                lo = max(lo, c)
            # no proof: move on to the next class, the bisection below covers this length again
        else:
            if stats.unresolved:
                raise self._failed(K, f"within {self.max_samples} samples", stats)
            tbb = t_bang_bang(K, self.plant.k0, self.imax)
            raise DesignInfeasible(f"seek of {K:g} tracks cannot settle within {self.max_samples} samples "
                                   f"at Imax {self.imax:g} A (T_bb = {tbb * 1e3:.4g} ms)")
        hi, best = self._bisect(qp, K, lo, c, sol, stats)
        return self._verify(qp, c, hi, best, K, stats, n_rigid)

    def _verify(self, qp, c, hi, best, K, stats, n_rigid):
        """Verify by simulation; step up on failure (tail beyond the QP horizon, row thinning)."""
        for N in range(hi, c + 1):
            if N != hi:
                best = self._solve(qp, K, N, self.beta, stats, warm=best.x)
                if not best.success:
                    continue
            try:       # checked now, packaged only when no nominal-first design replaces it
                played = played_design(self, qp, best, K, N, f"min_settle/{self.objective_kind}", strict=True)
            except DesignError:
                continue
            self._history[max(n_rigid, 1)] = N
            return self._nominal_first(qp, best, K, N, stats, max(n_rigid - 2, 0)) or packaged_design(
                self, played, stats)
        raise DesignError(f"no design for {K:g} tracks passed the simulator check up to {c} samples")

    # ------------------------------------------------------------------ verification
    def _finish(self, qp, sol, K, N, stats: SolveStats, objective, strict, settle_n=None,
                set_min=None) -> DesignResult:
        """Verify and package the design (:func:`seekopt.design.verification.verified_design`)."""
        return verified_design(self, qp, sol, K, N, stats, objective, strict, settle_n, set_min)

def design_seek(plant: ModalPlant, controller, tracks: float, imax: float, settle: float = 0.1,
                robust=None, **options) -> DesignResult:
    """One-shot :class:`SeekDesigner` ``(plant, controller, imax, settle, robust).design(tracks)``."""
    return SeekDesigner(plant, controller, imax, settle, robust, **options).design(tracks)
