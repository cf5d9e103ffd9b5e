"""Per-cell claims, so several sweeps into one results folder share the work instead of doubling it.

Before a sweep submits a cell it *claims* it: it creates ``claims/<key>.claim`` with
``O_CREAT | O_EXCL`` (atomic on a local file system and on NFSv3+) holding ``pid host start`` of the
claiming process (``start``: the process start time from ``/proc`` on Linux, so a reused pid is
not taken for the claimant).  A sweep that finds a cell claimed leaves it to the claimant and
waits for its result file.  It is released (deleted) when the cell is saved, or when the sweep
stops (Ctrl-C, an engine error).

A claim whose process is dead -- same host, no such pid, or a pid with another start time -- is
*stale* (the sweep was killed) and is taken over: under an exclusive ``flock`` of
``claims/.reclaim.lock`` the claim is re-read, deleted if still the same stale claim, and claimed
again with ``O_EXCL``, so two sweeps never both take over one cell.  Claims from another host
cannot be checked and are treated as live; if that host is gone, delete its ``.claim`` files.
"""
from __future__ import annotations

import contextlib
import os
import socket
import time
from pathlib import Path

__all__ = ["Claims", "process_start_time", "pid_alive", "EMPTY_CLAIM_STALE_S"]

#: an empty claim file (its writer died between creating and writing it) is stale after this [s]
EMPTY_CLAIM_STALE_S = 10.0


def process_start_time(pid: int) -> str:
    """Start time of ``pid`` in clock ticks since boot (Linux ``/proc``), ``""`` where unknown."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return ""
    return stat.rsplit(")", 1)[-1].split()[19]      # field 22 (after the comm field's ')')


def pid_alive(pid: int) -> bool:
    """Does a process ``pid`` exist (zombies count as dead)?"""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[-1].split()[0]
    except (OSError, IndexError):
        return True
    return state not in ("Z", "X")


class Claims:
    """The claims of one sweep in ``folder`` (``<results>/claims``)."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        pid = os.getpid()
        self.identity = f"{pid} {socket.gethostname()} {process_start_time(pid)}"
        self.mine: set = set()

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.claim"

    def _is_stale(self, text: str, path: Path) -> bool:
        parts = text.split()
        if len(parts) < 2:                     # being written -- or its writer died right after creating it
            try:
                return time.time() - path.stat().st_mtime > EMPTY_CLAIM_STALE_S
            except FileNotFoundError:
                return False
        try:
            pid = int(parts[0])
        except ValueError:
            return True
        if parts[1] != socket.gethostname():
            return False
        if not pid_alive(pid):
            return True
        start = parts[2] if len(parts) > 2 else ""
        return bool(start) and start != process_start_time(pid)

    @contextlib.contextmanager
    def _reclaim_lock(self):
        fd = os.open(self.folder / ".reclaim.lock", os.O_CREAT | os.O_RDWR, 0o644)
        try:
            try:
                import fcntl
                fcntl.flock(fd, fcntl.LOCK_EX)
            except ImportError:      # pragma: no cover - not POSIX: no concurrent take-over guard
                pass
            yield
        finally:
            os.close(fd)           # releases the flock

    def claim(self, key: str) -> str | None:
        """Claim ``key``; None if this sweep now holds it, else the live holder's ``"pid host start"``."""
        p = self.path(key)
        for _ in range(5):
            try:
                fd = os.open(p, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                pass
            else:
                try:
                    os.write(fd, (self.identity + "\n").encode())
                finally:
                    os.close(fd)
                self.mine.add(key)
                return None
            try:
                holder = p.read_text().strip()
            except FileNotFoundError:
                continue                        # released meanwhile: try again
            if not self._is_stale(holder, p):
                return holder or "(being claimed)"
            with self._reclaim_lock():
                try:
                    if p.read_text().strip() == holder:
                        p.unlink()
                except FileNotFoundError:
                    pass
        return "(contended)"

    def holder_alive(self, key: str) -> bool:
        """Is ``key`` still claimed by a live process?"""
        try:
            return not self._is_stale(self.path(key).read_text().strip(), self.path(key))
        except FileNotFoundError:
            return False

    def release(self, key: str) -> None:
        """Give up ``key`` (after saving it, or when stopping)."""
        if key in self.mine:
            self.mine.discard(key)
            with contextlib.suppress(FileNotFoundError):
                if self.path(key).read_text().strip() == self.identity:
                    self.path(key).unlink()

    def release_all(self) -> None:
        for key in list(self.mine):
            self.release(key)
