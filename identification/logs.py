"""Seek logs: the :class:`SeekLog` container, .csv/.npz/.mat I/O and seek segmentation.

File format, version 1 (shared with other tools, keep it exact)
-------------------------------------------------------------
CSV
    Optional leading lines ``# key: value`` (metadata; ``#`` lines without a colon are comments),
    then a header row, then one data row per sample. Required metadata key ``sample_rate_hz``;
    optional ``track_pitch_nm`` and ``seekopt-log`` (format version, written as ``1``); any other
    key is kept in :attr:`SeekLog.metadata` as a string. Required columns, in any order:
    ``time_s`` [s], ``current_a`` [A, total actuator current command], ``position_track``
    [track, measured absolute head position], ``target_track`` [track, seek target in force at
    that sample]. Further columns are kept as float arrays in :attr:`SeekLog.extra`. Floats are
    written with ``repr`` so a round trip is exact. Blank lines and later ``#`` lines are skipped.
NPZ
    One array per column plus a ``metadata`` entry: a JSON object string holding the same keys
    as the CSV header lines (``sample_rate_hz``/``track_pitch_nm`` as JSON numbers).
MAT (``scipy.io.savemat``, v5)
    One column vector per column plus ``metadata`` (a JSON string as for NPZ; a MATLAB struct is
    also accepted on read).
Data-row numbers in error messages are 1-based and count data rows only (= array index + 1).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import re
import struct
import tempfile
import zipfile
import zlib
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = ["COLUMNS", "MIN_SAMPLES", "LogError", "SeekLog", "Seek", "read_log", "write_log",
           "segment_seeks", "settle_windows"]

COLUMNS = ("time_s", "current_a", "position_track", "target_track")
FORMAT_VERSION = "1"
MIN_SAMPLES = 64           #: fewest samples a log may have
TIME_JITTER_TOL = 0.01     #: max |step - mean dt| / mean dt
RATE_TOL = 1e-3            #: max relative disagreement of sample_rate_hz with the time column
_RESERVED = ("seekopt-log", "sample_rate_hz", "track_pitch_nm")
_MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}\Z")


def _one_line(text: str) -> str:
    return " ".join(str(text).splitlines())


def _why(exc: BaseException) -> str:
    return _one_line(f"{type(exc).__name__}: {exc}")[:120]


class LogError(ValueError):
    """Bad seek-log input; ``str(err)`` is a single line ``"<file>: <problem>"``.

    Parameters
    ----------
    file : str
        The file (or ``"<arrays>"``) the problem is in.
    problem : str, optional
        What is wrong, e.g. ``"row 1207: current_a is NaN"``. If omitted, ``file`` is taken as
        the whole message (this keeps the exception picklable).
    """

    def __init__(self, file: str, problem: str | None = None):
        if problem is None:
            file, _, problem = str(file).partition(": ")
        self.file, self.problem = _one_line(file), _one_line(problem)
        super().__init__(f"{self.file}: {self.problem}")


def _vector(name: str, key: str, value: Any) -> np.ndarray:
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged sequences etc.
        raise LogError(name, f"column {key} is not numeric ({_why(exc)})") from None
    if arr.dtype.kind not in "biuf":
        raise LogError(name, f"column {key} is not numeric (dtype {arr.dtype})")
    if arr.ndim != 1:
        raise LogError(name, f"column {key} is not 1-D (shape {arr.shape})")
    return arr.astype(np.float64, copy=True)


def _number(name: str, key: str, value: Any, positive: bool = True) -> float:
    try:
        if isinstance(value, np.ndarray):
            value = value.item()
        x = float(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError):
        raise LogError(name, f"metadata {key} is not a number: {str(value)[:40]!r}") from None
    if positive and not (math.isfinite(x) and x > 0):
        raise LogError(name, f"metadata {key} must be positive and finite, got {x!r}")
    return x


def _bad_name(name: str) -> bool:
    return not name or name != name.strip() or "".join(name.splitlines()) != name


@dataclass(eq=False)
class SeekLog:
    """A uniformly sampled seek log (all arrays float64, length :attr:`n`).

    Attributes
    ----------
    time_s : ndarray
        Sample times [s], strictly increasing and uniform.
    current_a : ndarray
        Total actuator current command [A].
    position_track : ndarray
        Measured absolute head position [track].
    target_track : ndarray
        Seek target in force at each sample [track].
    sample_rate_hz : float
        Nominal sample rate [Hz]; agrees with ``time_s`` to 0.1 %.
    track_pitch_nm : float or None
        Track pitch [nm], if known.
    metadata : dict[str, str]
        Other header keys, values as strings.
    extra : dict[str, ndarray]
        Extra columns (may contain NaN).
    source : str or None
        File the log was read from.

    Build validated logs with :meth:`from_arrays`; the plain constructor does not check.
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

    def slice(self, i0: int | None = None, i1: int | None = None) -> SeekLog:
        """Samples ``[i0, i1)`` (Python slice semantics) as a new, unvalidated log.

        Times are kept absolute; metadata is copied; extra columns are sliced too.
        """
        s = slice(i0, i1)
        return SeekLog(self.time_s[s].copy(), self.current_a[s].copy(), self.position_track[s].copy(),
                       self.target_track[s].copy(), self.sample_rate_hz, self.track_pitch_nm,
                       dict(self.metadata), {k: v[s].copy() for k, v in self.extra.items()}, self.source)

    @classmethod
    def from_arrays(cls, time_s, current_a, position_track, target_track, sample_rate_hz, *,
                    track_pitch_nm=None, metadata: Mapping[str, Any] | None = None,
                    extra: Mapping[str, Any] | None = None, source: str | None = None) -> SeekLog:
        """Build a :class:`SeekLog` from arrays, copying and validating everything.

        Parameters
        ----------
        time_s : array_like or None
            Sample times [s]; ``None`` means ``arange(n) / sample_rate_hz``.
        current_a, position_track, target_track : array_like
            Current command [A], head position [track], seek target [track].
        sample_rate_hz : float
            Sample rate [Hz].
        track_pitch_nm : float, optional
            Track pitch [nm].
        metadata : mapping, optional
            Extra header keys; values are stored as ``str(value).strip()``. Keys must be
            non-empty, without ``:`` or line breaks, and not a reserved key (``sample_rate_hz``,
            ``track_pitch_nm``, ``seekopt-log``).
        extra : mapping of str to array_like, optional
            Extra columns of length ``n``.
        source : str, optional
            File name used in error messages and kept in :attr:`source`.

        Raises
        ------
        LogError
            Non-numeric or mismatched columns, fewer than :data:`MIN_SAMPLES` samples, NaN/inf
            in a required column, non-increasing or non-uniform time (jitter > 1 % of dt), a
            rate disagreeing with the time column by > 0.1 %, or no seek (target constant).
        """
        name = source if source is not None else "<arrays>"
        cols = {k: _vector(name, k, v) for k, v in
                (("current_a", current_a), ("position_track", position_track), ("target_track", target_track))}
        rate = _number(name, "sample_rate_hz", sample_rate_hz)
        pitch = None if track_pitch_nm is None else _number(name, "track_pitch_nm", track_pitch_nm)
        n = len(cols["current_a"])
        cols = {"time_s": np.arange(n) / rate if time_s is None else _vector(name, "time_s", time_s), **cols}
        meta: dict[str, str] = {}
        for key, value in (metadata or {}).items():
            value = str(value).strip()
            if not isinstance(key, str) or _bad_name(key) or ":" in key or key in _RESERVED \
                    or "".join(value.splitlines()) != value:
                raise LogError(name, f"invalid metadata entry {str(key)[:40]!r}")
            meta[key] = value
        extras: dict[str, np.ndarray] = {}
        for key, value in (extra or {}).items():
            if not isinstance(key, str) or _bad_name(key) or key in COLUMNS + _RESERVED + ("metadata",):
                raise LogError(name, f"invalid extra column name {str(key)[:40]!r}")
            extras[key] = _vector(name, key, value)
        n = len(cols["time_s"])
        for key, arr in (*cols.items(), *extras.items()):
            if len(arr) != n:
                raise LogError(name, f"column {key} has {len(arr)} values, expected {n}")
        if n < MIN_SAMPLES:
            raise LogError(name, f"too short to identify anything: {n} samples (need at least {MIN_SAMPLES})")
        bad = [(int(np.argmin(np.isfinite(a))), k) for k, a in cols.items() if not np.isfinite(a).all()]
        if bad:
            row, key = min(bad, key=lambda b: b[0])
            v = cols[key][row]
            raise LogError(name, f"row {row + 1}: {key} is {'NaN' if np.isnan(v) else ('+inf' if v > 0 else '-inf')}")
        t = cols["time_s"]
        d = np.diff(t)
        if (d <= 0).any():
            i = int(np.argmax(d <= 0))
            raise LogError(name, f"row {i + 2}: time_s {'repeated' if d[i] == 0 else 'decreasing'} "
                                 f"({t[i + 1]:.9g} s after {t[i]:.9g} s)")
        dt = (t[-1] - t[0]) / (n - 1)
        dev = np.abs(d - dt) / dt
        if dev.max() > TIME_JITTER_TOL:
            i = int(np.argmax(dev))
            raise LogError(name, f"row {i + 2}: non-uniform time_s: step {d[i]:.6g} s deviates {100 * dev[i]:.3g} % "
                                 f"from mean dt {dt:.6g} s (limit {100 * TIME_JITTER_TOL:g} %)")
        if abs(rate * dt - 1.0) > RATE_TOL:
            raise LogError(name, f"sample_rate_hz {rate:.9g} disagrees with time_s (1/dt = {1 / dt:.9g} Hz) by "
                                 f"{100 * abs(rate * dt - 1):.3g} % (limit {100 * RATE_TOL:g} %)")
        if np.all(cols["target_track"] == cols["target_track"][0]):
            raise LogError(name, "no seek in log: target_track never changes")
        return cls(**cols, sample_rate_hz=rate, track_pitch_nm=pitch, metadata=meta, extra=extras, source=source)


