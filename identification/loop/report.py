"""Evidence, unexplained structure, Markdown report and figures for closing the loop.

Residual evidence (used by :func:`identification.loop.closing.close_loop` to point at
candidates, to refuse proxies and to list what remains unexplained):
:func:`dependence` (free-form corrections of the residual along position,
|current|, current, time and the velocity sign, with cluster-robust Wald tests),
:func:`describe_residual`, :func:`evidence_lines`, :func:`unexplained_lines`.

:func:`write_report` writes the JSON report (exact keys, read by other tools),
and optionally a Markdown report with figures of the residual before and after
on the validation data:

* ``residual_seeks.png`` -- residual [track] of the four longest validation seeks;
* ``spectra.png`` -- residual PSD [track^2/Hz] and residual-current coherence;
* ``correlation.png`` -- residual autocorrelation (white band) and cross-correlation
  with the current (Ljung's coloured band), lags in samples;
* ``dependence.png`` -- free-form corrections along position, velocity sign,
  |current|, current and time (force [mA] or gain [%], +-2 sigma cluster-robust);
* ``sync.png`` -- synchronous average over spindle revolutions [track];
* ``steps.png`` -- validation RMS of every candidate tried, per iteration.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.stats import chi2 as _chi2

from identification.loop.fit_engine import Data, Engine, cluster_cov, lstsq, wald
from identification.model.plant import ModalPlant, atomic_write_text
from identification.loop.residual import Residual
from identification.loop.residual_analysis import correlations, detect_spindle, nonlinear_tests, spectra, synchronous_average

__all__ = ["write_report", "markdown", "figures", "Dependence", "dependence", "describe_residual",
           "evidence_lines", "unexplained_lines", "DEPENDENCE_TESTS"]

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
            edges, xs = _bins(xsrc[data.windows.index()], k, quantile=(on != "time"))
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
    from identification.model.effects import PeriodicDisturbance
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


# --------------------------------------------------------------------------- figures
BEFORE, AFTER = "#9a9a9a", "#1f5fbf"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    plt.rcParams.update({"font.size": 11, "axes.grid": True, "grid.alpha": 0.3, "figure.dpi": 110})
    return plt


def _longest_groups(res, k=4):
    lens = {}
    for (a, b), g in zip(res.windows.bounds, res.windows.groups):
        lo, hi = lens.get(g, (a, b))
        lens[g] = (min(lo, a), max(hi, b))
    return sorted(lens.values(), key=lambda ab: -(ab[1] - ab[0]))[:k]


def fig_residual_seeks(R, path):
    plt = _plt()
    spans = _longest_groups(R.res_after)
    fig, axes = plt.subplots(len(spans), 1, figsize=(10, 2.3 * len(spans) + 0.6), squeeze=False)
    eb, ea = R.res_before.full(), R.res_after.full()
    log = R.res_after.log
    for ax, (a, b) in zip(axes[:, 0], spans):
        t = 1e3 * (log.time_s[a:b] - log.time_s[a])
        ax.plot(t, eb[a:b], color=BEFORE, lw=1.0, label=f"before (rms {np.sqrt(np.nanmean(eb[a:b] ** 2)):.3g})")
        ax.plot(t, ea[a:b], color=AFTER, lw=1.0, label=f"after (rms {np.sqrt(np.nanmean(ea[a:b] ** 2)):.3g})")
        seek = log.target_track[a] - log.target_track[a - 1] if a > 0 else 0.0
        ax.set_title(f"validation seek at t = {log.time_s[a]:.3f} s, {seek:+.0f} track", fontsize=10)
        ax.set_ylabel("residual [track]")
        ax.legend(loc="upper right", fontsize=9)
    axes[-1, 0].set_xlabel("time from seek start [ms]")
    fig.suptitle("Measured minus simulated position (re-anchored every window)")
    fig.tight_layout()
    fig.savefig(path); plt.close(fig)


def fig_spectra(R, path):
    plt = _plt()
    sb, sa = R.analysis_before["spectra"], R.analysis_after["spectra"]
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    a1.semilogy(sb.f, sb.See, color=BEFORE, label="before")
    a1.semilogy(sa.f, sa.See, color=AFTER, label="after")
    a1.set_ylabel("residual PSD [track$^2$/Hz]"); a1.legend()
    a2.plot(sb.f, sb.coh, color=BEFORE, label="before")
    a2.plot(sa.f, sa.coh, color=AFTER, label="after")
    a2.axhline(sa.coh_band, color="k", ls="--", lw=1, label=f"95 % null ({sa.coh_band:.2f})")
    a2.set_ylim(0, 1.02); a2.set_ylabel("coherence with current [-]"); a2.set_xlabel("frequency [Hz]")
    a2.legend(loc="upper left")
    a2.set_title("closed loop: noise fed back through the controller is coherent with the current "
                 "even for an exact model", fontsize=9)
    fig.suptitle("Residual spectrum and coherence with the current (validation)")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_correlation(R, path):
    plt = _plt()
    cb, ca = R.analysis_before["corr"], R.analysis_after["corr"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.5))
    k = ca.lags >= 0
    a1.plot(ca.lags[k], cb.auto[k], "o-", ms=3, color=BEFORE, label="before")
    a1.plot(ca.lags[k], ca.auto[k], "o-", ms=3, color=AFTER, label="after")
    a1.fill_between(ca.lags[k], -ca.white_band, ca.white_band, color="g", alpha=0.2, label="white 95 %")
    a1.set_xlabel("lag [samples]"); a1.set_ylabel("autocorrelation [-]"); a1.legend(); a1.set_title("whiteness")
    a2.plot(ca.lags, cb.cross, color=BEFORE, label="before")
    a2.plot(ca.lags, ca.cross, color=AFTER, label="after")
    a2.fill_between(ca.lags, -ca.cross_band, ca.cross_band, color="g", alpha=0.2,
                    label="Ljung 95 % (after)")
    a2.axvline(0, color="k", lw=0.8)
    a2.set_xlabel("lag tau [samples] (tau > 0: current in the past)")
    a2.set_ylabel("rho(e(t), u(t - tau)) [-]"); a2.legend(); a2.set_title("cross-correlation with the current")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_dependence(R, path):
    plt = _plt()
    db = {d.name: d for d in R.analysis_before["dependence"]}
    da = {d.name: d for d in R.analysis_after["dependence"]}
    names = list(da)
    ncol = 3
    nrow = math.ceil(len(names) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(14, 3.8 * nrow), squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        for d, col, lab in ((db.get(name), BEFORE, "before"), (da[name], AFTER, "after")):
            if d is None:
                continue
            sc = 1e3 if d.unit == "A" else 100.0
            if len(d.x) > 1:
                x, val, se = d.x, d.value, d.se
            else:                       # Coulomb-like step: +f for v < 0, -f for v > 0
                x, val, se = np.array([-1.0, 1.0]), np.r_[d.value, -d.value], np.r_[d.se, d.se]
            ax.errorbar(x, sc * val, yerr=2 * sc * se, fmt="o-", color=col, capsize=3, ms=4,
                        label=f"{lab} (chi2 {d.chi2:.0f}/{d.dof})")
        d = da[name]
        ax.axhline(0, color="k", lw=0.8)
        ax.set_title(d.label, fontsize=10)
        ax.set_ylabel("force [mA]" if d.unit == "A" else "gain [%]")
        xl = {"position": "position [track]", "abs_current": "|current| [A]", "current": "current [A]",
              "time": "time [s]"}
        ax.set_xlabel(next((v for k, v in xl.items() if name.endswith(k)), "sign of the velocity [-]"))
        if name.endswith("current"):        # quantile bins crowd near zero current
            ax.set_xscale("symlog", linthresh=1e-3)
            ticks = [0, 1e-3, 1e-2, 1e-1, 1.0]
            ticks = ticks if name.endswith("abs_current") else sorted({-t for t in ticks} | set(ticks))
            xmax = float(np.max(np.abs(d.x))) * 1.5
            ax.set_xticks([t for t in ticks if abs(t) <= xmax])
            ax.set_xticklabels([f"{t:g}" for t in ticks if abs(t) <= xmax], fontsize=8)
            ax.set_xlim(0 if name.endswith("abs_current") else -xmax, xmax)
        ax.legend(fontsize=8)
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle("Free-form corrections of the validation residual (+-2 sigma, clusters = seeks)")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_sync(R, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4))
    for an, col, lab in ((R.analysis_before, BEFORE, "before"), (R.analysis_after, AFTER, "after")):
        if "sync" in an:
            ph, m, se, frac = an["sync"]
            ax.fill_between(ph, m - 2 * se, m + 2 * se, color=col, alpha=0.2)
            ax.plot(ph, m, color=col, label=f"{lab}: {an['spindle_hz']:.2f} Hz, {100 * frac:.0f} % repeatable")
    ax.set_xlabel("spindle phase [rev]"); ax.set_ylabel("mean residual [track]"); ax.legend()
    ax.set_title(f"Synchronous average over revolutions ({R.analysis_after['spindle_source']})")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


def fig_steps(R, path):
    plt = _plt()
    steps = R.steps or []
    fig, ax = plt.subplots(figsize=(10, 0.32 * max(len(steps), 4) + 1.4))
    y = np.arange(len(steps))[::-1]
    rel = [100 * (s.rms_after / s.rms_before - 1) for s in steps]
    shown = np.clip(rel, -100, 50)
    ax.barh(y, shown, color=[AFTER if s.accepted else "#d9a0a0" for s in steps])
    ax.set_yticks(y, [f"it {s.iteration}: {s.effect}" + ("  (accepted)" if s.accepted else "") for s in steps],
                  fontsize=9)
    for yi, r, sh in zip(y, rel, shown):
        ax.text(sh + (1 if sh >= 0 else -1), yi, f"{r:+.1f} %", va="center", ha="left" if sh >= 0 else "right",
                fontsize=8)
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlim(-115, 65)
    ax.set_xlabel("change of the validation RMS against the model of that iteration [%] (clipped to -100..50)")
    ax.set_title(f"Candidates tried: validation RMS {R.error_before['rms_track']:.3g} -> "
                 f"{R.error_after['rms_track']:.3g} track")
    fig.tight_layout(); fig.savefig(path); plt.close(fig)


FIGURES = {"residual_seeks.png": fig_residual_seeks, "spectra.png": fig_spectra,
           "correlation.png": fig_correlation, "dependence.png": fig_dependence,
           "sync.png": fig_sync, "steps.png": fig_steps}


def figures(R, folder) -> list:
    """Write all figures into ``folder``; returns their file names."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, fn in FIGURES.items():
        if name == "sync.png" and "sync" not in R.analysis_after:
            continue
        fn(R, folder / name)
        out.append(name)
    return out


