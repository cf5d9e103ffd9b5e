"""Seek logs: the :class:`SeekLog` container, .csv/.npz/.mat I/O and seek segmentation.

Log format, version 1 (other tools read and write it; keep it exact)
--------------------------------------------------------------------
CSV  Optional leading ``# key: value`` lines (``#`` lines without a colon are comments), a header
     row, one row per sample. Required key ``sample_rate_hz``; optional ``track_pitch_nm`` and
     ``seekopt-log`` (format version, written as ``1``); other keys go to ``metadata`` as strings.
     Required columns, any order: ``time_s`` [s], ``current_a`` [A, total actuator current
     command], ``position_track`` [track, measured absolute head position], ``target_track``
     [track, seek target in force]. Other columns go to ``extra`` (float). Floats are written
     with ``repr`` (exact round trip). Blank lines and later ``#`` lines are skipped.
NPZ  One array per column plus ``metadata``: a JSON object string with the same keys as the CSV
     header lines (``sample_rate_hz``, ``track_pitch_nm`` as numbers).
MAT  (v5, ``scipy.io.savemat``) one column vector per column plus ``metadata`` as the same JSON
     string (a MATLAB struct is accepted on read). Numeric, char and struct variables only.
Row numbers in messages are 1-based and count data rows only (row = array index + 1).

Multirate drives (optional): a drive that updates the current ``L`` times per position sample may
log the ``L`` held values as extra columns ``current_sub1_a`` ... ``current_subL_a`` [A] (the value
held over the ``j``-th of ``L`` equal sub-intervals after the sample instant); ``current_a`` is then
their mean.  :meth:`SeekLog.input_current` returns them and the robust identification models the
exact hold; without them the current is taken as held over the whole sample period.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import struct
import zipfile
import zlib
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from identification.fileio import atomic_write_bytes

__all__ = ["COLUMNS", "MIN_SAMPLES", "LogError", "SeekLog", "Seek", "read_log", "write_log",
           "segment_seeks", "settle_windows"]

COLUMNS = ("time_s", "current_a", "position_track", "target_track")
FORMAT_VERSION = "1"
MIN_SAMPLES = 64        #: fewest samples a log may have
TIME_JITTER_TOL = 0.01  #: max |step - mean dt| / mean dt
RATE_TOL = 1e-3         #: max relative disagreement of sample_rate_hz with the time column
_RESERVED = ("seekopt-log", "sample_rate_hz", "track_pitch_nm")
_SUBSTEP = re.compile(r"current_sub(\d+)_a")
_MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}\Z")


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
        _check_current_columns(log)  # ... and that current_a is their mean
        return log


# ------------------------------------------------------------------------------------------ reading
def _read_csv(name: str, raw: bytes) -> tuple[dict[str, Any], dict[str, Any]]:
    try:
        lines = raw.decode("utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        raise LogError(name, f"not UTF-8 text (bad byte at offset {exc.start})") from None
    meta: dict[str, Any] = {}
    i = 0
    while i < len(lines) and (not lines[i].strip() or lines[i].lstrip().startswith("#")):
        key, sep, value = lines[i].strip()[1:].partition(":")
        if sep and key.strip():
            if key.strip() in meta:
                raise LogError(name, f"line {i + 1}: duplicate metadata key {key.strip()!r}")
            meta[key.strip()] = value.strip()
        i += 1
    if i == len(lines):
        raise LogError(name, "no header row (only comments or blank lines)")
    try:
        rows = list(csv.reader((s for s in lines[i:] if s.strip() and not s.lstrip().startswith("#")), strict=True))
    except csv.Error as exc:
        raise LogError(name, f"CSV syntax error: {_why(exc)}") from None
    header, seen = [h.strip() for h in rows[0]], set()
    for j, h in enumerate(header):
        if not h or h in seen:
            raise LogError(name, f"header: column {j + 1} has no name" if not h else f"header: duplicate column {h!r}")
        seen.add(h)
    data = np.empty((len(rows) - 1, len(header)))
    for r, row in enumerate(rows[1:], 1):
        if len(row) != len(header):
            raise LogError(name, f"row {r}: expected {len(header)} fields, got {len(row)}")
        try:
            data[r - 1] = [float(c) for c in row]
        except ValueError:
            for h, c in zip(header, row):
                try:
                    float(c)
                except ValueError:
                    what = "empty" if not c.strip() else f"not a number: {c.strip()[:40]!r}"
                    raise LogError(name, f"row {r}: {h} is {what}") from None
    return {h: data[:, j] for j, h in enumerate(header)}, meta


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


def _read_npz(name: str, raw: bytes):
    try:
        z = np.load(io.BytesIO(raw), allow_pickle=False)
        if not hasattr(z, "files"):
            raise ValueError("not an .npz archive")
        entries = {k: z[k] for k in z.files}
    except Exception as exc:  # numpy/zipfile raise many types on garbage
        raise LogError(name, f"unreadable .npz file ({_why(exc)})") from None
    return _split_entries(name, entries)


_MI_SIZE = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 9: 8, 12: 8, 13: 8, 16: 1, 17: 2, 18: 4}  # miINT8...miUTF32


def _mat5_elements(buf: bytes, e: str) -> list[tuple[int, bytes]]:
    """Split ``buf`` into MAT v5 data elements ``(type, payload)``; ValueError if malformed."""
    out, pos = [], 0
    while pos < len(buf):
        if len(buf) - pos < 8:
            raise ValueError("truncated element tag")
        mdtype, nbytes = struct.unpack_from(e + "II", buf, pos)
        small = mdtype >> 16  # small data element: 2-byte size, 2-byte type, 4 data bytes
        mdtype, nbytes, at = (mdtype & 0xFFFF, small, pos + 4) if small else (mdtype, nbytes, pos + 8)
        if (mdtype not in _MI_SIZE and mdtype not in (14, 15)) or at + nbytes > len(buf) or (small and nbytes > 4):
            raise ValueError(f"corrupt element (type {mdtype}, {nbytes} bytes)")
        out.append((mdtype, buf[at:at + nbytes]))
        pos += 8 if small else 8 + nbytes + (0 if mdtype == 15 else -nbytes % 8)
    return out


def _check_mat5(elements: list[tuple[int, bytes]], e: str, depth: int = 0) -> None:
    """Let only well-formed real numeric, char and struct variables reach ``loadmat``, whose
    compiled reader can crash the interpreter (segfault) on corrupt files."""
    if depth > 20:
        raise ValueError("variables nested too deeply")
    for mdtype, body in elements:
        if mdtype == 15:
            _check_mat5(_mat5_elements(zlib.decompress(body), e), e, depth + 1)
            continue
        sub = _mat5_elements(body, e) if mdtype == 14 else None
        if sub == []:
            continue  # empty matrix
        if not sub or len(sub) < 3 or [s[0] for s in sub[:3]] != [6, 5, 1] or len(sub[0][1]) != 8 \
                or len(sub[1][1]) < 8 or len(sub[1][1]) % 4:
            raise ValueError("malformed variable header")
        flags, rest = struct.unpack_from(e + "I", sub[0][1])[0], sub[3:]
        dims = [d[0] for d in struct.iter_unpack(e + "i", sub[1][1])]
        count, cls = math.prod(dims), flags & 0xFF
        if flags & 0x800 or min(dims) < 0:
            raise ValueError("complex data or negative dimensions")
        if 4 <= cls <= 15 and cls != 5:  # char or numeric: exactly one real data element
            if len(rest) != 1 or rest[0][0] not in _MI_SIZE or (cls != 4 and rest[0][0] > 13) or \
                    (rest[0][0] != 16 and len(rest[0][1]) != count * _MI_SIZE[rest[0][0]]):
                raise ValueError("data size does not match dimensions")
        elif cls == 2:  # struct: name width, names, count * nfields matrices
            if len(rest) < 2 or rest[0][0] != 5 or len(rest[0][1]) != 4 or rest[1][0] != 1:
                raise ValueError("malformed struct")
            width = struct.unpack(e + "i", rest[0][1])[0]
            if width <= 0 or len(rest[1][1]) % width or len(rest) - 2 != count * (len(rest[1][1]) // width) \
                    or any(s[0] != 14 for s in rest[2:]):
                raise ValueError("malformed struct fields")
            _check_mat5(rest[2:], e, depth + 1)
        else:
            raise ValueError(f"unsupported MATLAB class {cls} (only numeric, char and struct)")


def _read_mat(name: str, raw: bytes):
    from scipy.io import loadmat
    from scipy.io.matlab import matfile_version
    try:
        major = matfile_version(io.BytesIO(raw))[0]
        if major != 1 or raw[126:128] not in (b"IM", b"MI"):
            raise ValueError(f"only MAT v5/v7 files are supported (found {('v4', 'v5', 'v7.3')[major]})")
        e = "<" if raw[126:128] == b"IM" else ">"
        _check_mat5(_mat5_elements(raw[128:], e), e)
        d = loadmat(io.BytesIO(raw), simplify_cells=True)
    except Exception as exc:  # scipy raises many types on garbage
        raise LogError(name, f"unreadable .mat file ({_why(exc)})") from None
    return _split_entries(name, {k: v for k, v in d.items() if not k.startswith("__")})


def _check_current_columns(log) -> None:
    from identification.logs.checks import check_current_columns
    check_current_columns(log)


def _read_mat_any(name: str, raw: bytes):
    """MAT v5/v7 (scipy) or v7.3 (HDF5, via h5py: :mod:`identification.logs.mat73`)."""
    from identification.logs.mat73 import is_mat73, read_mat73
    return read_mat73(name, raw) if is_mat73(raw) else _read_mat(name, raw)


_READERS = {".csv": _read_csv, ".npz": _read_npz, ".mat": _read_mat_any}


def _ext(name: str, table: Mapping[str, Any]):
    ext = os.path.splitext(name)[1].lower()
    if ext not in table:
        raise LogError(name, f"unknown extension {ext!r} (expected .csv, .npz or .mat)")
    return table[ext]


def read_log(path: str | os.PathLike) -> SeekLog:
    """Read and validate a seek log (.csv, .npz or .mat, by extension) from ``path``.

    Returns the validated :class:`SeekLog` with ``source = str(path)``. Raises
    :class:`LogError` (one line, naming the file) for every bad file; nothing else escapes.
    """
    name = os.fsdecode(os.fspath(path))
    reader = _ext(name, _READERS)
    try:
        with open(name, "rb") as fh:
            raw = fh.read()
    except OSError as exc:
        raise LogError(name, f"cannot read file ({exc.strerror or type(exc).__name__})") from None
    if not raw.strip():
        raise LogError(name, "empty file")
    cols, meta = reader(name, raw)
    version = str(meta.pop("seekopt-log", FORMAT_VERSION)).strip()
    if version != FORMAT_VERSION:
        raise LogError(name, f"unsupported seekopt-log version {version[:20]!r} (expected {FORMAT_VERSION})")
    if "sample_rate_hz" not in meta:
        raise LogError(name, "missing metadata key sample_rate_hz")
    rate = _positive(name, "sample_rate_hz", meta.pop("sample_rate_hz"))
    pitch = meta.pop("track_pitch_nm", None)
    pitch = None if pitch is None else _positive(name, "track_pitch_nm", pitch)
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise LogError(name, f"missing column(s): {', '.join(missing)}")
    return SeekLog.from_arrays(*(cols[c] for c in COLUMNS), rate, track_pitch_nm=pitch, metadata=meta,
                               extra={k: v for k, v in cols.items() if k not in COLUMNS}, source=name)


# ------------------------------------------------------------------------------------------ writing
def _header(log: SeekLog) -> dict[str, Any]:
    pitch = {} if log.track_pitch_nm is None else {"track_pitch_nm": log.track_pitch_nm}
    return {"seekopt-log": FORMAT_VERSION, "sample_rate_hz": log.sample_rate_hz, **pitch, **log.metadata}


def _columns(log: SeekLog) -> dict[str, np.ndarray]:
    return {**{c: getattr(log, c) for c in COLUMNS}, **log.extra}


def _csv_bytes(name: str, log: SeekLog) -> bytes:
    out = io.StringIO()
    out.writelines(f"# {k}: {repr(v) if isinstance(v, float) else v}\n" for k, v in _header(log).items())
    cols = _columns(log)
    csv.writer(out, lineterminator="\n").writerow(cols)
    out.writelines(",".join(row) + "\n" for row in zip(*(map(repr, a.tolist()) for a in cols.values())))
    return out.getvalue().encode("utf-8")


def _npz_bytes(name: str, log: SeekLog) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:  # what np.savez does, but any column name is allowed
        for key, arr in {"metadata": np.array(json.dumps(_header(log))), **_columns(log)}.items():
            with zf.open(key + ".npy", "w") as fh:
                np.lib.format.write_array(fh, arr, allow_pickle=False)
    return buf.getvalue()


def _mat_bytes(name: str, log: SeekLog) -> bytes:
    from scipy.io import savemat
    bad = [k for k in log.extra if not _MATLAB_NAME.match(k)]
    if bad:
        raise LogError(name, f"extra column {bad[0]!r} is not a valid MATLAB variable name")
    buf = io.BytesIO()
    savemat(buf, {**_columns(log), "metadata": json.dumps(_header(log))}, oned_as="column")
    return buf.getvalue()


_WRITERS = {".csv": _csv_bytes, ".npz": _npz_bytes, ".mat": _mat_bytes}


def write_log(log: SeekLog, path: str | os.PathLike) -> None:
    """Validate ``log`` (as :meth:`SeekLog.from_arrays`) and write it to ``path`` (.csv/.npz/.mat).

    Atomic: the bytes go to a temporary file in the same folder which then replaces ``path``
    (``os.replace``), so an existing file is never half-written; a replaced file keeps its mode.
    Raises :class:`LogError` for an unknown extension, an invalid log or (.mat) an extra column
    name MATLAB cannot hold, and OSError if the file system refuses.
    """
    name = os.fsdecode(os.fspath(path))
    writer = _ext(name, _WRITERS)
    data = writer(name, SeekLog.from_arrays(log.time_s, log.current_a, log.position_track, log.target_track,
                                            log.sample_rate_hz, track_pitch_nm=log.track_pitch_nm,
                                            metadata=log.metadata, extra=log.extra, source=name))
    atomic_write_bytes(name, data)


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
