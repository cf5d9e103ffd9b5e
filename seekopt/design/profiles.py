"""Seek profiles: the feedforward current and the reference it follows.

A :class:`Profile` is what firmware plays for one seek of ``tracks`` tracks:
``u_ff = current_a[k]`` and ``r = start + reference_track[k]`` sample by sample,
then ``r = start + tracks`` and ``u_ff = 0`` held.  The profile is long enough
for that hold to be right (the reference has arrived and is at rest).

Baselines (paper, Section 4; ERRATA items 3 and 4):

* sine: ``f(t) = A sin(2 pi t / T)`` on ``0 <= t < T``;
* windowed sine: ``f(t) = A sin(pi t / T) sin(2 pi t / T)`` (the printed amplitude
  ``9 pi K / (8 T^2)`` reaches ``K/pi``; ``9 pi^2 K / (8 T^2)`` reaches ``K``);
* bang-bang: ``+Imax`` then ``-Imax``; ``T_bb = 2 sqrt(K / (k0 Imax))`` is the
  rigid-body lower bound on seek time at that current limit.

Every baseline is sampled at the servo rate and then normalised so the sampled
profile brings the discrete (ZOH) rigid model exactly to rest at ``K``
(:func:`normalise_rest_to_rest`).
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identification.model.plant import ModalPlant, atomic_write_text as _atomic_write

__all__ = ["Profile", "ProfileError", "rigid_endpoint_matrix", "rigid_position_kernel", "normalise_rest_to_rest", "exact_rest",
           "sine_profile", "windowed_sine_profile", "bang_bang_profile", "t_bang_bang",
           "shortest_baseline", "reference_from_model", "finish_profile"]


class ProfileError(ValueError):
    """A profile that cannot be built or read (one-line message)."""


@dataclass
class Profile:
    """Feedforward current and reference for one seek, at the servo rate.

    Attributes
    ----------
    current_a : ndarray
        Feedforward current per sample [A].
    reference_track : ndarray
        Reference position relative to the seek start [track].
    sample_rate_hz, tracks, imax_a, settle_track : float
    kind : str
        ``sine``, ``windowed_sine``, ``bang_bang``, ``optimal``, ...
    seek_samples : int
        Samples of non-zero feedforward (the seek time is ``seek_samples / fs``).
    meta : dict
        Provenance: plant and controller hashes, tool version, design status, ...
    """

    current_a: np.ndarray
    reference_track: np.ndarray
    sample_rate_hz: float
    tracks: float
    imax_a: float
    settle_track: float = 0.1
    kind: str = "custom"
    seek_samples: int = 0
    meta: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.current_a)

    @property
    def seek_time_s(self) -> float:
        return self.seek_samples / self.sample_rate_hz

    def padded(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``(u_ff, r_rel)`` extended to ``n`` samples with the firmware's hold."""
        u = np.zeros(max(n, self.n)); u[:self.n] = self.current_a
        r = np.full(max(n, self.n), float(self.tracks)); r[:self.n] = self.reference_track
        return u[:n], r[:n]

    # ------------------------------------------------------------ file formats
    def header(self) -> dict:
        from seekopt import __version__
        h = {"seekopt-profile": "1", "sample_rate_hz": self.sample_rate_hz, "tracks": self.tracks,
             "imax_a": self.imax_a, "settle_track": self.settle_track, "kind": self.kind,
             "seek_samples": self.seek_samples, "tool_version": __version__}
        h.update(self.meta)
        return h

    def to_csv(self, path: str | Path | None = None) -> str:
        buf = io.StringIO()
        for k, v in self.header().items():
            buf.write(f"# {k}: {v}\n")
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["sample", "current_a", "reference_track"])
        for k, (u, r) in enumerate(zip(self.current_a, self.reference_track)):
            w.writerow([k, repr(float(u)), repr(float(r))])
        text = buf.getvalue()
        if path is not None:
            _atomic_write(Path(path), text)
        return text

    @classmethod
    def from_csv(cls, path: str | Path) -> "Profile":
        path = Path(path)
        try:
            lines = path.read_text().splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise ProfileError(f"{path}: cannot read profile ({exc.__class__.__name__})") from None
        meta, body = {}, []
        for line in lines:
            if line.startswith("#"):
                k, _, v = line[1:].partition(":")
                meta[k.strip()] = v.strip()
            elif line.strip():
                body.append(line)
        try:
            rows = list(csv.reader(body))
            head = rows[0]
            iu, ir = head.index("current_a"), head.index("reference_track")
            u = np.array([float(r[iu]) for r in rows[1:]])
            ref = np.array([float(r[ir]) for r in rows[1:]])
            known = {k: meta.pop(k) for k in ("sample_rate_hz", "tracks", "imax_a", "settle_track",
                                              "kind", "seek_samples", "seekopt-profile", "tool_version")
                     if k in meta}
            return cls(u, ref, float(known["sample_rate_hz"]), float(known["tracks"]),
                       float(known["imax_a"]), float(known.get("settle_track", 0.1)),
                       known.get("kind", "custom"), int(float(known.get("seek_samples", 0))), meta)
        except (IndexError, KeyError, ValueError) as exc:
            raise ProfileError(f"{path}: not a seekopt profile ({exc.__class__.__name__}: {exc})") from None

    def to_dict(self) -> dict:
        d = self.header()
        d["current_a"] = [float(x) for x in self.current_a]
        d["reference_track"] = [float(x) for x in self.reference_track]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Profile":
        meta = {k: v for k, v in d.items() if k not in (
            "current_a", "reference_track", "sample_rate_hz", "tracks", "imax_a", "settle_track",
            "kind", "seek_samples", "seekopt-profile", "tool_version")}
        return cls(np.asarray(d["current_a"], float), np.asarray(d["reference_track"], float),
                   float(d["sample_rate_hz"]), float(d["tracks"]), float(d["imax_a"]),
                   float(d.get("settle_track", 0.1)), d.get("kind", "custom"),
                   int(d.get("seek_samples", 0)), meta)