# ----------------------------------------------------------------------------------------- reading
def _read_csv(name: str, raw: bytes) -> tuple[dict[str, Any], dict[str, Any]]:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise LogError(name, f"not UTF-8 text (bad byte at offset {exc.start})") from None
    lines = text.splitlines()
    meta: dict[str, Any] = {}
    i = 0
    while i < len(lines):
        s = lines[i].strip()
        if s.startswith("#"):
            key, sep, value = s[1:].partition(":")
            key = key.strip()
            if sep and key:
                if key in meta:
                    raise LogError(name, f"line {i + 1}: duplicate metadata key {key!r}")
                meta[key] = value.strip()
        elif s:
            break
        i += 1
    if i == len(lines):
        raise LogError(name, "no header row (only comments or blank lines)")
    body = (ln for ln in lines[i:] if ln.strip() and not ln.lstrip().startswith("#"))
    try:
        rows = list(csv.reader(body, strict=True))
    except csv.Error as exc:
        raise LogError(name, f"CSV syntax error: {_why(exc)}") from None
    header = [h.strip() for h in rows[0]]
    for j, h in enumerate(header):
        if not h:
            raise LogError(name, f"header: column {j + 1} has no name")
        if h in header[:j]:
            raise LogError(name, f"header: duplicate column {h!r}")
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


