"""Candidate effects for closing the loop: each one a model extension that is re-fitted.

Each ``fit_<effect>(plant, data)`` extends ``plant`` by one library effect and
re-fits it on ``data`` with the fast engine of :mod:`identification.loop.fit_engine`,
jointly with the base (``k0``, ``bias_a``, the declared modes' gains and the
linear parameters of the effects already accepted).  Linear-in-parameter effects
(pivot spring, position bias, Coulomb/viscous friction, Kt(p), periodic
disturbance, extra-mode gain) are least squares on the model's response to a
feature; the others (delay, amplifier bandwidth, saturation limit, extra-mode
frequency and damping, spindle frequency) are found by 1-D/2-D search with the
linear parameters projected out (variable projection).  Friction is fitted with a
fast sticking model (a head at rest holds while the applied force is below the
Coulomb level) and then refined by ``DiscretePlant`` simulation: when the head
sticks only the model's own state reproduces the friction force, and the rigid
body turns a 1e-6 A bias error into a visible position error.

The criterion is the output error (what is reported), not a prewhitened one: an
AR noise model estimated from a residual that still contains the effect whitens
the effect away.  A candidate returns None when its own parameters are not
significant on the fit data (cluster-robust Wald chi^2 below ``MIN_WALD``) or
its search ends at a bound that means "no such effect".

Where the data cannot tell candidates apart the parameterisation decides: an
amplifier lag faster than fs/2 is reported as a fractional input delay, an extra
mode within max(3 zeta, 2 %) of a declared mode as a misfit of that mode (not
added), an extra mode whose damping reaches ``ZETA_MAX`` as no resonance.

Units: tracks, A, s, Hz.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from identification.model.effects import (AmplifierLag, CurrentSaturation, ExtraMode, Friction, InputDelay,
                      PeriodicDisturbance, PivotSpringDamper, PositionBias, TorqueConstantVariation)
from identification.loop.fit_engine import (Data, Engine, Fit, _hats, _mode_column, bic, cluster_cov, effective_n, lstsq,
                         rebase, refit_base, segments, wald)
from identification.model.plant import ModalPlant
from identification.loop.residual import detect_spindle, simulate

__all__ = ["Data", "Engine", "Fit", "CANDIDATES", "fit_candidate", "refit_base", "bic", "effective_n",
           "cluster_cov", "lstsq", "segments", "MIN_WALD", "ZETA_MAX"]

MIN_WALD = 16.0   #: chi^2 a candidate's own parameters must reach on the fit data (~4 sigma)
ZETA_MAX = 0.5    #: largest damping ratio an extra mode may have (beyond: not a resonance)


def _vp_cost(data):
    def cost(p):
        eng = Engine(p, data)
        P = eng.project(eng.target(), *eng.base_cols())
        return lstsq(P[:, 0], P[:, 1:])[1]
    return cost


def _vp_search(data, make, grid, log_scale=False, max_samples: int = 8000):
    """Minimise the base-projected SSE over a scalar; ``make(x) -> plant``; grid then Brent
    on a subset of the windows, final base re-fit on all of them."""
    cost = _vp_cost(data.subset(max_samples))
    gx = np.log(grid) if log_scale else np.asarray(grid, float)
    f = (lambda x: cost(make(math.exp(x) if log_scale else x)))
    costs = [f(x) for x in gx]
    i = int(np.argmin(costs))
    lo, hi = gx[max(i - 1, 0)], gx[min(i + 1, len(gx) - 1)]
    res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3 * (hi - lo)})
    x = res.x if res.fun < costs[i] else gx[i]
    x = math.exp(x) if log_scale else float(x)
    return refit_base(make(x), data), x


def fit_input_delay(plant, data):
    dt = data.log.dt
    p, tau = _vp_search(data, lambda t: plant.copy(effects=plant.effects + [InputDelay(float(t))]),
                        np.linspace(-plant.total_delay_s, 8 * dt, 17))
    return Fit("input_delay", p, 1, {"delay_s": float(tau)})


def fit_amplifier_lag(plant, data):
    fs = data.log.sample_rate_hz
    p, bw = _vp_search(data, lambda b: plant.copy(effects=plant.effects + [AmplifierLag(float(b))]),
                       np.geomspace(0.02 * fs, 20 * fs, 10), log_scale=True)
    if bw > 0.5 * fs:       # a lag faster than the Nyquist rate is a fractional delay to the data
        return None
    return Fit("amplifier_lag", p, 1, {"bandwidth_hz": float(bw)})


def fit_current_saturation(plant, data):
    u = np.abs(data.log.current_a[data.windows.index()])
    umax = float(u.max())
    grid = np.unique(np.r_[np.quantile(u, [0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.96, 0.98, 0.99, 0.995, 0.999]),
                           umax])
    p, lim = _vp_search(data, lambda x: plant.copy(effects=[CurrentSaturation(float(x))] + plant.effects),
                        grid)
    if np.sum(u > lim) < max(20, 0.002 * len(u)):   # clips (almost) nothing
        return None
    return Fit("current_saturation", p, 1, {"limit_a": float(lim)})


def _linear_fit(plant, data, cols, rigid=False, bounds=None, channel="force", with_bias=True,
                centred=False):
    """Fit extra regressors (features through the force or command channel) jointly with the
    base (:meth:`Engine.base_cols`; without the bias column if ``with_bias`` is False).

    Returns ``(apply, theta, sse, wald_chi2)``: ``apply(new_plant)`` applies the base part of
    the fit; the Wald statistic tests ``theta = 0`` or, with ``centred``, equal ``theta``
    (variation only, for bins that sum to a base term)."""
    eng = Engine(plant, data)
    allb = eng.base_cols()
    keep = [i for i in range(len(allb)) if with_bias or i != 1]
    feats = [eng.resp(force=c, rigid_only=rigid) if channel == "force" else eng.resp(cmd=c) for c in cols]
    P = eng.project(eng.target(), *[allb[i] for i in keep], *feats)
    nb = len(keep)
    bnd = None if bounds is None else ([-np.inf] * nb + list(bounds[0]), [np.inf] * nb + list(bounds[1]))
    th, sse = lstsq(P[:, 0], P[:, 1:], bnd)
    e = P[:, 0] - P[:, 1:] @ th
    cov = cluster_cov(P[:, 1:], e, data)[nb:, nb:]
    t = th[nb:]
    if centred:
        C = (np.eye(len(t)) - 1.0 / len(t))[:-1]
        t, cov = C @ t, C @ cov @ C.T
    full = np.zeros(len(allb))
    full[keep] = th[:nb]
    setters = eng.setters

    def apply(new_plant):
        return rebase(new_plant, full, setters)
    apply.k = float(full[0])
    apply.bias = float(full[1])
    apply.t2 = th[nb:] ** 2 / np.maximum(np.diag(cluster_cov(P[:, 1:], e, data))[nb:], 1e-300)
    return apply, th[nb:], sse, wald(t, cov)


def _friction_force(c, vis, bias, u_del, v, moving):
    """Fast friction model from measured signals [A]: ``-c sign(v) - vis v`` while moving,
    and while stuck the force that holds the head, ``-clip(u + bias, -c, c)``."""
    return np.where(moving, -c * np.sign(v) - vis * v, -np.clip(u_del + bias, -c, c))


def fit_friction(plant, data, max_sim_samples: int = 8000):
    v = data.v
    ap, (c, vis), _, w = _linear_fit(plant, data, [-np.tanh(v / data.v_scale), -v],
                                     bounds=([0, 0], [np.inf, np.inf]))
    if w < MIN_WALD:
        return None
    # 1. fast model with sticking (a head at rest stays while |u + bias| < c), base jointly
    eng = Engine(plant, data)
    m = eng.lm.m
    u = eng.cmd
    u_del = np.r_[np.full(m + 1, u[0]), u[:len(u) - m - 1]]
    moving = np.abs(v) > 2 * data.v_scale
    base = eng.base_cols()
    B = eng.project(*[base[i] for i in range(len(base)) if i != 1])
    c0, v0 = max(c / (1 + ap.k), 1e-6), max(vis / (1 + ap.k), 1e-12)

    def fast(x):
        cc, bb, vv = abs(c0 * (1 + x[0])), plant.bias_a + c0 * x[1], abs(v0 * (1 + x[2]))
        col = eng.resp(force=_friction_force(cc, vv, bb, u_del, v, moving) + bb - plant.bias_a)
        th, sse = lstsq(eng.project(eng.target() - col)[:, 0], B)
        return sse, th, (cc, bb, vv)
    x = minimize(lambda x: fast(x)[0], np.zeros(3), method="Nelder-Mead",
                 options={"maxiter": 150, "xatol": 2e-3, "initial_simplex": np.vstack([np.zeros(3), 0.2 * np.eye(3)])}).x
    _, th, (cc, bb, vv) = fast(x)
    full = np.r_[th[0], 0.0, th[1:]]
    p = rebase(plant.copy(bias_a=bb), full, eng.setters, effects=plant.effects + [Friction(float(cc), float(vv))])
    # 2. bias and Coulomb level by simulation (the rigid body integrates 1e-6 A errors visibly)
    p = sim_refine(p, data.subset(max_sim_samples))
    p = polish(p, data, 1, bias=False)
    return Fit("friction", p, 2, p.effects[-1].params,
               "fast sticking model, then bias and Coulomb level refined by DiscretePlant simulation")


def sim_refine(plant: ModalPlant, data: Data, rounds=("bias", "coulomb", "bias")) -> ModalPlant:
    """Coordinate refinement (Brent, by ``DiscretePlant`` simulation) of ``bias_a`` and of the
    last effect's (friction) Coulomb level."""
    for what in rounds:
        fr = plant.effects[-1]
        c = fr.coulomb_a
        if what == "bias":
            def make(x, p=plant):
                return p.copy(bias_a=p.bias_a + x)
            lo, hi = -0.05 * c, 0.05 * c
        else:
            def make(x, p=plant, fr=fr):
                return p.copy(effects=p.effects[:-1] + [Friction(max(fr.coulomb_a + x, 0.0), fr.viscous_a_per_tps)])
            lo, hi = -0.15 * c, 0.15 * c

        def cost(x):
            e = simulate(make(x), data.log, data.windows, passes=1, continuous=False).e
            return float(e @ e)
        r = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 0.002 * c, "maxiter": 14})
        if r.fun < cost(0.0):
            plant = make(r.x)
    return plant