# ------------------------------------------------------------------ rigid model
def rigid_position_kernel(n: int, delay_samples: float, c: float) -> np.ndarray:
    """Rigid position [track] at samples ``0..n-1`` after a unit current [A] held over sample 0 (ZOH,
    input delay ``delay_samples``; ``c = k0 Ts^2``): ``c f(q - tau)`` with ``f(t) = 0, t^2/2, t - 1/2`` for
    ``t <= 0, 0 < t < 1, t >= 1``."""
    t = np.arange(int(n)) - float(delay_samples)
    return c * np.where(t <= 0, 0.0, np.where(t < 1, 0.5 * t * t, t - 0.5))


def rigid_endpoint_matrix(n: int, k0: float, ts: float) -> np.ndarray:
    """``M`` with ``M @ u = [position, velocity * ts]`` of the ZOH double integrator
    ``k0/s^2`` after ``n`` samples of ``u`` from rest (delay does not change the end state).

    ``position = k0 ts^2 sum_k (n - k - 1/2) u_k``, ``velocity = k0 ts sum_k u_k``.
    """
    k = np.arange(n)
    return np.vstack([k0 * ts ** 2 * (n - k - 0.5), k0 * ts ** 2 * np.ones(n)])


def normalise_rest_to_rest(u: np.ndarray, tracks: float, k0: float, ts: float) -> np.ndarray:
    """Scale ``u`` (and, if its samples do not sum to zero, add the smallest correction)
    so the ZOH rigid model ends at rest at exactly ``tracks`` (ERRATA item 4)."""
    u = np.asarray(u, dtype=float)
    M = rigid_endpoint_matrix(len(u), k0, ts)
    pos = M[0] @ u
    if pos == 0:
        raise ProfileError("profile shape moves the rigid body nowhere; cannot normalise")
    u = u * (tracks / pos)
    miss = np.array([tracks, 0.0]) - M @ u
    return u + M.T @ np.linalg.solve(M @ M.T, miss)


def exact_rest(u: np.ndarray, tracks: float, k0: float, fs: float, imax: float, iters: int = 3):
    """``u`` [A] clipped to ``±imax`` and corrected to end exactly at rest at ``tracks`` on the ZOH
    rigid model (:func:`rigid_endpoint_matrix`): a least-norm correction on the unsaturated samples,
    re-clipped, ``iters`` times.  Returns None when the rest point is still missed by more than
    1e-6 (track, track/sample) or ``u`` is not finite."""
    M = rigid_endpoint_matrix(len(u), k0, 1.0 / fs)
    target = np.array([float(tracks), 0.0])
    u = np.clip(np.asarray(u, float), -imax, imax)
    for _ in range(iters):
        miss = target - M @ u
        free = np.abs(u) < imax * (1 - 1e-9)
        if np.max(np.abs(miss)) <= 1e-9 or free.sum() < 2:
            break
        Mf = M[:, free]
        u[free] += Mf.T @ np.linalg.solve(Mf @ Mf.T, miss)
        u = np.clip(u, -imax, imax)
    if np.max(np.abs(M @ u - target)) > 1e-6 or not np.all(np.isfinite(u)):
        return None
    return u


