"""Candidate effects for closing the loop: each one a model extension that is re-fitted.

Every fit works on the fast, exact linear engine
(:class:`identification.residual.LinearModel`, the blocks of the one
``DiscretePlant``): the model's prediction is the linear response to the
command (after ``input`` effects) and to the undelayed force (bias and
``force`` effects), plus ``output`` effects.  State-dependent effects are
evaluated on the *measured* position and on a velocity estimated from it, which
makes most candidates linear in their parameters (their regressors are the
model's response to a feature); the remaining ones (delay, amplifier
bandwidth, saturation limit, extra-mode frequency and damping, spindle
frequency) are found by 1-D/2-D search with the linear parameters projected out
(variable projection).  Every candidate re-fits the base parameters ``k0`` and
``bias_a`` with it; the per-window anchors are projected out throughout.

Units: tracks, A, s, Hz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import lsq_linear, minimize, minimize_scalar
from scipy.signal import lfilter

from .effects import (AmplifierLag, CurrentSaturation, ExtraMode, Friction, InputDelay,
                      PeriodicDisturbance, PivotSpringDamper, PositionBias, TorqueConstantVariation)
from .logs import SeekLog
from .plant import ModalPlant, Mode
from .residual import (LinearModel, Windows, detect_spindle, eval_forces, eval_inputs, eval_outputs,
                       velocity_estimate)

__all__ = ["Data", "Engine", "Fit", "CANDIDATES", "fit_candidate", "noise_model", "refit_base",
           "sse_of"]


# ------------------------------------------------------------------------------ data
@dataclass
class Data:
    """A log, the windows of it used for fitting or validation, and the noise model.

    ``ar`` holds the coefficients ``[1, a1, ..., ap]`` of the prewhitening filter
    ``A(q)`` (:func:`noise_model`); None means plain output error."""

    log: SeekLog
    windows: Windows
    ar: np.ndarray | None = None
    v: np.ndarray = None         # velocity estimate [track/s]
    v_scale: float = 0.0         # its noise level [track/s]
    _q: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.v is None:
            self.v = velocity_estimate(self.log)
            tail = np.abs(self.log.pes) < 0.5
            vs = self.v[tail] if tail.sum() > 50 else self.v
            self.v_scale = float(1.4826 * np.median(np.abs(vs - np.median(vs)))) or 1.0

    def with_noise(self, ar) -> "Data":
        """The same data with another prewhitening filter."""
        return Data(self.log, self.windows, None if ar is None else np.asarray(ar, float),
                    self.v, self.v_scale)

    @property
    def n(self) -> int:
        return self.windows.n_samples

    def skip(self, whiten: bool) -> int:
        return len(self.ar) - 1 if whiten and self.ar is not None else 0

    def rows(self, whiten: bool) -> np.ndarray:
        """Log indices of the samples that enter the criterion."""
        p = self.skip(whiten)
        return np.concatenate([np.arange(a + p, b) for a, b in self.windows.bounds])

    def q(self, basis_fn, key, whiten: bool) -> list:
        """Orthonormal (whitened) anchor bases per window, cached per rigid block."""
        k = (key, whiten)
        if k not in self._q:
            p = self.skip(whiten)
            out = []
            for a, b in self.windows.bounds:
                B = basis_fn(b - a)
                if p:
                    B = lfilter(self.ar, [1.0], B, axis=0)[p:]
                U, sv, _ = np.linalg.svd(B, full_matrices=False)
                out.append(U[:, sv > 1e-9 * max(sv.max(), 1e-300)])
            self._q[k] = out
        return self._q[k]


def noise_model(e_segments: list, order: int = 12) -> np.ndarray:
    """AR prewhitening filter ``[1, a1..ap]`` fitted by pooled least squares to residual
    segments (one per window) [-]."""
    rows, rhs = [], []
    for e in e_segments:
        if len(e) <= order + 2:
            continue
        X = np.column_stack([e[order - i - 1:len(e) - i - 1] for i in range(order)])
        rows.append(X); rhs.append(e[order:])
    X, r = np.vstack(rows), np.concatenate(rhs)
    a = np.linalg.lstsq(X, r, rcond=None)[0]
    return np.r_[1.0, -a]


def _rigid_key(plant: ModalPlant) -> tuple:
    return tuple((e.freq_hz, e.zeta) for e in plant.effects if isinstance(e, PivotSpringDamper))


# ---------------------------------------------------------------------------- engine
class Engine:
    """Fast prediction, projection and least squares for one plant on one :class:`Data`."""

    def __init__(self, plant: ModalPlant, data: Data):
        self.plant, self.d = plant, data
        self.lm = LinearModel(plant, data.log.dt)
        log = data.log
        self.cmd = eval_inputs(plant.effects, log.current_a, log.position_track)
        self.force = eval_forces(plant, log.position_track, data.v, data.v_scale)
        self.key = _rigid_key(plant)
        self.y_lin = self.lm.response(self.cmd, self.force, data.windows)
        self.y_out = eval_outputs(plant.effects, log.time_s)

    # ........................................................................ helpers
    def resp(self, cmd=None, force=None, rigid_only: bool = False) -> np.ndarray:
        """Linear response of the plant to an extra command and/or force sequence."""
        c = np.zeros(self.d.log.n) if cmd is None else cmd
        r, f = self.lm.response(c, force, self.d.windows, split=True)
        return r if rigid_only else r + f

    def project(self, *cols, whiten: bool = True) -> np.ndarray:
        """Full-length columns -> criterion samples, prewhitened (if the data has a noise
        model and ``whiten``) with the anchors projected out, ``(N, k)``."""
        X = np.column_stack(cols)
        d = self.d
        p = d.skip(whiten)
        out = []
        for (a, b), Q in zip(d.windows.bounds, d.q(self.lm.free_basis, self.key, whiten)):
            S = X[a:b]
            if p:
                S = lfilter(d.ar, [1.0], S, axis=0)[p:]
            out.append(S - Q @ (Q.T @ S))
        return np.vstack(out)

    def target(self) -> np.ndarray:
        """Measured minus predicted position, full length [track]."""
        return self.d.log.position_track - self.y_lin - self.y_out

    def base_cols(self) -> list:
        """Regressors of the base re-fit: relative k0 change, bias change [A]."""
        return [self.y_lin, self.resp(force=np.ones(self.d.log.n))]

    def residual(self, whiten: bool = False) -> np.ndarray:
        """Projected residual on the criterion samples [track]."""
        return self.project(self.target(), whiten=whiten)[:, 0]


def lstsq(r: np.ndarray, Z: np.ndarray, bounds=None):
    """Least squares ``r ~ Z theta`` (optionally bounded): ``(theta, sse)``."""
    if Z.shape[1] == 0:
        return np.zeros(0), float(r @ r)
    s = np.linalg.norm(Z, axis=0); s[s == 0] = 1.0
    if bounds is None:
        th = np.linalg.lstsq(Z / s, r, rcond=None)[0]
    else:
        lo, hi = bounds
        th = lsq_linear(Z / s, r, bounds=(np.asarray(lo) * s, np.asarray(hi) * s)).x
    th = th / s
    e = r - Z @ th
    return th, float(e @ e)


def rebase(plant: ModalPlant, th_k0: float, th_bias: float, **changes) -> ModalPlant:
    """Apply a base re-fit: ``k0 *= 1 + th_k0``, ``bias_a += th_bias / (1 + th_k0)``."""
    return plant.copy(k0=plant.k0 * (1.0 + th_k0), bias_a=plant.bias_a + th_bias / (1.0 + th_k0),
                      **changes)


def refit_base(plant: ModalPlant, data: Data, iters: int = 2) -> ModalPlant:
    """Least-squares re-fit of ``k0`` and ``bias_a`` (Gauss-Newton, ``iters`` steps)."""
    for _ in range(iters):
        eng = Engine(plant, data)
        P = eng.project(eng.target(), *eng.base_cols())
        th, _ = lstsq(P[:, 0], P[:, 1:])
        plant = rebase(plant, th[0], th[1])
    return plant


def sse_of(plant: ModalPlant, data: Data, whiten: bool = True) -> tuple[float, int]:
    """Sum of squared (prewhitened) residuals and their number."""
    e = Engine(plant, data).residual(whiten)
    return float(e @ e), len(e)


# ------------------------------------------------------------------------------ fits
@dataclass
class Fit:
    """A re-fitted candidate: the extended plant and what the fit found."""

    effect: str
    plant: ModalPlant
    n_params: int
    params: dict
    note: str = ""


def _vp_search(plant: ModalPlant, data: Data, make, x0, bounds, grid=None, log_scale=False):
    """Minimise the base-projected SSE over a scalar ``x``; ``make(x) -> plant``."""
    def cost(x):
        p = make(math.exp(x) if log_scale else x)
        eng = Engine(p, data)
        P = eng.project(eng.target(), *eng.base_cols())
        return lstsq(P[:, 0], P[:, 1:])[1]
    lo, hi = (math.log(bounds[0]), math.log(bounds[1])) if log_scale else bounds
    if grid is not None:
        gx = np.log(grid) if log_scale else np.asarray(grid)
        costs = [cost(x) for x in gx]
        i = int(np.argmin(costs))
        lo, hi = gx[max(i - 1, 0)], gx[min(i + 1, len(gx) - 1)]
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3 * (hi - lo)})
    x = math.exp(res.x) if log_scale else res.x
    return refit_base(make(x), data), x


def fit_input_delay(plant, data):
    dt = data.log.dt
    def make(tau):
        return plant.copy(effects=plant.effects + [InputDelay(float(tau))])
    p, tau = _vp_search(plant, data, make, 0.0, (-plant.total_delay_s, 4 * dt),
                        grid=np.linspace(-plant.total_delay_s, 4 * dt, 13))
    return Fit("input_delay", p, 1, {"delay_s": tau})


def fit_amplifier_lag(plant, data):
    fs = data.log.sample_rate_hz
    def make(bw):
        return plant.copy(effects=plant.effects + [AmplifierLag(float(bw))])
    p, bw = _vp_search(plant, data, make, None, (0.02 * fs, 20 * fs),
                       grid=np.geomspace(0.02 * fs, 20 * fs, 14), log_scale=True)
    if bw > 10 * fs:
        return None
    return Fit("amplifier_lag", p, 1, {"bandwidth_hz": bw})


def fit_current_saturation(plant, data):
    u = np.abs(data.log.current_a[data.windows.index()])
    umax = float(u.max())
    grid = np.unique(np.r_[np.quantile(u, [0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.96, 0.98, 0.99, 0.995, 0.999]), umax])
    def make(lim):
        return plant.copy(effects=[CurrentSaturation(float(lim))] + plant.effects)
    p, lim = _vp_search(plant, data, make, None, (grid[0], umax), grid=grid)
    if lim >= 0.999 * umax:
        return None
    return Fit("current_saturation", p, 1, {"limit_a": lim})


def _linear_fit(plant, data, cols, rigid=False, bounds=None, channel="force", with_bias=True):
    """Fit extra regressors (features through the force or command channel) with the base."""
    eng = Engine(plant, data)
    base = eng.base_cols() if with_bias else eng.base_cols()[:1]
    feats = [eng.resp(force=c, rigid_only=rigid) if channel == "force" else eng.resp(cmd=c)
             for c in cols]
    P = eng.project(eng.target(), *base, *feats)
    nb = len(base)
    bnd = None
    if bounds is not None:
        bnd = ([-np.inf] * nb + list(bounds[0]), [np.inf] * nb + list(bounds[1]))
    th, sse = lstsq(P[:, 0], P[:, 1:], bnd)
    return th[:nb], th[nb:], sse


def fit_friction(plant, data):
    s = np.tanh(data.v / data.v_scale)
    (k, b), (c, vis), _ = _linear_fit(plant, data, [-s, -data.v], bounds=([0, 0], [np.inf, np.inf]))
    if c <= 0 and vis <= 0:
        return None
    eff = Friction(float(c / (1 + k)), float(vis / (1 + k)))
    return Fit("friction", refit_base(rebase(plant, k, b, effects=plant.effects + [eff]), data), 2,
               eff.params)


def fit_pivot_spring_damper(plant, data):
    y = data.log.position_track
    (k, b), (ks, kd), _ = _linear_fit(plant, data, [-y, -data.v], rigid=True,
                                       bounds=([0, 0], [np.inf, np.inf]))
    if ks <= 0:
        return None
    k0 = plant.k0 * (1 + k)
    wp = math.sqrt(ks / (1 + k) * k0)   # stiffness force ks*y [A] -> wp^2 = ks k0
    zeta = kd / (1 + k) * k0 / (2 * wp)
    rest = b / ks                        # constant force b = ks * rest (bias_a kept)
    eff = PivotSpringDamper(float(wp / (2 * math.pi)), float(zeta), float(rest))
    p = refit_base(plant.copy(k0=k0, effects=plant.effects + [eff]), data)
    return Fit("pivot_spring_damper", p, 2, eff.params,
               "rest_track is confounded with bias_a (bias_a kept at the null model's value)")


def _pos_range(data):
    p = data.log.position_track[data.windows.index()]
    return float(np.min(p)), float(np.max(p))


def _hats(x, knots):
    """Piecewise-linear interpolation basis (hat functions) at ``knots``."""
    return [np.interp(x, knots, np.eye(len(knots))[j]) for j in range(len(knots))]


def fit_position_bias(plant, data):
    lo, hi = _pos_range(data)
    n = data.n
    best = None
    for K in (3, 5, 9):
        knots = np.linspace(lo, hi, K)
        (k, *_), th, sse = _linear_fit(plant, data, _hats(data.log.position_track, knots), with_bias=False)
        bic = n * math.log(sse / n) + (K - 1) * math.log(n)
        if best is None or bic < best[0]:
            best = (bic, knots, k, th)
    _, knots, k, th = best
    eff = PositionBias([float(x) for x in knots], [float(t / (1 + k)) for t in th])
    p = refit_base(plant.copy(k0=plant.k0 * (1 + k), effects=plant.effects + [eff]), data)
    return Fit("position_bias", p, len(knots) - 1, eff.params)


def fit_torque_constant_variation(plant, data):
    lo, hi = _pos_range(data)
    c0, sc = 0.5 * (lo + hi), max(0.5 * (hi - lo), 1.0)
    x = (data.log.position_track - c0) / sc
    eng = Engine(plant, data)
    n = data.n
    best = None
    for deg in (1, 2, 3):
        (k, b), th, sse = _linear_fit(plant, data, [eng.cmd * x ** (i + 1) for i in range(deg)],
                                      channel="cmd")
        bic = n * math.log(sse / n) + deg * math.log(n)
        if best is None or bic < best[0]:
            best = (bic, k, b, th)
    _, k, b, th = best
    eff = TorqueConstantVariation([float(t / (1 + k)) for t in th], float(c0), float(sc))
    p = refit_base(rebase(plant, k, b, effects=plant.effects + [eff]), data)
    return Fit("torque_constant_variation", p, len(th), eff.params)


def _mode_column(plant, eng, f, z):
    """Response [track] of a unit-gain mode at ``f`` Hz, damping ``z``, to the model's inputs."""
    keep = [e for e in plant.effects if isinstance(e, (InputDelay, AmplifierLag))]
    mini = ModalPlant(k0=plant.k0, modes=[Mode(f, z, 1.0)], delay_s=plant.delay_s, effects=keep)
    return LinearModel(mini, eng.d.log.dt).response(eng.cmd, eng.force, eng.d.windows, with_rigid=False)


