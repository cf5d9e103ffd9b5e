"""Seek logs: the :class:`SeekLog` container and the seek segmentation (:class:`Seek`,
:func:`segment_seeks`, :func:`settle_windows`).

A log holds four required columns, ``time_s`` [s], ``current_a`` [A, total actuator current
command], ``position_track`` [track, measured absolute head position] and ``target_track``
[track, seek target in force], uniformly sampled at ``sample_rate_hz``, plus optional extra float
columns and string metadata.  Reading and writing files (.csv/.npz/.mat, format version 1) is
:mod:`identification.logs.formats`.

Multirate drives (optional): a drive that updates the current ``L`` times per position sample may
log the ``L`` held values as extra columns ``current_sub1_a`` ... ``current_subL_a`` [A] (the value
held over the ``j``-th of ``L`` equal sub-intervals after the sample instant); ``current_a`` is then
their mean.  :meth:`SeekLog.input_current` returns them and the robust identification models the
exact hold; without them the current is taken as held over the whole sample period.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from identification.logs.checks import check_current_columns
from identification.logs.schema import (COLUMNS, MIN_SAMPLES, RATE_TOL, TIME_JITTER_TOL, LogError,  # noqa: F401
                                        _RESERVED, _SUBSTEP, _positive, _vector)

__all__ = ["COLUMNS", "MIN_SAMPLES", "LogError", "SeekLog", "Seek", "segment_seeks", "settle_windows"]


def _bad_name(key: Any) -> bool:
    return not isinstance(key, str) or not key or key != key.strip() or "".join(key.splitlines()) != key


@dataclass(eq=False)
class SeekLog:
    """A uniformly sampled seek log; build validated ones with :meth:`from_arrays`.

    Attributes
    ----------
    time_s, current_a : ndarray
        Sample times [s] (strictly increasing, uniform) and total actuator current command [A].
    position_track, target_track : ndarray
        Measured absolute head position and the seek target in force [track].
    sample_rate_hz : float
        Sample rate [Hz]. ``track_pitch_nm`` [nm] is optional (None).
    metadata : dict[str, str]
        Other header keys. ``extra`` holds extra float columns (may contain NaN).
    source : str or None
        File the log was read from.
    """

    time_s: np.ndarray
    current_a: np.ndarray
    position_track: np.ndarray
    target_track: np.ndarray
    sample_rate_hz: float
    track_pitch_nm: float | None = None
    metadata: dict[str, str] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    source: str | None = None

    @property
    def pes(self) -> np.ndarray:
        """Position error signal ``position_track - target_track`` [track]."""
        return self.position_track - self.target_track

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(len(self.time_s))

    @property
    def dt(self) -> float:
        """Nominal sample period ``1 / sample_rate_hz`` [s]."""
        return 1.0 / self.sample_rate_hz

    def input_current(self) -> np.ndarray:
        """The current as the plant sees it [A]: ``(n, L)`` sub-step currents of a multirate drive
        (extra columns ``current_sub1_a`` .. ``current_subL_a``, see the module notes), else
        ``current_a`` (held over the sample).

        Raises
        ------
        LogError
            Sub-step columns that are not numbered 1..L, or not finite (the row is named).
        """
        idx = sorted(int(m.group(1)) for k in self.extra if (m := _SUBSTEP.fullmatch(k)))
        if not idx:
            return self.current_a
        name = self.source or "<arrays>"
        if idx != list(range(1, len(idx) + 1)) or len(idx) < 2:
            raise LogError(name, f"sub-step current columns must be current_sub1_a .. current_subL_a "
                                 f"with L >= 2, got numbers {idx[:8]}")
        u = np.column_stack([self.extra[f"current_sub{j}_a"] for j in idx])
        if not np.isfinite(u).all():
            row, col = np.argwhere(~np.isfinite(u))[0]
            raise LogError(name, f"row {row + 1}: current_sub{col + 1}_a is not finite")
        return u

    def slice(self, i0: int | None = None, i1: int | None = None) -> SeekLog:
        """Samples ``[i0, i1)`` (Python slice rules) as a new, unvalidated log; times stay absolute."""
        s = slice(i0, i1)
        return SeekLog(self.time_s[s].copy(), self.current_a[s].copy(), self.position_track[s].copy(),
                       self.target_track[s].copy(), self.sample_rate_hz, self.track_pitch_nm,
                       dict(self.metadata), {k: v[s].copy() for k, v in self.extra.items()}, self.source)

    @classmethod
    def from_arrays(cls, time_s, current_a, position_track, target_track, sample_rate_hz, *,
                    track_pitch_nm=None, metadata: Mapping[str, Any] | None = None,
                    extra: Mapping[str, Any] | None = None, source: str | None = None) -> SeekLog:
        """Build a :class:`SeekLog` from arrays, copying (to float64) and validating.

        Parameters
        ----------
        time_s : array_like or None
            Sample times [s]; ``None`` gives ``arange(n) / sample_rate_hz``.
        current_a, position_track, target_track : array_like
            Current command [A], head position [track], seek target [track].
        sample_rate_hz, track_pitch_nm : float
            Sample rate [Hz]; track pitch [nm] or None.
        metadata, extra : mapping, optional
            Header keys (values stored as ``str(v).strip()``) and extra columns of length n.
        source : str, optional
            File name used in messages and kept in :attr:`source`.

        Raises
        ------
        LogError
            Bad or mismatched columns, fewer than :data:`MIN_SAMPLES` samples, NaN/inf in a
            required column, time not increasing or jitter > 1 % of dt, rate off the time
            column by > 0.1 %, or no seek (target never changes).
        """
        name = source if source is not None else "<arrays>"
        cols = {k: _vector(name, k, v) for k, v in
                (("current_a", current_a), ("position_track", position_track), ("target_track", target_track))}
        rate = _positive(name, "sample_rate_hz", sample_rate_hz)
        pitch = None if track_pitch_nm is None else _positive(name, "track_pitch_nm", track_pitch_nm)
        t = np.arange(len(cols["current_a"])) / rate if time_s is None else _vector(name, "time_s", time_s)
        cols = {"time_s": t, **cols}
        meta = {k: str(v).strip() for k, v in (metadata or {}).items()}
        for k, v in meta.items():
            if _bad_name(k) or ":" in k or k in _RESERVED or "".join(v.splitlines()) != v:
                raise LogError(name, f"invalid metadata entry {str(k)[:40]!r}")
        for k in extra or {}:
            if _bad_name(k) or k in COLUMNS + _RESERVED + ("metadata",):
                raise LogError(name, f"invalid extra column name {str(k)[:40]!r}")
        extras = {k: _vector(name, k, v) for k, v in (extra or {}).items()}
        n = len(t)
        for k, a in (*cols.items(), *extras.items()):
            if len(a) != n:
                raise LogError(name, f"column {k} has {len(a)} values, expected {n}")
        if n < MIN_SAMPLES:
            raise LogError(name, f"too short to identify anything: {n} samples (need at least {MIN_SAMPLES})")
        bad = [(int(np.argmin(np.isfinite(a))), k) for k, a in cols.items() if not np.isfinite(a).all()]
        if bad:
            row, k = min(bad, key=lambda b: b[0])
            v = cols[k][row]
            raise LogError(name, f"row {row + 1}: {k} is {'NaN' if np.isnan(v) else ('+inf' if v > 0 else '-inf')}")
        d = np.diff(t)
        if (d <= 0).any():
            i = int(np.argmax(d <= 0))
            raise LogError(name, f"row {i + 2}: time_s {'repeated' if d[i] == 0 else 'decreasing'} "
                                 f"({t[i + 1]:.9g} s after {t[i]:.9g} s)")
        dt = (t[-1] - t[0]) / (n - 1)
        dev = np.abs(d - dt) / dt
        if dev.max() > TIME_JITTER_TOL:
            i = int(np.argmax(dev))
            raise LogError(name, f"row {i + 2}: non-uniform time_s: step {d[i]:.6g} s is {100 * dev[i]:.3g} % off "
                                 f"the mean dt {dt:.6g} s (limit {100 * TIME_JITTER_TOL:g} %)")
        if abs(rate * dt - 1.0) > RATE_TOL:
            raise LogError(name, f"sample_rate_hz {rate:.9g} disagrees with time_s (1/dt = {1 / dt:.9g} Hz) "
                                 f"by {100 * abs(rate * dt - 1):.3g} % (limit {100 * RATE_TOL:g} %)")
        if np.all(cols["target_track"] == cols["target_track"][0]):
            raise LogError(name, "no seek in log: target_track never changes")
        log = cls(**cols, sample_rate_hz=rate, track_pitch_nm=pitch, metadata=meta, extra=extras, source=source)
        log.input_current()          # validates the optional sub-step current columns
        check_current_columns(log)   # ... and that current_a is their mean
        return log


# ------------------------------------------------------------------------------------- segmentation
@dataclass(frozen=True)
class Seek:
    """One seek in a :class:`SeekLog`; indices are sample indices into the log.

    Attributes
    ----------
    start : int
        First sample with the new target (``target_track[start] != target_track[start - 1]``).
    settle : int
        The paper's N: first index of the tail of ``[start, end)`` in which every sample has
        ``|PES| <= settle_band``; ``settle == end`` if the seek never settles.
    end : int
        Exclusive end: the next seek's ``start``, or the log length.
    from_track, to_track : float
        Target before and after the change [track].
    length_track : float
        Signed seek length ``to_track - from_track`` [track].
    settled : bool
        Whether the in-band tail ``[settle, end)`` has at least ``min_settle_samples`` samples.
    """

    start: int
    settle: int
    end: int
    from_track: float
    to_track: float
    length_track: float
    settled: bool

    @property
    def settle_samples(self) -> int:
        """Samples from the target change to settling, ``settle - start``."""
        return self.settle - self.start


def segment_seeks(log: SeekLog, settle_band: float = 0.1, min_settle_samples: int = 10) -> list[Seek]:
    """Split a log into seeks, one per change of ``target_track``, in time order.

    Samples before the first target change belong to no seek.

    Parameters
    ----------
    log : SeekLog
        The log.
    settle_band : float, default 0.1
        Half-width of the settle band on |PES| [track]; ``|PES| <= settle_band`` is in band.
    min_settle_samples : int, default 10
        A seek is ``settled`` only if it then stays in band for at least this many samples before
        its window ends; otherwise (e.g. the log ends mid-overshoot) ``settle = end``.

    Returns
    -------
    list of Seek
    """
    if not settle_band > 0 or min_settle_samples < 1:
        raise ValueError("settle_band must be > 0 and min_settle_samples >= 1")
    target = np.asarray(log.target_track, dtype=float)
    out_of_band = ~(np.abs(np.asarray(log.pes, dtype=float)) <= settle_band)  # NaN counts as out
    starts = (np.flatnonzero(target[1:] != target[:-1]) + 1).tolist()
    seeks = []
    for start, end in zip(starts, starts[1:] + [len(target)]):
        out = np.flatnonzero(out_of_band[start:end])
        settle = start + (int(out[-1]) + 1 if out.size else 0)
        settled = end - settle >= min_settle_samples
        a, b = float(target[start - 1]), float(target[start])
        seeks.append(Seek(start, settle if settled else end, end, a, b, b - a, settled))
    return seeks


def settle_windows(log: SeekLog, seeks: list[Seek] | None = None) -> list[tuple[int, int]]:
    """Half-open index ranges ``(settle, end)`` of the settled ``seeks`` (default
    ``segment_seeks(log)``), for ``log.slice(*w)`` or ``array[settle:end]``.
    """
    seeks = segment_seeks(log) if seeks is None else seeks
    for s in seeks:
        if not 0 <= s.start <= s.settle <= s.end <= log.n:
            raise ValueError(f"{s} does not fit a log of {log.n} samples")
    return [(s.settle, s.end) for s in seeks if s.settled]