def polish(plant: ModalPlant, data: Data, iters: int = 2, bias: bool = True) -> ModalPlant:
    """Base re-fit with the command and force sequences of the plant's own simulation
    (for effects the measured signals do not reproduce, e.g. friction sticking);
    ``bias=False`` keeps ``bias_a``."""
    for _ in range(iters):
        res = simulate(plant, data.log, data.windows, continuous=False, record=True)
        new = refit_base(plant, data.freeze(plant, res), iters=1)
        plant = new if bias else new.copy(bias_a=plant.bias_a)
    return plant


def fit_pivot_spring_damper(plant, data):
    y = data.log.position_track
    ap, (ks, kd), _, w = _linear_fit(plant, data, [-y, -data.v], rigid=True, bounds=([0, 0], [np.inf, np.inf]))
    if ks <= 0 or ap.t2[0] < MIN_WALD:      # a spring needs a significant stiffness
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


def _pick_by_bic(plant, data, fits):
    """``fits``: list of (n_params, plant) -> the plant with the lowest :func:`bic`."""
    n_eff = effective_n(Engine(plant, data).residual(), data)
    scored = [(bic(Engine(p, data).residual(), data, k, n_eff), k, p) for k, p in fits]
    return min(scored, key=lambda t: t[0])[1:]