def _near_existing(plant, f):
    return any(abs(f - m.freq_hz) < max(3 * m.zeta, 0.02) * m.freq_hz for m in plant.all_modes())


def fit_extra_mode(plant, data, n_grid: int = 40):
    fs = data.log.sample_rate_hz
    eng = Engine(plant, data)
    dur = np.median([b - a for a, b in data.windows.bounds]) * data.log.dt
    flo = max(20.0, 1.5 / dur)
    P0 = eng.project(eng.target(), *eng.base_cols())

    def cost(lf, lz):
        f, z = math.exp(lf), math.exp(lz)
        if _near_existing(plant, f) or not flo <= f <= 0.45 * fs or not 0.002 <= z <= 0.7:
            return float(P0[:, 0] @ P0[:, 0])
        col = eng.project(_mode_column(plant, eng, f, z))
        return lstsq(P0[:, 0], np.column_stack([P0[:, 1:], col]))[1]

    grid = [(math.log(f), math.log(z)) for f in np.geomspace(flo, 0.45 * fs, n_grid)
            for z in (0.01, 0.04, 0.15)]
    costs = np.array([cost(*g) for g in grid])
    best = None
    for i in np.argsort(costs)[:3]:
        r = minimize(lambda x: cost(*x), np.array(grid[i]), method="Nelder-Mead",
                     options={"xatol": 1e-3, "fatol": 1e-9 * costs[i], "maxiter": 80})
        if best is None or r.fun < best.fun:
            best = r
    f, z = (math.exp(v) for v in best.x)
    if _near_existing(plant, f):
        return None
    col = eng.project(_mode_column(plant, eng, f, z))
    th, _ = lstsq(P0[:, 0], np.column_stack([P0[:, 1:], col]))
    eff = ExtraMode(float(f), float(z), float(th[2] / (1 + th[0])))
    p = refit_base(rebase(plant, th[0], th[1], effects=plant.effects + [eff]), data)
    return Fit("extra_mode", p, 3, eff.params)


