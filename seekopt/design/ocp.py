"""Optimal seek-profile design (CasADi): feedforward and reference for minimum seek-settle time.

Problem (linear plant, one seek of ``K`` tracks, servo rate ``fs``, ``N`` seek samples)::

    find  u_ff(0..N-1) [A], r(0..N-1) [track]       (r = K and u_ff = 0 from N on)
    s.t.  |y_i(k) - K| <= beta * band     for k >= N_s, every plant i of the robust set
          |i_i(k, l)|  <= gamma * Imax    total current (feedforward + feedback + hold), all sub-steps
          |z_hf(f)|    <= hf_tol * band   residual of unmodelled modes, f in [0.45, 0.65] fs
          M u_ff = [K, 0]                 ZOH rigid model at rest at K (profiles.rigid_endpoint_matrix)
          |u_ff(k) - u_ff(k-1)| <= slew/fs   (optional)

``y_i`` and ``i_i`` are convolutions of ``u_ff`` and ``r`` with the closed-loop impulse
responses of plant ``i`` under the drive's controller (:class:`seekopt.design.qp.LoopMaps`, from the one
simulator).  Objectives:

(a) ``design(K, seek_samples=N)``: minimum residual vibration after the seek (``N_s = N``): the
    worst ``|PES|`` over the robust set (epigraph ``t``, ``objective="worst"``) or over the nominal
    plant with the tail energy averaged over the set (``objective="mean"``);
(b) ``design(K)``: minimum seek-settle time: bisection over ``N_s = N`` (feasibility is monotone
    in ``N``) with the band constraint, on the sample grid.

The reference is designed jointly (``reference="free"``, default; ERRATA item 6) or taken from a
model that includes the identified modes (``"model"``) or the rigid body (``"rigid"``, paper).

The design sees the plant's *linear part*: nonlinear effects (friction, saturation, position
bias) are not modelled by the optimiser; every design is re-checked on the full plant by
:func:`seekopt.drive.simulator.simulate_2dof` and a design that fails the check is never returned.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from identification.model.plant import ModalPlant, Mode

import seekopt.design.qp as _qp
from seekopt.design.metrics import SeekMetrics, evaluate_profile, worst_case
from seekopt.design.profiles import Profile, finish_profile, reference_from_model, rigid_endpoint_matrix, t_bang_bang

__all__ = ["DesignInfeasible", "DesignError", "RobustSpec", "seek_induced", "DesignResult", "SeekDesigner", "design_seek",
           "SIZE_CLASSES"]

#: Seek-length classes [samples]: one QP structure (and solver) per class, built on first use.  Above
#: 128 samples (seeks of about 2500 tracks and longer) the classes are 1/8 to 1/4 apart: the dense QP's
#: cost grows steeply with its size (K = 10000: class 256 took 45-75 s per solve, 224 about 25 s).
SIZE_CLASSES = (8, 16, 24, 32, 48, 64, 96, 128, 144, 160, 176, 192, 208, 224, 240, 256, 288, 320, 352, 384,
                448, 512)
#: Classes above this carry the non-nominal plants' band rows on every ``THIN_STRIDE``-th sample only
#: (the nominal plant keeps every row; current rows stay on every sub-step of every plant: thinning them
#: let set plants exceed Imax by 5-15 %; band stride 4 let the set's worst settle 1.3 ms later at K = 3000).
THIN_ABOVE, THIN_STRIDE = 128, 2


class DesignInfeasible(ValueError):
    """The request cannot be met (e.g. seek too short for ``Imax``); names the shortest feasible time."""


class DesignError(RuntimeError):
    """The solver failed or its answer failed the simulator check (never returned as a profile)."""


def seek_induced(mode: Mode) -> bool:
    """True for a seek-induced mode: gain below the rigid body at resonance, ``|g| / (2 zeta) < 1``
    (the paper's modes that a frequency response cannot see; :data:`seekopt.drive.presets.SEEK_MODES`)."""
    return abs(mode.gain) < 2.0 * mode.zeta


@dataclass
class RobustSpec:
    """Uncertainty of the identified plant for robust design (the robust set of plants).

    Every range is a half-width around the identified value, and never narrower than
    ``n_sigma`` reported standard deviations of that parameter (``Mode.std``,
    ``ModalPlant.std["delay_s"]``, ``ModalPlant.std["k0"]``).  The defaults are what the
    identification can promise, not what one truth plant needs:

    * ``freq_pct = 5`` on the **seek-induced** modes (:func:`seek_induced`): they move by a few
      percent with temperature, flex-cable shape and head position, far more than the reported
      std (0.01-0.1 %); the robust option promises tolerance to +-5 % of them.
    * ``other_freq_pct = 1`` on the other (high-gain) modes: the identification pins them to about
      0.5 % on synthetic logs and the notches hold them; 5 % on a mode of gain ~1 costs seek time.
    * ``gain_pct = 8``: about three times the identification's gain error on synthetic logs
      (2.8 %), at least three reported std of every mode below 0.45 fs (at most 7.5 %).  15 % cost
      2-4 samples at K = 200 (2.0-2.1 T_bb) with the array's column draw; 8 % is within one sample
      for every draw.  ``zeta_pct = 30``: damping is the least certain parameter (the 7 kHz
      mode's comes out 30 % low on the multirate drive).
    * ``delay_s = 1 us`` (2.6 % of a 26.4 kHz sample): the reported std (0.01 us) is noise only;
      the delay also absorbs unmodelled amplifier lag and sub-sample timing.
    * modes above ``nyquist_guard * fs / 2`` keep their identified values: near Nyquist the
      identification cannot pin them (aliasing); the unmodelled-mode guard covers that band.

    Parameters
    ----------
    freq_pct : float
        Frequency half-width of the seek-induced modes [%].
    zeta_pct, gain_pct : float
        Damping and gain half-widths of every mode [%].
    delay_s : float
        Delay half-width [s].
    n_samples : int
        Orthogonal-array vertices besides the nominal and the corners (all frequencies x delay x
        ``k0`` at +-, all gains +-): rows of a Sylvester-Hadamard array, one +-1 column per varied
        factor (each mode's frequency and gain, delay, ``k0``), damping uniform (seeded).  15 rows
        and at most 15 factors (7 modes and the delay) make a strength-2 array: every pair of
        factors meets all four sign pairs.  (Random signs moved T_ss by 3 samples with the draw.)
    objective : {"worst", "mean"}
        ``worst``: settle band (or residual epigraph) enforced on every plant; ``mean``: on the
        nominal plant, tail energy averaged over the set.
    k0_pct : float
        Half-width of the rigid-body gain range [%].
    seed : int
    other_freq_pct : float
        Frequency half-width of the other modes [%].
    n_sigma : float
        Floor of every range in reported standard deviations.
    nyquist_guard : float
        Modes above ``nyquist_guard * fs / 2`` (``fs`` the plant's sample rate) are not varied.
    """

    freq_pct: float = 5.0
    zeta_pct: float = 30.0
    gain_pct: float = 8.0
    delay_s: float = 1e-6
    n_samples: int = 15
    objective: str = "worst"
    k0_pct: float = 0.0
    seed: int = 0
    other_freq_pct: float = 1.0
    n_sigma: float = 3.0
    nyquist_guard: float = 0.9

    _KEYS = {"freq": "freq_pct", "zeta": "zeta_pct", "gain": "gain_pct", "delay": "delay_s",
             "n": "n_samples", "samples": "n_samples", "objective": "objective", "k0": "k0_pct",
             "seed": "seed", "ofreq": "other_freq_pct", "sigma": "n_sigma", "nyq": "nyquist_guard"}

    def __post_init__(self):
        if self.objective not in ("worst", "mean"):
            raise ValueError(f"robust objective must be 'worst' or 'mean', not {self.objective!r}")
        vals = (self.freq_pct, self.zeta_pct, self.gain_pct, self.delay_s, self.k0_pct, self.other_freq_pct,
                self.n_sigma, self.nyquist_guard)
        if any((not math.isfinite(v)) or v < 0 for v in vals) or self.n_samples < 0:
            raise ValueError("robust ranges must be finite and >= 0")

    @classmethod
    def from_string(cls, text: str | None) -> "RobustSpec":
        """``"freq=5,ofreq=1,zeta=30,gain=8,delay=1e-6,n=15,objective=worst,k0=0,sigma=3"``
        (percent / s); ``""``, ``"default"`` or None give the defaults."""
        kw = {}
        for item in filter(None, (text or "").replace(" ", "").split(",")):
            if item == "default":
                continue
            k, eq, v = item.partition("=")
            if not eq or k not in cls._KEYS:
                raise ValueError(f"robust spec {text!r}: unknown item {item!r} "
                                 f"(keys: {', '.join(sorted(cls._KEYS))})")
            name = cls._KEYS[k]
            try:
                kw[name] = v if name == "objective" else (int(float(v)) if name in ("n_samples", "seed")
                                                          else float(v))
            except ValueError:
                raise ValueError(f"robust spec {text!r}: {k} is not a number") from None
        return cls(**kw)

    def to_string(self) -> str:
        return (f"freq={self.freq_pct:g},ofreq={self.other_freq_pct:g},zeta={self.zeta_pct:g},"
                f"gain={self.gain_pct:g},delay={self.delay_s:g},k0={self.k0_pct:g},sigma={self.n_sigma:g},"
                f"nyq={self.nyquist_guard:g},n={self.n_samples},seed={self.seed},objective={self.objective}")

    def ranges(self, plant: ModalPlant):
        """Relative half-widths ``(df, dz, dg)`` per mode [fraction], delay [s] and ``k0`` [fraction]."""
        ns = self.n_sigma
        fny = self.nyquist_guard * 0.5 * plant.sample_rate_hz if plant.sample_rate_hz else math.inf
        df, dz, dg = [], [], []
        for m in plant.modes:
            sd = m.std or {}
            if m.freq_hz >= fny:
                df.append(0.0); dz.append(0.0); dg.append(0.0)
                continue
            base = self.freq_pct if seek_induced(m) else self.other_freq_pct
            df.append(max(base / 100, ns * sd.get("freq_hz", 0.0) / m.freq_hz))
            dz.append(max(self.zeta_pct / 100, ns * sd.get("zeta", 0.0) / m.zeta if m.zeta else 0.0))
            dg.append(max(self.gain_pct / 100, ns * sd.get("gain", 0.0) / abs(m.gain) if m.gain else 0.0))
        dd = max(self.delay_s, ns * float(plant.std.get("delay_s", 0.0))) if (self.delay_s or ns) else 0.0
        dk = max(self.k0_pct / 100, ns * float(plant.std.get("k0", 0.0)) / plant.k0) if self.k0_pct else 0.0
        return np.array(df), np.array(dz), np.array(dg), dd, dk

    def plants(self, plant: ModalPlant) -> list:
        """Nominal first, then the corners, then ``n_samples`` orthogonal-array vertices of the box (each
        mode's frequency and gain, the delay and ``k0`` at +- their range; damping uniform): the settle
        residual is linear in the gains, so its worst case sits on vertices."""
        f, z, g, d, k = self.ranges(plant)

        def var(sf=0.0, sz=0.0, sg=0.0, sd=0.0, sk=0.0):
            modes = [Mode(m.freq_hz * (1 + a), m.zeta * (1 + b), m.gain * (1 + c))
                     for m, a, b, c in zip(plant.modes, sf * f, sz * z, sg * g)]
            return plant.copy(modes=modes, delay_s=max(0.0, plant.delay_s + sd * d), k0=plant.k0 * (1 + sk * k))

        out = [plant]
        anyf, anyg = bool(np.any(f)), bool(np.any(g))
        for sf in ((1, -1) if anyf else (0,)):            # corners: frequency x delay x k0 (all signs)
            for sd in ((1, -1) if d else (0,)):
                for sk in ((1, -1) if k else (0,)):
                    if sf or sd or sk:
                        out.append(var(sf=sf, sd=sd, sk=sk))
        if anyg:
            out += [var(sg=1.0), var(sg=-1.0)]
        n = len(plant.modes)
        # orthogonal-array vertices: the varied factors (frequency and gain sign of each varied mode,
        # delay and k0 sign) are columns 1.. of a Sylvester-Hadamard matrix of order > n_samples, rows
        # 1..n_samples (row 0, all +, is a corner): with at most order - 1 factors and n_samples =
        # order - 1 every pair of factors sees all four sign pairs equally often (strength 2).
        factors = ([("f", i) for i in range(n) if f[i]] + [("g", i) for i in range(n) if g[i]]
                   + [("d", 0)] * bool(d) + [("k", 0)] * bool(k))
        if self.n_samples and factors:
            H = _sylvester(self.n_samples)
            rng = np.random.default_rng(self.seed)
            cols = 1 + np.resize(rng.permutation(H.shape[1] - 1), len(factors))
            for row in H[1:1 + self.n_samples]:
                sg = {"f": np.zeros(n), "g": np.zeros(n), "d": np.zeros(1), "k": np.zeros(1)}
                for (kind, i), c in zip(factors, cols):
                    sg[kind][i] = row[c]
                out.append(var(sf=sg["f"], sg=sg["g"], sd=sg["d"][0], sk=sg["k"][0], sz=rng.uniform(-1, 1, n)))
        return out


def _sylvester(nrows: int) -> np.ndarray:
    """Sylvester-Hadamard matrix (+-1 entries) of the smallest order ``2^m > nrows``."""
    H = np.ones((1, 1))
    while H.shape[1] <= nrows:
        H = np.block([[H, H], [H, -H]])
    return H


@dataclass
class DesignResult:
    """A verified design.

    ``metrics`` are measured by :func:`seekopt.design.metrics.evaluate_profile` on the design plant
    (the full plant, effects included); ``worst_metrics`` the worst case over the robust set
    (when checked).  ``solve_time_s`` sums the QP solves of this design; ``objective`` is
    ``"min_settle/<worst|mean>"`` or ``"min_residual/<worst|mean>"``.
    """

    profile: Profile
    metrics: SeekMetrics
    status: str
    solve_time_s: float
    solver: str
    objective: str
    settle_samples: int = 0
    n_solves: int = 0
    residual_band: float = float("nan")
    worst_metrics: SeekMetrics | None = None
    qp_status: str = ""
    build_time_s: float = 0.0


class SeekDesigner:
    """Seek designer for one plant, controller and current limit; build once, design many times.

    Parameters
    ----------
    plant : ModalPlant
        Identified (design) plant; its linear part is designed for, the full plant checked.
    controller : Controller
        The drive's feedback controller (servo rate = ``controller.sample_rate_hz``).
    imax : float
        Current limit [A] on the total current (feedforward + feedback + hold, all sub-steps).
    settle : float
        Settle band [track].
    robust : RobustSpec or str, optional
        Plant uncertainty (None: nominal plant only; the unmodelled-mode guard always applies).
    tail_s : float
        Time after the seek over which the band is enforced in the QP [s] (checked longer by
        simulation).
    reference : {"free", "model", "rigid"}
        Reference designed jointly, or the response of the plant model (modes included) or of the
        rigid body to the feedforward.
    solver : str
        ``casadi.conic`` plugin (``daqp`` default, ``qpoases``, ``highs``, ``osqp``, ``proxqp``) or
        ``ipopt`` (Opti + Ipopt, ``opti.to_function``).
    band_margin : float
        ``beta``: design band as a fraction of ``settle``.  The robust set carries the identified
        plant's parametric uncertainty; ``beta = 0.8`` keeps 20 % of the band (0.02 track at 0.1)
        for what no set covers: the QP checks the tail on thinned rows, the optimiser does not see
        nonlinear effects, and the set is a finite sample of its box.  With the default robust set
        at K = 200 on the identified plant: 0.7 -> 46 samples (2.12 T_bb), 0.8 -> 42 (1.93), 0.9 -> 39.
    current_margin : float
        ``gamma``: design current limit as a fraction of ``imax``.
    hf_guard : (float, float) or None
        Band of unmodelled modes as fractions of ``fs`` (default 0.45-0.65: identification does not
        see modes near and above Nyquist); ``hf_gain`` their gain relative to the rigid body,
        ``hf_tol`` the allowed residual per mode as a fraction of ``settle``.
    slew_a_per_s : float, optional
        Feedforward slew-rate limit [A/s].
    check_robust : bool
        Also simulate the design on every plant of the robust set (``DesignResult.worst_metrics``).
    max_samples : int
        Longest seek considered [samples].
    """

    def __init__(self, plant: ModalPlant, controller, imax: float, settle: float = 0.1, robust=None, *,
                 tail_s: float = 0.008, reference: str = "free", solver: str = "daqp",
                 solver_options: dict | None = None, band_margin: float = 0.8, current_margin: float = 0.97,
                 hf_guard=(0.45, 0.65), hf_gain: float = 1.0, hf_tol: float = 0.1,
                 slew_a_per_s: float | None = None, check_robust: bool = False, max_samples: int = 512):
        if not (imax > 0 and settle > 0 and 0 < band_margin <= 1 and 0 < current_margin <= 1):
            raise ValueError("imax, settle > 0 and 0 < band_margin, current_margin <= 1 required")
        if reference not in ("free", "model", "rigid"):
            raise ValueError(f"reference must be 'free', 'model' or 'rigid', not {reference!r}")
        self.plant, self.controller = plant, controller
        self.imax, self.settle = float(imax), float(settle)
        self.robust = RobustSpec.from_string(robust) if isinstance(robust, str) else robust
        self.fs = float(controller.sample_rate_hz)
        self.L = int(controller.fast_multiple)
        self.tail = max(int(round(tail_s * self.fs)), 64)
        self.reference, self.solver_name = reference, solver
        self.solver_options = solver_options
        self.beta, self.gamma = float(band_margin), float(current_margin)
        self.hf_guard, self.hf_gain, self.hf_tol = hf_guard, float(hf_gain), float(hf_tol)
        self.slew = slew_a_per_s
        self.check_robust = check_robust
        self.max_samples = int(max_samples)
        self.plants = self.robust.plants(plant) if self.robust else [plant]
        self.objective_kind = self.robust.objective if self.robust else "worst"
        self.ignored_effects = [e.name for e in plant.effects if e.kind != "structural"]
        self._maps, self._maps_h = None, 0
        self._qps: dict = {}
        self.builds = 0
        self.thin_above, self.thin_stride = THIN_ABOVE, THIN_STRIDE

    # ------------------------------------------------------------------ structures
    def _loop_maps(self, horizon: int) -> list:
        if self._maps is None or self._maps_h < horizon:
            h = max(horizon, 2 * self._maps_h)
            self._maps = [_qp.LoopMaps(p, self.controller, h) for p in self.plants]
            self._maps_h = h
        return self._maps

    def _structure(self, nmax: int, epigraph: bool) -> _qp.SeekQP:
        key = (nmax, epigraph)
        if key not in self._qps:
            H = nmax + self.tail
            maps = self._loop_maps(H)
            R = None
            if self.reference != "free":
                model = self.plant if self.reference == "model" else ModalPlant(
                    k0=self.plant.k0, delay_s=self.plant.total_delay_s)
                imp = np.zeros(H); imp[0] = 1.0
                hm = reference_from_model(model, imp, self.fs, H)
                R = _qp.toeplitz_rows(hm, np.arange(H), H)
            hf = None
            if self.hf_guard:
                lo, hi = self.hf_guard
                hf = _qp.hf_guard_matrix(self.plant.k0, self.fs, self.L, H * self.L, lo * self.fs, hi * self.fs,
                                         self.hf_gain, spacing_hz=max(self.fs / (2 * nmax), 50.0))
            band_plants = range(len(self.plants)) if self.objective_kind == "worst" else [0]
            self._qps[key] = _qp.SeekQP(
                maps, nmax, H, self.imax, self.settle, self.fs, band_plants,
                lambda n, m: _qp.make_qp_solver(n, m, self.solver_name, self.solver_options),
                epigraph=epigraph, R=R, hf=hf, slew=self.slew, stride=self._stride(nmax))
            self.builds += 1
        return self._qps[key]

    def _stride(self, nmax: int) -> int:
        """Row stride of the non-nominal plants' band rows (1: every sample)."""
        return 1 if nmax <= self.thin_above else self.thin_stride

    def _classes(self, n_from: int):
        return [c for c in SIZE_CLASSES if n_from <= c <= self.max_samples] or [self.max_samples]

    # ------------------------------------------------------------------ solving
    def _solve(self, qp: _qp.SeekQP, K, n, beta, stats, warm=None, epigraph=False):
        hf_tol = self.hf_tol if self.hf_guard else None
        data = qp.data(K, n, None if epigraph else beta, self.gamma, hf_tol, self.slew)
        x0 = None if warm is None else warm
        sol = qp.solver.solve(*data, x0=x0)
        if sol.success:     # never trust a status alone: re-check the answer against the data
            viol = qp.violation(sol.x, K, *data[3:])
            if viol > 1e-3:
                sol.success, sol.status = False, f"{sol.status}; constraint violation {viol:.2g}"
        stats["n"] += 1
        stats["t"] += sol.solve_time_s
        stats["status"] = sol.status
        return sol

    def shortest_feasible(self, tracks: float) -> int:
        """Fewest seek samples for which currents, guard and rest-to-rest can be met (no band)."""
        K = float(tracks)
        stats = {"n": 0, "t": 0.0, "status": ""}
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
        n = self.shortest_feasible(K)
        what = (f"shortest feasible seek time is {n} samples ({n / self.fs * 1e3:.4g} ms)" if n > 0 else
                f"no feasible seek within {self.max_samples} samples")
        return DesignInfeasible(f"seek of {K:g} tracks in {n_req} samples ({n_req / self.fs * 1e3:.4g} ms) "
                                f"cannot be met at Imax {self.imax:g} A: {what}; "
                                f"T_bb = {tbb * 1e3:.4g} ms = {tbb * self.fs:.2f} samples")

    def design(self, tracks: float, seek_samples: int | None = None) -> DesignResult:
        """Design the seek of ``tracks`` tracks.

        ``seek_samples=None``: minimum seek-settle time (objective (b)); an integer: minimum residual
        vibration for that seek length (objective (a)).  Raises :class:`DesignInfeasible` when the
        request cannot be met and :class:`DesignError` when no verified design is found.
        """
        K = float(tracks)
        if not math.isfinite(K) or K == 0:
            raise ValueError(f"tracks must be a non-zero number, not {tracks!r}")
        stats = {"n": 0, "t": 0.0, "status": ""}
        n_rigid = int(math.ceil(t_bang_bang(K, self.plant.k0, self.imax) * self.fs - 1e-9))
        if seek_samples is not None:
            N = int(seek_samples)
            if N < max(n_rigid - 1, 1) or N > self.max_samples:
                raise self._infeasible(K, N)
            epi = True      # residual epigraph over the band plants (all: worst; nominal: mean)
            qp = self._structure(self._classes(N)[0], epi)
            sol = self._solve(qp, K, N, None, stats, epigraph=epi)
            if not sol.success:
                if not sol.infeasible:
                    raise DesignError(f"QP solver {self.solver_name} failed ({sol.status}) for {K:g} tracks "
                                      f"in {N} samples")
                n_min = self.shortest_feasible(K)
                if n_min < 0 or N < n_min:
                    raise self._infeasible(K, N)
                raise DesignError(f"QP solver {self.solver_name} failed ({sol.status}) for {K:g} tracks "
                                  f"in {N} samples")
            return self._finish(qp, sol, K, N, stats, f"min_residual/{self.objective_kind}", strict=False)
        # (b) minimum seek-settle time: size class whose longest seek settles, then bisection
        lo = max(n_rigid - 2, 0)
        # long seeks settle no sooner than 1.25 T_bb (measured 1.37-1.58 for K = 1000-10000): skip the
        # hopeless big classes below that (lo stays at T_bb, so the bisection still covers them)
        first = max(n_rigid, 1) if n_rigid <= self.thin_above else int(math.ceil(1.25 * n_rigid))
        for c in self._classes(first):
            qp = self._structure(c, False)
            sol = self._solve(qp, K, c, self.beta, stats)
            if sol.success:
                break
            if not sol.infeasible:
                raise DesignError(f"QP solver {self.solver_name} failed ({sol.status}) for {K:g} tracks "
                                  f"in {c} samples")
            lo = max(lo, c)
        else:
            raise DesignInfeasible(f"seek of {K:g} tracks cannot settle within {self.max_samples} samples "
                                   f"at Imax {self.imax:g} A (T_bb = {t_bang_bang(K, self.plant.k0, self.imax) * 1e3:.4g} ms)")
        hi, best = c, sol
        while hi - lo > 1:
            mid = (lo + hi) // 2
            s = self._solve(qp, K, mid, self.beta, stats, warm=best.x)
            if s.success:
                hi, best = mid, s
            else:           # infeasible, or a failed solve: either way not a design at ``mid``
                lo = mid
        # verify by simulation; step up on failure (tail beyond the QP horizon, row thinning)
        for N in range(hi, c + 1):
            if N != hi:
                best = self._solve(qp, K, N, self.beta, stats, warm=best.x)
                if not best.success:
                    continue
            try:
                return self._finish(qp, best, K, N, stats, f"min_settle/{self.objective_kind}", strict=True)
            except DesignError:
                continue
        raise DesignError(f"no design for {K:g} tracks passed the simulator check up to {c} samples")

    # ------------------------------------------------------------------ verification
    def _finish(self, qp, sol, K, N, stats, objective, strict) -> DesignResult:
        u, r = qp.unpack(sol.x, K, N)
        M = rigid_endpoint_matrix(N, self.plant.k0, 1.0 / self.fs)
        u = np.clip(u, -self.imax, self.imax)
        for _ in range(3):      # exact rest-to-rest: least-norm correction on the unsaturated samples
            miss = np.array([K, 0.0]) - M @ u
            free = np.abs(u) < self.imax * (1 - 1e-9)
            if np.max(np.abs(miss)) <= 1e-9 or free.sum() < 2:
                break
            Mf = M[:, free]
            u[free] += Mf.T @ np.linalg.solve(Mf @ Mf.T, miss)
            u = np.clip(u, -self.imax, self.imax)
        if np.max(np.abs(M @ u - [K, 0.0])) > 1e-6 or not np.all(np.isfinite(u)):
            raise DesignError(f"design misses rest at {K:g} tracks")
        meta = {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
                "design_objective": objective, "solver": self.solver_name, "reference": self.reference,
                "robust": self.robust.to_string() if self.robust else "none",
                "band_margin": self.beta, "current_margin": self.gamma, "design_settle_samples": N}
        if self.ignored_effects:
            meta["effects_not_in_design"] = ";".join(self.ignored_effects)
        if r is not None:   # jointly designed reference; one closing sample shows the hold (u = 0, r = K)
            prof = Profile(np.r_[u, 0.0], np.r_[r, K], self.fs, K, self.imax, self.settle, "optimal", N, meta)
        else:
            model = self.plant if self.reference == "model" else ModalPlant(
                k0=self.plant.k0, delay_s=self.plant.total_delay_s)
            prof = finish_profile(u, K, self.fs, self.imax, model, "optimal", self.settle, meta=meta)
            prof.seek_samples = N
        metrics = evaluate_profile(self.plant, self.controller, prof, settle=self.settle)   # the one simulator
        if not metrics.peak_current_a <= self.imax * (1 + 1e-9):
            raise DesignError(f"design exceeds Imax in simulation ({metrics.peak_current_a:.4g} A)")
        if strict and not metrics.settle_time_s * self.fs <= N + 1 + 1e-9:
            raise DesignError(f"design does not settle by sample {N} in simulation")
        worst = None
        if self.check_robust and len(self.plants) > 1:
            worst = worst_case([metrics] + [evaluate_profile(p, self.controller, prof, settle=self.settle,
                                                             k0_for_tbb=self.plant.k0) for p in self.plants[1:]])
        prof.meta["design_status"] = "verified"
        return DesignResult(prof, metrics, "verified", stats["t"], self.solver_name, objective,
                            settle_samples=N, n_solves=stats["n"],
                            residual_band=qp.residual(sol.x, K, N) * 1.0, worst_metrics=worst,
                            qp_status=stats["status"],
                            build_time_s=sum(q.build_time_s for q in self._qps.values()))


def design_seek(plant: ModalPlant, controller, tracks: float, imax: float, settle: float = 0.1,
                robust=None, **options) -> DesignResult:
    """One-shot :class:`SeekDesigner` ``(plant, controller, imax, settle, robust).design(tracks)``."""
    return SeekDesigner(plant, controller, imax, settle, robust, **options).design(tracks)
