"""Identify the modal plant from a seek log: the paper's method and a robust output-error method.

``identify(log, method="robust" | "paper", **options) -> Identification``.  Only the columns a real
drive logs are used: ``time_s``, ``current_a``, ``position_track``, ``target_track`` (never the
synthetic drive's feedforward or reference columns); a multirate drive's sub-step currents
``current_sub1_a`` .. ``current_subL_a``, when logged, replace ``current_a`` in the robust method
(exact hold, :meth:`identification.logs.seeklog.SeekLog.input_current`).

``method="paper"`` (Sections 2-3 of the seed paper, in order)
    1. eq. (8): rigid-body ``b0, b1`` by LS over each seek (start to end, position relative to the
       start), pooled; ``k0 = b0 / Ts^2`` (:mod:`identification.estimate.rigid` on ERRATA item 5: not the
       printed ``2 b0 / Ts^2``).  No delay (the paper has none).
    2. LS Prony (eqs. (4)-(7), :func:`identification.estimate.prony.ls_prony`, ``prony_order`` mode pairs) on
       the PES after settling, pooled over the settle windows.  As in the paper the PES is used as it
       is: no rigid-body prediction is removed (the paper treats the PES after settling as the modes'
       response).  Stable roots with a natural frequency in ``freq_range`` and ``zeta < 0.5`` are kept.
    3. eqs. (9)-(11) (:func:`identification.estimate.gains.modal_gains`): gains by LS of the settle-window PES
       on each mode's response to the measured current (regressors over the whole log).

``method="robust"`` (default)
    a. Start: the ZOH rigid fit with fractional delay (:func:`identification.estimate.rigid.rigid_fit`) and
       the pooled matrix pencil on the settle-window PES (automatic order, spurious-pole rejection,
       :func:`identification.estimate.prony.matrix_pencil`).
    b. Joint output-error fit of the measured position to the measured current over whole seek
       segments (seek start to end: the seek is where the modes are excited far above the noise,
       while after settling they are not -- at the benchmark noise no mode's settle-window response
       exceeds the noise at its frequency), by variable projection (:class:`identification.estimate.gains.VarPro`):
       ``scipy.optimize.least_squares`` over each mode's frequency and damping and the delay, with the
       linear parameters (``k0``, ``k0 bias``, ``k0 g_r``, per-segment initial position and velocity,
       run-out harmonics) projected out by LS at every evaluation.  The rigid body is the exact ZOH +
       delay discretisation of plant.py; each mode's response runs over the whole log, so mode states
       carry over from seek to seek.  The noise is coloured (flutter, run-out, and above all the
       unlogged force noise, which the double integrator turns into a random walk of position): the
       residual is prewhitened by an AR(``ar_order``) model of the first fit's residual -- the direct
       prediction-error method with an AR noise model, consistent in closed loop when the noise
       model whitens the residual, and near-efficient.  Modes the settle windows do not show are
       found by a scan of the whitened residual over a frequency grid (the residual-sum-of-squares
       reduction of one more mode, refined on a finer local grid, added while significant), and
       modes whose gain is not significant (``|g| / std < t_min``) are dropped.  A repeatable
       run-out (period detected in the residual of the model with its modes,
       :func:`identification.estimate.gains.detect_period`) enters as ``periodic_harmonics`` harmonics.  The
       search runs on the first fitted seeks holding about ``stage_rows`` samples (a contiguous
       stretch of the log), the final refinement on all fitted seeks.
    c. Standard deviations from the Jacobian of the whitened problem with respect to all parameters
       (Gauss-Newton covariance), as a Newey-West sandwich (Bartlett weights, ``nw_lags`` lags,
       within segments) for the colour the AR model leaves; the ratio to the plain ``s^2 (J^T J)^-1``
       is reported (``diagnostics["std_inflation_median"]``).  They are statistical only: the model
       error below is not in them.

Known model error (tolerated, not modelled).  The synthetic drive steps the plant at 2x the PES rate
with multirate notches and logs the mean current per PES sample; the intersample current then acts
as an unlogged feedback around the high-frequency modes.  Measured on the default drive: 4.1 kHz
frequency +0.5 %, 7 kHz damping about -33 %; on a drive with single-rate notches these vanish
(``tests/test_identify.py``, ``docs/results_identification.md``).

Fit % on held-out seeks (both methods).  Seeks ``i`` with ``i % holdout_every == holdout_every - 1``
are not fitted.  For each of them the model is simulated from the measured current (modes over the
whole log, rigid body and bias from the seek start, plus the identified run-out), the seek's initial
position and velocity are fitted by LS over the whole seek (two numbers per seek), and on the settle
windows ``[N, M]`` of those seeks ``fit = 100 (1 - ||y - y_hat|| / ||y - y_bar||)`` with ``y`` the PES,
``y_hat`` the predicted PES and ``y_bar`` the mean of ``y`` over those windows
(:func:`heldout_fit`).  ``diagnostics["fit_percent_window_init"]`` fits the initial position and
velocity on the settle window instead.  With force noise the open-loop simulation accumulates a
position random walk over a seek that no model predicts, so the fit is only meaningful on logs
without it (``SynthConfig(noise=False)``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from identification.estimate.gains import (VarPro, ar_whitener, detect_period, modal_gains, mode_regressors, periodic_columns,
                    sandwich_cov)
from identification.logs.seeklog import LogError, SeekLog, segment_seeks
from identification.model.plant import ModalPlant, Mode
from identification.estimate.prony import fit_amplitudes, ls_prony, matrix_pencil, modal_to_z, stabilisation_diagram, z_to_modal
from identification.estimate.rigid import bias_response, eq8_fit, rigid_fit, zoh_rigid_response

__all__ = ["Identification", "identify", "heldout_fit", "predict_segments", "runout_signal"]


@dataclass
class Identification:
    """What :func:`identify` found.

    Attributes
    ----------
    plant : ModalPlant
        The identified plant; ``plant.std`` holds ``k0``, ``bias_a``, ``delay_s`` standard
        deviations and each mode's ``std`` its ``freq_hz``, ``zeta``, ``gain`` ones.
    method : str
        ``"robust"`` or ``"paper"``.
    poles_per_order : dict
        Pole sets seen on the way: ``{label: [(freq_hz, zeta), ...]}`` (pencil, Prony order,
        after each refinement stage).
    fit_percent : float
        Held-out fit % on settle windows (see the module notes); nan without held-out seeks.
    fit_percent_rigid : float
        The same for the identified rigid body alone (modes removed).
    residual_rms : float
        RMS of the fit residual [track] (robust: output error on the fit segments, before
        whitening; paper: eq. (10) residual on the settle windows).
    timing : dict
        Seconds per stage.
    diagnostics : dict
        Anything else, e.g. ``fit_percent_window_init`` (held-out fit with the initial conditions
        fitted on the settle window), ``runout`` (period and harmonic amplitudes [track] of the
        identified repeatable run-out), ``t_stat`` (|gain| / std per mode), ``std_inflation_median``
        (sandwich / plain std), ``scan_added``, ``pencil_rejected``, ``samples_per_s``.
    """
    plant: ModalPlant
    method: str
    poles_per_order: dict = field(default_factory=dict)
    fit_percent: float = float("nan")
    fit_percent_rigid: float = float("nan")
    residual_rms: float = float("nan")
    timing: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------- held-out fit
def runout_signal(n: int, runout: dict | None) -> np.ndarray:
    """The identified repeatable run-out [track] at log samples ``0..n-1`` (zeros if None):
    ``sum_h a_h cos(2 pi h k / P) + b_h sin(2 pi h k / P)``."""
    if not runout:
        return np.zeros(n)
    Z = periodic_columns(n, runout["period_samples"], len(runout["cos_track"]))
    return Z @ np.ravel(np.column_stack([runout["cos_track"], runout["sin_track"]]))


def predict_segments(log: SeekLog, plant: ModalPlant, segments, init=None, steady: bool = True, runout=None):
    """Predicted position [track] on each segment ``[i0, i1)`` (list of arrays).

    The plant's response to the measured current -- modes run over the whole log (their state at
    ``i0`` comes from the current history), rigid body and bias restarted at ``i0`` -- plus an
    initial position and velocity fitted by LS over ``init[j] = (a, b)`` (log indices inside the
    segment; default the whole segment), plus the identified run-out (:func:`runout_signal`) if given.
    """
    dt, u = log.dt, log.input_current()
    starts = [a for a, _ in segments]
    d = plant.delay_s
    y = plant.k0 * (zoh_rigid_response(u, dt, d, starts) + plant.bias_a * bias_response(len(u), dt, starts))
    if plant.modes:
        M = mode_regressors(u, [m.freq_hz for m in plant.modes], [m.zeta for m in plant.modes], dt, d, steady)
        y = y + M @ (plant.k0 * np.array([m.gain for m in plant.modes]))
    if runout:
        y = y + runout_signal(len(u), runout)
    out = []
    for j, (a, b) in enumerate(segments):
        ia, ib = (a, b) if init is None else init[j]
        t = (np.arange(a, b, dtype=float) - a) / max(b - a, 1)
        V = np.column_stack([np.ones_like(t), t])
        k = slice(ia - a, ib - a)
        coef = np.linalg.lstsq(V[k], log.position_track[ia:ib] - y[ia:ib], rcond=None)[0]
        out.append(y[a:b] + V @ coef)
    return out


def heldout_fit(log: SeekLog, plant: ModalPlant, seeks, init: str = "seek", runout=None) -> float:
    """Fit % ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` of the settle-window PES of ``seeks``.

    ``y`` is the PES on the settle windows ``[N, M]`` of the (settled) seeks, concatenated;
    ``y_hat`` the PES predicted by :func:`predict_segments` over each seek, its initial position and
    velocity fitted over the whole seek (``init="seek"``: a simulation from the seek start, the
    definition used for :attr:`Identification.fit_percent`) or over the settle window only
    (``init="window"``: insensitive to the double-integrated force noise accumulated during
    the seek).  ``runout`` (``Identification.diagnostics["runout"]``) adds the identified repeatable
    run-out to the prediction.
    """
    seeks = [s for s in seeks if s.settled and s.settle - s.start >= 2 and s.end - s.settle >= 4]
    if not seeks:
        return float("nan")
    segs = [(s.start, s.end) for s in seeks]
    pred = predict_segments(log, plant, segs, None if init == "seek" else [(s.settle, s.end) for s in seeks],
                            runout=runout)
    pes = log.pes                                   # (a property: compute once)
    y = np.concatenate([pes[s.settle:s.end] for s in seeks])
    yh = np.concatenate([p[s.settle - s.start:] - log.target_track[s.settle:s.end] for p, s in zip(pred, seeks)])
    return float(100.0 * (1.0 - np.linalg.norm(y - yh) / np.linalg.norm(y - y.mean())))


# ------------------------------------------------------------------------------- identify
def _split(log: SeekLog, holdout_every: int):
    seeks = segment_seeks(log)
    name = log.source or "<log>"
    if len(seeks) < 2:
        raise LogError(name, f"need at least 2 seeks to identify a plant, found {len(seeks)}")
    if holdout_every and holdout_every > 1 and len(seeks) >= 2 * holdout_every:
        held = [s for i, s in enumerate(seeks) if i % holdout_every == holdout_every - 1]
        fit = [s for i, s in enumerate(seeks) if i % holdout_every != holdout_every - 1]
    else:
        held, fit = [], seeks
    if not any(s.settled for s in fit):
        raise LogError(name, "no seek settles within the 0.1-track band: no settle window to identify modes from")
    return seeks, fit, held


def identify(log: SeekLog, method: str = "robust", **options) -> Identification:
    """Identify the modal plant (rigid body, modes, bias, delay) from a seek log.

    Parameters
    ----------
    log : SeekLog
        Seek log; only ``current_a``, ``position_track``, ``target_track`` (and the rate) are used.
    method : {"robust", "paper"}
        See the module notes.
    **options
        ``holdout_every`` (int, 5: every 5th seek is held out for the fit %; 0 or fewer than
        ``2 holdout_every`` seeks: none), ``freq_range`` ((lo, hi) [Hz], default ``(100, 0.47 fs)``:
        where modes are looked for), ``prony_order`` (8, paper: mode pairs of LS Prony).
        Robust only: ``max_modes`` (12), ``ar_order`` (32: whitening AR order, 0 disables),
        ``t_min`` (5.0: least |gain| / std kept), ``scan`` (True: add modes the pencil missed),
        ``max_nfev`` / ``final_nfev`` (25 / 10: evaluations per refinement in the search / final
        stage), ``stage_rows`` (60000: samples of the search stage, a contiguous stretch of the log
        starting ``stage_history`` (4096) samples before its first seek), ``periodic`` ("auto",
        None or a period in samples: repeatable run-out), ``periodic_harmonics`` (10),
        ``cov`` ("newey-west" or "cluster": see :func:`identification.estimate.gains.sandwich_cov`),
        ``nw_lags`` (32: Newey-West lags), ``blind`` (True: write the bands where a mode would have
        escaped detection into ``plant.meta``, :func:`identification.estimate.blind.blind_meta`).

    Returns
    -------
    Identification

    Raises
    ------
    LogError
        Too few seeks, no settled seek, or no usable data.
    """
    if method not in ("robust", "paper"):
        raise ValueError(f"method must be 'robust' or 'paper', got {method!r}")
    fs = log.sample_rate_hz
    opts = dict(holdout_every=5, freq_range=(100.0, 0.47 * fs), max_modes=12, ar_order=32, t_min=5.0,
                scan=True, max_nfev=25, final_nfev=10, stage_rows=60_000, stage_history=4096, periodic="auto",
                periodic_harmonics=10, nw_lags=32, cov="newey-west", prony_order=8, blind=True)
    unknown = set(options) - set(opts)
    if unknown:
        raise TypeError(f"identify: unknown option(s) {sorted(unknown)}")
    opts.update(options)
    t0 = time.perf_counter()
    seeks, fit_seeks, held = _split(log, opts["holdout_every"])
    timing = {"segment": time.perf_counter() - t0}
    run = _identify_paper if method == "paper" else _identify_robust
    ident = run(log, fit_seeks, opts, timing)
    t1 = time.perf_counter()
    if held:
        ro, rigid = ident.diagnostics.get("runout"), ident.plant.copy(modes=[])
        ident.fit_percent = heldout_fit(log, ident.plant, held, runout=ro)
        ident.fit_percent_rigid = heldout_fit(log, rigid, held, runout=ro)
        ident.diagnostics["fit_percent_window_init"] = heldout_fit(log, ident.plant, held, "window", ro)
        ident.diagnostics["fit_percent_rigid_window_init"] = heldout_fit(log, rigid, held, "window", ro)
    timing["heldout"] = time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    ident.timing = timing
    ident.diagnostics.update(n_samples=log.n, n_seeks=len(seeks), n_fit_seeks=len(fit_seeks),
                             n_heldout_seeks=len(held), holdout_every=opts["holdout_every"] if held else 0,
                             samples_per_s=log.n / timing["total"] if timing["total"] > 0 else float("inf"))
    fit = None if math.isnan(ident.fit_percent) else round(ident.fit_percent, 3)
    ident.plant.meta.update(method=method, log=log.source or "<arrays>", heldout_fit_percent=fit)
    if opts["blind"] and method == "robust":     # what the log could not show (identification.estimate.blind)
        from identification.estimate.blind import blind_meta
        t2 = time.perf_counter()
        ident.plant.meta.update(blind_meta(log, ident.plant, t_min=opts["t_min"], freq_range=opts["freq_range"],
                                           runout=ident.diagnostics.get("runout")))
        timing["blind"] = time.perf_counter() - t2
    return ident


def _t_stats(vp: VarPro, x):
    """|c_r| / std(c_r) of the mode coefficients (white LS covariance of the whitened problem)."""
    R = (len(x) - 1) // 2
    X, c, r, _ = vp.solve(x)
    s = np.linalg.norm(X, axis=0)
    s[s == 0] = 1.0
    cov = np.linalg.pinv((X / s).T @ (X / s)) / np.outer(s, s) * float(r @ r) / max(len(r) - X.shape[1], 1)
    return np.abs(c[2:2 + R]) / np.sqrt(np.maximum(np.diag(cov)[2:2 + R], 1e-300))


def _drop(x, keep):
    R = (len(x) - 1) // 2
    keep = np.asarray(keep, dtype=bool)
    return np.r_[x[:R][keep], x[R:2 * R][keep], x[2 * R]]


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


def _identify_robust(log: SeekLog, fit_seeks, opts, timing) -> Identification:
    fs, dt = log.sample_rate_hz, log.dt
    u, y = log.input_current(), log.position_track     # (n, L) for a multirate log: exact hold
    lo, hi = opts["freq_range"]
    segs = [(s.start, s.end) for s in fit_seeks]
    ppo, diag, tabu, runout_hz = {}, {}, [], [0.0]
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        timing[name] = now - clock
        clock = now

    rf = rigid_fit(u, y, segs, dt)
    lap("rigid")
    # (a) pooled matrix pencil on the settle windows
    pes = log.pes                                   # one array: slices of it share its memory
    wins = [pes[s.settle:s.end] for s in fit_seeks if s.settled]
    try:
        poles, pdiag = matrix_pencil(wins, fs, freq_range=(lo, hi))
        diag["pencil_order"] = pdiag.order
        diag["pencil_rejected"] = [(float(z_to_modal(z, fs)[0]), why) for z, why in pdiag.rejected]
    except ValueError as exc:                      # no window long enough
        poles, diag["pencil_error"] = [], str(exc)
    try:                                            # stabilisation diagram: pencil poles per order
        for o, fz in zip(range(2, 26, 2), stabilisation_diagram(wins, fs, range(2, 26, 2))):
            ppo[f"pencil order {o}"] = [tuple(map(float, row)) for row in fz]
    except ValueError:
        pass
    ppo["pencil"] = [(p.freq_hz, p.zeta) for p in poles]
    diag["settle_modes"] = [(p.freq_hz, p.zeta, p.amplitude) for p in poles]
    cand = sorted((p for p in poles if lo <= p.freq_hz <= hi), key=lambda p: -p.energy)[:opts["max_modes"]]
    x = np.r_[np.log([p.freq_hz for p in cand]), np.log([max(p.zeta, 1e-3) for p in cand]), rf.delay_s / dt]
    lap("pencil")

    def bounds(x):
        R = (len(x) - 1) // 2
        return (np.r_[np.full(R, math.log(0.8 * lo)), np.full(R, math.log(1e-4)), 0.0],
                np.r_[np.full(R, math.log(0.499 * fs)), np.full(R, math.log(0.7)), 4.0])

    def refine(vp, x, nfev=opts["max_nfev"]):
        return vp.fit(x, *bounds(x), max_nfev=nfev)

    def make(data, x, nuis, white=True):
        """The OE problem ``data = (i0, i1, segments)``, whitened by an AR model of its residual at
        ``x``; returns (whitened, unwhitened)."""
        i0, i1, seg = data
        uu, yy = u[i0:i1], y[i0:i1]
        Z = None if nuis is None else periodic_columns(len(uu), nuis, opts["periodic_harmonics"], offset=i0)
        vp = VarPro(uu, yy, dt, seg, nuisance=Z)
        if not (white and opts["ar_order"]):
            return vp, vp
        b = vp.proj.bounds
        r = vp.solve(x)[2]
        ar = ar_whitener([r[b[i]:b[i + 1]] for i in range(len(b) - 1)], int(opts["ar_order"]))
        return VarPro(uu, yy, dt, seg, ar=ar, nuisance=Z), vp

    def prune(vp, x):
        """Drop the least significant mode while any |gain|/std < t_min, near-duplicates, and
        run-out lines (undamped, zeta < 1e-3, on a harmonic of the run-out period)."""
        while (len(x) - 1) // 2 > 0:
            R = (len(x) - 1) // 2
            tv, f, z = _t_stats(vp, x), np.exp(x[:R]), np.exp(x[R:2 * R])
            for i in range(R):                     # two modes within 1.5 %: drop the weaker
                for j in range(i + 1, R):
                    if abs(f[i] / f[j] - 1) < 0.015:
                        tv[i if tv[i] < tv[j] else j] = -1.0
            if runout_hz[0]:
                h = f / runout_hz[0]
                tv[(z < 1e-3) & (np.abs(h - np.round(h)) < 0.02)] = -2.0
            worst = int(np.argmin(tv))
            if tv[worst] >= opts["t_min"]:
                return x
            tabu.append(float(f[worst]))
            x = _drop(x, np.arange(R) != worst)
            if len(x) > 1:
                x = refine(vp, x, opts["final_nfev"])
        return x

    # (b) search stage on at most stage_rows samples: OE from the pencil poles, AR whitening, the scan
    # for modes the settle windows did not show; then the repeatable run-out (period detected in the
    # residual of the model with its modes) as nuisance columns, and the scan again
    sub = _stage(segs, opts["stage_rows"], opts["stage_history"])
    vp0 = make(sub, x, None, white=False)[0]
    if len(x) > 1:
        x = refine(vp0, x)
    ppo["OE from pencil"] = list(zip(*VarPro.unpack(x)[:2]))
    lap("refine")
    grid = np.exp(np.arange(math.log(lo), math.log(hi), math.log(1.02)))
    zetas, fine_zetas = (0.01, 0.05), (0.003, 0.01, 0.03, 0.1)
    added = []

    def search(vp, x):
        idle = 0
        for _ in range(opts["max_modes"]):
            R = R0 = (len(x) - 1) // 2
            if not opts["scan"] or R >= opts["max_modes"]:
                break
            stat, r = vp.scan(x, grid, zetas)
            s2 = float(r @ r) / max(len(r) - R - 2, 1)
            best = stat.max(axis=1) / s2
            for f0 in tabu:                         # not again where a mode was proposed or dropped
                best[np.abs(grid / f0 - 1) < 0.01] = 0.0
            for f0 in np.exp(x[:R]):                # nor where one is
                best[np.abs(grid / f0 - 1) < 0.02] = 0.0
            new = []
            for i in np.argsort(best)[::-1]:       # the best peaks, >= 5 % apart, up to 3 per round
                if best[i] <= 2 * opts["t_min"] ** 2 or len(new) >= min(3, opts["max_modes"] - R):
                    break
                if all(abs(grid[i] / grid[j] - 1) > 0.05 for j in new):
                    new.append(i)
            if not new:
                break
            props = []
            for i in new:                           # refine each peak on a fine local grid
                fl = grid[i] * np.exp(np.linspace(-0.02, 0.02, 17))
                st = vp.scan(x, fl, fine_zetas)[0]
                k, j = np.unravel_index(int(np.argmax(st)), st.shape)
                if all(abs(fl[k] / f0 - 1) > 0.03 for f0, _, _ in props) and \
                        all(abs(fl[k] / f0 - 1) > 0.01 for f0 in tabu):
                    props.append((float(fl[k]), fine_zetas[j], float(st[k, j] / s2)))
            for f0, zt, st in props:
                added.append((f0, zt, st))
                tabu.append(f0)                     # each frequency is proposed once
                R = (len(x) - 1) // 2
                x = np.r_[x[:R], math.log(f0), x[R:2 * R], math.log(zt), x[2 * R]]
            x = prune(vp, refine(vp, x))
            idle = idle + 1 if (len(x) - 1) // 2 <= R0 else 0
            if idle >= 2:                           # two rounds without a new mode: stop
                break
        return x

    vp, vp0 = make(sub, x, None)
    if len(x) > 1:
        x = prune(vp, refine(vp, x))
    x = search(vp, x)
    period, fstat, nuis = None, 0.0, None
    if opts["periodic"] == "auto":
        period, fstat = detect_period(vp0.proj.rows, vp0.solve(x)[2])
    elif opts["periodic"]:
        period = int(opts["periodic"])
    diag.update(periodic_period_samples=period, periodic_F=fstat)
    if period:
        nuis, runout_hz[0] = period, fs / period
        vp, vp0 = make(sub, x, nuis)
        if len(x) > 1:
            x = prune(vp, refine(vp, x))
        x = search(vp, x)
    diag["scan_added"], diag["tabu_hz"] = added, tabu
    lap("scan")
    # final stage on all fit seeks: AR model from the OE residual, refine, prune, covariance
    vp, vp0 = make((0, None, segs), x, nuis)
    if len(x) > 1:
        x = prune(vp, refine(vp, x, opts["final_nfev"]))
    while True:                                     # covariance; drop modes not significant in it
        R = (len(x) - 1) // 2
        J, r = vp.jacobian(x, full=True)
        cov, cov_white = sandwich_cov(J, r, vp.proj.bounds, lags=opts["nw_lags"], kind=opts["cov"])
        X, c, r, _ = vp.solve(x)
        tv = np.abs(c[2:2 + R]) / np.maximum(np.sqrt(np.diag(cov)[len(x) + 2:len(x) + 2 + R]), 1e-300)
        if R == 0 or tv.min() >= opts["t_min"]:
            break
        x = _drop(x, np.arange(R) != int(np.argmin(tv)))
        if len(x) > 1:
            x = refine(vp, x, opts["final_nfev"])
    ppo["final"] = list(zip(*VarPro.unpack(x)[:2]))
    f, z, d = VarPro.unpack(x)
    sd = np.sqrt(np.abs(np.diag(cov)))
    nx = len(x)
    cc = cov[nx:, nx:]                              # covariance of c = [k0, k0 bias, k0 g]

    def ratio_std(i):                               # delta method: std of c_i / c_0
        gv = np.zeros(len(c))
        gv[0], gv[i] = -c[i] / c[0] ** 2, 1.0 / c[0]
        return float(np.sqrt(max(gv @ cc @ gv, 0.0)))

    modes = [Mode(float(f[i]), float(z[i]), float(c[2 + i] / c[0]),
                  {"freq_hz": float(f[i] * sd[i]), "zeta": float(z[i] * sd[R + i]), "gain": ratio_std(2 + i)})
             for i in np.argsort(f)]
    plant = ModalPlant(k0=float(c[0]), modes=modes, bias_a=float(c[1] / c[0]), delay_s=float(d * dt),
                       sample_rate_hz=fs, track_pitch_nm=log.track_pitch_nm,
                       std={"k0": float(sd[nx]), "bias_a": ratio_std(1), "delay_s": float(sd[2 * R] * dt)})
    r_oe = vp0.solve(x)[2]
    if nuis is not None:
        rho = vp.nuisance_coef(x)
        diag["runout"] = {"period_samples": int(period), "cos_track": rho[0::2].tolist(),
                          "sin_track": rho[1::2].tolist()}
    infl = np.sqrt(np.diag(cov) / np.maximum(np.diag(cov_white), 1e-300))
    diag.update(ar_order=int(opts["ar_order"]), std_inflation_median=float(np.median(infl)),
                std_inflation_max=float(np.max(infl)), whitened_residual_rms=float(np.sqrt(np.mean(r ** 2))),
                t_stat=[float(v) for v in np.abs(c[2:2 + R]) / np.maximum(np.sqrt(np.diag(cc)[2:2 + R]), 1e-300)],
                rigid_init={"k0": rf.k0, "bias_a": rf.bias_a, "delay_s": rf.delay_s},
                n_fit_rows=int(vp.proj.n_rows), n_stage_rows=int(sum(b - a for a, b in sub[2])),
                nfev=vp.nfev + vp0.nfev)
    lap("final")
    return Identification(plant, "robust", ppo, residual_rms=float(np.sqrt(np.mean(r_oe ** 2))), diagnostics=diag)


def _identify_paper(log: SeekLog, fit_seeks, opts, timing) -> Identification:
    fs, dt = log.sample_rate_hz, log.dt
    lo, hi = opts["freq_range"]
    t = time.perf_counter()
    e8 = eq8_fit(log.current_a, log.position_track, [(s.start, s.end) for s in fit_seeks], dt)   # eq. (8)
    timing["rigid"] = time.perf_counter() - t
    t = time.perf_counter()
    windows = [(s.settle, s.end) for s in fit_seeks if s.settled]
    pes = log.pes
    wins = [pes[a:b] for a, b in windows]
    ppo = {}
    n_max = int(opts["prony_order"])
    roots = None
    for n in range(1, n_max + 1):                            # eqs. (4)-(7) at each order
        try:
            roots = ls_prony(wins, n, fs)
        except ValueError:
            break
        up = roots[(roots.imag > 1e-12) & (np.abs(roots) < 1)]
        ppo[f"prony n={n}"] = sorted(zip(*[v.tolist() for v in z_to_modal(up, fs)]))
    if roots is None:
        raise LogError(log.source or "<log>", "settle windows too short for LS Prony")
    up = roots[(roots.imag > 1e-12) & (np.abs(roots) < 1)]
    f, z = z_to_modal(up, fs)
    keep = (f >= lo) & (f <= hi) & (z < 0.5)
    f, z = f[keep], z[keep]
    timing["prony"] = time.perf_counter() - t
    t = time.perf_counter()
    Y = mode_regressors(log.current_a, f, z, dt, 0.0)        # eq. (9), the paper has no delay
    gf = modal_gains(pes, Y, windows)                         # eqs. (10)-(11)
    timing["gains"] = time.perf_counter() - t
    g = gf.coef / e8.k0
    rss_dof = e8.residual_rms ** 2 * e8.n_samples / max(e8.n_samples - 2, 1)
    cov8 = np.linalg.inv(e8.U) * rss_dof
    modes = [Mode(float(fi), float(zi), float(gi), {"gain": float(si / e8.k0)})
             for fi, zi, gi, si in sorted(zip(f, z, g, gf.std))]
    plant = ModalPlant(k0=e8.k0, modes=modes, bias_a=e8.bias_a, delay_s=0.0, sample_rate_hz=fs,
                       track_pitch_nm=log.track_pitch_nm, std={"k0": float(np.sqrt(cov8[0, 0]) / dt ** 2)})
    amps = []
    for w in wins:
        if len(w) > 2 * len(f) + 2 and len(f):
            amps.append(2 * np.abs(fit_amplitudes(w, modal_to_z(f, z, fs), fs)))
    amp = np.mean(amps, axis=0) if amps else np.full(len(f), np.nan)
    diag = {"eq8": {"b0": e8.b0, "b1": e8.b1, "residual_rms": e8.residual_rms},
            "settle_modes": [(float(a), float(b), float(c)) for a, b, c in zip(f, z, amp)],
            "prony_order": n_max}
    return Identification(plant, "paper", ppo, residual_rms=gf.residual_rms, diagnostics=diag)