def fit_position_bias(plant, data):
    lo, hi = _pos_range(data)
    fits, walds = [], {}
    for K in (3, 5, 9):
        knots = np.linspace(lo, hi, K)
        ap, th, _, w = _linear_fit(plant, data, _hats(data.log.position_track, knots), with_bias=False,
                                   centred=True)
        eff = PositionBias([float(x) for x in knots], [float(t / (1 + ap.k)) for t in th])
        base = ap(plant)
        fits.append((K - 1, refit_base(base.copy(effects=base.effects + [eff]), data)))
        walds[K - 1] = w
    n, p = _pick_by_bic(plant, data, fits)
    if walds[n] < MIN_WALD:
        return None
    return Fit("position_bias", p, n, p.effects[-1].params)


def fit_torque_constant_variation(plant, data):
    lo, hi = _pos_range(data)
    c0, sc = 0.5 * (lo + hi), max(0.5 * (hi - lo), 1.0)
    x = (data.log.position_track - c0) / sc
    eng = Engine(plant, data)
    fits = []
    for deg in (1, 2, 3):
        ap, th, _, w = _linear_fit(plant, data, [eng.cmd * x ** (i + 1) for i in range(deg)], channel="cmd")
        if deg == 1 and w < MIN_WALD:
            return None
        eff = TorqueConstantVariation([float(t / (1 + ap.k)) for t in th], float(c0), float(sc))
        base = ap(plant)
        fits.append((deg, refit_base(base.copy(effects=base.effects + [eff]), data)))
    n, p = _pick_by_bic(plant, data, fits)
    return Fit("torque_constant_variation", p, n, p.effects[-1].params)


