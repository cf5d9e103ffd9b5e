"""MATLAB v7.3 ``.mat`` seek logs (HDF5 files with a 512-byte MATLAB header), read with h5py.

MATLAB writes ``save(file, ..., '-v7.3')`` (and by default for variables over 2 GB) as HDF5, which
``scipy.io.loadmat`` cannot read.  The same variables as in a v5/v7 log are expected (one column
vector per log column, ``metadata`` as a JSON char string or a struct, see
:mod:`identification.logs.seeklog`); numeric, logical, char and struct variables are accepted,
anything else (cell, complex, sparse, objects) is a one-line :class:`LogError`.

h5py is an optional dependency (``pip install seekopt[hdf5]``); without it a v7.3 file is
refused with a one-line message saying how to save the log as v7 instead.

Layout conventions of MATLAB's v7.3 files: each variable is an HDF5 dataset (or, for a struct, a
group of datasets) with the attribute ``MATLAB_class``; arrays are stored transposed (an ``n x 1``
column is a ``(1, n)`` dataset); char arrays are ``uint16`` code units; empty arrays carry
``MATLAB_empty = 1`` and store their dimensions as data.
"""
from __future__ import annotations

import io
from typing import Any

import numpy as np

from identification.logs.schema import LogError, _split_entries, _why

__all__ = ["is_mat73", "read_mat73", "HDF5_SIGNATURE"]

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_NUMERIC = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
            "logical"}
_HOW_TO_V7 = "or save the log as v7 in MATLAB: save('log.mat', ..., '-v7')"


def is_mat73(raw: bytes) -> bool:
    """Is ``raw`` an HDF5 file (MATLAB v7.3 puts the HDF5 superblock after its 512-byte header)?"""
    return any(raw[o:o + 8] == HDF5_SIGNATURE for o in (0, 512, 1024, 2048, 4096))


def _attr(obj, key: str, default: Any = None) -> Any:
    v = obj.attrs.get(key, default)
    return v.decode("ascii", "replace") if isinstance(v, bytes) else v


def _value(h5py, name: str, path: str, obj, depth: int = 0):
    cls = _attr(obj, "MATLAB_class", "double")
    cls = str(cls.item() if isinstance(cls, np.ndarray) else cls)
    if isinstance(obj, h5py.Group):
        if cls != "struct" or depth > 20:
            raise LogError(name, f"variable {path}: unsupported MATLAB class {cls!r} "
                                 "(only numeric, char and struct)")
        return {k: _value(h5py, name, f"{path}.{k}", obj[k], depth + 1) for k in obj}
    if cls not in _NUMERIC and cls != "char":
        raise LogError(name, f"variable {path}: unsupported MATLAB class {cls!r} (only numeric, char and struct)")
    if _attr(obj, "MATLAB_empty", 0):
        return "" if cls == "char" else np.zeros(0)
    if obj.dtype.kind not in "biuf":
        raise LogError(name, f"variable {path}: {'complex' if obj.dtype.names else 'non-numeric'} data "
                             "is not supported")
    data = np.asarray(obj[()]).T                  # MATLAB stores arrays transposed
    if cls == "char":
        return "".join(chr(int(c)) for c in data.ravel())
    if data.ndim == 2 and 1 in data.shape:
        data = data.ravel()
    if data.size == 1:
        return data.reshape(()).item()
    return data.astype(np.float64)


def read_mat73(name: str, raw: bytes) -> tuple[dict[str, Any], dict[str, Any]]:
    """Columns and metadata of a v7.3 ``.mat`` log (as the other readers of :mod:`.formats` return them).

    Raises
    ------
    LogError
        h5py is not installed (the message says how to save as v7 instead), the file is not
        readable HDF5, or it holds a variable of an unsupported class.
    """
    try:
        import h5py
    except ImportError:
        raise LogError(name, "MATLAB v7.3 (HDF5) .mat file: reading it needs h5py "
                             f"(pip install 'seekopt[hdf5]'), {_HOW_TO_V7}") from None
    try:
        with h5py.File(io.BytesIO(raw), "r") as f:
            entries = {k: _value(h5py, name, k, f[k]) for k in f if not k.startswith("#")}
    except LogError:
        raise
    except Exception as exc:  # h5py raises many types on damaged files
        raise LogError(name, f"unreadable MATLAB v7.3 (HDF5) .mat file ({_why(exc)}); {_HOW_TO_V7}") from None
    return _split_entries(name, entries)