def _meta_entry(name: str, m: Any) -> dict[str, Any]:
    if isinstance(m, dict):  # MATLAB struct
        return dict(m)
    if isinstance(m, np.ndarray) and m.dtype.kind == "U" and m.size == 1:
        m = str(m.item())
    if not isinstance(m, str):
        raise LogError(name, "metadata entry is not a JSON string")
    try:
        d = json.loads(m)
    except (ValueError, RecursionError) as exc:
        raise LogError(name, f"metadata is not valid JSON ({_why(exc)})") from None
    if not isinstance(d, dict):
        raise LogError(name, "metadata JSON is not an object")
    return d


def _split_entries(name: str, entries: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    meta = _meta_entry(name, entries.pop("metadata")) if "metadata" in entries else {}
    for key in ("sample_rate_hz", "track_pitch_nm"):  # tolerate top-level scalars from other tools
        if key in entries and key not in meta and np.size(entries[key]) == 1:
            meta[key] = entries.pop(key)
    return entries, meta


def _read_npz(name: str, raw: bytes):
    try:
        z = np.load(io.BytesIO(raw), allow_pickle=False)
        if not hasattr(z, "files"):
            raise ValueError("not an .npz archive")
        entries = {k: z[k] for k in z.files}
    except Exception as exc:  # numpy/zipfile raise many types on garbage
        raise LogError(name, f"unreadable .npz file ({_why(exc)})") from None
    return _split_entries(name, entries)


_MI_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 15, 16, 17, 18})


