"""The robust output-error identification method (``identify(log, method="robust")``, the default).

a. Start: the ZOH rigid fit with fractional delay (:func:`identification.estimate.rigid.rigid_fit`) and
   the pooled matrix pencil on the settle-window PES (automatic order, spurious-pole rejection,
   :func:`identification.estimate.pencil.matrix_pencil`).
b. Joint output-error fit of the measured position to the measured current over whole seek
   segments (seek start to end: the seek is where the modes are excited far above the noise, while
   after settling they are not -- at the benchmark noise no mode's settle-window response exceeds
   the noise at its frequency), by variable projection (:class:`identification.estimate.varpro.VarPro`):
   ``scipy.optimize.least_squares`` over each mode's frequency and damping and the delay, with the
   linear parameters (``k0``, ``k0 bias``, ``k0 g_r``, in the final stage the residual compliance ``k0 D``
   of the modes the model does not hold (``residual_fs_multiple``, :class:`VarPro`; the plant does not hold it, so it
   is kept only while its term is no larger than the model's output error or half the settle band, ``residual_max_share``
   and ``residual_max_track``, else the final
   stage is refined without it: on an amplifier-lag log it paired with a broad mode at the frequency bound,
   gain 129, to build the lag's phase, and the plant without it missed the data by 2.4 track), per-segment initial position
   and velocity, run-out harmonics) projected out by LS at every evaluation.  The rigid body and the modes are the
   one discretisation of :mod:`identification.model.discrete` (ZOH, fractional delay, multirate
   sub-step hold when the log has the sub-step currents); each mode's response runs over the whole
   log, so mode states carry over from seek to seek.  The noise is coloured (flutter, run-out, and
   above all the unlogged force noise, which the double integrator turns into a random walk of
   position): the residual is prewhitened by an AR(``ar_order``) model of the first fit's residual
   -- the direct prediction-error method with an AR noise model, consistent in closed loop when
   the noise model whitens the residual, and near-efficient.  Modes the settle windows do not show
   are found by a scan of the whitened residual over a frequency grid stepped by the scanned
   damping (and finer around lightly damped poles of the noise model; the residual-sum-of-squares
   reduction of one more mode, refined on a finer local grid, added while significant), and modes
   whose gain is not significant (``|g| / std < t_min``) are dropped.  A repeatable run-out (period
   detected in the residual of the model with its modes, :func:`identification.estimate.varpro.detect_period`)
   enters as ``periodic_harmonics`` harmonics.  The search runs on the first fitted seeks holding
   about ``stage_rows`` samples (a contiguous stretch of the log), the final refinement on all
   fitted seeks.
   The final stage fits the AR model to the output error of the whitened estimate itself and
   refines again (``noise_model_passes``): an AR model of the unwhitened LS residual whitens that
   fit's closed-loop misfit as well as the noise (whitened residual correlated -0.04 .. -0.05 at lags 1-3 on
   a 36 kHz test drive; at most 0.0024 in magnitude with the re-fit, ``tests/test_identify_calibration.py``).
   The noise model has ``noise_unit_poles`` (2) poles at z = 1 imposed: the dominant low-frequency
   noise is the unlogged force noise through the rigid body's double integrator, a random walk of
   velocity within every seek, and an AR model fitted to short per-seek detrended segments puts
   those poles inside the unit circle (k0's std came out 2-3x optimistic on the 36 kHz drive with
   force noise only).  The AR model is fitted to the twice-differenced output error and multiplied by
   ``(1 - q^-1)^2``; that whitener maps each seek's ``p0 + v0 t`` to 0, so it is not projected out
   again (:attr:`VarPro.affine_free`).
c. Standard deviations from the Jacobian of the whitened problem with respect to all parameters
   (Gauss-Newton covariance), as a Newey-West sandwich (Bartlett weights, ``nw_lags`` lags, within
   segments, :func:`identification.estimate.linalg.sandwich_cov`) for the colour the AR model leaves,
   each variance floored at the plain ``s^2 (J^T J)^-1`` (``cov_floor_white``: a sandwich of the
   estimate's own residuals is biased low when few seeks carry a parameter; on the 36 kHz drive the
   gains' normalised errors had RMS 1.24 with the sandwich alone, 1.11 with the Gauss-Newton one);
   the ratio to the plain ``s^2 (J^T J)^-1`` is reported (``diagnostics["std_inflation_median"]``).
   They are statistical only: model error is not in them.
d. The bias force from the whole log (``bias_from="whole-log"``, default): the rigid body's momentum
   balance from seek start to seek start over all seeks (:func:`identification.estimate.rigid.momentum_bias`),
   the velocity at each start being the fitted model's
   (:func:`identification.estimate.heldout.initial_velocities`; exact on a noise-free log): the
   velocity's continuity from seek to seek, which the per-seek fit of (b) frees, pins the bias to the
   mean force over the whole log.  Its error is dominated by the mean of the unlogged force noise
   over the log, which any momentum balance over the same span shares; the standard deviation is
   the batch-means one of the model-free balance between the settle windows
   (:func:`identification.estimate.rigid.whole_log_bias`, chunk by chunk; its velocity-slope errors
   make it slightly conservative: RMS of normalised errors 0.8 over 20 noise seeds, where the
   chunks of the model-velocity balance, whose velocities share each chunk's noise, gave 1.3).  The per-seek fit's bias (a nuisance there) is in
   ``diagnostics["bias_per_seek"]``.

Every threshold is a named field of :class:`identification.estimate.settings.RobustSettings`.
"""
from __future__ import annotations