def _harmonic_cols(t, f0, hs):
    cols = []
    for h in hs:
        cols += [np.cos(2 * np.pi * h * f0 * t), np.sin(2 * np.pi * h * f0 * t)]
    return cols


def _select_harmonics(eng, P0, t, f0, hmax, chi2_min: float = 13.8):
    """Fit harmonics 1..hmax jointly, keep those whose (cos, sin) pair is significant
    (Wald chi^2 with 2 dof > ``chi2_min``, 13.8 = p 0.001); returns (harmonics, bic)."""
    n = P0.shape[0]
    C = eng.project(*_harmonic_cols(t, f0, range(1, hmax + 1)))
    X = np.column_stack([P0[:, 1:], C])
    th, sse = lstsq(P0[:, 0], X)
    cov = np.linalg.pinv(X.T @ X) * sse / max(n - X.shape[1], 1)
    keep = []
    for i in range(hmax):
        j = slice(2 + 2 * i, 4 + 2 * i)
        w = th[j] @ np.linalg.solve(cov[j, j], th[j])
        if w > chi2_min:
            keep.append(i + 1)
    if not keep:
        return [], np.inf
    X = np.column_stack([P0[:, 1:], eng.project(*_harmonic_cols(t, f0, keep))])
    sse = lstsq(P0[:, 0], X)[1]
    return keep, n * math.log(sse / n) + 2 * len(keep) * math.log(n)