def _walk_mat5(buf: bytes, endian: str, depth: int = 0) -> None:
    """Check every MAT v5 element tag (type, size) and recurse into matrices/compressed data.

    scipy's compiled reader can crash the interpreter (segfault) on corrupt tags, so a file
    must pass this walk before it reaches ``loadmat``.
    """
    if depth > 40:
        raise ValueError("elements nested too deeply")
    pos = 0
    while pos < len(buf):
        if len(buf) - pos < 8:
            raise ValueError(f"truncated element tag at byte {pos}")
        mdtype, nbytes = struct.unpack_from(endian + "II", buf, pos)
        if mdtype >> 16:  # small data element: 2-byte size, 2-byte type, 4 data bytes
            mdtype, nbytes, step = mdtype & 0xFFFF, mdtype >> 16, 8
            if nbytes > 4:
                raise ValueError(f"bad small element at byte {pos}")
        else:
            step = 8 + nbytes + (0 if mdtype == 15 else -nbytes % 8)
            if pos + 8 + nbytes > len(buf):
                raise ValueError(f"element at byte {pos} runs past the end")
        if mdtype not in _MI_TYPES:
            raise ValueError(f"unknown element type {mdtype} at byte {pos}")
        if mdtype in (14, 15):
            body = buf[pos + 8:pos + 8 + nbytes]
            _walk_mat5(body if mdtype == 14 else zlib.decompress(body), endian, depth + 1)
        pos += step


def _read_mat(name: str, raw: bytes):
    from scipy.io import loadmat
    from scipy.io.matlab import matfile_version
    try:
        major = matfile_version(io.BytesIO(raw))[0]
        if major != 1:
            raise ValueError(f"MAT {('v4', 'v5', 'v7.3 (HDF5)')[major]} files are not supported; use v5/v7")
        if raw[126:128] not in (b"IM", b"MI"):
            raise ValueError("bad endian indicator")
        _walk_mat5(raw[128:], "<" if raw[126:128] == b"IM" else ">")
        d = loadmat(io.BytesIO(raw), simplify_cells=True)
    except Exception as exc:  # scipy raises many types on garbage
        raise LogError(name, f"unreadable .mat file ({_why(exc)})") from None
    return _split_entries(name, {k: v for k, v in d.items() if not k.startswith("__")})


_READERS = {".csv": _read_csv, ".npz": _read_npz, ".mat": _read_mat}


def _ext(name: str, table: Mapping[str, Any]):
    ext = os.path.splitext(name)[1].lower()
    if ext not in table:
        raise LogError(name, f"unknown extension {ext!r} (expected .csv, .npz or .mat)")
    return table[ext]


