"""Seek-log files: read and write :class:`~identification.logs.seeklog.SeekLog` as .csv, .npz or .mat.

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
Multirate sub-step currents are extra columns ``current_sub1_a`` .. ``current_subL_a`` [A]
(:mod:`identification.logs.seeklog`).
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
from typing import Any, Mapping

import numpy as np

from identification.fileio import atomic_write_bytes
from identification.logs.schema import COLUMNS, MIN_SAMPLES, LogError, _positive, _split_entries, _why
from identification.logs.seeklog import SeekLog

# COLUMNS and MIN_SAMPLES (defined with SeekLog) are part of the file format too
__all__ = ["COLUMNS", "FORMAT_VERSION", "MIN_SAMPLES", "read_log", "write_log"]

FORMAT_VERSION = "1"
_MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}\Z")


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
