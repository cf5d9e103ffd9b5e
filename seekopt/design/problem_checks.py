"""The checks of a :class:`~seekopt.design.problem.SeekProblem`'s settings that need no plant or optimiser:
each returns the value in its canonical type or raises :class:`ProblemError` (one line naming the setting).

Also :func:`check_closed_loop` (the stability check every plant of a set passes before anything is
built).  Kept apart from :mod:`seekopt.design.problem` so the problem module holds the data and its JSON form only.
"""
from __future__ import annotations

import math

import numpy as np

from identification.model.plant import ModalPlant
from seekopt.drive.loopcheck import closed_loop_poles

__all__ = ["ProblemError", "check_closed_loop", "positive", "fraction", "nonnegative_s", "samples_within"]


class ProblemError(ValueError):
    """A seek problem that cannot be designed for (bad numbers, unstable loop); one-line message."""


def positive(name: str, v) -> float:
    """``v`` as float if a finite number > 0."""
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
        raise ProblemError(f"{name} must be a positive number (got {v!r})")
    return float(v)


def fraction(name: str, v) -> float:
    """``v`` as float if in (0, 1]."""
    if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= 1):
        raise ProblemError(f"{name} must be in (0, 1] (got {v!r})")
    return float(v)


def nonnegative_s(name: str, v) -> float:
    """A duration [s]: ``v`` as float if a finite number >= 0."""
    if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0):
        raise ProblemError(f"{name} must be a time >= 0 s (got {v!r})")
    return float(v)


def samples_within(duration_s: float, fs_hz: float) -> int:
    """Whole servo samples that fit in ``duration_s`` [s] at ``fs_hz`` [Hz] (rounded down: never longer than
    the stated time; a relative 1e-9 forgives the float error of a time stated as a multiple of the period)."""
    return int(math.floor(float(duration_s) * float(fs_hz) * (1 + 1e-9)))


def check_closed_loop(plant: ModalPlant, controller, margin: float = 1e-9) -> float:
    """Spectral radius of the closed loop of ``plant``'s linear part under ``controller`` (servo rate):
    the poles of :func:`seekopt.drive.loopcheck.closed_loop_poles` (the plant discretised as the
    simulator runs it, the controller lifted to the servo rate).  Raises :class:`ProblemError` (one
    line) when a pole is on or outside the unit circle."""
    poles = closed_loop_poles(plant, controller)
    rho = float(np.max(np.abs(poles))) if poles.size else 0.0
    if not math.isfinite(rho) or rho >= 1.0 - margin:
        p = poles[int(np.argmax(np.abs(poles)))] if poles.size else complex("nan")
        f = abs(np.angle(p)) * float(controller.sample_rate_hz) / (2 * math.pi)
        raise ProblemError(f"closed loop of the plant and controller {getattr(controller, 'name', '')!r} is "
                           f"unstable: pole |z| = {rho:.6g} at {f:.0f} Hz")
    return rho