import math
import time

import numpy as np

from identification.estimate.heldout import initial_velocities
from identification.estimate.linalg import floored_cov, sandwich_cov, white_cov
from identification.estimate.modescan import ModeScan, _drop, _n_modes
from identification.estimate.pencil import matrix_pencil, stabilisation_diagram
from identification.estimate.prony import z_to_modal
from identification.estimate.result import Identification
from identification.estimate.rigid import momentum_bias, rigid_fit, whole_log_bias
from identification.estimate.settings import RobustSettings
from identification.estimate.varpro import VarPro, ar_whitener, detect_period, fir_filter, periodic_columns
from identification.logs.seeklog import SeekLog, segment_seeks
from identification.model.plant import ModalPlant, Mode

__all__ = ["RobustIdentifier"]

_TINY = 1e-300          # floor of a variance before a division


class RobustIdentifier:
    """The robust method, built once from :class:`RobustSettings` and run on any number of logs.

    ``RobustIdentifier(settings).run(log, fit_seeks)`` -> :class:`Identification`; each run keeps its
    own state (:class:`_Run`), so one identifier may serve many logs.
    """

    def __init__(self, settings: RobustSettings | None = None):
        self.settings = settings if settings is not None else RobustSettings()

    def run(self, log: SeekLog, fit_seeks, timing: dict | None = None) -> Identification:
        """Identify from the seeks ``fit_seeks`` of ``log``; seconds per stage go to ``timing``."""
        return _Run(self.settings, log, fit_seeks, {} if timing is None else timing).identify()


def _t_stats(vp: VarPro, x):
    """|c_r| / std(c_r) of the mode coefficients (white LS covariance of the whitened problem)."""
    R = _n_modes(x)
    X, c, r, _ = vp.solve(x)
    cov = white_cov(X, r)
    return np.abs(c[2:2 + R]) / np.sqrt(np.maximum(np.diag(cov)[2:2 + R], _TINY))


def _stage(segs, max_rows, history):
    """The search stage's data: the first fitted seeks holding about ``max_rows`` samples, as a
    contiguous stretch of the log that starts ``history`` samples before the first of them (the
    mode filters start there in the steady state of the current).  Returns ``(i0, i1, segments)``
    with the segments relative to ``i0``; the whole log when it is small enough."""
    total = sum(b - a for a, b in segs)
    if total <= max_rows:
        return 0, None, segs
    n, acc = 0, 0
    while n < len(segs) and acc < max_rows:
        acc += segs[n][1] - segs[n][0]
        n += 1
    i0 = max(segs[0][0] - history, 0)
    return i0, segs[n - 1][1], [(a - i0, b - i0) for a, b in segs[:n]]


