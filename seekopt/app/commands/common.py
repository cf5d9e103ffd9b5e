"""What every ``seekopt`` command shares: the one-line input error (exit status 2), the stage log on
stderr and the checks of arguments and output paths run before any computation.

A command raises :class:`UsageError` (or any type of :func:`input_errors`) for bad input;
:func:`seekopt.app.cli.main` prints it as ``seekopt COMMAND: error: <one line>`` and exits with status 2.
Outputs are checked writable here first and then written atomically by the writers of the API
(:mod:`identification.fileio`).
"""
from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
from pathlib import Path

__all__ = ["UsageError", "input_errors", "message", "warn", "progress", "check_positive", "parse_duration",
           "check_seek_args",
           "check_output_file", "check_output_dir", "LOG_SUFFIXES", "DEFAULT_CONTROLLER", "PROGRESS_AFTER_S"]

DEFAULT_CONTROLLER = ("the IEEJ NSS benchmark's PID + 4 notches at 26400 Hz (notches at twice the PES rate; "
                      "seekopt/data/nss_controller.json)")
LOG_SUFFIXES = (".csv", ".npz", ".mat")
_HEARTBEAT_S = 30.0
#: a stage is logged once it has run this long [s]
PROGRESS_AFTER_S = 2.0


class UsageError(ValueError):
    """Bad command-line input (reported as one line, exit status 2)."""


def input_errors() -> tuple:
    """Exception types that are the user's input, not a bug: one line, exit status 2."""
    from identification.logs.seeklog import LogError
    from identification.model.plant import PlantError
    from seekopt.app.demo import DemoError
    from seekopt.design.problem import ProblemError
    from seekopt.design.profiles import ProfileError
    from seekopt.drive.controller import ControllerError
    from seekopt.drive.loopcheck import LoopError
    from seekopt.evaluate.sweep import SweepError
    from seekopt.evaluate.synth import SynthError
    from seekopt.export.tables import ExportError
    return (UsageError, LogError, PlantError, ControllerError, ProfileError, LoopError, SynthError, ProblemError,
            SweepError, ExportError, DemoError,
            FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError)


def message(exc: BaseException) -> str:
    """The one line that reports ``exc``: an OS error as ``<file>: <reason>``, else its first line."""
    if isinstance(exc, OSError) and exc.filename:
        return f"{exc.filename}: {exc.strerror or type(exc).__name__}"
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


# ------------------------------------------------------------------ stage log, warnings


def warn(args, text: str) -> None:
    """``seekopt <command>: warning: <text>`` on stderr (also with --quiet)."""
    print(f"seekopt {getattr(args, 'command', '')}: warning: {text}", file=sys.stderr, flush=True)


@contextlib.contextmanager


def progress(args, what: str, after_s: float | None = None):
    """One stage of a command, logged on stderr with its elapsed time once it has run ``after_s``
    (2 s; quicker stages print nothing); silent with ``--quiet``.

    On a terminal one line counts the seconds while the stage runs; otherwise (a log file) a line
    after 2 s, one every 30 s while it runs, and one when it ends::

        seekopt identify: identifying the plant from 120 seeks (robust) ... (2 s)
        seekopt identify: identifying the plant from 120 seeks (robust): done in 61.2 s

    Usage: ``with progress(args, "closing the loop"): result = close_loop(...)``.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (``command``, ``quiet`` and, set by :func:`seekopt.app.cli.main`,
        ``progress_after_s``).
    what : str
        The stage, in words.
    after_s : float, optional
        Log the stage once it has run this long [s] (default ``args.progress_after_s``, else
        :data:`PROGRESS_AFTER_S`).
    """
    if getattr(args, "quiet", False):
        yield
        return
    if after_s is None:     # the dispatcher passes its setting on the parsed arguments
        after_s = getattr(args, "progress_after_s", PROGRESS_AFTER_S)
    head = f"seekopt {getattr(args, 'command', '')}: {what}"
    tty = sys.stderr.isatty()
    t0 = time.perf_counter()
    stop = threading.Event()
    lock = threading.Lock()
    shown = []

    def tick():
        wait = after_s
        while not stop.wait(wait):
            with lock:
                if stop.is_set():
                    return
                el = time.perf_counter() - t0
                if tty:
                    sys.stderr.write(f"\r{head} ... {el:.0f} s")
                elif not shown:
                    sys.stderr.write(f"{head} ... ({el:.0f} s)\n")
                else:
                    sys.stderr.write(f"{head} ... still running ({el:.0f} s)\n")
                sys.stderr.flush()
                shown.append(el)
            wait = 1.0 if tty else _HEARTBEAT_S
    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    ok = False
    try:
        yield
        ok = True
    finally:
        with lock:
            stop.set()
        thread.join()
        if shown:
            dt = time.perf_counter() - t0
            end = f"done in {dt:.1f} s" if ok else f"stopped after {dt:.1f} s"
            sys.stderr.write(f"\r{head}: {end}\033[K\n" if tty else f"{head}: {end}\n")
            sys.stderr.flush()


# ------------------------------------------------------------------ argument and path checks


def check_positive(value: float, option: str) -> float:
    """``value`` if finite and > 0, else a :class:`UsageError` naming ``option`` (e.g. ``"--imax [A]"``)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise UsageError(f"{option} must be a positive number (got {value})")
    return value


_TIME_UNITS_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


def parse_duration(text, option: str) -> float:
    """A duration >= 0 given on the command line (``0.04ms``, ``40us``, ``4e-5``: s without a unit) -> s;
    else a :class:`UsageError` naming ``option``."""
    import re
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|ms|us|µs|ns)?\s*", str(text))
    v = float(m.group(1)) * _TIME_UNITS_S[m.group(2) or "s"] if m else float("nan")
    if not math.isfinite(v):
        raise UsageError(f"{option} must be a time >= 0 such as 0.04ms, 40us or 4e-5 (s) (got {text!r})")
    return v


def check_seek_args(args) -> None:
    """The seek of ``design`` and ``bench``: ``--imax`` [A] and ``--settle`` [track] positive, ``--tracks``
    a non-zero finite number of tracks (its sign is the direction).  :class:`UsageError` naming the option."""
    for name, v in (("--imax [A]", args.imax), ("--settle [track]", args.settle)):
        check_positive(v, name)
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number of tracks (got {args.tracks})")


def check_output_file(path, option: str, suffixes: tuple | None = None) -> None:
    """Before computing: ``path`` can be written -- its folder exists and is writable, it is not a
    folder, not read-only, and has one of ``suffixes``.  :class:`UsageError` naming the user's path."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise UsageError(f"{option} {path}: unknown extension {p.suffix!r} (expected {', '.join(suffixes)})")
    folder = p.parent
    if not folder.exists():
        raise UsageError(f"{option} {path}: folder {folder} does not exist")
    if not folder.is_dir():
        raise UsageError(f"{option} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: folder {folder} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise UsageError(f"{option} {path}: exists and is read-only")


def check_output_dir(path, option: str) -> None:
    """Before computing: ``path`` is a folder or can be created as one (its nearest existing
    ancestor is a writable folder).  :class:`UsageError` naming the user's path."""
    if path is None:
        return
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise UsageError(f"{option} {path}: exists and is not a folder")
    q = p
    while not q.exists() and q != q.parent:
        q = q.parent
    if not q.is_dir():
        raise UsageError(f"{option} {path}: {q} is not a folder")
    if not os.access(q, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: {q} is not writable")


