"""Output-error residual of a plant model on a seek log, and its analysis.

The model is simulated from the *measured* current with the one discretisation
(:class:`identification.model.plant.DiscretePlant`).  The rigid body integrates any
force error twice, so the simulation is **anchored per window**: each seek
(target change to the next one) is simulated from rest at its start (previous
current held) and cut into windows of at most 10 ms (:func:`seek_windows`); at
each window start the rigid-body position and velocity are linear nuisance
parameters fitted by least squares, while modes, amplifier and delay-line states
carry on through the seek.  ``residual = measured - simulated`` [track].  (The
force noise integrated twice grows like window length^1.5; 10 ms keeps it near
the sensor-noise level on the benchmark drive.)

Two equivalent engines:

* :func:`simulate` steps ``DiscretePlant`` sample by sample (effects evaluated
  on the simulated state) -- the reference used for reported errors;
* :class:`LinearModel` filters through the *same* ``Phi``/``Gamma`` blocks of
  ``DiscretePlant`` with ``scipy.signal.lfilter`` (exactly equal for the linear
  part, ~100x faster), used to fit candidate effects
  (:mod:`identification.loop.candidates`).

The analysis of the residual (correlations with coloured-signal bands, spectra and
coherence, spindle detection and synchronous average, nonlinear correlation tests)
is in :mod:`identification.loop.residual_analysis` (re-exported here).  Dependence of the residual on position,
velocity sign, |current|, current x position and time is measured in
:func:`identification.loop.report.dependence`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter, lfilter_zi, savgol_filter

from identification.model.effects import AmplifierLag
from identification.logs.seeklog import SeekLog, segment_seeks
from identification.model.plant import ModalPlant, block_tf

__all__ = ["Windows", "seek_windows", "LinearModel", "Residual", "simulate", "residual",
           "fit_percent", "velocity_estimate", "eval_inputs", "eval_forces", "eval_outputs",
           "pooled_xcorr", "CorrelationTest", "correlations", "Spectra", "spectra", "detect_spindle",
           "synchronous_average", "nonlinear_tests"]


# ----------------------------------------------------------------------------- windows
@dataclass
class Windows:
    """Half-open index ranges ``[a, b)`` into a log, each with its own anchor (initial
    position and velocity); ``groups[i]`` is the seek window ``i`` belongs to (contiguous
    windows of one seek are simulated in one go and only re-anchored)."""

    bounds: list
    groups: list | None = None

    def __post_init__(self):
        if self.groups is None:
            self.groups = list(range(len(self.bounds)))

    def __len__(self) -> int:
        return len(self.bounds)

    @property
    def n_samples(self) -> int:
        return int(sum(b - a for a, b in self.bounds))

    def index(self) -> np.ndarray:
        """Concatenated sample indices of all windows."""
        return np.concatenate([np.arange(a, b) for a, b in self.bounds]) if self.bounds \
            else np.zeros(0, int)

    def select_groups(self, keep) -> "Windows":
        keep = set(keep)
        sel = [i for i, g in enumerate(self.groups) if g in keep]
        return Windows([self.bounds[i] for i in sel], [self.groups[i] for i in sel])

    def split(self, n: int) -> list:
        """``n`` interleaved subsets by seek (seek ``j`` goes to subset ``j % n``)."""
        ids = list(dict.fromkeys(self.groups))
        return [self.select_groups(ids[i::n]) for i in range(n)]

    def every(self, k: int) -> "Windows":
        """Every ``k``-th seek."""
        return self.select_groups(list(dict.fromkeys(self.groups))[::k])


def seek_windows(log: SeekLog, max_len_s: float | None = 0.010, min_len: int = 32) -> Windows:
    """Windows per seek (target change to next target change), each split into pieces of at
    most ``max_len_s`` [s] (re-anchored; the force noise integrated by the rigid body grows
    like length^1.5), pieces shorter than ``min_len`` samples merged into the previous one.
    Without target changes the log is cut into ``max_len_s`` pieces."""
    seeks = segment_seeks(log)
    spans = [(s.start, s.end) for s in seeks] or [(0, log.n)]
    L = max(min_len, int(round((max_len_s or np.inf) * log.sample_rate_hz))) if max_len_s else None
    bounds, groups = [], []
    for g, (a, b) in enumerate(spans):
        if b - a < min_len:
            continue
        cuts = list(range(a, b, L)) if L else [a]
        if len(cuts) > 1 and b - cuts[-1] < min_len:
            cuts.pop()
        for i, c in enumerate(cuts):
            bounds.append((int(c), int(cuts[i + 1] if i + 1 < len(cuts) else b)))
            groups.append(g if seeks else len(groups))   # no seeks: every window on its own
    return Windows(bounds, groups)


# ---------------------------------------------------------------- vectorised effects
def velocity_estimate(log: SeekLog, window: int = 9) -> np.ndarray:
    """Head velocity [track/s] from the measured position (Savitzky-Golay derivative)."""
    w = max(5, min(window | 1, log.n - (1 - log.n % 2)))
    return savgol_filter(log.position_track, w, 2, deriv=1, delta=log.dt)


def eval_inputs(effects, u: np.ndarray, position: np.ndarray) -> np.ndarray:
    """Apply ``input`` effects (in order) to a current array [A] at ``position`` [track]."""
    from identification.model.effects import CurrentSaturation, TorqueConstantVariation
    for e in effects:
        if e.kind != "input":
            continue
        if isinstance(e, CurrentSaturation):
            u = np.clip(u, -e.limit_a, e.limit_a)
        elif isinstance(e, TorqueConstantVariation):
            u = u * e.factor(position)
        else:
            u = np.array([e.input_map(float(a), float(p)) for a, p in zip(u, position)])
    return u


def eval_forces(plant: ModalPlant, position: np.ndarray, velocity: np.ndarray,
                v_scale: float = 0.0) -> np.ndarray:
    """Undelayed current-equivalent force [A]: bias, pivot rest offset, ``force`` effects.

    ``v_scale`` [track/s] smooths ``sign(v)`` as ``tanh(v / v_scale)`` (velocity estimated
    from a noisy position: near zero velocity its sign is unknown)."""
    from identification.model.effects import Friction, PivotSpringDamper, PositionBias
    f = np.full(len(position), float(plant.bias_a))
    for e in plant.effects:
        if isinstance(e, PivotSpringDamper):
            f += (2 * np.pi * e.freq_hz) ** 2 * e.rest_track / plant.k0
        elif isinstance(e, PositionBias):
            f += np.interp(position, e.knots_track, e.bias_a)
        elif isinstance(e, Friction):
            s = np.tanh(velocity / v_scale) if v_scale > 0 else np.sign(velocity)
            f += -e.coulomb_a * s - e.viscous_a_per_tps * velocity
        elif e.kind == "force":
            f += np.array([e.force(float(p), float(v)) for p, v in zip(position, velocity)])
    return f


def eval_outputs(effects, t: np.ndarray) -> np.ndarray:
    """Sum of ``output`` effects [track] at times ``t`` [s]."""
    out = np.zeros(len(t))
    for e in effects:
        if e.kind == "output":
            out += e.output(t)
    return out


# ------------------------------------------------------------------ linear engine
_LM_CACHE: dict = {}


def _linear_key(plant: ModalPlant) -> str:
    """The linear structure of a plant, independent of ``k0`` and ``bias_a``."""
    import json
    d = plant.copy(k0=1.0, bias_a=0.0, effects=[e for e in plant.effects if e.kind == "structural"]).to_dict()
    d.pop("meta", None); d.pop("std", None)
    for m in d["modes"]:
        m.pop("std", None)
    return json.dumps(d, sort_keys=True)


def _blocks(plant: ModalPlant, dt: float):
    """Per-block filters of ``plant.discretize(dt)`` (``plant.k0`` = 1: ``Gamma`` and the
    lag column of ``Phi`` scale with k0, ``Phi`` otherwise does not, so outputs scale
    exactly with k0; the pivot's rest force is k0-normalised in the force input)."""
    dp = plant.discretize(dt)
    Phi, n = dp.Phi, dp.n
    lag = n - 1 if any(isinstance(e, AmplifierLag) for e in plant.effects) else None
    nb = (n - (1 if lag is not None else 0)) // 2
    blocks = []
    for i in range(nb):
        s = slice(2 * i, 2 * i + 2)
        P, c = Phi[s, s], dp.C[s]
        bn, a = block_tf(P, c, dp.G_new[s])
        bo, _ = block_tf(P, c, dp.G_old[s])
        bf, _ = block_tf(P, c, dp.G_f[s])
        bl = block_tf(P, c, Phi[s, lag])[0] if lag is not None else None
        blocks.append(dict(P=P, a=a, b_cmd=np.array([0.0, bn[0], bn[1] + bo[0], bo[1]]),
                           b_f=np.r_[0.0, bf], b_lag=None if bl is None else np.r_[0.0, bl]))
    lag_b = lag_a = None
    if lag is not None:
        lag_b = np.array([0.0, dp.G_new[lag], dp.G_old[lag]])
        lag_a = np.array([1.0, -Phi[lag, lag]])
    off = Phi.copy()
    for i in range(nb):
        off[2 * i:2 * i + 2, 2 * i:2 * i + 2] = 0
    if lag is not None:
        off[:, lag] = 0
    if np.abs(off).max() > 1e-9 * max(1.0, np.abs(Phi).max()):   # beyond expm round-off
        raise ValueError("DiscretePlant is not block diagonal: unsupported structure")
    return dp.m, lag, blocks, lag_b, lag_a


class LinearModel:
    """The linear part of ``plant.discretize(dt)`` as parallel 2-state blocks + lfilter.

    ``DiscretePlant``'s ``Phi`` is block diagonal (rigid body, each mode) apart from
    the amplifier-lag column, so each block is exactly a 2nd-order filter of the
    delayed command (``Gamma_new``/``Gamma_old``), of the lag state and of the undelayed
    force channel.  Outputs match ``DiscretePlant.output`` (before the step) exactly.
    """

    def __init__(self, plant: ModalPlant, dt: float):
        self.plant, self.dt = plant, float(dt)
        key = (_linear_key(plant), self.dt)
        if key not in _LM_CACHE:
            if len(_LM_CACHE) > 256:
                _LM_CACHE.clear()
            _LM_CACHE[key] = _blocks(plant.copy(k0=1.0), self.dt)
        self.m, self.lag, blocks, self.lag_b, self.lag_a = _LM_CACHE[key]
        k0 = float(plant.k0)    # every response is proportional to k0 (see _blocks)
        self.blocks = [dict(b, b_cmd=b["b_cmd"] * k0, b_f=b["b_f"] * k0,
                            b_lag=None if b["b_lag"] is None else b["b_lag"] * k0) for b in blocks]

    def free_basis(self, length: int) -> np.ndarray:
        """``(length, 2)`` rigid-block output from unit initial position / velocity."""
        P = self.blocks[0]["P"]
        out = np.empty((length, 2))
        x = np.eye(2)
        for k in range(length):
            out[k] = x[0]
            x = P @ x
        return out

    def _delayed(self, cmd: np.ndarray, hist: float) -> np.ndarray:
        """``cmd[k - m]`` (``hist`` before the first sample)."""
        return np.r_[np.full(self.m, hist), cmd[:len(cmd) - self.m]] if self.m else cmd

    def response(self, cmd, force=None, windows: Windows | None = None, hist_cmd=None,
                 hist_force=None, split: bool = False, with_rigid: bool = True):
        """Output [track] of the linear part (per sample, before each step).

        Parameters
        ----------
        cmd : array
            Command current entering the delay line at each step [A].
        force : array or None
            Undelayed current-equivalent force [A].
        windows : Windows or None
            If given, the rigid block is filtered per window from an arbitrary state at the
            window start (its free response is the anchor nuisance; numerically clean);
            samples outside the windows are then meaningless.  Otherwise the rigid block
            starts at rest at sample 0.
        hist_cmd, hist_force : float
            Constant inputs before sample 0 (default the first samples): the flexible
            blocks start in steady state for them.
        split : bool
            Return ``(rigid, flexible)`` separately.
        with_rigid : bool
            Compute the rigid block (False: flexible blocks only).
        """
        cmd = np.asarray(cmd, float)
        hc = float(cmd[0]) if hist_cmd is None else float(hist_cmd)
        w = self._delayed(cmd, hc)
        f = None if force is None else np.asarray(force, float)
        hf = 0.0 if f is None else (float(f[0]) if hist_force is None else float(hist_force))
        xl = None
        if self.lag is not None:   # lag state, steady at the history before sample 0
            xl = lfilter(self.lag_b, self.lag_a, w, zi=lfilter_zi(self.lag_b, self.lag_a) * hc)[0]
        rigid = np.zeros(len(cmd))
        flex = np.zeros(len(cmd))
        for i, bl in enumerate(self.blocks):
            if i == 0 and not with_rigid:
                continue
            terms = [(bl["b_cmd"], w, hc)]
            if xl is not None:
                terms.append((bl["b_lag"], xl, hc))
            if f is not None:
                terms.append((bl["b_f"], f, hf))
            for b, x, h in terms:
                if i > 0:
                    flex += lfilter(b, bl["a"], x, zi=lfilter_zi(b, bl["a"]) * h)[0]
                elif windows is None:
                    rigid += lfilter(b, bl["a"], x)
                else:
                    for a0, b0 in windows.bounds:
                        s = max(a0 - 4, 0)
                        rigid[a0:b0] += lfilter(b, bl["a"], x[s:b0])[a0 - s:]
        return (rigid, flex) if split else rigid + flex


# ------------------------------------------------------------------------ results
@dataclass
class Residual:
    """Measured minus simulated position on a set of windows.

    Attributes
    ----------
    windows : Windows
    e : ndarray
        Residual [track] on the window samples (concatenated, see ``windows.index()``).
    y_sim : ndarray
        Simulated position [track], anchored, full log length (NaN outside windows).
    log : SeekLog
    cmd, force : ndarray or None
        With ``simulate(..., record=True)``: the command after ``input`` effects and the
        net undelayed force (bias + ``force`` effects) the simulation applied [A]
        (NaN where not simulated).
    state : ndarray or None
        With ``record=True``: ``(n, 2)`` rigid-body position [track] and velocity [track/s]
        of the simulation at each step (NaN where not simulated).
    """

    windows: Windows
    e: np.ndarray
    y_sim: np.ndarray
    log: SeekLog
    cmd: np.ndarray | None = None      #: command after input effects [A] (``record=True``)
    force: np.ndarray | None = None    #: net undelayed force [A] (``record=True``)
    state: np.ndarray | None = None    #: (n, 2) simulated rigid position, velocity (``record=True``)

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.e ** 2)))

    @property
    def fit_percent(self) -> float:
        return fit_percent(self.log, self.windows, self.e)

    def full(self) -> np.ndarray:
        """Residual on the full log grid (NaN outside windows)."""
        out = np.full(self.log.n, np.nan)
        out[self.windows.index()] = self.e
        return out