def _ratio_std(c, cc, i) -> float:
    """Delta-method std of ``c_i / c_0`` from the covariance ``cc`` of ``c``."""
    gv = np.zeros(len(c))
    gv[0], gv[i] = -c[i] / c[0] ** 2, 1.0 / c[0]
    return float(np.sqrt(max(gv @ cc @ gv, 0.0)))


class _Run(ModeScan):
    """The state of one robust identification: the data, the frequencies proposed or dropped so far
    (``tabu``), the modes the scan added, the run-out frequency, diagnostics and timing."""

    def __init__(self, settings: RobustSettings, log: SeekLog, fit_seeks, timing: dict):
        self.s, self.log, self.fit_seeks, self.timing = settings, log, fit_seeks, timing
        self.fs, self.dt = log.sample_rate_hz, log.dt
        self.u, self.y = log.input_current(), log.position_track   # (n, L) for a multirate log: exact hold
        self.lo, self.hi = settings.band(self.fs)
        self.segs = [(q.start, q.end) for q in fit_seeks]
        self.ppo, self.diag = {}, {}
        self.tabu: list[float] = []          # frequencies [Hz] proposed or dropped: not proposed again
        self.added: list[tuple] = []         # (freq_hz, zeta, statistic) of each mode the scan proposed
        self.runout_hz = 0.0                 # fundamental of the detected run-out [Hz] (0: none)
        self.nuisance_period = None          # run-out period [samples] once detected
        self.clock = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.timing[name] = now - self.clock
        self.clock = now

    # ----------------------------------------------------------------------- problem and refinement
    def bounds(self, x):
        s, R = self.s, _n_modes(x)
        return (np.r_[np.full(R, math.log(s.freq_low_factor * self.lo)), np.full(R, math.log(s.zeta_bounds[0])),
                      s.delay_bounds_samples[0]],
                np.r_[np.full(R, math.log(s.freq_high_fraction * self.fs)), np.full(R, math.log(s.zeta_bounds[1])),
                      s.delay_bounds_samples[1]])

    def refine(self, vp: VarPro, x, nfev: int | None = None):
        return vp.fit(x, *self.bounds(x), max_nfev=self.s.max_nfev if nfev is None else nfev)

    def problem(self, data, x, white: bool = True, noise_from: VarPro | None = None, residual: bool = False):
        """The OE problem on ``data = (i0, i1, segments)`` with the run-out columns (once detected),
        whitened by an AR model of its residual at ``x``; returns ``(whitened, unwhitened)``.

        The residual the AR model is fitted to is the unwhitened LS fit's, or, with ``noise_from``
        (a whitened problem on the same data), the output error of *its* coefficients
        (:meth:`VarPro.output_error`): in closed loop the unwhitened LS coefficients are biased
        (the feedback current is correlated with the coloured noise), and an AR model of their
        residual whitens their misfit, not the noise -- the whitened residual then stays coloured
        and the prediction-error estimate keeps a bias.

        ``residual``: the model has the residual compliance column (``residual_fs_multiple``): the
        final stage's, not the search's -- near-collinear with the quasi-static response of broad
        high-frequency candidates, it lets the search's refinement wander (on the 36 kHz calibration
        drive two logs of 20 lost their 8.3 kHz mode to a broad 15.2 kHz one of gain 2).  The search
        finds the modes with the plant model alone; the final estimate and covariance hold the term."""
        i0, i1, seg = data
        uu, yy = self.u[i0:i1], self.y[i0:i1]
        P = self.nuisance_period
        Z = None if P is None else periodic_columns(len(uu), P, self.s.periodic_harmonics, offset=i0)
        rh = self.s.residual_fs_multiple * self.fs if residual else 0.0
        vp = VarPro(uu, yy, self.dt, seg, nuisance=Z, residual_hz=rh)
        if not (white and self.s.ar_order):
            return vp, vp
        b = vp.proj.bounds                           # the residual is the unwhitened problem's: projected
        r = vp.solve(x)[2] if noise_from is None else vp._project(vp.proj.take(noise_from.output_error(x)))
        d = np.atleast_1d(np.poly(np.ones(int(self.s.noise_unit_poles))))   # (1 - q^-1)^m: noise poles at z = 1
        ar = ar_whitener([fir_filter(d, r[b[i]:b[i + 1]])[len(d) - 1:] for i in range(len(b) - 1)],
                         int(self.s.ar_order))
        ar = None if ar is None else np.convolve(d, ar)
        return VarPro(uu, yy, self.dt, seg, ar=ar, nuisance=Z, residual_hz=rh), vp

    def prune(self, vp: VarPro, x):
        """Drop the least significant mode while any |gain|/std < t_min, near-duplicates, and
        run-out lines (undamped, on a harmonic of the run-out period)."""
        s = self.s
        while _n_modes(x) > 0:
            R = _n_modes(x)
            tv, f, z = _t_stats(vp, x), np.exp(x[:R]), np.exp(x[R:2 * R])
            for i in range(R):                     # two modes closer than duplicate_sep_rel: drop the weaker
                for j in range(i + 1, R):
                    if abs(f[i] / f[j] - 1) < s.duplicate_sep_rel:
                        tv[i if tv[i] < tv[j] else j] = -1.0
            if self.runout_hz:
                h = f / self.runout_hz
                tv[(z < s.runout_zeta_max) & (np.abs(h - np.round(h)) < s.runout_harmonic_tol)] = -2.0
            worst = int(np.argmin(tv))
            if tv[worst] >= s.t_min:
                return x
            self.tabu.append(float(f[worst]))
            x = _drop(x, np.arange(R) != worst)
            if len(x) > 1:
                x = self.refine(vp, x, s.final_nfev)
        return x

    # ----------------------------------------------------------------------- stages
    def start(self):
        """(a) The rigid fit and the pooled matrix pencil on the settle windows: the start ``x``."""
        s, fs = self.s, self.fs
        rf = rigid_fit(self.u, self.y, self.segs, self.dt, delay_range=s.rigid_delay_range_samples,
                       ngrid=s.rigid_delay_grid)
        self.lap("rigid")
        pes = self.log.pes                          # one array: slices of it share its memory
        wins = [pes[q.settle:q.end] for q in self.fit_seeks if q.settled]
        try:
            poles, pdiag = matrix_pencil(wins, fs, freq_range=(self.lo, self.hi))
            self.diag["pencil_order"] = pdiag.order
            self.diag["pencil_rejected"] = [(float(z_to_modal(z, fs)[0]), why) for z, why in pdiag.rejected]
        except ValueError as exc:                  # no window long enough
            poles, self.diag["pencil_error"] = [], str(exc)
        orders = range(2, s.stabilisation_max_order + 2, 2)
        try:                                        # stabilisation diagram: pencil poles per order
            for o, fz in zip(orders, stabilisation_diagram(wins, fs, orders)):
                self.ppo[f"pencil order {o}"] = [tuple(map(float, row)) for row in fz]
        except ValueError:
            pass
        self.ppo["pencil"] = [(p.freq_hz, p.zeta) for p in poles]
        self.diag["settle_modes"] = [(p.freq_hz, p.zeta, p.amplitude) for p in poles]
        cand = sorted((p for p in poles if self.lo <= p.freq_hz <= self.hi), key=lambda p: -p.energy)[:s.max_modes]
        x = np.r_[np.log([p.freq_hz for p in cand]), np.log([max(p.zeta, s.zeta_start_min) for p in cand]),
                  rf.delay_s / self.dt]
        self.lap("pencil")
        return rf, x

    def search_stage(self, x):
        """(b) On the search stage's data: OE from the pencil poles, AR whitening, the scan; then the
        repeatable run-out (period detected in the residual of the model with its modes) as nuisance
        columns, and the scan again."""
        s = self.s
        sub = _stage(self.segs, s.stage_rows, s.stage_history)
        vp0 = self.problem(sub, x, white=False)[0]
        if len(x) > 1:
            x = self.refine(vp0, x)
        self.ppo["OE from pencil"] = list(zip(*VarPro.unpack(x)[:2]))
        self.lap("refine")
        vp, vp0 = self.problem(sub, x)
        if len(x) > 1:
            x = self.prune(vp, self.refine(vp, x))
        x = self.search(vp, x)
        period, fstat = None, 0.0
        if s.periodic == "auto":
            lo, hi = s.periodic_search_samples
            period, fstat = detect_period(vp0.proj.rows, vp0.solve(x)[2], periods=range(int(lo), int(hi) + 1),
                                          f_min=s.periodic_min_F)
        elif s.periodic:
            period = int(s.periodic)
        self.diag.update(periodic_period_samples=period, periodic_F=fstat)
        if period:
            self.nuisance_period, self.runout_hz = period, self.fs / period
            vp, vp0 = self.problem(sub, x)
            if len(x) > 1:
                x = self.prune(vp, self.refine(vp, x))
            x = self.search(vp, x)
        self.diag["scan_added"], self.diag["tabu_hz"] = self.added, self.tabu
        self.lap("scan")
        return x, int(sum(b - a for a, b in sub[2]))

    def final_stage(self, x, residual: bool = True):
        """(c) All fitted seeks: AR model from the OE residual, refine, prune, covariance (modes not
        significant in it dropped); ``residual``: with the residual-compliance column."""
        s = self.s
        data = (0, None, self.segs)
        vp, vp0 = self.problem(data, x, residual=residual)
        if len(x) > 1:
            x = self.prune(vp, self.refine(vp, x, s.final_nfev))
        for _ in range(s.noise_model_passes):       # the noise model of the prediction-error estimate's own error
            vp, vp0 = self.problem(data, x, noise_from=vp, residual=residual)
            if len(x) > 1:
                x = self.refine(vp, x, s.final_nfev)
        while True:
            R = _n_modes(x)
            cov, cov_white, r = self.covariance(vp, x)
            X, c, r, _ = vp.solve(x)
            tv = np.abs(c[2:2 + R]) / np.maximum(np.sqrt(np.diag(cov)[len(x) + 2:len(x) + 2 + R]), _TINY)
            if R == 0 or tv.min() >= s.t_min:
                return x, vp, vp0, cov, cov_white, c, r
            x = _drop(x, np.arange(R) != int(np.argmin(tv)))
            if len(x) > 1:
                x = self.refine(vp, x, s.final_nfev)

    def residual_share(self, vp0: VarPro, x, c) -> tuple[float, float]:
        """``(RMS of the residual-compliance term, RMS of the output error)`` [track] on the fit rows
        (unwhitened, per-segment affine projected out) of the coefficients ``c`` at ``x``: what the
        plant, which does not hold the term, loses against the model fitted."""
        R = _n_modes(x)
        X = vp0.solve(x)[0]
        term = X[:, 2 + R] * c[2 + R]
        return float(np.sqrt(np.mean(term ** 2))), float(np.sqrt(np.mean((vp0.yt - X @ c) ** 2)))

    def covariance(self, vp: VarPro, x):
        """``(cov, cov_white, r)`` of ``[x, c]``: the sandwich (``cov`` setting) of the whitened
        problem and the plain Gauss-Newton one."""
        J, r = vp.jacobian(x, full=True)
        cov, cov_white = sandwich_cov(J, r, vp.proj.bounds, lags=self.s.nw_lags, kind=self.s.cov)
        return cov, cov_white, r

    def bias(self, plant: ModalPlant, runout):
        """(d) ``(bias_a, std)`` [A] from the whole log (``bias_from="whole-log"``), else ``plant``'s
        (the per-seek fit's)."""
        per_seek = (plant.bias_a, plant.std["bias_a"])
        self.diag["bias_per_seek"] = {"bias_a": per_seek[0], "std": per_seek[1]}
        if self.s.bias_from != "whole-log":
            return per_seek
        seeks = segment_seeks(self.log)
        segs = [(q.start, q.end) for q in seeks]
        try:
            v0 = initial_velocities(self.log, plant, segs, runout)
            be = momentum_bias(self.u, [a for a, _ in segs], v0, plant.k0, self.dt, plant.delay_s)
        except ValueError as exc:                   # fewer than 3 seeks: the per-seek value
            self.diag["bias_whole_log_error"] = str(exc)
            return per_seek
        std = be.std_a
        try:                                        # the model-free balance between rest windows
            rest = whole_log_bias(self.u, self.y, [(q.settle, q.end) for q in seeks if q.settled], plant.k0,
                                  self.dt, plant.delay_s)
            std = rest.std_a
        except ValueError:
            rest = None
        self.diag["bias_whole_log"] = {"bias_a": be.bias_a, "std": std, "std_model_velocity": be.std_a,
                                       "bias_rest_windows": None if rest is None else rest.bias_a,
                                       "n_chunks": be.n_chunks, "span_s": be.span_s}
        return be.bias_a, std

    def identify(self) -> Identification:
        rf, x = self.start()
        x, n_stage = self.search_stage(x)
        x_search = x
        x, vp, vp0, cov, cov_white, c, r = self.final_stage(x)
        dropped = None
        if vp.residual_hz:                          # the plant does not hold the term: it must stay small
            term, oe = self.residual_share(vp0, x, c)
            if term > max(self.s.residual_max_share * oe, self.s.residual_max_track):
                R = _n_modes(x)
                dropped = {"s2": float(c[2 + R] / c[0]), "mode_hz": vp.residual_hz, "kept": False,
                           "term_rms_track": term, "oe_rms_track": oe,
                           "modes_with_it": [(float(f), float(z)) for f, z in zip(*VarPro.unpack(x)[:2])]}
                x, vp, vp0, cov, cov_white, c, r = self.final_stage(x_search, residual=False)
        if self.s.cov_floor_white:                  # the reported std (the modes' t-test above kept as it was)
            cov = floored_cov(cov, cov_white)
        self.ppo["final"] = list(zip(*VarPro.unpack(x)[:2]))
        f, z, d = VarPro.unpack(x)
        R, nx = _n_modes(x), len(x)
        sd = np.sqrt(np.abs(np.diag(cov)))
        cc = cov[nx:, nx:]                          # covariance of c = [k0, k0 bias, k0 g]
        modes = [Mode(float(f[i]), float(z[i]), float(c[2 + i] / c[0]),
                      {"freq_hz": float(f[i] * sd[i]), "zeta": float(z[i] * sd[R + i]),
                       "gain": _ratio_std(c, cc, 2 + i)})
                 for i in np.argsort(f)]
        log = self.log
        plant = ModalPlant(k0=float(c[0]), modes=modes, bias_a=float(c[1] / c[0]), delay_s=float(d * self.dt),
                           sample_rate_hz=self.fs, track_pitch_nm=log.track_pitch_nm,
                           std={"k0": float(sd[nx]), "bias_a": _ratio_std(c, cc, 1),
                                "delay_s": float(sd[2 * R] * self.dt)})
        r_oe = vp0.solve(x)[2]
        diag = self.diag
        if self.nuisance_period is not None:
            rho = vp.nuisance_coef(x)
            diag["runout"] = {"period_samples": int(self.nuisance_period), "cos_track": rho[0::2].tolist(),
                              "sin_track": rho[1::2].tolist()}
        plant.bias_a, plant.std["bias_a"] = self.bias(plant, diag.get("runout"))
        if vp.residual_hz:                          # c[2 + R] = k0 D: the residual compliance [s^2]
            diag["residual_compliance"] = {"s2": float(c[2 + R] / c[0]), "std": _ratio_std(c, cc, 2 + R),
                                           "mode_hz": vp.residual_hz, "kept": True}
        elif dropped is not None:
            diag["residual_compliance"] = dropped
        infl = np.sqrt(np.diag(cov) / np.maximum(np.diag(cov_white), _TINY))
        diag.update(ar_order=int(self.s.ar_order), std_inflation_median=float(np.median(infl)),
                    std_inflation_max=float(np.max(infl)), whitened_residual_rms=float(np.sqrt(np.mean(r ** 2))),
                    t_stat=[float(v) for v in np.abs(c[2:2 + R]) / np.maximum(np.sqrt(np.diag(cc)[2:2 + R]), _TINY)],
                    rigid_init={"k0": rf.k0, "bias_a": rf.bias_a, "delay_s": rf.delay_s},
                    n_fit_rows=int(vp.proj.n_rows), n_stage_rows=n_stage, nfev=vp.nfev + vp0.nfev)
        self.lap("final")
        return Identification(plant, "robust", self.ppo, residual_rms=float(np.sqrt(np.mean(r_oe ** 2))),
                              diagnostics=diag, settings=self.s)
