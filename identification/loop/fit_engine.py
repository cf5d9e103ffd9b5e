"""The fast fitting engine of closing the loop: fit data, linear prediction, base re-fit.

Fits use the exact linear engine (:class:`identification.loop.linear.LinearModel`, the blocks
of the one ``DiscretePlant``): the prediction is the linear response to the command (after
``input`` effects) and to the undelayed force (bias and ``force`` effects), plus ``output``
effects, with the per-window anchors (rigid-body position and velocity at each window start)
projected out.  State-dependent effects are evaluated on the *measured* position (known to a
fraction of a track) and a velocity estimated from it, on the sub-step grid of
:class:`identification.loop.grid.Grid`, so most candidate effects are linear in their
parameters: their regressors are the model's response to a feature (:meth:`Engine.resp`).
Effects that only the model's own state reproduces (friction sticking in dwell) are taken
from a reference simulation (:meth:`Data.freeze`).

Every candidate is re-fitted jointly with the base: ``k0``, ``bias_a``, the gains of the
declared modes (an identification may have let them absorb the effect) and the linear
parameters of the effects already accepted (:meth:`Engine.base_cols`, applied by
:func:`rebase`).

Units: tracks, A, s, Hz.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from identification.logs.seeklog import SeekLog
from identification.loop.grid import Grid, eval_forces, eval_inputs, eval_outputs
from identification.loop.linear import LinearModel
from identification.loop.stats import bic, cluster_cov, effective_n, lstsq, wald
from identification.loop.windows import Windows
from identification.model.effects import (AmplifierLag, ExtraMode, InputDelay, PeriodicDisturbance, PivotSpringDamper,
                                          TorqueConstantVariation, effect_from_dict)
from identification.model.plant import ModalPlant, Mode

__all__ = ["Data", "Engine", "Fit", "rebase", "refit_base", "hats", "mode_column", "linear_fit", "vp_search",
           "pick_by_bic"]


# ------------------------------------------------------------------------------ data
@dataclass
class Data:
    """A log and the windows of it used for fitting or validation.

    ``grid`` holds the sub-step currents and the evaluation steps of state-dependent effects;
    ``domain`` the range of positions [track] on which position-dependent effects are tabulated
    (default: the log's); ``v`` the velocity estimate [track/s] and ``v_scale`` its noise level near rest
    [track/s]; ``frozen`` the ``(effect dicts, cmd, state-dependent force)`` [A] of a
    reference simulation (:meth:`freeze`).  The filters of the linear engine are cached in
    ``cache`` (held here, shared by subsets of the same log)."""

    log: SeekLog
    windows: Windows
    grid: Grid | None = None
    effect_step_s: float | None = None
    domain: tuple | None = None
    v: np.ndarray = None
    v_scale: float = 0.0
    frozen: tuple | None = None
    cache: dict = field(default_factory=dict, repr=False)
    _q: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.grid is None:
            self.grid = Grid(self.log, self.effect_step_s)
        if self.domain is None:
            self.domain = (float(np.min(self.log.position_track)), float(np.max(self.log.position_track)))
        if self.v is None:
            self.v = self.grid.velocity[:, 0]
            rest = np.abs(self.log.pes) < 0.5
            vs = self.v[rest] if rest.sum() > 50 else self.v
            self.v_scale = float(1.4826 * np.median(np.abs(vs - np.median(vs)))) or 1.0

    @property
    def n(self) -> int:
        return self.windows.n_samples

    def _with(self, windows=None, frozen=None) -> "Data":
        return Data(self.log, windows or self.windows, self.grid, self.effect_step_s, self.domain, self.v,
                    self.v_scale, frozen, self.cache)

    def subset(self, max_samples: int) -> "Data":
        """Every k-th seek so that at most ~``max_samples`` samples remain."""
        k = max(1, math.ceil(self.n / max_samples))
        return self._with(self.windows.every(k), self.frozen)

    def freeze(self, plant: ModalPlant, res) -> "Data":
        """The same data, with the command and state-dependent force that the reference
        simulation ``res`` (``simulate(..., record=True)`` of ``plant``) applied: the fast
        engine then reproduces that simulation for ``plant``'s own effects (e.g. friction
        sticking in dwell) and adds new effects on top."""
        if not any(e.kind in ("input", "force") for e in plant.effects):
            return self._with()
        rest = plant.copy(effects=[e for e in plant.effects if e.kind not in ("input", "force")])
        f_state = res.force - self.grid.substep_mean(eval_forces(rest, self.grid.position, self.grid.velocity))
        frozen = ([e.to_dict() for e in plant.effects if e.kind in ("input", "force")], res.cmd, f_state)
        return self._with(frozen=frozen)

    def q(self, basis_fn, key) -> list:
        """Orthonormal anchor bases per window, cached per rigid block."""
        if key not in self._q:
            self._q[key] = [np.linalg.qr(basis_fn(b - a))[0] for a, b in self.windows.bounds]
        return self._q[key]

    def on_grid(self, values: np.ndarray) -> np.ndarray:
        """``(n, S)`` values on the evaluation grid -> ``(n, L)`` sub-step means."""
        return self.grid.substep_mean(values)


def _rigid_key(plant: ModalPlant) -> tuple:
    return tuple((e.freq_hz, e.zeta) for e in plant.effects if isinstance(e, PivotSpringDamper))


# ---------------------------------------------------------------------------- engine
class Engine:
    """Fast prediction, anchor projection and regressors for one plant on one :class:`Data`."""

    def __init__(self, plant: ModalPlant, data: Data, refit_modes: bool = True):
        self.plant, self.d = plant, data
        self.refit_modes = refit_modes   #: re-fit the declared modes' gains with the base (they may have absorbed an effect)
        g = data.grid
        self.lm = LinearModel(plant, data.log.dt, g.L, data.cache)
        self.cmd_fine = eval_inputs(plant.effects, g.u_fine(), g.position)          # (n, S)
        force_fine = eval_forces(plant, g.position, g.velocity, data.v_scale)
        self.cmd, self.force = g.substep_mean(self.cmd_fine), g.substep_mean(force_fine)   # (n, L)
        if data.frozen is not None:     # simulated sequences for the effects they cover
            done, cmd0, f0 = data.frozen
            have = [e.to_dict() for e in plant.effects]
            if all(d in have for d in done):
                ok = (np.isfinite(cmd0) & np.isfinite(f0)).all(axis=1)[:, None]
                new = [e for e in plant.effects if e.kind in ("input", "force") and e.to_dict() not in done]
                cmd_fine = eval_inputs(new, np.repeat(cmd0, g.M, axis=1), g.position)
                rest = plant.copy(effects=[e for e in plant.effects if e.kind not in ("input", "force")] + new)
                force = f0 + g.substep_mean(eval_forces(rest, g.position, g.velocity, data.v_scale))
                self.cmd = np.where(ok, g.substep_mean(cmd_fine), self.cmd)
                self.force = np.where(ok, force, self.force)
                self.cmd_fine = np.where(np.repeat(ok, g.S, axis=1), cmd_fine, self.cmd_fine)
        self.key = _rigid_key(plant)
        rig, self._flex = self.lm.response(self.cmd, self.force, data.windows, split=True, per_block=True)
        self.y_lin = rig + self._flex.sum(axis=1)
        self.y_out = eval_outputs(plant.effects, data.log.time_s)
        self._base = None

    def resp(self, cmd=None, force=None, rigid_only: bool = False) -> np.ndarray:
        """Linear response [track] of the plant to an extra command and/or force [A], each
        ``(n,)`` per sample or ``(n, L)`` per sub-step."""
        c = np.zeros(self.d.log.n) if cmd is None else cmd
        r, f = self.lm.response(c, force, self.d.windows, split=True)
        return r if rigid_only else r + f

    def project(self, *cols) -> np.ndarray:
        """Full-length columns -> window samples with the anchors projected out, ``(N, k)``."""
        X = np.column_stack(cols)
        out = []
        for (a, b), Q in zip(self.d.windows.bounds, self.d.q(self.lm.free_basis, self.key)):
            S = X[a:b]
            out.append(S - Q @ (Q.T @ S))
        return np.vstack(out)

    def target(self) -> np.ndarray:
        """Measured minus predicted position, full length [track]."""
        return self.d.log.position_track - self.y_lin - self.y_out

    def base_cols(self) -> list:
        """Regressors of the base re-fit: relative k0 change [-], bias change [A], then the
        declared modes' gains (``refit_modes``) and the linear parameters of the plant's
        effects (Kt coefficients, periodic cos/sin, extra-mode gains; ``self.setters`` says
        which), re-fitted jointly with every candidate.  A position-bias table is re-fitted by
        its own penalised fit (backfitting), not here: its knots without support in the data
        are set by its roughness penalty."""
        if self._base is None:
            cols, self.setters = [self.y_lin, self.resp(force=np.ones(self.d.log.n))], []
            g, t = self.d.grid, self.d.log.time_s
            for i, m in enumerate(self.plant.modes if self.refit_modes else []):
                cols.append(self._mode(i, m.gain, m.freq_hz, m.zeta))
                self.setters.append((("mode", i), "gain", None, True))
            for e in self.plant.effects:
                d = e.to_dict()
                if isinstance(e, TorqueConstantVariation):
                    pre = self.cmd_fine / e.factor(g.position)
                    x = (g.position - e.center_track) / e.scale_track
                    for j in range(len(e.coeffs)):
                        cols.append(self.resp(cmd=g.substep_mean(pre * x ** (j + 1))))
                        self.setters.append((d, "coeffs", j, True))
                elif isinstance(e, PeriodicDisturbance):
                    for j, h in enumerate(e.harmonics):
                        ph = 2 * np.pi * h * e.spindle_hz * t
                        cols += [np.cos(ph), np.sin(ph)]
                        self.setters += [(d, "cos_track", j, False), (d, "sin_track", j, False)]
                elif isinstance(e, ExtraMode):
                    j = len(self.plant.modes) + [x for x in self.plant.effects if isinstance(x, ExtraMode)].index(e)
                    cols.append(self._mode(j, e.gain, e.freq_hz, e.zeta))
                    self.setters.append((d, "gain", None, True))
            self._base = cols
        return self._base

    def _mode(self, j: int, gain: float, f: float, z: float) -> np.ndarray:
        """Response of mode ``j`` (``all_modes`` order) with unit gain: its block's share of the
        prediction divided by its gain (the block is linear in the gain)."""
        if gain != 0.0:
            return self._flex[:, j] / gain
        return mode_column(self.plant, self, f, z)

    def residual(self) -> np.ndarray:
        """Output-error residual on the window samples [track]."""
        return self.project(self.target())[:, 0]


def rebase(plant: ModalPlant, th, setters=(), **changes) -> ModalPlant:
    """Apply a base re-fit ``th`` (:meth:`Engine.base_cols` order): ``k0 *= 1 + th[0]``,
    ``bias_a += th[1] / (1 + th[0])``, each effect parameter in ``setters`` += its theta
    (divided by ``1 + th[0]`` where the regressor scales with k0)."""
    k = float(th[0])
    p = plant.copy(k0=plant.k0 * (1.0 + k), **changes)
    if len(th) > 1:
        p.bias_a = plant.bias_a + float(th[1]) / (1.0 + k)
    if len(th) > 2 and setters:
        eff = [e.to_dict() for e in p.effects]
        keys = [json.dumps(e, sort_keys=True) for e in eff]
        for (d, key, j, scaled), t in zip(setters, th[2:]):
            if isinstance(d, tuple) and d[0] == "mode":
                p.modes[d[1]].gain = plant.modes[d[1]].gain + float(t) / (1.0 + k)
                continue
            kd = json.dumps(d, sort_keys=True)
            if kd not in keys:
                continue
            prm = eff[keys.index(kd)]["params"]
            val = float(t) / (1.0 + k) if scaled else float(t)
            if j is None:
                prm[key] = prm[key] + val
            else:
                prm[key] = list(prm[key]); prm[key][j] = prm[key][j] + val
        p.effects = [effect_from_dict(e) for e in eff]
    return p


def refit_base(plant: ModalPlant, data: Data, iters: int = 2) -> ModalPlant:
    """Output-error least-squares re-fit of ``k0``, ``bias_a`` and the effects' linear
    parameters (Gauss-Newton, ``iters`` steps)."""
    for _ in range(iters):
        eng = Engine(plant, data)
        P = eng.project(eng.target(), *eng.base_cols())
        th, _ = lstsq(P[:, 0], P[:, 1:])
        plant = rebase(plant, th, eng.setters)
    return plant


@dataclass
class Fit:
    """A re-fitted candidate: the extended plant and what the fit found.

    ``n_params`` is the change in the number of free parameters against the plant it was
    fitted on (negative for a re-parameterisation that removes some)."""

    effect: str
    plant: ModalPlant
    n_params: int
    params: dict
    note: str = ""


def vp_search(data: Data, make, grid, settings, log_scale: bool = False):
    """Minimise the base-projected SSE over a scalar; ``make(x) -> plant``; grid then Brent
    on a subset of the windows, final base re-fit on all of them.  Returns ``(plant, x)``."""
    sub = data.subset(settings.search_samples)

    def cost_of(p):
        eng = Engine(p, sub)
        P = eng.project(eng.target(), *eng.base_cols())
        return lstsq(P[:, 0], P[:, 1:])[1]
    gx = np.log(grid) if log_scale else np.asarray(grid, float)
    f = (lambda x: cost_of(make(math.exp(x) if log_scale else x)))
    costs = [f(x) for x in gx]
    i = int(np.argmin(costs))
    lo, hi = gx[max(i - 1, 0)], gx[min(i + 1, len(gx) - 1)]
    res = minimize_scalar(f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3 * (hi - lo)})
    x = res.x if res.fun < costs[i] else gx[i]
    x = math.exp(x) if log_scale else float(x)
    return refit_base(make(x), data), x


def pick_by_bic(plant: ModalPlant, data: Data, fits, rate: bool = False):
    """``fits``: list of (n_params, plant) -> ``(n_params, plant)`` with the lowest BIC (of the
    residual's rate, :meth:`~identification.loop.windows.Windows.rate`, with ``rate``)."""
    f = (lambda e: data.windows.rate(e)) if rate else (lambda e: (e, data.windows))
    n_eff = effective_n(*f(Engine(plant, data).residual()))
    scored = [(bic(f(Engine(p, data).residual())[0], k, n_eff), k, p) for k, p in fits]
    return min(scored, key=lambda t: t[0])[1:]


def linear_fit(plant, data, cols, rigid=False, bounds=None, channel="force", with_bias=True, centred=False):
    """Fit extra regressors (features through the force or command channel, ``(n,)`` or
    ``(n, L)``) jointly with the base (:meth:`Engine.base_cols`; without the bias column if
    ``with_bias`` is False).

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
    full_cov = cluster_cov(P[:, 1:], e, data.windows)
    cov = full_cov[nb:, nb:]
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
    apply.t2 = th[nb:] ** 2 / np.maximum(np.diag(full_cov)[nb:], 1e-300)
    return apply, th[nb:], sse, wald(t, cov)


def hats(x, knots) -> list:
    """Piecewise-linear interpolation basis (hat functions) at ``knots``, evaluated at ``x``."""
    return [np.interp(x, knots, np.eye(len(knots))[j]) for j in range(len(knots))]


def mode_column(plant: ModalPlant, eng: Engine, f: float, z: float) -> np.ndarray:
    """Response [track] of a unit-gain mode at ``f`` Hz, damping ``z``, to the model's inputs."""
    keep = [e for e in plant.effects if isinstance(e, (InputDelay, AmplifierLag))]
    mini = ModalPlant(k0=plant.k0, modes=[Mode(f, z, 1.0)], delay_s=plant.delay_s, effects=keep)
    return LinearModel(mini, eng.d.log.dt, eng.d.grid.L, eng.d.cache).response(
        eng.cmd, eng.force, eng.d.windows, with_rigid=False)
