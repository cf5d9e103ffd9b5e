"""Simulation windows of closing the loop: where the model is compared with the log.

The rigid body integrates any force error twice, so the model is never run open loop over a
whole log.  Each seek (target change to the next target change) is simulated from rest at its
start, and cut into windows of at most ``window_s`` (10 ms by default); at every window start
the rigid-body position and velocity are linear nuisance parameters (the *anchors*).  The force
noise integrated twice grows like window length^1.5: 10 ms keeps it near the sensor-noise level
of the benchmark drive.

Indices are log samples; windows are half-open ``[a, b)``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from identification.logs.seeklog import SeekLog, segment_seeks

__all__ = ["Windows", "seek_windows"]


@dataclass
class Windows:
    """Half-open index ranges ``[a, b)`` into a log, each with its own anchor (initial rigid-body
    position and velocity); ``groups[i]`` is the seek window ``i`` belongs to (contiguous
    windows of one seek are simulated in one go and only re-anchored)."""

    bounds: list
    groups: list | None = None
    _layouts: dict = field(default_factory=dict, repr=False, compare=False)   # of the linear engine

    def __post_init__(self):
        if self.groups is None:
            self.groups = list(range(len(self.bounds)))

    def __len__(self) -> int:
        return len(self.bounds)

    @property
    def n_samples(self) -> int:
        return int(sum(b - a for a, b in self.bounds))

    @property
    def n_groups(self) -> int:
        """Number of seeks (clusters) [-]."""
        return len(set(self.groups))

    def index(self) -> np.ndarray:
        """Concatenated sample indices of all windows."""
        return np.concatenate([np.arange(a, b) for a, b in self.bounds]) if self.bounds \
            else np.zeros(0, int)

    def spans(self) -> list:
        """``[(a, b)]`` runs of contiguous windows of one seek (group): each is simulated in one
        go from rest at its start."""
        out, last = [], None
        for (a, b), g in zip(self.bounds, self.groups):
            if out and out[-1][1] == a and g == last:
                out[-1] = (out[-1][0], b)
            else:
                out.append((a, b))
            last = g
        return out

    def rate(self, e: np.ndarray) -> tuple:
        """First difference of ``e`` (concatenated window samples, e.g. a residual [track]) within
        each window, and the windows it lives on (each one sample shorter: ``[a + 1, b)``).

        The rate of the output error is what the fast dynamics set (amplifier lag, delay, modes):
        differencing divides by ``~ 1 / (2 sin(pi f / fs))`` the force noise the rigid body
        integrates twice, which dominates the output error's RMS at low frequency.
        Returns ``(rate [unit per sample], Windows)``."""
        cuts = np.cumsum([b - a for a, b in self.bounds])[:-1]
        segs = np.split(np.asarray(e), cuts) if self.bounds else []
        d = np.concatenate([np.diff(s, axis=0) for s in segs]) if segs else np.zeros((0,) + np.shape(e)[1:])
        return d, Windows([(a + 1, b) for a, b in self.bounds], list(self.groups))

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

    def per_group(self, e: np.ndarray) -> dict:
        """``{group: sum of e^2}`` of a residual ``e`` on the window samples (concatenated)."""
        out, i = {}, 0
        for (a, b), g in zip(self.bounds, self.groups):
            out[g] = out.get(g, 0.0) + float(e[i:i + b - a] @ e[i:i + b - a])
            i += b - a
        return out


def seek_windows(log: SeekLog, max_len_s: float | None = 0.010, min_len: int = 32) -> Windows:
    """Windows per seek (target change to next target change), each split into pieces of at
    most ``max_len_s`` [s] (re-anchored), pieces shorter than ``min_len`` samples merged into
    the previous one.  Without target changes the log is cut into ``max_len_s`` pieces."""
    seeks = segment_seeks(log)
    spans = [(s.start, s.end) for s in seeks] or [(0, log.n)]
    L = max(min_len, int(round(max_len_s * log.sample_rate_hz))) if max_len_s else None
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
