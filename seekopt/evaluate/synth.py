"""The synthetic drive: a closed-loop 2DOF drive that writes seek logs.

A truth plant (default: :func:`seekopt.drive.presets.default_truth_plant`, effects
allowed), the drive's controller (default: the NSS PID + notch), a schedule of
seeks with the paper's sine and windowed-sine currents, the benchmark's noise,
flutter and RRO, all run through the one simulator
:func:`seekopt.drive.simulator.simulate_2dof` and returned as a
:class:`identification.logs.seeklog.SeekLog`.  Deterministic for a seed.

Each seek: length drawn log-uniformly between ``min_tracks`` and ``max_tracks``
(sign chosen to stay inside the stroke), profile kind alternating sine /
windowed sine, current limit drawn in ``[0.5, 1] * imax_a`` (varied excitation), the
shortest such profile within that limit (at least ``min_seek_s`` long), the reference from the firmware's rigid
model (the paper's 2DOF), then a dwell (the settle window) of ``dwell_s``.

The NSS controller updates the current twice per position sample (its notches run at
twice the PES rate): ``current_a`` is the mean over the sample and, with
``log_substeps`` (default), the held sub-step values are logged as ``current_sub1_a``,
``current_sub2_a`` (the multirate columns of the log format).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from identification.model.effects import Effect, effect_from_dict
from identification.logs.seeklog import SeekLog
from identification.model.plant import ModalPlant

from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant, nss_disturbances
from seekopt.design.profiles import reference_from_model, shortest_baseline, sine_profile, windowed_sine_profile
from seekopt.drive.simulator import Disturbances, simulate_2dof

__all__ = ["SynthError", "SynthConfig", "synthesize", "schedule_seeks"]


class SynthError(ValueError):
    """A synthetic-drive setting that cannot work (one-line message naming the field)."""


@dataclass
class SynthConfig:
    """What the synthetic drive does.  Times in s, currents in A, positions in tracks."""

    n_seeks: int = 120
    seed: int = 0
    imax_a: float = 0.3
    min_tracks: float = 1.0
    max_tracks: float = 20000.0
    dwell_s: tuple = (0.005, 0.010)
    min_seek_s: float = 0.0003
    stroke_track: tuple = (0.0, 60000.0)
    preroll_s: float = 0.01
    profiles: tuple = ("sine", "windowed_sine")
    noise: bool = True
    rro: bool = True
    rro_scale: float = 1.0
    effects: list = field(default_factory=list)   # undeclared effects added to the truth
    log_substeps: bool = True     # a multirate drive also logs current_sub1_a .. current_subL_a

    def __post_init__(self):
        def positive(name, v):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SynthError(f"{name} must be a positive number (got {v!r})")
        if isinstance(self.n_seeks, bool) or not isinstance(self.n_seeks, int) or self.n_seeks < 1:
            raise SynthError(f"n_seeks must be an integer >= 1 (got {self.n_seeks!r})")
        positive("imax_a [A]", self.imax_a)
        positive("min_tracks [track]", self.min_tracks)
        positive("min_seek_s [s]", self.min_seek_s)
        if not self.max_tracks >= self.min_tracks:
            raise SynthError(f"max_tracks ({self.max_tracks!r}) must be >= min_tracks ({self.min_tracks!r})")
        if not (len(self.dwell_s) == 2 and 0 < self.dwell_s[0] <= self.dwell_s[1]):
            raise SynthError(f"dwell_s must be (low, high) seconds with 0 < low <= high (got {self.dwell_s!r})")
        if not (math.isfinite(self.rro_scale) and self.rro_scale >= 0):
            raise SynthError(f"rro_scale must be >= 0 (got {self.rro_scale!r})")
        bad = [p for p in self.profiles if p not in _BASELINES]
        if bad or not self.profiles:
            raise SynthError(f"profiles must be among {', '.join(_BASELINES)} (got {list(self.profiles)!r})")

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["effects"] = [e.to_dict() if isinstance(e, Effect) else e for e in self.effects]
        return d


_BASELINES = {"sine": sine_profile, "windowed_sine": windowed_sine_profile}


@dataclass
class Seek:
    start: int
    from_track: float
    to_track: float
    kind: str
    u_ff: np.ndarray


def schedule_seeks(cfg: SynthConfig, k0: float, fs: float) -> tuple[list[Seek], int]:
    """Draw the seek schedule; returns the seeks and the total number of samples."""
    rng = np.random.default_rng(cfg.seed)
    lo, hi = cfg.stroke_track
    pos = float(np.round(rng.uniform(lo + 0.3 * (hi - lo), lo + 0.7 * (hi - lo))))
    k = int(round(cfg.preroll_s * fs))
    seeks = []
    for i in range(cfg.n_seeks):
        length = float(np.round(math.exp(rng.uniform(math.log(cfg.min_tracks), math.log(cfg.max_tracks)))))
        length = max(length, 1.0)
        sign = rng.choice([-1.0, 1.0])
        if not lo <= pos + sign * length <= hi:
            sign = -sign
        if not lo <= pos + sign * length <= hi:
            length = min(length, (hi - lo) / 2)
            sign = 1.0 if pos < (lo + hi) / 2 else -1.0
        kind = cfg.profiles[i % len(cfg.profiles)]
        imax = cfg.imax_a * rng.uniform(0.5, 1.0)
        u = shortest_baseline(kind, sign * length, k0, fs, imax)
        if len(u) < cfg.min_seek_s * fs:
            u = _BASELINES[kind](sign * length, cfg.min_seek_s, k0, fs)
        seeks.append(Seek(k, pos, pos + sign * length, kind, u))
        dwell = int(round(rng.uniform(*cfg.dwell_s) * fs))
        k += len(u) + dwell
        pos += sign * length
    return seeks, k


def synthesize(cfg: SynthConfig | None = None, plant: ModalPlant | None = None,
               controller: Controller | None = None, disturbances: Disturbances | None = None,
               firmware_k0: float | None = None) -> tuple[SeekLog, ModalPlant]:
    """Run the synthetic drive; returns ``(log, truth_plant)``.

    Raises :class:`seekopt.drive.loopcheck.LoopError` before simulating if the controller runs at
    another rate than the plant's ``sample_rate_hz`` or does not close a stable loop with it.

    ``firmware_k0`` is the rigid-body gain the drive's firmware uses for its
    profiles and reference model (default: the truth's ``k0``).
    """
    from seekopt.drive.loopcheck import check_loop
    cfg = cfg or SynthConfig()
    plant = plant or default_truth_plant()
    effects = [e if isinstance(e, Effect) else effect_from_dict(e) for e in cfg.effects]
    truth = plant.copy(effects=list(plant.effects) + effects)
    controller = controller or Controller.nss()
    check_loop(truth, controller)       # LoopError: another sample rate, or an unstable loop
    fs = float(controller.sample_rate_hz)
    if disturbances is None:
        disturbances = (nss_disturbances(cfg.seed, rro=cfg.rro, scale_rro=cfg.rro_scale) if cfg.noise
                        else None)
    k0_fw = firmware_k0 or plant.k0
    rigid = ModalPlant(k0=k0_fw, delay_s=plant.delay_s)
    seeks, n = schedule_seeks(cfg, k0_fw, fs)
    u_ff = np.zeros(n)
    start_pos = seeks[0].from_track if seeks else 0.0
    r = np.full(n, start_pos)
    target = np.full(n, start_pos)
    for s in seeks:
        m = len(s.u_ff)
        u_ff[s.start:s.start + m] = s.u_ff
        ref = reference_from_model(rigid, s.u_ff, fs, m + 64)
        end = min(n, s.start + m + 64)
        r[s.start:end] = s.from_track + ref[:end - s.start]
        r[end:] = s.to_track
        target[s.start:] = s.to_track
    sim = simulate_2dof(truth, controller, u_ff, r, disturbances=disturbances, record_substeps=cfg.log_substeps)
    k_keep = int(round(cfg.preroll_s * fs)) - int(round(0.002 * fs))  # keep 2 ms before the first seek
    meta = {"generator": "seekopt.synth", "seed": str(cfg.seed),
            "truth_plant_hash": truth.hash(), "n_seeks": str(cfg.n_seeks)}
    sl = slice(max(k_keep, 0), n)
    sub = sim.current_sub_a                 # a multirate drive logs its sub-step currents too
    substeps = ({f"current_sub{j + 1}_a": sub[sl, j] for j in range(sub.shape[1])}
                if sub is not None and sub.shape[1] > 1 else {})
    log = SeekLog.from_arrays(
        time_s=sim.time_s[sl] - sim.time_s[sl][0], current_a=sim.current_a[sl],
        position_track=sim.position_track[sl], target_track=target[sl], sample_rate_hz=fs,
        track_pitch_nm=truth.track_pitch_nm, metadata=meta,
        extra={"u_ff_a": sim.ff_a[sl], "reference_track": r[sl], **substeps})
    return log, truth
