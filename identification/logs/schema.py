"""The seek-log schema every reader and check shares: column names, limits, :class:`LogError` and
the value checks that turn a bad entry into one line naming the file.

The bottom of :mod:`identification.logs`: it imports nothing else of the package, so
:mod:`~identification.logs.seeklog`, :mod:`~identification.logs.checks`,
:mod:`~identification.logs.formats` and :mod:`~identification.logs.mat73` import it one way.
"""
from __future__ import annotations

import json
import math
import re
from typing import Any

import numpy as np

__all__ = ["COLUMNS", "MIN_SAMPLES", "TIME_JITTER_TOL", "RATE_TOL", "LogError"]

COLUMNS = ("time_s", "current_a", "position_track", "target_track")
MIN_SAMPLES = 64        #: fewest samples a log may have
TIME_JITTER_TOL = 0.01  #: max |step - mean dt| / mean dt
RATE_TOL = 1e-3         #: max relative disagreement of sample_rate_hz with the time column
_RESERVED = ("seekopt-log", "sample_rate_hz", "track_pitch_nm")
_SUBSTEP = re.compile(r"current_sub(\d+)_a")


def _one_line(text: Any) -> str:
    return " ".join(str(text).splitlines())


def _why(exc: BaseException) -> str:
    return _one_line(f"{type(exc).__name__}: {exc}")[:120]


class LogError(ValueError):
    """Bad seek-log input. ``str(err)`` is one line ``"<file>: <problem>"``, e.g.
    ``"run3.csv: row 1207: current_a is NaN"``; also available as ``err.file``, ``err.problem``.
    """

    def __init__(self, file: str, problem: str | None = None):
        if problem is None:  # also the path taken when unpickling
            file, _, problem = str(file).partition(": ")
        self.file, self.problem = _one_line(file), _one_line(problem)
        super().__init__(f"{self.file}: {self.problem}")


def _vector(name: str, key: str, value: Any) -> np.ndarray:
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged sequences and the like
        raise LogError(name, f"column {key} is not numeric ({_why(exc)})") from None
    if arr.dtype.kind not in "biuf":
        raise LogError(name, f"column {key} is not numeric (dtype {arr.dtype})")
    if arr.ndim != 1:
        raise LogError(name, f"column {key} is not 1-D (shape {arr.shape})")
    return arr.astype(np.float64, copy=True)


def _positive(name: str, key: str, value: Any) -> float:
    try:
        value = value.item() if isinstance(value, np.ndarray) else value
        x = float(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError, OverflowError):
        raise LogError(name, f"metadata {key} is not a number: {str(value)[:40]!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise LogError(name, f"metadata {key} must be positive and finite, got {x!r}")
    return x


def _split_entries(name: str, entries: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Separate the ``metadata`` entry (JSON string or MATLAB struct) from the columns."""
    m = entries.pop("metadata", "{}")
    if isinstance(m, np.ndarray) and m.dtype.kind == "U" and m.size == 1:
        m = str(m.item())
    if isinstance(m, str):
        try:
            m = json.loads(m)
        except (ValueError, RecursionError) as exc:
            raise LogError(name, f"metadata is not valid JSON ({_why(exc)})") from None
    if not isinstance(m, dict):
        raise LogError(name, "metadata entry is not a JSON object string or struct")
    for key in ("sample_rate_hz", "track_pitch_nm"):  # tolerate top-level scalars from other tools
        if key in entries and key not in m and np.size(entries[key]) == 1:
            m[key] = entries.pop(key)
    return entries, m
