"""The fast fitting engine of closing the loop: data, linear prediction, base re-fit, statistics.

Fits use the exact linear engine (:class:`identification.loop.residual.LinearModel`,
the blocks of the one ``DiscretePlant``): the prediction is the linear response to
the command (after ``input`` effects) and to the undelayed force (bias and
``force`` effects), plus ``output`` effects, with the per-window anchors
(rigid-body position and velocity at each window start) projected out.
State-dependent effects are evaluated on the *measured* position (known to a
fraction of a track) and a velocity estimated from it, so most candidate effects
are linear in their parameters: their regressors are the model's response to a
feature (:meth:`Engine.resp`).  Effects that only the model's own state
reproduces (friction sticking in dwell) are taken from a reference simulation
(:meth:`Data.freeze`).

Every candidate is re-fitted jointly with the base: ``k0``, ``bias_a``, the gains
of the declared modes (an identification may have let them absorb the effect)
and the linear parameters of the effects already accepted
(:meth:`Engine.base_cols`, applied by :func:`rebase`).

Statistics: the information criterion is the output-error BIC on an effective
sample size (:func:`bic`, :func:`effective_n`); significance tests use a
covariance robust to any correlation within a seek (:func:`cluster_cov`,
:func:`wald`).

Units: tracks, A, s, Hz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from identification.estimate.linalg import cluster_cov as _cluster_cov, lstsq as _ls, wald
from identification.model.effects import ExtraMode, InputDelay, AmplifierLag, PeriodicDisturbance, PivotSpringDamper, PositionBias, \
    TorqueConstantVariation
from identification.logs.seeklog import SeekLog
from identification.model.plant import ModalPlant, Mode
from identification.loop.residual import LinearModel, Windows, eval_forces, eval_inputs, eval_outputs, velocity_estimate

__all__ = ["Data", "Engine", "Fit", "rebase", "lstsq", "cluster_cov", "wald", "effective_n", "bic",
           "refit_base", "segments"]


# ------------------------------------------------------------------------------ data
@dataclass
class Data:
    """A log and the windows of it used for fitting or validation."""

    log: SeekLog
    windows: Windows
    v: np.ndarray = None         # velocity estimate [track/s]
    v_scale: float = 0.0         # its noise level near rest [track/s]
    frozen: tuple | None = None  # (effect dicts, cmd [A], state-dependent force [A]) simulated
    _q: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.v is None:
            self.v = velocity_estimate(self.log)
            rest = np.abs(self.log.pes) < 0.5
            vs = self.v[rest] if rest.sum() > 50 else self.v
            self.v_scale = float(1.4826 * np.median(np.abs(vs - np.median(vs)))) or 1.0

    @property
    def n(self) -> int:
        return self.windows.n_samples

    def subset(self, max_samples: int) -> "Data":
        """Every k-th window so that at most ~``max_samples`` samples remain."""
        k = max(1, math.ceil(self.n / max_samples))
        return Data(self.log, self.windows.every(k), self.v, self.v_scale, self.frozen)

    def freeze(self, plant: ModalPlant, res) -> "Data":
        """The same data, with the command and state-dependent force that the reference
        simulation ``res`` (``simulate(..., record=True)`` of ``plant``) applied: the fast
        engine then reproduces that simulation for ``plant``'s own effects (e.g. friction
        sticking in dwell) and adds new effects on top."""
        if not any(e.kind in ("input", "force") for e in plant.effects):
            return Data(self.log, self.windows, self.v, self.v_scale, None)
        f_state = res.force - eval_forces(plant.copy(effects=[e for e in plant.effects
                                                               if e.kind not in ("input", "force")]),
                                          self.log.position_track, self.v)
        frozen = ([e.to_dict() for e in plant.effects if e.kind in ("input", "force")], res.cmd, f_state)
        return Data(self.log, self.windows, self.v, self.v_scale, frozen)

    def q(self, basis_fn, key) -> list:
        """Orthonormal anchor bases per window, cached per rigid block."""
        if key not in self._q:
            self._q[key] = [np.linalg.qr(basis_fn(b - a))[0] for a, b in self.windows.bounds]
        return self._q[key]


def segments(data: Data, e: np.ndarray) -> list:
    """Split concatenated window samples into per-window arrays."""
    cuts = np.cumsum([b - a for a, b in data.windows.bounds])[:-1]
    return np.split(e, cuts)


def _rigid_key(plant: ModalPlant) -> tuple:
    return tuple((e.freq_hz, e.zeta) for e in plant.effects if isinstance(e, PivotSpringDamper))


# ---------------------------------------------------------------------------- engine
class Engine:
    """Fast prediction, anchor projection and regressors for one plant on one :class:`Data`."""

    refit_modes = True   #: re-fit the declared modes' gains with the base (they may have absorbed an effect)

    def __init__(self, plant: ModalPlant, data: Data):
        self.plant, self.d = plant, data
        self.lm = LinearModel(plant, data.log.dt)
        log = data.log
        y, u = log.position_track, log.current_a
        self.cmd = eval_inputs(plant.effects, u, y)
        self.force = eval_forces(plant, y, data.v, data.v_scale)
        if data.frozen is not None:     # simulated sequences for the effects they cover
            done, cmd0, f0 = data.frozen
            ok = np.isfinite(cmd0) & np.isfinite(f0)
            new = [e for e in plant.effects if e.kind in ("input", "force") and e.to_dict() not in done]
            if all(d in [e.to_dict() for e in plant.effects] for d in done):
                cmd = eval_inputs(new, cmd0, y)
                rest = plant.copy(effects=[e for e in plant.effects if e.kind not in ("input", "force")] + new)
                force = f0 + eval_forces(rest, y, data.v, data.v_scale)
                self.cmd = np.where(ok, cmd, self.cmd)
                self.force = np.where(ok, force, self.force)
        self.key = _rigid_key(plant)
        self.y_lin = self.lm.response(self.cmd, self.force, data.windows)
        self.y_out = eval_outputs(plant.effects, log.time_s)

    def resp(self, cmd=None, force=None, rigid_only: bool = False) -> np.ndarray:
        """Linear response [track] of the plant to an extra command and/or force [A]."""
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
        effects (Kt coefficients, position-bias table, periodic cos/sin, extra-mode gains;
        ``self.setters`` says which), re-fitted jointly with every candidate."""
        if getattr(self, "_base", None) is None:
            cols, self.setters = [self.y_lin, self.resp(force=np.ones(self.d.log.n))], []
            y, t = self.d.log.position_track, self.d.log.time_s
            for i, m in enumerate(self.plant.modes if self.refit_modes else []):
                cols.append(_mode_column(self.plant, self, m.freq_hz, m.zeta))
                self.setters.append((("mode", i), "gain", None, True))
            for e in self.plant.effects:
                d = e.to_dict()
                if isinstance(e, TorqueConstantVariation):
                    pre = self.cmd / e.factor(y)
                    x = (y - e.center_track) / e.scale_track
                    for j in range(len(e.coeffs)):
                        cols.append(self.resp(cmd=pre * x ** (j + 1))); self.setters.append((d, "coeffs", j, True))
                elif isinstance(e, PositionBias):
                    for j, h in enumerate(_hats(y, e.knots_track)):
                        cols.append(self.resp(force=h)); self.setters.append((d, "bias_a", j, True))
                elif isinstance(e, PeriodicDisturbance):
                    for j, h in enumerate(e.harmonics):
                        ph = 2 * np.pi * h * e.spindle_hz * t
                        cols += [np.cos(ph), np.sin(ph)]
                        self.setters += [(d, "cos_track", j, False), (d, "sin_track", j, False)]
                elif isinstance(e, ExtraMode):
                    cols.append(_mode_column(self.plant, self, e.freq_hz, e.zeta))
                    self.setters.append((d, "gain", None, True))
            self._base = cols
        return self._base

    def residual(self) -> np.ndarray:
        """Output-error residual on the window samples [track]."""
        return self.project(self.target())[:, 0]


