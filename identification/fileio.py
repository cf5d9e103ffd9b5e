"""Atomic, durable file writes: the one writer every seekopt output goes through.

A file is written to a temporary file in the same folder, flushed and fsync'ed, given the mode
the replaced file had (or the umask default), and renamed over the target with ``os.replace``;
the folder is then fsync'ed.  An existing file is therefore never left half-written, and a
crash leaves either the old or the new content.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes", "atomic_write_text"]


def _fsync_dir(folder: str) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically and durably (see the module notes).

    Raises
    ------
    OSError
        If the file system refuses; ``path`` is then untouched and no temporary file is left.
        Its ``filename`` is ``path`` (never the temporary file's name).
    """
    name = os.fsdecode(os.fspath(path))
    folder = os.path.dirname(os.path.abspath(name))
    try:
        mode = os.stat(name).st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        mode = 0o666 & ~umask
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{os.path.basename(name)}.", suffix=".tmp")
    except OSError as exc:     # name the user's file, not the temporary one
        raise type(exc)(exc.errno, exc.strerror, name) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        try:
            os.replace(tmp, name)
        except OSError as exc:
            raise type(exc)(exc.errno, exc.strerror, name) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _fsync_dir(folder)


def atomic_write_text(path: str | os.PathLike | Path, text: str) -> None:
    """:func:`atomic_write_bytes` of ``text`` encoded as UTF-8."""
    atomic_write_bytes(path, text.encode("utf-8"))
