"""Evidence of closing the loop: what the residual points at, and what stays unexplained.

Used by :func:`identification.loop.closing.close_loop` to point at candidates, to refuse
proxies and to list what remains unexplained: :func:`dependence` (free-form corrections of the
residual along position, |current|, current, time and the velocity sign, each through the
model's own response, with cluster-robust Wald tests), :func:`describe_residual` (correlations,
spectra and coherence, synchronous average, nonlinear tests, dependence curves),
:func:`evidence_lines`, :func:`unexplained_lines`.  Units: tracks, A, s, Hz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2 as _chi2

from identification.loop.analysis import (correlations, nonlinear_tests, significant_spindle, spectra,
                                          spindle_from_metadata, synchronous_average)
from identification.loop.fit_engine import Data, Engine
from identification.loop.residual import Residual
from identification.loop.settings import LoopSettings
from identification.loop.stats import cluster_cov, lstsq, wald
from identification.model.plant import ModalPlant

__all__ = ["Dependence", "dependence", "describe_residual", "evidence_lines", "unexplained_lines",
           "DEPENDENCE_TESTS", "sync_null", "spindle_of"]


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
        return [eng.resp(cmd=eng.cmd * i[:, None]) for i in ind]
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
    bfit = eng.base_cols()
    out = []
    for name in names or list(DEPENDENCE_TESTS) + ["force_vs_velocity_sign"]:
        if name == "force_vs_velocity_sign":
            cols = [eng.resp(force=data.on_grid(-np.tanh(data.grid.velocity / data.v_scale)))]
            vcols = None if veng is None else [veng.resp(force=val.on_grid(-np.tanh(val.grid.velocity / val.v_scale)))]
            label, unit, xs, centred, bi = "Coulomb-like force step across v = 0", "A", np.array([0.0]), False, [0, 1]
        else:
            label, on, ch, unit, k = DEPENDENCE_TESTS[name]
            xsrc = {"position": data.log.position_track, "abs_current": np.abs(data.log.current_a),
                    "current": data.log.current_a, "time": data.log.time_s}[on]
            edges, xs = _bins(xsrc[data.windows.index()], k, quantile=(on != "time"))
            spec = {"on": on, "channel": ch, "edges": edges}
            cols = _features(eng, data, spec)
            vcols = None if veng is None else _features(veng, val, spec)
            centred, bi = True, ([1] if ch == "gain" else [0])   # the bins sum to k0 (gain) or bias
        P = eng.project(eng.target(), *[bfit[i] for i in bi], *cols)
        nb = len(bi)
        th, _ = lstsq(P[:, 0], P[:, 1:])
        full_cov = cluster_cov(P[:, 1:], P[:, 0] - P[:, 1:] @ th, data.windows)
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


def spindle_of(plant: ModalPlant, res: Residual) -> tuple[float, str]:
    """Spindle frequency [Hz] and its source: an accepted periodic disturbance, the log's
    metadata (:func:`identification.loop.analysis.spindle_from_metadata`), else detected."""
    from identification.model.effects import PeriodicDisturbance
    for e in plant.effects:
        if isinstance(e, PeriodicDisturbance):
            return e.spindle_hz, "accepted periodic_disturbance"
    f0, src = spindle_from_metadata(res.log.metadata, res.log.sample_rate_hz)
    if f0:
        return f0, src
    pk = significant_spindle(res.full(), res.windows, res.log.sample_rate_hz)
    if pk is None:
        return float("nan"), "none: no spindle in the metadata, no harmonic-sum peak above chance"
    return pk[0], f"detected (harmonic-sum peak {pk[1]:.1f} of the residual, chance level {pk[2]:.1f})"


def sync_null(res: Residual, f0: float, n: int = 12) -> float:
    """Median repeatable fraction of the synchronous average at ``n`` frequencies between
    0.6 f0 and 1.6 f0 that are not near a harmonic of f0: what noise alone gives [-]."""
    t, fs = res.log.time_s, res.log.sample_rate_hz
    out = []
    for f in np.linspace(0.6 * f0, 1.6 * f0, n + 3):
        if min(abs(f / f0 - k) for k in (1,)) > 0.08:
            out.append(synchronous_average(res.full(), t, res.windows, f, fs=fs)[3])
    return float(np.median(out)) if out else 0.0


def describe_residual(plant: ModalPlant, data: Data, res: Residual, settings: LoopSettings | None = None) -> dict:
    """Analyses of a residual ``res`` of ``plant`` on ``data`` (frozen on ``res``): correlations,
    spectra/coherence, synchronous average, nonlinear tests (on the model's output, at
    ``settings.false_alarm``), dependence curves."""
    settings = settings or LoopSettings()
    log = res.log
    ef, u = res.full(), log.current_a
    f0, src = spindle_of(plant, res)
    out = {"corr": correlations(ef, u, res.windows), "spectra": spectra(ef, u, res.windows, log.sample_rate_hz),
           "nonlinear": nonlinear_tests(ef, u, res.y_sim, res.windows, false_alarm=settings.false_alarm),
           "false_alarm": settings.false_alarm, "spindle_hz": f0,
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
    f0, src = spindle_of(plant, res)
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
                      settings: LoopSettings | None = None) -> list:
    """What the final model leaves in the validation residual, one line each."""
    settings = settings or LoopSettings()
    out = []
    for d in dependence(plant, fdata, vdata):
        if d.p < settings.unexplained_p and d.val_drop >= settings.unexplained_min_val_drop:
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
    bad = [f"{k} ({m / b:.1f}x)" for k, (m, b) in an["nonlinear"].items() if m > b]
    if bad:
        out.append(f"nonlinear correlation tests beyond their threshold (false-alarm rate "
                   f"{100 * an['false_alarm']:g} % per test on a linear drive): " + ", ".join(bad))
    return out