def rebase(plant: ModalPlant, th, setters=(), **changes) -> ModalPlant:
    """Apply a base re-fit ``th`` (:meth:`Engine.base_cols` order): ``k0 *= 1 + th[0]``,
    ``bias_a += th[1] / (1 + th[0])``, each effect parameter in ``setters`` += its theta
    (divided by ``1 + th[0]`` where the regressor scales with k0)."""
    import json
    from identification.model.effects import effect_from_dict
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


def lstsq(r: np.ndarray, Z: np.ndarray, bounds=None):
    """Least squares ``r ~ Z theta`` (optionally bounded): ``(theta, sse)``
    (:func:`identification.estimate.linalg.lstsq`, relative cut-off 1e-9)."""
    th = _ls(Z, r, rcond=1e-9, bounds=bounds)
    e = r - Z @ th
    return th, float(e @ e)


def cluster_cov(Z: np.ndarray, e: np.ndarray, data: Data) -> np.ndarray:
    """Covariance of LS coefficients robust to any correlation within a seek (clusters:
    :func:`identification.estimate.linalg.cluster_cov`)."""
    return _cluster_cov(Z, e, np.repeat(data.windows.groups, [b - a for a, b in data.windows.bounds]))


def effective_n(e: np.ndarray, data: Data, max_lag: int = 100) -> float:
    """Effective number of independent samples of a residual: ``N / (1 + 2 sum rho(k))``,
    ``rho`` its autocorrelation pooled within windows, summed up to its first drop below
    0.05; at least one per seek [-]."""
    segs = segments(data, e)
    den = sum(float(s @ s) for s in segs) or 1e-300
    tau = 0.0
    for k in range(1, max_lag + 1):
        rho = sum(float(s[k:] @ s[:-k]) for s in segs if len(s) > k) / den
        if rho < 0.05:
            break
        tau += rho
    return max(len(e) / (1.0 + 2.0 * tau), float(len(set(data.windows.groups))))


def bic(e: np.ndarray, data: Data, k: int, n_eff: float) -> float:
    """Bayesian information criterion of an output-error residual ``e`` with ``k`` parameters,
    on ``n_eff`` effective samples (:func:`effective_n` of the reference model's residual):
    ``n_eff log(SSE / N) + k log(n_eff)``.  (An AR noise model fitted to each residual would
    reward a large, smooth -- hence predictable -- misfit.)"""
    return float(n_eff * math.log(max(float(e @ e) / len(e), 1e-300)) + k * math.log(n_eff))


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
    """A re-fitted candidate: the extended plant and what the fit found."""

    effect: str
    plant: ModalPlant
    n_params: int
    params: dict
    note: str = ""


def _hats(x, knots):
    """Piecewise-linear interpolation basis (hat functions) at ``knots``."""
    return [np.interp(x, knots, np.eye(len(knots))[j]) for j in range(len(knots))]


def _mode_column(plant, eng, f, z):
    """Response [track] of a unit-gain mode at ``f`` Hz, damping ``z``, to the model's inputs."""
    keep = [e for e in plant.effects if isinstance(e, (InputDelay, AmplifierLag))]
    mini = ModalPlant(k0=plant.k0, modes=[Mode(f, z, 1.0)], delay_s=plant.delay_s, effects=keep)
    return LinearModel(mini, eng.d.log.dt).response(eng.cmd, eng.force, eng.d.windows, with_rigid=False)