def _near_existing(plant, f):
    return any(abs(f - m.freq_hz) < max(3 * m.zeta, 0.02) * m.freq_hz for m in plant.all_modes())


def fit_extra_mode(plant, data, n_grid: int = 24, max_samples: int = 8000):
    fs = data.log.sample_rate_hz
    full, data = data, data.subset(max_samples)
    eng = Engine(plant, data)
    dur = np.median([b - a for a, b in data.windows.bounds]) * data.log.dt
    flo, fhi = max(20.0, 1.5 / dur), 0.45 * fs
    P0 = eng.project(eng.target(), *eng.base_cols())
    sse0 = float(P0[:, 0] @ P0[:, 0])

    def cost(x):
        f, z = math.exp(x[0]), math.exp(x[1])
        if _near_existing(plant, f) or not flo <= f <= fhi or not 0.002 <= z <= ZETA_MAX:
            return sse0
        col = eng.project(_mode_column(plant, eng, f, z))
        return lstsq(P0[:, 0], np.column_stack([P0[:, 1:], col]))[1]

    grid = [np.log([f, z]) for f in np.geomspace(flo, fhi, n_grid) for z in (0.01, 0.05, 0.2)]
    costs = np.array([cost(g) for g in grid])
    i = int(np.argmin(costs))
    best = minimize(cost, grid[i], method="Nelder-Mead",
                    options={"xatol": 2e-3, "fatol": 1e-6 * costs[i], "maxiter": 60})
    f, z = (float(math.exp(v)) for v in best.x)
    if _near_existing(plant, f) or not flo <= f <= fhi or z > 0.95 * ZETA_MAX:
        return None          # at a bound: not a resonance the data pin down
    col = eng.project(_mode_column(plant, eng, f, z))
    X = np.column_stack([P0[:, 1:], col])
    th, _ = lstsq(P0[:, 0], X)
    cov = cluster_cov(X, P0[:, 0] - X @ th, data)
    if th[-1] ** 2 / cov[-1, -1] < MIN_WALD:
        return None
    eff = ExtraMode(f, z, float(th[-1] / (1 + th[0])))
    p = refit_base(rebase(plant, th[:-1], eng.setters, effects=plant.effects + [eff]), full)
    return Fit("extra_mode", p, 3, eff.params)


def _harmonic_cols(t, f0, hs):
    cols = []
    for h in hs:
        cols += [np.cos(2 * np.pi * h * f0 * t), np.sin(2 * np.pi * h * f0 * t)]
    return cols


def _harmonic_fit(eng, P0, data, f0, hs):
    X = np.column_stack([P0[:, 1:], eng.project(*_harmonic_cols(data.log.time_s, f0, hs))])
    th, sse = lstsq(P0[:, 0], X)
    return X, th, sse