def _fmt_params(p: dict) -> str:
    def f(v):
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(f(x) for x in v) + "]"
        return f"{v:.4g}" if isinstance(v, float) else str(v)
    return ", ".join(f"{k}={f(v)}" for k, v in p.items())


def markdown(R, figs=(), fig_dir: str = ".") -> str:
    """The human-readable report (figures referenced relative to ``fig_dir``)."""
    eb, ea = R.error_before, R.error_after
    loop = R.plant.meta.get("loop", {})
    L = ["# Closing the loop: residual analysis and model augmentation", "",
         f"* fit log: `{R.fit.log.source or 'arrays'}` ({len(set(R.fit.windows.groups))} seeks), "
         f"validation: {loop.get('validation', '?')} ({len(set(R.val.windows.groups))} seeks)",
         f"* simulation: {loop.get('simulation', '')} (the rigid body integrates force errors twice)",
         f"* base re-fit of k0 and bias on the fit data: {'kept' if loop.get('base_refit', {}).get('kept') else 'not kept'}"
         f" (validation RMS {loop.get('base_refit', {}).get('rms_track', float('nan')):.4g} track)",
         f"* runtime {R.runtime_s:.1f} s", "",
         "## Validation error", "", "| | RMS [track] | fit [%] |", "|---|---|---|",
         f"| before (identified model) | {eb['rms_track']:.4g} | {eb['fit_percent']:.4f} |",
         f"| after | {ea['rms_track']:.4g} | {ea['fit_percent']:.4f} |", "",
         f"Ratio after/before: {ea['rms_track'] / max(eb['rms_track'], 1e-300):.3f}. Fit % is "
         "100 (1 - |e| / |y - mean_w(y)|) with the mean per window (the seek motion dominates it).", "",
         "## Steps", "",
         "Each candidate is fitted on the fit data (jointly with k0, bias, the declared modes' gains and the "
         "linear parameters of the effects already accepted), simulated, and accepted if its BIC on the fit "
         "data drops, its validation "
         "RMS drops by the required fraction, most validation seeks improve, and no free-form correction along "
         "a variable outside the library explains clearly more.", "",
         "| it | effect | accepted | val RMS before | val RMS after | seeks improved | params | evidence |",
         "|---|---|---|---|---|---|---|---|"]
    for s in R.steps:
        L.append(f"| {s.iteration} | {s.effect} | {'**yes**' if s.accepted else 'no'} | {s.rms_before:.4g} | "
                 f"{s.rms_after:.4g} | {100 * s.improved_fraction:.0f} % | {_fmt_params(s.params)} | {s.evidence} |")
    if R.notes:
        L += [""] + [f"Note: {n}" for n in R.notes]
    L += ["", "## Final plant effects", ""]
    L += [f"* `{e.name}`: {_fmt_params(e.params)}" for e in R.plant.effects] or ["* none"]
    L += [f"* k0 = {R.plant.k0:.6g} track/(A s^2) (model {R.model.k0:.6g}), bias = {1e3 * R.plant.bias_a:.4g} mA "
          f"(model {1e3 * R.model.bias_a:.4g} mA)", "", "## Unexplained", ""]
    L += [f"* {u}" for u in R.unexplained] or ["* nothing significant"]
    if figs:
        L += ["", "## Figures (validation data)", ""]
        L += [f"![{f}]({fig_dir}/{f})" for f in figs]
    return "\n".join(L) + "\n"


def write_report(R, report_path, figures_dir=None) -> dict:
    """Write ``report_path`` (JSON) and, with ``figures_dir``, the figures and
    ``figures_dir/loop_report.md``; otherwise the Markdown goes next to the JSON."""
    rep = R.report()
    atomic_write_text(report_path, json.dumps(rep, indent=2))
    if figures_dir is not None:
        figs = figures(R, figures_dir)
        atomic_write_text(Path(figures_dir) / "loop_report.md", markdown(R, figs, "."))
    else:
        atomic_write_text(Path(report_path).with_suffix(".md"), markdown(R))
    return rep