def t_bang_bang(tracks: float, k0: float, imax: float) -> float:
    """Rigid-body minimum seek time ``T_bb = 2 sqrt(K / (k0 Imax))`` [s]."""
    return 2.0 * math.sqrt(abs(tracks) / (k0 * imax))


def _shape(kind: str, n: int) -> np.ndarray:
    t = (np.arange(n) + 0.5) / n  # sample centres: the held value over each sample
    if kind == "sine":
        return np.sin(2 * np.pi * t)
    if kind == "windowed_sine":
        return np.sin(np.pi * t) * np.sin(2 * np.pi * t)
    if kind == "bang_bang":
        return np.sign(0.5 - t) * (np.abs(t - 0.5) > 0.25 / n)  # odd n: zero middle sample
    raise ProfileError(f"unknown baseline {kind!r}")


def _baseline(kind: str, tracks, seek_time_s, k0, fs) -> np.ndarray:
    n = max(2, int(round(seek_time_s * fs)))
    return normalise_rest_to_rest(_shape(kind, n), tracks, k0, 1.0 / fs)


def sine_profile(tracks: float, seek_time_s: float, k0: float, fs: float) -> np.ndarray:
    """The paper's sinusoidal current ``2 pi K / T^2 sin(2 pi t / T) / k0``, sampled and normalised."""
    return _baseline("sine", tracks, seek_time_s, k0, fs)


def windowed_sine_profile(tracks: float, seek_time_s: float, k0: float, fs: float) -> np.ndarray:
    """The paper's smoothed current ``9 pi^2 K / (8 T^2) sin(pi t/T) sin(2 pi t/T) / k0``
    (ERRATA item 3 amplitude), sampled and normalised."""
    return _baseline("windowed_sine", tracks, seek_time_s, k0, fs)


def bang_bang_profile(tracks: float, seek_time_s: float, k0: float, fs: float) -> np.ndarray:
    """Rigid-body bang-bang current over ``seek_time_s`` (rounded to samples), normalised."""
    return _baseline("bang_bang", tracks, seek_time_s, k0, fs)


def shortest_baseline(kind: str, tracks: float, k0: float, fs: float, imax: float,
                      max_samples: int = 100000) -> np.ndarray:
    """The shortest sampled baseline of ``kind`` whose peak current is within ``imax``."""
    n = max(2, int(math.floor(t_bang_bang(tracks, k0, imax) * fs)))
    while n < max_samples:
        u = normalise_rest_to_rest(_shape(kind, n), tracks, k0, 1.0 / fs)
        if np.max(np.abs(u)) <= imax * (1 + 1e-12):
            return u
        n += 1
    raise ProfileError(f"no {kind} profile of {tracks} tracks within {imax} A")


def reference_from_model(model: ModalPlant, u_ff: np.ndarray, fs: float, n: int | None = None) -> np.ndarray:
    """Reference ``r(k)`` [track, relative] = the model's response to ``u_ff`` from rest
    (the 2DOF model-following reference; rigid-only model in the paper).  Bias and
    nonlinear effects of ``model`` are ignored."""
    n = len(u_ff) if n is None else n
    u = np.zeros(n); u[:len(u_ff)] = u_ff[:n]
    return model.linear_part().simulate_open_loop(u, 1.0 / fs, history_a=0.0)


def finish_profile(u_ff: np.ndarray, tracks: float, fs: float, imax: float, model: ModalPlant,
                   kind: str, settle_track: float = 0.1, tol_track: float = 1e-6,
                   max_extra: int = 20000, meta: dict | None = None) -> Profile:
    """Wrap a feedforward into a :class:`Profile` whose reference comes from ``model``
    and is long enough for the firmware's hold (reference within ``tol_track`` of ``tracks``
    with the model at rest)."""
    u_ff = np.asarray(u_ff, float)
    seek = int(np.max(np.nonzero(np.abs(u_ff) > 0)[0]) + 1) if np.any(u_ff) else 0
    n = len(u_ff) + 8
    while True:
        r = reference_from_model(model, u_ff, fs, n)
        tail = r[seek:]
        idx = np.nonzero(np.abs(tail - tracks) > tol_track)[0]
        last_bad = seek + (idx[-1] + 1 if len(idx) else 0)
        if last_bad + 4 <= n or n > len(u_ff) + max_extra:
            break
        n *= 2
    n = max(last_bad + 1, seek + 1, len(u_ff))
    u = np.zeros(n); u[:len(u_ff)] = u_ff
    return Profile(u, r[:n], fs, tracks, imax, settle_track, kind, seek, dict(meta or {}))


