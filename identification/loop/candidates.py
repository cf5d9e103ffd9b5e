"""Candidate effects for closing the loop: each one a model extension that is re-fitted.

Each ``fit_<effect>(plant, data, settings)`` extends ``plant`` by one library effect and
re-fits it on ``data`` with the fast engine of :mod:`identification.loop.fit_engine`, jointly
with the base (``k0``, ``bias_a``, the declared modes' gains and the linear parameters of the
effects already accepted).  Linear-in-parameter effects (pivot spring, position bias, Kt(p),
extra-mode gain) are least squares on the model's response to a feature; the others (delay,
amplifier bandwidth, saturation limit, extra-mode frequency and damping) are found by 1-D/2-D
search with the linear parameters projected out (variable projection).  Friction is in
:mod:`identification.loop.friction`, the periodic disturbance in
:mod:`identification.loop.periodic`.

The criterion is the output error (what is reported), not a prewhitened one: an AR noise
model estimated from a residual that still contains the effect whitens the effect away.  A
candidate returns None when its own parameters are not significant on the fit data
(cluster-robust Wald chi^2 below ``settings.min_wald_chi2``) or its search ends at a bound that
means "no such effect".

Where the data cannot tell candidates apart the parameterisation decides: an amplifier lag
faster than fs/2 is a fractional input delay to the data, an extra mode within max(3 zeta, 2 %)
of a declared mode a misfit of that mode (not added), an extra mode whose damping reaches
``settings.max_mode_zeta`` no resonance.  Where they can, the physical effect is tried as a
re-parameterisation: an identification that absorbed an amplifier lag as extra delay and a
heavily damped "mode" is compared, by the same criterion, with the lag and a shorter delay
without that mode (:func:`fit_amplifier_lag`, fewer parameters).

Units: tracks, A, s, Hz.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from identification.loop.fit_engine import (Data, Engine, Fit, hats, linear_fit, mode_column, pick_by_bic, rebase,
                                             refit_base, vp_search)
from identification.loop.friction import fit_friction
from identification.loop.periodic import fit_periodic_disturbance
from identification.loop.settings import LoopSettings
from identification.loop.stats import cluster_cov, lstsq, smooth_lstsq
from identification.model.effects import (AmplifierLag, CurrentSaturation, ExtraMode, InputDelay,
                                          PivotSpringDamper, PositionBias, TorqueConstantVariation)
from identification.model.plant import ModalPlant

__all__ = ["CANDIDATES", "fit_candidate"]


def fit_input_delay(plant, data, settings):
    dt = data.log.dt
    p, tau = vp_search(data, lambda t: plant.copy(effects=plant.effects + [InputDelay(float(t))]),
                       np.linspace(-plant.total_delay_s, 8 * dt, 17), settings)
    return Fit("input_delay", p, 1, {"delay_s": float(tau)})


def fit_amplifier_lag(plant, data, settings):
    """A first-order amplifier lag: added to the plant as it is (1 parameter), or with the plant's
    own delay re-fitted (2: at low frequency a lag of bandwidth ``b`` is a delay of
    ``1 / (2 pi b)``, so an identification without a lag absorbs it as delay), the latter also
    without the plant's heavily damped modes (``zeta >= settings.damped_mode_zeta``: what a lag's
    roll-off looks like to a modal fit; 3 parameters fewer per mode).  The variant with the
    lowest BIC is returned.  Searched and chosen on the output error's rate (first difference
    within each window, :meth:`~identification.loop.windows.Windows.rate`): the output error
    itself is dominated by integrated force noise, and on the combination drive of
    ``studies/loop_to_design.py`` its minimum sat at 4420 Hz with 27 us delay (truth: 3000 Hz, 10 us)."""
    fs = data.log.sample_rate_hz
    sub = data.subset(settings.search_samples)
    damped = [i for i, m in enumerate(plant.modes) if m.zeta >= settings.damped_mode_zeta]
    fits, found = [], {}
    variants = [([], False), ([], True)] + ([(damped, True)] if damped else [])
    for drop, free_delay in variants:
        base = plant.copy(modes=[m for i, m in enumerate(plant.modes) if i not in drop])

        def make(x, base=base, free_delay=free_delay):
            d = float(max(x[1], 0.0)) if free_delay else base.delay_s
            return base.copy(delay_s=d, effects=base.effects + [AmplifierLag(float(math.exp(x[0])))])

        def cost(x, make=make):       # the remaining modes' gains re-fitted with it (they shared the roll-off)
            eng = Engine(make(x), sub)   # judged on the error's rate: the lag's signature (Windows.rate)
            R = sub.windows.rate(eng.project(eng.target(), *eng.base_cols()))[0]
            return lstsq(R[:, 0], R[:, 1:])[1]
        # each bandwidth with the delay as it is (a lag the model lacks) or shortened by the
        # lag's low-frequency delay (a lag the identification absorbed as delay)
        delays = (lambda b: (plant.delay_s, max(plant.delay_s - 1.0 / (2 * math.pi * b), 0.0))) if free_delay \
            else (lambda b: (plant.delay_s,))
        grid = [(math.log(b), d) for b in np.geomspace(0.02 * fs, 0.6 * fs, 7) for d in dict.fromkeys(delays(b))]
        costs = [cost(g) for g in grid]
        x0 = np.array(grid[int(np.argmin(costs))])
        if math.exp(x0[0]) > 0.5 * fs:       # best as fast as the grid goes: a delay to the data
            continue
        if free_delay:
            res = minimize(cost, x0, method="Nelder-Mead",
                           options={"xatol": 2e-3, "fatol": 1e-6 * min(costs), "maxiter": 40,
                                    "initial_simplex": np.vstack([x0, x0 + [0.3, 0.0], x0 + [0.0, 0.2 / fs]])})
            x = res.x if res.fun < min(costs) else x0
        else:
            res = minimize_scalar(lambda v: cost((v, x0[1])), bounds=(x0[0] - 0.5, x0[0] + 0.5), method="bounded",
                                  options={"xatol": 2e-3})
            x = np.array([res.x, x0[1]]) if res.fun < min(costs) else x0
        bw = math.exp(x[0])
        if bw > 0.5 * fs or bw < 0.021 * fs:     # faster: a fractional delay; slower: at the bound
            continue
        p = refit_base(make(x), data)
        fits.append(((2 if free_delay else 1) - 3 * len(drop), p))
        found[id(p)] = (bw, len(drop))
    if not fits:
        return None
    n, p = pick_by_bic(plant, data, fits, rate=True)
    bw, nd = found[id(p)]
    note = (f"delay {1e6 * plant.delay_s:.2f} -> {1e6 * p.delay_s:.2f} us" if p.delay_s != plant.delay_s
            else "delay kept") + (f"; {nd} damped mode(s) replaced" if nd else "")
    return Fit("amplifier_lag", p, n, {"bandwidth_hz": float(bw), "delay_s": float(p.delay_s),
                                       "modes_replaced": nd}, note)


def fit_current_saturation(plant, data, settings):
    """Amplifier saturation: the limit [A] by a 1-D search over quantiles of the commanded sub-step
    currents (``SeekLog.input_current``: a multirate drive clips each sub-step, not their logged mean).
    Applicable when the limit found clips the command on at least ``settings.min_clipped_seeks`` seeks
    of the fit data (default 1), however few sub-steps: a seek's current peak lasts a sub-step or two,
    and a log may hold only a few seeks long enough to reach the limit (the independent drive's
    36-seek log with a 0.277 A limit: 9 clipped sub-steps on 1 of 18 fit seeks, 93 in the whole log;
    a former rule of >= 20 clipped samples called it "not applicable" and left the validation RMS at
    1.04 track instead of 0.12).  A limit fitted to one seek's noise is rejected where every candidate
    is, by the decision rule on the held-out seeks (validation drop, BIC, seeks improved)."""
    idx = data.windows.index()
    U = np.abs(data.grid.u[idx]).reshape(len(idx), -1)          # (samples, sub-steps)
    u = U.ravel()
    grid = np.unique(np.r_[np.quantile(u, [0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.96, 0.98, 0.99, 0.995, 0.999]),
                           float(u.max())])
    p, lim = vp_search(data, lambda x: plant.copy(effects=[CurrentSaturation(float(x))] + plant.effects),
                       grid, settings)
    seek_of = np.repeat(data.windows.groups, [b - a for a, b in data.windows.bounds])
    if len(set(seek_of[np.any(U > lim, axis=1)].tolist())) < settings.min_clipped_seeks:
        return None
    return Fit("current_saturation", p, 1, {"limit_a": float(lim)})


def fit_pivot_spring_damper(plant, data, settings):
    g = data.grid
    ap, (ks, kd), _, w = linear_fit(plant, data, [data.on_grid(-g.position), data.on_grid(-g.velocity)],
                                    rigid=True, bounds=([0, 0], [np.inf, np.inf]))
    if ks <= 0 or ap.t2[0] < settings.min_wald_chi2:      # a spring needs a significant stiffness
        return None
    wp = math.sqrt(ks * plant.k0)          # stiffness force ks*y [A] -> wp^2 = ks k0
    zeta = kd * plant.k0 / (2 * wp)
    eff = PivotSpringDamper(float(wp / (2 * math.pi)), float(zeta), float(ap.bias / ks))
    base = ap(plant)
    p = refit_base(base.copy(bias_a=plant.bias_a, effects=base.effects + [eff]), data)
    return Fit("pivot_spring_damper", p, 2, eff.params,
               "rest_track is confounded with bias_a (constant force b = stiffness * rest)")


def _pos_range(data):
    p = data.log.position_track[data.windows.index()]
    return float(np.min(p)), float(np.max(p))


def fit_position_bias(plant, data, settings):
    """Bias force vs position as a penalised piecewise-linear table (a P-spline).

    ``settings.bias_knots`` equally spaced knots over ``data.domain`` (the positions the fit
    and validation logs visit: the table is defined wherever the model will be simulated),
    values by least squares jointly with the base, with a roughness penalty (second or third
    differences, or a smooth count of kinks) whose order and weight are chosen by
    ``settings.bias_cv_folds``-fold cross-validation over seeks
    (:func:`identification.loop.stats.smooth_lstsq`: a smooth flex-cable bias and a table with
    kinks alike).  A force error of 1e-5 A already shows as about a track over a 10 ms window,
    so the table must interpolate between the positions where the head dwelt to the
    micro-ampere: a few equally spaced knots cannot.  Where the fit data have no support the
    penalty continues the table linearly (second differences) or quadratically (third).  A
    5-knot unpenalised fit over the fitted range must first show a significant variation
    (centred Wald test)."""
    g = data.grid
    lo, hi = _pos_range(data)
    _, _, _, w = linear_fit(plant, data, [data.on_grid(h) for h in hats(g.position, np.linspace(lo, hi, 5))],
                            with_bias=False, centred=True)
    if w < settings.min_wald_chi2:
        return None
    dlo, dhi = data.domain or (lo, hi)
    knots = np.linspace(min(dlo, lo), max(dhi, hi), max(int(settings.bias_knots), 3))
    K = len(knots)
    eng = Engine(plant, data)
    allb = eng.base_cols()
    keep = [i for i in range(len(allb)) if i != 1]         # the table holds the constant bias
    feats = [eng.resp(force=data.on_grid(h)) for h in hats(g.position, knots)]
    P = eng.project(eng.target(), *[allb[i] for i in keep], *feats)
    nb = len(keep)
    th, edf, order, lam = smooth_lstsq(P[:, 0], P[:, 1:], nb, data.windows,
                                       folds=int(settings.bias_cv_folds))
    full = np.zeros(len(allb))
    full[keep] = th[:nb]
    k = float(full[0])
    eff = PositionBias([float(x) for x in knots], [float(t / (1 + k)) for t in th[nb:]])
    base = rebase(plant, full, eng.setters)
    p = refit_base(base.copy(bias_a=plant.bias_a, effects=base.effects + [eff]), data)
    return Fit("position_bias", p, max(edf - 1.0, 1.0), p.effects[-1].params,
               f"{K} knots over {knots[0]:.0f}..{knots[-1]:.0f} track (fit data {lo:.0f}..{hi:.0f}), "
               f"{order} roughness penalty chosen by {int(settings.bias_cv_folds)}-fold cross-validation over seeks: "
               f"{edf:.1f} effective parameters")


def fit_torque_constant_variation(plant, data, settings):
    g = data.grid
    lo, hi = _pos_range(data)
    c0, sc = 0.5 * (lo + hi), max(0.5 * (hi - lo), 1.0)
    x = (g.position - c0) / sc
    eng = Engine(plant, data)
    fits = []
    for deg in (1, 2, 3):
        ap, th, _, w = linear_fit(plant, data, [data.on_grid(eng.cmd_fine * x ** (i + 1)) for i in range(deg)],
                                  channel="cmd")
        if deg == 1 and w < settings.min_wald_chi2:
            return None
        eff = TorqueConstantVariation([float(t / (1 + ap.k)) for t in th], float(c0), float(sc))
        base = ap(plant)
        fits.append((deg, refit_base(base.copy(effects=base.effects + [eff]), data)))
    # degree chosen on the output error itself, not its rate: Kt(x) is a slow, position-dependent gain that
    # differencing de-weights (chosen on the rate, the independent 50.4 kHz drive's kt+bias+friction log
    # validated at 0.730 track against 0.192 on the level; the combination drive's plant is the same either way)
    n, p = pick_by_bic(plant, data, fits)
    return Fit("torque_constant_variation", p, n, p.effects[-1].params)


def _near_existing(plant, f):
    return any(abs(f - m.freq_hz) < max(3 * m.zeta, 0.02) * m.freq_hz for m in plant.all_modes())


def fit_extra_mode(plant, data, settings, n_grid: int = 24):
    fs = data.log.sample_rate_hz
    full, data = data, data.subset(settings.search_samples)
    zmax = settings.max_mode_zeta
    eng = Engine(plant, data)
    dur = np.median([b - a for a, b in data.windows.bounds]) * data.log.dt
    flo, fhi = max(20.0, 1.5 / dur), 0.45 * fs
    P0 = eng.project(eng.target(), *eng.base_cols())
    sse0 = float(P0[:, 0] @ P0[:, 0])

    def cost(x):
        f, z = math.exp(x[0]), math.exp(x[1])
        if _near_existing(plant, f) or not flo <= f <= fhi or not 0.002 <= z <= zmax:
            return sse0
        col = eng.project(mode_column(plant, eng, f, z))
        return lstsq(P0[:, 0], np.column_stack([P0[:, 1:], col]))[1]

    grid = [np.log([f, z]) for f in np.geomspace(flo, fhi, n_grid) for z in (0.01, 0.05, 0.2)]
    costs = np.array([cost(g) for g in grid])
    i = int(np.argmin(costs))
    best = minimize(cost, grid[i], method="Nelder-Mead",
                    options={"xatol": 2e-3, "fatol": 1e-6 * costs[i], "maxiter": 60})
    f, z = (float(math.exp(v)) for v in best.x)
    if _near_existing(plant, f) or not flo <= f <= fhi or z > 0.95 * zmax:
        return None          # at a bound: not a resonance the data pin down
    col = eng.project(mode_column(plant, eng, f, z))
    X = np.column_stack([P0[:, 1:], col])
    th, _ = lstsq(P0[:, 0], X)
    cov = cluster_cov(X, P0[:, 0] - X @ th, data.windows)
    if th[-1] ** 2 / cov[-1, -1] < settings.min_wald_chi2:
        return None
    eff = ExtraMode(f, z, float(th[-1] / (1 + th[0])))
    p = refit_base(rebase(plant, th[:-1], eng.setters, effects=plant.effects + [eff]), full)
    return Fit("extra_mode", p, 3, eff.params)


#: candidate name -> fit function ``(plant, data, settings) -> Fit | None``
CANDIDATES = {
    "input_delay": fit_input_delay,
    "amplifier_lag": fit_amplifier_lag,
    "pivot_spring_damper": fit_pivot_spring_damper,
    "position_bias": fit_position_bias,
    "friction": fit_friction,
    "torque_constant_variation": fit_torque_constant_variation,
    "current_saturation": fit_current_saturation,
    "periodic_disturbance": fit_periodic_disturbance,
    "extra_mode": fit_extra_mode,
}


def fit_candidate(name: str, plant: ModalPlant, data: Data, settings: LoopSettings | None = None) -> Fit | None:
    """Fit one candidate (``CANDIDATES[name]``) on top of ``plant`` on ``data``.

    Returns None when the candidate does not apply (its parameters are not significant
    on the fit data, or the search ends at a bound meaning "no such effect")."""
    return CANDIDATES[name](plant, data, settings or LoopSettings())