def fit_percent(log: SeekLog, windows: Windows, e: np.ndarray) -> float:
    """NRMSE fit ``100 (1 - |e| / |y - mean_w(y)|)`` [%], ``mean_w`` the per-window mean."""
    y = log.position_track
    den = np.concatenate([y[a:b] - y[a:b].mean() for a, b in windows.bounds])
    return float(100.0 * (1.0 - np.linalg.norm(e) / max(np.linalg.norm(den), 1e-300)))


def simulate(plant: ModalPlant, log: SeekLog, windows: Windows, passes: int | None = None,
             continuous: bool = True, record: bool = False) -> Residual:
    """Reference simulation: ``DiscretePlant`` stepped from the measured current, rigid
    states re-anchored at each window start, anchors fitted by least squares.

    Parameters
    ----------
    plant : ModalPlant
        Model, effects included.
    log : SeekLog
    windows : Windows
    passes : int, optional
        Anchor passes; default 1 for plants whose effects do not depend on the state,
        else 2 (the second starts from the anchors fitted by the first).
    continuous : bool
        True: step the whole log (modes, amplifier and delay line carry over between
        windows).  False: step the windows only, each from rest at its start
        (``DiscretePlant.reset`` with the previous current held before it).
    record : bool
        Also record the command and force sequences applied (last pass).
    """
    u, y, dt = log.current_a, log.position_track, log.dt
    state_dep = any(e.kind in ("input", "force") for e in plant.effects)
    passes = passes or (2 if state_dep else 1)
    v = velocity_estimate(log)
    anchors = {a: (y[a], v[a]) for a, _ in windows.bounds}
    basis = LinearModel(plant.linear_part(), dt).free_basis
    for _ in range(passes):
        dp = plant.discretize(dt)
        ysim = np.full(log.n, np.nan)
        if continuous:
            dp.reset(y[0], 0.0, current=u[0], t0=log.time_s[0])
            spans, starts = [(0, log.n)], {a for a, _ in windows.bounds}
        else:           # one span per run of contiguous windows (one seek), re-anchored inside
            spans, starts = [], {a for a, _ in windows.bounds}
            for a, b in windows.bounds:
                if spans and spans[-1][1] == a:
                    spans[-1] = (spans[-1][0], b)
                else:
                    spans.append((a, b))
        step, output = dp.step, dp.output
        cmd_r = np.full(log.n, np.nan) if record else None
        f_r = np.full(log.n, np.nan) if record else None
        x_r = np.full((log.n, 2), np.nan) if record else None
        for a0, b0 in spans:
            if not continuous:   # from rest at the window start; time keeps the log's origin
                dp.reset(*anchors[a0], current=u[max(a0 - 1, 0)], t0=log.time_s[0])
                dp.k = a0
            for k in range(a0, b0):
                if k in starts:
                    dp.x[0], dp.x[1] = anchors[k]
                ysim[k] = output()
                if record:
                    cmd_r[k] = dp.command(u[k], dp.x[0])
                    f_r[k] = dp.net_force(dp.x[0], dp.x[1])
                    x_r[k] = dp.x[:2]
                step(u[k])
        e_parts, ys = [], np.full(log.n, np.nan)
        for a, b in windows.bounds:
            B = basis(b - a)
            r = y[a:b] - ysim[a:b]
            c, *_ = np.linalg.lstsq(B, r, rcond=None)
            ys[a:b] = ysim[a:b] + B @ c
            e_parts.append(r - B @ c)
            anchors[a] = (anchors[a][0] + c[0], anchors[a][1] + c[1])
    return Residual(windows, np.concatenate(e_parts) if e_parts else np.zeros(0), ys, log, cmd_r, f_r, x_r)


def residual(plant: ModalPlant, log: SeekLog, windows: Windows | None = None) -> Residual:
    """:func:`simulate` on :func:`seek_windows` by default."""
    return simulate(plant, log, windows or seek_windows(log))


# analysis of the residual (re-exported here; defined in residual_analysis)
from identification.loop.residual_analysis import (CorrelationTest, Spectra, correlations, detect_spindle,  # noqa: E402
                                nonlinear_tests, pooled_xcorr, spectra, synchronous_average)