def _cv_sse(y: np.ndarray, X: np.ndarray, data: Data) -> float:
    """2-fold cross-validated SSE over interleaved windows (fit on one half, test on the other)."""
    lens = np.array([b - a for a, b in data.windows.bounds])
    half = np.repeat(np.arange(len(lens)) < len(lens) // 2, lens)   # first / second half in time
    sse = 0.0
    for tr in (half, ~half):
        th = lstsq(y[tr], X[tr])[0]
        r = y[~tr] - X[~tr] @ th
        sse += float(r @ r)
    return sse


def _select_harmonics(eng, P0, data, f0, hmax, min_gain: float = 0.01):
    """Forward selection of harmonics 1..hmax by 2-fold cross-validated SSE (each added
    harmonic must lower it by ``min_gain``); returns ``(harmonics, cv_sse)``."""
    C = eng.project(*_harmonic_cols(data.log.time_s, f0, range(1, hmax + 1)))
    y, base = P0[:, 0], P0[:, 1:]
    keep, best = [], _cv_sse(y, base, data)
    while True:
        trial = {h: _cv_sse(y, np.column_stack([base] + [C[:, 2 * j - 2:2 * j] for j in keep + [h]]), data)
                 for h in range(1, hmax + 1) if h not in keep}
        if not trial:
            break
        h = min(trial, key=trial.get)
        if trial[h] > (1 - min_gain) * best:
            break
        keep.append(h)
        best = trial[h]
    return sorted(keep), best


def spindle_candidates(eng, data, spindle_hz=None) -> list:
    """Spindle frequencies to try [Hz]: given, from metadata (``spindle_hz``/``spindle_rpm``),
    else the three strongest harmonic-sum peaks of the residual (strongest first)."""
    if spindle_hz:
        return [float(spindle_hz)]
    md = data.log.metadata
    for key, scale in (("spindle_hz", 1.0), ("spindle_rpm", 1 / 60.0), ("rpm", 1 / 60.0)):
        try:
            return [float(md[key]) * scale]
        except (KeyError, ValueError):
            pass
    e = np.zeros(data.log.n)
    e[data.windows.index()] = eng.residual()
    out = []
    for f, _ in detect_spindle(e, data.windows, data.log.sample_rate_hz, top=3):
        out += [f]
    return [f for f in dict.fromkeys(round(x, 3) for x in out) if 20.0 <= f <= 400.0]


def fit_periodic_disturbance(plant, data, spindle_hz=None):
    eng = Engine(plant, data)
    fs = data.log.sample_rate_hz
    P0 = eng.project(eng.target(), *eng.base_cols())
    known = bool(spindle_hz) or any(k in data.log.metadata for k in ("spindle_hz", "spindle_rpm", "rpm"))
    best = None
    for i, f0 in enumerate(spindle_candidates(eng, data, spindle_hz)):
        hs, sse = _select_harmonics(eng, P0, data, f0, int(min(8, 0.45 * fs / f0)))
        # the strongest detected peak first; an alternative must do clearly better
        if hs and (best is None or sse < 0.98 * best[0]):
            best = (sse, f0, hs)
    if best is None:
        return None
    _, f0, hs = best
    g = math.gcd(*hs)
    f0, hs = f0 * g, [h // g for h in hs]
    if not known:   # refine the spindle frequency (phase drift over the log)
        T = data.log.time_s[-1] - data.log.time_s[0]
        f0 = float(minimize_scalar(lambda f: _harmonic_fit(eng, P0, data, f, hs)[2],
                                   bounds=(f0 - 1.0 / T, f0 + 1.0 / T), method="bounded",
                                   options={"xatol": 2e-3}).x)
    _, th, _ = _harmonic_fit(eng, P0, data, f0, hs)
    nb = P0.shape[1] - 1
    eff = PeriodicDisturbance(float(f0), [int(h) for h in hs], [float(x) for x in th[nb::2]],
                              [float(x) for x in th[nb + 1::2]])
    p = refit_base(rebase(plant, th[:nb], eng.setters, effects=plant.effects + [eff]), data)
    return Fit("periodic_disturbance", p, 2 * len(hs) + (0 if known else 1), eff.params)


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


def fit_candidate(name: str, plant: ModalPlant, data: Data, **kw) -> Fit | None:
    """Fit one candidate (``CANDIDATES[name]``) on top of ``plant`` on ``data``.

    Returns None when the candidate does not apply (its parameters are not significant
    on the fit data, or the search ends at a bound meaning "no such effect")."""
    return CANDIDATES[name](plant, data, **kw)
