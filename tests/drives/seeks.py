"""Seek schedules of the independent test drive: feedforward currents and the firmware's reference.

A seek of ``K`` tracks uses a feedforward current ``u_n = A g((n + 1/2)/N)``, ``n = 0..N-1``, held
over each servo sample, with a shape ``g`` antisymmetric about the middle (so the rigid body ends
at rest); ``A`` puts the firmware's rigid model ``k0_fw / s^2`` exactly ``K`` tracks further, and
``N`` is the shortest length (at least ``min_samples``) with ``|A| <= imax`` (shapes scaled to a unit peak).  Shapes: ``sine``
(``sin 2 pi x``), ``windowed_sine`` (``sin 2 pi x * (1 - cos 2 pi x)/2``), ``bangbang`` (full current,
reversed at the middle, with raised-cosine transitions over ``ramp`` of the length).

The reference is the firmware's rigid model driven by the feedforward, delayed by the firmware's
delay estimate ``tau``: the exact continuous response ``k0 sum_j u_j [R(t - j Ts - tau) - R(t - (j+1) Ts - tau)]``,
``R(s) = max(s, 0)^2 / 2``, sampled at the servo instants (the paper's 2DOF structure).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SHAPES", "shape", "seek_current", "rigid_reference", "Schedule", "SeekPlan", "plan_seeks"]


def _sine(x):
    return np.sin(2 * np.pi * x)


def _windowed_sine(x):
    return np.sin(2 * np.pi * x) * 0.5 * (1 - np.cos(2 * np.pi * x))


def _bangbang(x, ramp=0.12):
    """+1 on the first half, -1 on the second, raised-cosine transitions of width ``ramp``
    (rise over ``[0, ramp]``, reversal centred on the middle, fall over ``[1 - ramp, 1]``)."""
    def step(s):                                 # 0 -> 1 over [0, ramp]
        return 0.5 * (1 - np.cos(np.pi * np.clip(s / ramp, 0.0, 1.0)))
    return step(x) - 2 * step(x - 0.5 + ramp / 2) + step(x - 1.0 + ramp)


SHAPES = {"sine": _sine, "windowed_sine": _windowed_sine, "bangbang": _bangbang}
_PEAK = {k: float(np.max(np.abs(g(np.linspace(0.0, 1.0, 100001))))) for k, g in SHAPES.items()}


def shape(kind: str, N: int) -> np.ndarray:
    """The shape sampled at the middle of each of ``N`` samples, scaled to a unit continuous peak."""
    return SHAPES[kind]((np.arange(N) + 0.5) / N) / _PEAK[kind]


def _travel_per_amp(g: np.ndarray, k0: float, Ts: float) -> float:
    """Rigid-body travel [track] per ampere of a ZOH current ``g`` ending at zero velocity."""
    N = len(g)
    return k0 * Ts * Ts * float(np.sum((N - np.arange(N) - 0.5) * g))


def seek_current(kind: str, tracks: float, k0: float, fs: float, imax_a: float, min_samples: int = 4) -> np.ndarray:
    """Shortest feedforward of shape ``kind`` moving the rigid model ``tracks`` within ``imax_a``."""
    Ts = 1.0 / fs
    c = _travel_per_amp(shape(kind, 1000), k0, Ts) / 1000 ** 2
    N = max(min_samples, int(math.sqrt(abs(tracks) / (imax_a * c))))

    def amp(N):
        return tracks / _travel_per_amp(shape(kind, N), k0, Ts)
    while abs(amp(N)) > imax_a:
        N += 1
    while N - 1 >= min_samples and abs(amp(N - 1)) <= imax_a:
        N -= 1
    return amp(N) * shape(kind, N)


def rigid_reference(u: np.ndarray, k0: float, fs: float, delay_s: float, n: int) -> np.ndarray:
    """Displacement [track] of ``k0/s^2`` at ``t = k Ts``, ``k < n``, for the ZOH current ``u`` delayed by ``delay_s``."""
    Ts = 1.0 / fs
    t = np.arange(n)[:, None] * Ts - delay_s - np.arange(len(u))[None, :] * Ts

    def R(s):
        return 0.5 * np.maximum(s, 0.0) ** 2
    return k0 * (R(t) - R(t - Ts)) @ u


@dataclass
class Schedule:
    """What the drive does: seeks drawn like a drive's self test.  Times in s, currents in A."""

    n_seeks: int = 30
    seed: int = 0
    imax_a: float = 0.3
    min_tracks: float = 1.0
    max_tracks: float = 20000.0
    dwell_s: tuple = (0.005, 0.010)
    min_seek_s: float = 0.0003
    stroke_track: tuple = (0.0, 60000.0)
    preroll_s: float = 0.01
    keep_before_s: float = 0.002           # log kept from this long before the first seek
    shapes: tuple = ("sine", "windowed_sine", "bangbang")


@dataclass
class SeekPlan:
    start: int          # sample at which the feedforward starts
    from_track: float
    to_track: float
    kind: str
    u_ff: np.ndarray


def plan_seeks(sch: Schedule, k0_fw: float, fs: float) -> tuple[list[SeekPlan], int]:
    """Seek lengths log-uniform in ``[min_tracks, max_tracks]`` (direction kept inside the stroke),
    shapes in turn, current limit drawn in ``[0.5, 1] imax_a``, dwell drawn in ``dwell_s``.
    Returns the seeks and the total number of samples."""
    rng = np.random.default_rng(sch.seed + 7_000_003)
    lo, hi = sch.stroke_track
    pos = float(np.round(rng.uniform(lo + 0.3 * (hi - lo), lo + 0.7 * (hi - lo))))
    k = int(round(sch.preroll_s * fs))
    out = []
    for i in range(sch.n_seeks):
        length = max(1.0, float(np.round(math.exp(rng.uniform(math.log(sch.min_tracks), math.log(sch.max_tracks))))))
        sign = 1.0 if rng.uniform() < 0.5 else -1.0
        if not lo <= pos + sign * length <= hi:
            sign = -sign
        if not lo <= pos + sign * length <= hi:
            length = min(length, (hi - lo) / 2)
            sign = 1.0 if pos < (lo + hi) / 2 else -1.0
        kind = sch.shapes[i % len(sch.shapes)]
        u = seek_current(kind, sign * length, k0_fw, fs, sch.imax_a * rng.uniform(0.5, 1.0),
                         max(4, int(math.ceil(sch.min_seek_s * fs))))
        out.append(SeekPlan(k, pos, pos + sign * length, kind, u))
        k += len(u) + int(round(rng.uniform(*sch.dwell_s) * fs))
        pos += sign * length
    return out, k