def spindle_candidates(eng, data, spindle_hz=None) -> list:
    """Spindle frequencies to try [Hz]: metadata if known, else harmonic-sum peaks and their
    multiples / halves."""
    if spindle_hz:
        return [float(spindle_hz)]
    md = data.log.metadata
    for key, scale in (("spindle_hz", 1.0), ("spindle_rpm", 1 / 60.0), ("rpm", 1 / 60.0)):
        if key in md:
            try:
                return [float(md[key]) * scale]
            except ValueError:
                pass
    e = np.zeros(data.log.n)
    e[data.windows.index()] = eng.residual()
    peaks = detect_spindle(e, data.windows, data.log.sample_rate_hz, top=3)
    out = []
    for f, _ in peaks:
        out += [f, 2 * f, f / 2]
    return [f for f in dict.fromkeys(round(x, 3) for x in out) if 20.0 <= f <= 400.0]


def fit_periodic_disturbance(plant, data, spindle_hz=None):
    eng = Engine(plant, data)
    t = data.log.time_s
    fs = data.log.sample_rate_hz
    P0 = eng.project(eng.target(), *eng.base_cols())
    best = None
    for f0 in spindle_candidates(eng, data, spindle_hz):
        hs, bic = _select_harmonics(eng, P0, t, f0, int(min(12, 0.45 * fs / f0)))
        if hs and (best is None or bic < best[0]):
            best = (bic, f0, hs)
    if best is None:
        return None
    _, f0, hs = best
    g = math.gcd(*hs)
    f0, hs = f0 * g, [h // g for h in hs]
    T = data.log.time_s[-1] - data.log.time_s[0]

    def cost(f):
        C = eng.project(*_harmonic_cols(t, f, hs))
        return lstsq(P0[:, 0], np.column_stack([P0[:, 1:], C]))[1]
    if not spindle_hz:
        f0 = float(minimize_scalar(cost, bounds=(f0 - 1.0 / T, f0 + 1.0 / T), method="bounded",
                                   options={"xatol": 1e-4}).x)
    C = eng.project(*_harmonic_cols(t, f0, hs))
    th, _ = lstsq(P0[:, 0], np.column_stack([P0[:, 1:], C]))
    eff = PeriodicDisturbance(float(f0), [int(h) for h in hs], [float(x) for x in th[2::2]],
                              [float(x) for x in th[3::2]])
    p = refit_base(rebase(plant, th[0], th[1], effects=plant.effects + [eff]), data)
    return Fit("periodic_disturbance", p, 2 * len(hs) + 1, eff.params)


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
    """Fit one candidate (``CANDIDATES[name]``) on top of ``plant``; None if not applicable."""
    return CANDIDATES[name](plant, data, **kw)