def read_log(path: str | os.PathLike) -> SeekLog:
    """Read and validate a seek log; the format is chosen by extension (.csv, .npz, .mat).

    Parameters
    ----------
    path : str or path-like
        File to read.

    Returns
    -------
    SeekLog
        Validated log with ``source = str(path)``.

    Raises
    ------
    LogError
        For every bad file (one-line message naming the file); no other exception escapes
        for bad file contents.
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
    rate = _number(name, "sample_rate_hz", meta.pop("sample_rate_hz"))
    pitch = meta.pop("track_pitch_nm", None)
    pitch = None if pitch is None else _number(name, "track_pitch_nm", pitch)
    missing = [c for c in COLUMNS if c not in cols]
    if missing:
        raise LogError(name, f"missing column(s): {', '.join(missing)}")
    extra = {k: v for k, v in cols.items() if k not in COLUMNS}
    return SeekLog.from_arrays(*(cols[c] for c in COLUMNS), rate, track_pitch_nm=pitch, metadata=meta,
                               extra=extra, source=name)


# ----------------------------------------------------------------------------------------- writing
def _header(log: SeekLog) -> dict[str, Any]:
    head: dict[str, Any] = {"seekopt-log": FORMAT_VERSION, "sample_rate_hz": log.sample_rate_hz}
    if log.track_pitch_nm is not None:
        head["track_pitch_nm"] = log.track_pitch_nm
    return {**head, **log.metadata}


def _columns(log: SeekLog) -> dict[str, np.ndarray]:
    return {**{c: getattr(log, c) for c in COLUMNS}, **log.extra}


def _csv_bytes(name: str, log: SeekLog) -> bytes:
    out = io.StringIO()
    for key, value in _header(log).items():
        out.write(f"# {key}: {repr(value) if isinstance(value, float) else value}\n")
    cols = _columns(log)
    csv.writer(out, lineterminator="\n").writerow(cols)
    out.write("\n".join(map(",".join, zip(*(map(repr, a.tolist()) for a in cols.values())))))
    out.write("\n")
    return out.getvalue().encode("utf-8")


def _npz_bytes(name: str, log: SeekLog) -> bytes:
    buf = io.BytesIO()
    arrays = {"metadata": np.array(json.dumps(_header(log))), **_columns(log)}
    with zipfile.ZipFile(buf, "w") as zf:  # like np.savez, but any column name is allowed
        for key, arr in arrays.items():
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


def _file_mode(path: str) -> int:
    try:
        return os.stat(path).st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def write_log(log: SeekLog, path: str | os.PathLike) -> None:
    """Validate ``log`` and write it atomically; the format is chosen by extension.

    The data go to a temporary file in the destination folder which then replaces ``path``
    (``os.replace``), so an existing file is never left half-written.

    Parameters
    ----------
    log : SeekLog
        Log to write (re-validated as by :meth:`SeekLog.from_arrays`).
    path : str or path-like
        Destination ending in .csv, .npz or .mat.

    Raises
    ------
    LogError
        Unknown extension, invalid log, or (.mat) an extra column name MATLAB cannot hold.
    OSError
        If the file system refuses the write.
    """
    name = os.fsdecode(os.fspath(path))
    writer = _ext(name, _WRITERS)
    checked = SeekLog.from_arrays(log.time_s, log.current_a, log.position_track, log.target_track,
                                  log.sample_rate_hz, track_pitch_nm=log.track_pitch_nm,
                                  metadata=log.metadata, extra=log.extra, source=name)
    data = writer(name, checked)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(name)),
                               prefix=f".{os.path.basename(name)}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _file_mode(name))
        os.replace(tmp, name)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


# ------------------------------------------------------------------------------------ segmentation
@dataclass(frozen=True)
class Seek:
    """One seek within a :class:`SeekLog` (all indices are sample indices into the log).

    Attributes
    ----------
    start : int
        First sample with the new target (``target_track[start] != target_track[start - 1]``).
    settle : int
        The paper's N: first index of the tail of the window in which ``|PES| <= settle_band``
        holds at every sample up to ``end``. If the seek never settles, ``settle == end``.
    end : int
        Exclusive end: the next seek's ``start`` or the log length.
    from_track, to_track : float
        Target before and after the change [track].
    length_track : float
        Signed seek length ``to_track - from_track`` [track].
    settled : bool
        True if the settled tail ``[settle, end)`` has at least ``min_settle_samples`` samples.
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
        """Samples from the target change to settling, ``settle - start`` (the paper's N relative to the seek)."""
        return self.settle - self.start


def segment_seeks(log: SeekLog, settle_band: float = 0.1, min_settle_samples: int = 10) -> list[Seek]:
    """Split a log into seeks, one per change of ``target_track``.

    Samples before the first target change belong to no seek.

    Parameters
    ----------
    log : SeekLog
        The log.
    settle_band : float, default 0.1
        Settle band half-width on |PES| [track] (inclusive: ``|PES| <= settle_band`` is in band).
    min_settle_samples : int, default 10
        A seek counts as settled only if it stays in band for at least this many samples before
        its window ends; otherwise (e.g. the log ends mid-overshoot) ``settled=False`` and
        ``settle = end``.

    Returns
    -------
    list of Seek
        In time order.
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
    """Index ranges ``(settle, end)`` (half-open) of the settled seeks.

    Parameters
    ----------
    log : SeekLog
        The log the seeks index into.
    seeks : list of Seek, optional
        Defaults to ``segment_seeks(log)``.

    Returns
    -------
    list of (int, int)
        Use as ``log.slice(*window)`` or ``arr[settle:end]``.
    """
    seeks = segment_seeks(log) if seeks is None else seeks
    for s in seeks:
        if not 0 <= s.start <= s.settle <= s.end <= log.n:
            raise ValueError(f"seek {s} does not fit a log of {log.n} samples")
    return [(s.settle, s.end) for s in seeks if s.settled]
