"""Closing the loop: residual analysis, candidate effects, re-fit and decision.

:func:`close_loop` takes a seek log and an identified plant and:

1. splits the data: fit on the log, validate on ``validation`` (another log) or, by
   default, on held-out seeks (odd-numbered seeks validate, even ones fit);
2. simulates the model per seek (:func:`identification.residual.simulate`, one
   ``DiscretePlant`` per seek from rest at its start, initial position and velocity
   fitted by least squares) and analyses the residual (evidence);
3. fits every candidate of :data:`identification.candidates.CANDIDATES` on the fit
   data (each re-fitted with ``k0`` and ``bias_a``), simulates it, and accepts the
   best one if (a) its BIC on the fit data (output error with an AR noise model)
   is lower than the current model's by more than ``min_bic``, (b) its RMS error
   on the validation data is at most ``(1 - min_drop)`` times the current one and
   (c) it lowers the error of at least ``min_seeks`` of the validation seeks;
   accepted effects are re-fitted jointly with every later candidate (their linear
   parameters) or re-fitted one by one (backfitting);
4. repeats greedily until no candidate passes, then lists in ``unexplained`` the
   structure that is still in the validation residual.

Every reported error is on validation data, from the reference simulation.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from scipy.stats import chi2 as _chi2

from .candidates import CANDIDATES, Data, Engine, bic, cluster_cov, fit_candidate, lstsq, refit_base, wald
from .logs import SeekLog
from .plant import ModalPlant
from .residual import (Residual, Windows, correlations, detect_spindle, nonlinear_tests, seek_windows,
                       simulate, spectra, synchronous_average)

__all__ = ["Step", "LoopResult", "close_loop", "Dependence", "dependence", "describe_residual",
           "REPEATABLE", "SIMULATION_NOTE"]

#: candidates that may be accepted more than once
REPEATABLE = ("extra_mode",)

#: free-form dependences along variables that no library effect models; a candidate that
#: explains clearly less than one of them is a proxy and is not accepted
OUT_OF_LIBRARY = ("gain_vs_time", "force_vs_time", "current_error_vs_current")

SIMULATION_NOTE = ("each seek (target change to next target change) simulated with DiscretePlant "
                   "from rest at its start (previous current held), the initial position and "
                   "velocity fitted by least squares over the seek")


@dataclass
class Step:
    """One candidate tried at one iteration (errors: validation RMS [track])."""

    effect: str
    params: dict
    evidence: str
    rms_before: float
    rms_after: float
    accepted: bool
    iteration: int = 0
    bic_drop: float = 0.0
    fit_percent_after: float = float("nan")
    improved_fraction: float = float("nan")
    plant: ModalPlant | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {"effect": self.effect, "params": _jsonable(self.params), "evidence": self.evidence,
                "rms_before": float(self.rms_before), "rms_after": float(self.rms_after),
                "accepted": bool(self.accepted)}


@dataclass
class LoopResult:
    """Outcome of :func:`close_loop`; :meth:`report` is the JSON report."""

    plant: ModalPlant
    model: ModalPlant
    error_before: dict
    error_after: dict
    steps: list
    unexplained: list
    res_before: Residual
    res_after: Residual
    fit: Data
    val: Data
    analysis_before: dict
    analysis_after: dict
    runtime_s: float
    notes: list = field(default_factory=list)

    @property
    def accepted(self) -> list:
        """Accepted effects in order of first acceptance."""
        return list(dict.fromkeys(s.effect for s in self.steps if s.accepted))

    def report(self) -> dict:
        """The JSON report: ``plant`` (ModalPlant JSON, accepted effects included),
        ``error_before``/``error_after`` (validation RMS [track], fit [%]), ``steps``,
        ``unexplained``."""
        plant = _jsonable(self.plant.to_dict())
        return {"plant": plant, "error_before": self.error_before, "error_after": self.error_after,
                "steps": [s.to_dict() for s in self.steps], "unexplained": list(self.unexplained)}


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


# ----------------------------------------------------------------------- evaluation
def _harmonic_nuisance(res: Residual, plant: ModalPlant) -> np.ndarray:
    """For a separate validation log: the periodic disturbance's phase at the log start is
    unknown, so its cos/sin coefficients are re-estimated on one half of the windows and
    applied to the other (2-fold, halves in time) -- the error stays out of sample."""
    from .effects import PeriodicDisturbance
    pd = [e for e in plant.effects if isinstance(e, PeriodicDisturbance)]
    if not pd:
        return res.e
    t = res.log.time_s
    idx = res.windows.index()
    cols = []
    for e in pd:
        for h in e.harmonics:
            ph = 2 * np.pi * h * e.spindle_hz * t[idx]
            cols += [np.cos(ph), np.sin(ph)]
    X = np.column_stack(cols)
    half = np.zeros(len(idx), bool)
    half[:len(idx) // 2] = True
    e = res.e.copy()
    for a, b in ((half, ~half), (~half, half)):
        th = lstsq(res.e[a], X[a])[0]
        e[b] = res.e[b] - X[b] @ th
    return e


def evaluate(plant: ModalPlant, data: Data, same_log: bool = True, record: bool = False) -> Residual:
    """Reference residual of ``plant`` on ``data`` (per-seek simulation).  On a log other than
    the fit log, output effects (periodic disturbance) are re-phased out of sample."""
    if same_log:
        return simulate(plant, data.log, data.windows, continuous=False, record=record)
    keep = [e for e in plant.effects if e.kind != "output"]
    res = simulate(plant.copy(effects=keep), data.log, data.windows, continuous=False, record=record)
    return Residual(res.windows, _harmonic_nuisance(res, plant), res.y_sim, res.log, res.cmd, res.force)


def improved_fraction(new: Residual, old: Residual) -> float:
    """Fraction of validation seeks whose squared error the new model lowers [-]."""
    def per_seek(r):
        out, i = {}, 0
        for (a, b), g in zip(r.windows.bounds, r.windows.groups):
            out[g] = out.get(g, 0.0) + float(r.e[i:i + b - a] @ r.e[i:i + b - a])
            i += b - a
        return out
    n, o = per_seek(new), per_seek(old)
    return float(np.mean([n[g] < o[g] for g in n]))


def errors(res: Residual) -> dict:
    """``{"rms_track", "fit_percent"}`` of a residual."""
    return {"rms_track": float(res.rms), "fit_percent": float(res.fit_percent)}


# ------------------------------------------------------------------------- evidence
@dataclass
class Dependence:
    """A free-form correction of the residual along one feature, fitted by LS.

    ``x`` bin centres (feature units), ``value`` the correction per bin (``unit``), ``se``
    cluster-robust standard errors, ``chi2``/``dof``/``p`` the Wald test of "no variation
    along the feature", ``val_drop`` the relative drop of the validation RMS when the
    correction fitted on the fit data is applied there [-]."""

    name: str
    label: str
    unit: str
    x: np.ndarray
    value: np.ndarray
    se: np.ndarray
    chi2: float
    dof: int
    p: float
    val_drop: float = float("nan")
    theta: np.ndarray | None = field(default=None, repr=False)


def _bins(x, k, quantile=True, min_frac: float = 0.01):
    """``k`` bins of ``x``: quantiles, or equal widths over the 0.5..99.5 % range merged until
    each holds ``min_frac`` of the samples; returns ``(edges, centres)``."""
    if quantile:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, k + 1)))
    else:
        lo, hi = np.quantile(x, [0.005, 0.995])
        edges = np.linspace(lo, hi, k + 1)
        edges[0], edges[-1] = min(x.min(), lo), max(x.max(), hi)
        cnt = np.histogram(x, edges)[0]
        keep = [edges[0]]
        acc = 0
        for c, e in zip(cnt, edges[1:]):
            acc += c
            if acc >= min_frac * len(x):
                keep.append(e); acc = 0
        keep[-1] = edges[-1]
        edges = np.unique(keep)
    edges[-1] += 1e-9 * max(1.0, abs(edges[-1]))
    return edges, 0.5 * (edges[1:] + edges[:-1])


def _features(eng: Engine, data: Data, spec: dict):
    """Regressor columns of one dependence test on ``data`` (bins from ``spec``)."""
    log = data.log
    x = {"position": log.position_track, "abs_current": np.abs(log.current_a), "current": log.current_a,
         "time": log.time_s}[spec["on"]]
    ind = [((x >= lo) & (x < hi)).astype(float) for lo, hi in zip(spec["edges"][:-1], spec["edges"][1:])]
    if spec["channel"] == "gain":
        return [eng.resp(cmd=eng.cmd * i) for i in ind]
    if spec["channel"] == "cmd":
        return [eng.resp(cmd=i) for i in ind]
    return [eng.resp(force=i) for i in ind]


DEPENDENCE_TESTS = {   # name: (label, feature, channel, unit, bins)
    "force_vs_position": ("force error vs position", "position", "force", "A", 8),
    "gain_vs_position": ("gain error vs position (current x position)", "position", "gain", "-", 8),
    "gain_vs_abs_current": ("gain error vs |current|", "abs_current", "gain", "-", 6),
    "current_error_vs_current": ("delivered-current error vs current", "current", "cmd", "A", 8),
    "gain_vs_time": ("gain error vs time", "time", "gain", "-", 8),
    "force_vs_time": ("force error vs time", "time", "force", "A", 8),
}


def dependence(plant: ModalPlant, data: Data, val: Data | None = None, names=None) -> list:
    """Free-form dependence of the residual on position, |current|, current, time (bins) and on
    the velocity sign; each fitted on ``data`` with the base (k0 or bias, whichever the bins
    sum to, is left out), tested by a cluster-robust Wald test of variation across bins, and
    (with ``val``) applied to the validation data."""
    eng = Engine(plant, data)
    veng = Engine(plant, val) if val is not None else None
    e_val = veng.residual() if veng is not None else None
    bfit, bval = eng.base_cols(), (veng.base_cols() if veng is not None else None)
    out = []
    for name in names or list(DEPENDENCE_TESTS) + ["force_vs_velocity_sign"]:
        if name == "force_vs_velocity_sign":
            cols = [eng.resp(force=-np.tanh(data.v / data.v_scale))]
            vcols = None if veng is None else [veng.resp(force=-np.tanh(val.v / val.v_scale))]
            label, unit, xs, centred, bi = "Coulomb-like force step across v = 0", "A", np.array([0.0]), False, [0, 1]
        else:
            label, on, ch, unit, k = DEPENDENCE_TESTS[name]
            xsrc = {"position": data.log.position_track, "abs_current": np.abs(data.log.current_a),
                    "current": data.log.current_a, "time": data.log.time_s}[on]
            edges, xs = _bins(xsrc[data.windows.index()], k, quantile=(on == "position"))
            spec = {"on": on, "channel": ch, "edges": edges}
            cols = _features(eng, data, spec)
            vcols = None if veng is None else _features(veng, val, spec)
            centred, bi = True, ([1] if ch == "gain" else [0])   # the bins sum to k0 (gain) or bias
        P = eng.project(eng.target(), *[bfit[i] for i in bi], *cols)
        nb = len(bi)
        th, _ = lstsq(P[:, 0], P[:, 1:])
        full_cov = cluster_cov(P[:, 1:], P[:, 0] - P[:, 1:] @ th, data)
        t, cov = th[nb:], full_cov[nb:, nb:]
        if centred:      # variation across bins: contrasts against the mean
            C = (np.eye(len(t)) - 1.0 / len(t))[:-1]
            t, cov = C @ t, C @ cov @ C.T
        w = wald(t, cov) if len(t) else 0.0
        dof = max(len(t), 1)
        val_ = th[nb:] - (th[nb:].mean() if centred else 0.0)
        dep = Dependence(name, label, unit, xs, val_, np.sqrt(np.maximum(np.diag(full_cov)[nb:], 0)),
                         float(w), dof, float(_chi2.sf(w, dof)), theta=th)
        if veng is not None:   # only the variation along the feature, fitted on the fit data
            corr = veng.project(*vcols) @ val_
            dep.val_drop = float(1.0 - np.linalg.norm(e_val - corr) / max(np.linalg.norm(e_val), 1e-300))
        out.append(dep)
    return out


def _spindle(plant: ModalPlant, res: Residual) -> tuple[float, str]:
    from .effects import PeriodicDisturbance
    for e in plant.effects:
        if isinstance(e, PeriodicDisturbance):
            return e.spindle_hz, "accepted periodic_disturbance"
    md = res.log.metadata
    for key, sc in (("spindle_hz", 1.0), ("spindle_rpm", 1 / 60.0), ("rpm", 1 / 60.0)):
        try:
            return float(md[key]) * sc, f"metadata {key}"
        except (KeyError, ValueError):
            pass
    pk = detect_spindle(res.full(), res.windows, res.log.sample_rate_hz)
    return (pk[0][0], "detected (harmonic-sum peak of the residual)") if pk else (float("nan"), "none")


def sync_null(res: Residual, f0: float, n: int = 12) -> float:
    """Median repeatable fraction of the synchronous average at ``n`` frequencies between
    0.6 f0 and 1.6 f0 that are not near a harmonic of f0: what noise alone gives [-]."""
    t, fs = res.log.time_s, res.log.sample_rate_hz
    out = []
    for f in np.linspace(0.6 * f0, 1.6 * f0, n + 3):
        if min(abs(f / f0 - k) for k in (1,)) > 0.08:
            out.append(synchronous_average(res.full(), t, res.windows, f, fs=fs)[3])
    return float(np.median(out)) if out else 0.0


def describe_residual(plant: ModalPlant, data: Data, res: Residual) -> dict:
    """Analyses of a residual ``res`` of ``plant`` on ``data`` (frozen on ``res``): correlations,
    spectra/coherence, synchronous average, nonlinear tests, dependence curves."""
    log = res.log
    ef, u = res.full(), log.current_a
    f0, src = _spindle(plant, res)
    out = {"corr": correlations(ef, u, res.windows), "spectra": spectra(ef, u, res.windows, log.sample_rate_hz),
           "nonlinear": nonlinear_tests(ef, u, log.position_track, res.windows), "spindle_hz": f0,
           "spindle_source": src, "dependence": dependence(plant, data)}
    if math.isfinite(f0):
        out["sync"] = synchronous_average(ef, log.time_s, res.windows, f0, fs=log.sample_rate_hz)
        out["sync_null"] = sync_null(res, f0)
    return out


def _fmt_dep(d: Dependence) -> str:
    if d.unit == "A":
        span = f"{1e3 * (d.value.max() - d.value.min()):.3g} mA across bins" if len(d.value) > 1 \
            else f"{1e3 * d.value[0]:+.3g} mA"
    else:
        span = f"{100 * (d.value.max() - d.value.min()):.3g} % across bins"
    return f"{d.label}: {span} (Wald chi2 {d.chi2:.0f}, {d.dof} dof)"


def evidence_lines(plant: ModalPlant, data: Data, res: Residual) -> dict:
    """One line of evidence per candidate from the current fit residual (what points to it)."""
    deps = {d.name: d for d in dependence(plant, data)}
    ef, u = res.full(), data.log.current_a
    sp = spectra(ef, u, res.windows, data.log.sample_rate_hz)
    cr = correlations(ef, u, res.windows, max_lag=10)
    eng = Engine(plant, data)
    vel = np.gradient(eng.y_lin) / data.log.dt          # first-order sensitivity to a lag/delay
    P = eng.project(eng.target(), vel)
    r = float(abs(P[:, 0] @ P[:, 1]) / max(np.linalg.norm(P[:, 0]) * np.linalg.norm(P[:, 1]), 1e-300))
    lag = f"residual vs model velocity (first-order effect of a lag/delay): |r| = {r:.2f}; " \
          f"max |rho(e, u)| at lags 0..10 = {np.max(np.abs(cr.cross[cr.lags >= 0])):.2f} (band {cr.cross_band:.2f})"
    f0, src = _spindle(plant, res)
    sync = synchronous_average(ef, data.log.time_s, res.windows, f0, fs=data.log.sample_rate_hz) \
        if math.isfinite(f0) else None
    pk = sp.coherent_peaks(max_peaks=3)
    d = deps["force_vs_position"]
    slope = np.polyfit(d.x, d.value, 1)[0] if len(d.x) > 1 else 0.0
    null = sync_null(res, f0) if math.isfinite(f0) else float("nan")
    return {
        "input_delay": lag, "amplifier_lag": lag,
        "pivot_spring_damper": f"force error vs position: slope {1e3 * slope * 1e4:+.3g} mA per 10 ktrack "
                               f"(Wald chi2 {d.chi2:.0f})",
        "position_bias": _fmt_dep(d),
        "friction": _fmt_dep(deps["force_vs_velocity_sign"]),
        "torque_constant_variation": _fmt_dep(deps["gain_vs_position"]),
        "current_saturation": _fmt_dep(deps["gain_vs_abs_current"]),
        "periodic_disturbance": "spindle not found" if sync is None else
        f"spindle {f0:.2f} Hz ({src}): {100 * sync[3]:.1f} % of residual variance repeats per revolution "
        f"({100 * null:.1f} % at non-harmonic frequencies)",
        "extra_mode": "residual-current coherence peaks: " + (", ".join(f"{f:.0f} Hz ({c:.2f})" for f, c in pk)
                                                             or "none above the null band"),
    }


def unexplained_lines(plant: ModalPlant, fdata: Data, vdata: Data, res: Residual, an: dict,
                      min_val_drop: float = 0.02) -> list:
    """What the final model leaves in the validation residual, one line each."""
    out = []
    for d in dependence(plant, fdata, vdata):
        if d.p < 1e-4 and d.val_drop >= min_val_drop:
            out.append(f"residual depends on {d.name.split('_vs_')[-1].replace('_', ' ')}: {_fmt_dep(d)}; "
                       f"a free-form correction fitted on the fit data lowers the validation RMS by "
                       f"{100 * d.val_drop:.0f} % (no library effect accepted for it)")
    sp, cr = an["spectra"], an["corr"]
    pk = sp.coherent_peaks(max_peaks=3)
    if pk:
        out.append("residual coherent with current at " + ", ".join(f"{f:.0f} Hz (coh {c:.2f})" for f, c in pk)
                   + f" (null band {sp.coh_band:.2f}); in closed loop part of this is sensor noise fed back "
                     "through the controller, not necessarily unmodelled dynamics")
    if cr.whiteness_fraction > 0.1:
        out.append(f"residual not white: {100 * cr.whiteness_fraction:.0f} % of autocorrelation lags 1..50 outside "
                   f"+-{cr.white_band:.3f} (coloured noise: force noise integrated by the rigid body, flutter)")
    v = cr.past_input_violations
    if len(v):
        out.append(f"residual correlated with past current at {len(v)} of 51 lags beyond Ljung's band "
                   f"+-{cr.cross_band:.3f} (closed loop: the current reacts to the noise)")
    if "sync" in an and an["sync"][3] > max(0.05, 3 * an["sync_null"]):
        out.append(f"{100 * an['sync'][3]:.0f} % of the residual variance repeats with the spindle at "
                   f"{an['spindle_hz']:.2f} Hz ({an['spindle_source']}; {100 * an['sync_null']:.0f} % at "
                   f"non-harmonic frequencies)")
    bad = [k for k, (m, b) in an["nonlinear"].items() if m > 3 * b]
    if bad:
        out.append("nonlinear correlation tests beyond 3x their band: " + ", ".join(bad))
    return out


# ------------------------------------------------------------------------------ loop
def _backfit(name: str, plant: ModalPlant, fit: Data, val: Data, same: bool, cur_val: Residual,
             it: int, why: str):
    """Re-fit the (last) accepted effect ``name`` with the others in place; a Step if the
    validation error drops, else None."""
    idx = [i for i, e in enumerate(plant.effects) if e.name == name]
    if not idx:
        return None, None
    base = plant.copy(effects=[e for i, e in enumerate(plant.effects) if i != idx[-1]])
    try:
        F = fit_candidate(name, base, fit.freeze(base, evaluate(base, fit, record=True)))
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None, None
    if F is None:
        return None, None
    rv = evaluate(F.plant, val, same, record=True)
    if rv.rms >= cur_val.rms:
        return None, None
    st = Step(name, F.params, f"re-fitted {why} (backfitting)", cur_val.rms, rv.rms, True, it,
              float("nan"), rv.fit_percent, improved_fraction(rv, cur_val), F.plant)
    return st, (evaluate(F.plant, fit, record=True), rv)



def split_data(log: SeekLog, validation: SeekLog | None = None):
    """Fit and validation :class:`Data` (held-out odd seeks when no validation log)."""
    w = seek_windows(log)
    if validation is not None:
        return Data(log, w), Data(validation, seek_windows(validation)), False
    if len(w) < 4:
        raise ValueError(f"{log.source or 'log'}: needs at least 4 seeks to hold some out "
                         f"(has {len(w)}); give a validation log")
    fw, vw = w.split(2)
    return Data(log, fw), Data(log, vw), True


def close_loop(log: SeekLog, model: ModalPlant, validation: SeekLog | None = None,
               candidates=None, min_drop: float = 0.05, min_bic: float = 10.0, min_seeks: float = 0.6,
               proxy_margin: float = 0.05, max_steps: int = 6, verbose: bool = False) -> LoopResult:
    """Augment ``model`` with effects that the data support (see the module notes).

    Parameters
    ----------
    log : SeekLog
        Fit log (current [A] and position [track] only are used, with the targets for seeks).
    model : ModalPlant
        The identified plant (its own effects are kept).
    validation : SeekLog, optional
        Validation log; default: the odd-numbered seeks of ``log`` are held out.
    candidates : list of str, optional
        Names from :data:`CANDIDATES` (default all).
    min_drop : float
        Required relative drop of the validation RMS for an acceptance [-].
    min_bic : float
        Required BIC drop on the fit data.
    min_seeks : float
        Required fraction of validation seeks whose error the candidate lowers [-] (the RMS
        is dominated by the longest seeks; the improvement must be consistent).
    proxy_margin : float
        A candidate whose relative validation drop is smaller by more than this than that of
        a free-form correction along a variable outside the library (:data:`OUT_OF_LIBRARY`)
        is only a proxy for that structure and is not accepted [-].
    max_steps : int
        Maximum number of accepted effects.
    """
    t0 = time.time()
    names = list(candidates or CANDIDATES)
    fit, val, same = split_data(log, validation)
    say = print if verbose else (lambda *a, **k: None)
    res0 = evaluate(model, val, same, record=True)
    error_before = errors(res0)
    refit = refit_base(model, fit)       # k0 and bias re-estimated (output error, fit data)
    rv = evaluate(refit, val, same, record=True)
    base_refit = rv.rms < res0.rms       # kept only if it lowers the validation error
    current, cur_val = (refit, rv) if base_refit else (model, res0)
    cur_fit = evaluate(current, fit, record=True)
    cur_bic = bic(cur_fit.e, fit, 0)
    analysis_before = describe_residual(current, val.freeze(current, cur_val), cur_val)
    say(f"start: validation rms {cur_val.rms:.4g} track ({time.time() - t0:.1f} s)")
    steps, accepted = [], []
    for it in range(1, max_steps + 1):
        fdata = fit.freeze(current, cur_fit)
        ev = evidence_lines(current, fdata, cur_fit)
        tried = []
        for name in names:
            if name in accepted and name not in REPEATABLE:
                continue
            tc = time.time()
            try:
                F = fit_candidate(name, current, fdata)
            except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
                say(f"  {name}: fit failed ({exc})")
                continue
            if F is None:
                say(f"  {name}: not applicable ({time.time() - tc:.1f} s)")
                continue
            rv = evaluate(F.plant, val, same, record=True)
            rf, drop = None, float("nan")
            if rv.rms <= (1 - min_drop) * cur_val.rms:      # information criterion on the fit data
                rf = evaluate(F.plant, fit, record=True)
                drop = cur_bic - bic(rf.e, fit, F.n_params)
            st = Step(name, F.params, ev.get(name, ""), cur_val.rms, rv.rms, False, it, drop,
                      rv.fit_percent, improved_fraction(rv, cur_val), F.plant)
            tried.append((st, rf, rv))
            say(f"  {name}: val rms {rv.rms:.4g} ({100 * (1 - rv.rms / cur_val.rms):+.1f} %), "
                f"BIC drop {drop:.1f}, seeks improved {100 * st.improved_fraction:.0f} % "
                f"({time.time() - tc:.1f} s)")
        ok = [t for t in tried if t[1] is not None and t[0].bic_drop > min_bic
              and t[0].rms_after <= (1 - min_drop) * cur_val.rms and t[0].improved_fraction >= min_seeks]
        steps += [t[0] for t in tried]
        if ok:      # is the best one only a proxy for structure outside the library?
            best_drop = 1 - min(t[0].rms_after for t in ok) / cur_val.rms
            free = [d for d in dependence(current, fdata, val.freeze(current, cur_val), OUT_OF_LIBRARY)
                    if d.p < 1e-4 and d.val_drop > best_drop + proxy_margin]
            if free:
                say("  best candidate explains less than a free-form " + ", ".join(d.name for d in free)
                    + " correction: not accepted")
                break
        if not ok:
            break
        best, rf, rv = min(ok, key=lambda t: t[0].rms_after)
        best.accepted = True
        accepted.append(best.effect)
        current, cur_fit, cur_val = best.plant, rf, rv
        say(f"accepted {best.effect}: validation rms {rv.rms:.4g}")
        for old in accepted[:-1] if len(accepted) > 1 else []:     # backfitting
            st, fitted = _backfit(old, current, fit, val, same, cur_val, it, f"after accepting {best.effect}")
            if st is not None:
                steps.append(st)
                current, cur_fit, cur_val = st.plant, fitted[0], fitted[1]
                say(f"  re-fitted {old}: validation rms {cur_val.rms:.4g}")
        cur_bic = bic(cur_fit.e, fit, 0)
    plant = current.copy()
    plant.meta = dict(plant.meta, loop={
        "simulation": SIMULATION_NOTE,
        "validation": "validation log" if not same else "held-out odd seeks of the log",
        "base_refit": {"kept": bool(base_refit), "k0": float(refit.k0), "bias_a": float(refit.bias_a),
                       "rms_track": float(rv.rms)},
        "accepted": accepted})
    fdata, vdata = fit.freeze(current, cur_fit), val.freeze(current, cur_val)
    analysis_after = describe_residual(current, vdata, cur_val)
    unexplained = unexplained_lines(current, fdata, vdata, cur_val, analysis_after)
    return LoopResult(plant, model, error_before, errors(cur_val), steps, unexplained, res0,
                      cur_val, fit, val, analysis_before, analysis_after, time.time() - t0)
