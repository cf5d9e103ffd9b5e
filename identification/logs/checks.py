"""Plausibility and consistency of a seek log's units, beyond the format checks of :mod:`.seeklog`.

A log can be well formed and still wrong by a unit: a current logged in mA identifies with a
rigid-body gain 1000 times too small and a "bias" of thousands of mA, without any error.  These
checks name the likely mistake:

* :func:`unit_warnings` -- the peak current is implausible for a disk-drive actuator
  (:data:`PLAUSIBLE_PEAK_CURRENT_A`): one line per finding, naming the unit that fits;
* :func:`k0_warning` -- an identified rigid-body gain outside :data:`PLAUSIBLE_K0` track/(A s^2);
* :func:`convert_current` -- a log whose currents are in ``mA`` (or ``uA``) converted to A
  (``seekopt identify --current-unit mA``);
* :func:`check_current_columns` -- ``current_a`` must be the mean of the multirate sub-step
  columns ``current_sub1_a .. current_subL_a`` when both are logged (a :class:`LogError` if not).
"""
from __future__ import annotations

import math

import numpy as np

from identification.logs.schema import _SUBSTEP, LogError

__all__ = ["CURRENT_UNITS", "PLAUSIBLE_PEAK_CURRENT_A", "PLAUSIBLE_K0", "CURRENT_MEAN_RTOL",
           "convert_current", "unit_warnings", "k0_warning", "check_current_columns"]

#: current units a log may use, and their factor to A
CURRENT_UNITS = {"A": 1.0, "mA": 1e-3, "uA": 1e-6}
#: peak |current| [A] a disk-drive voice-coil actuator plausibly reaches during seeks
PLAUSIBLE_PEAK_CURRENT_A = (1e-3, 10.0)
#: rigid-body gain [track/(A s^2)] of disk drives (a few 1e9 at 100k TPI, tens of 1e9 at 1M TPI)
PLAUSIBLE_K0 = (1e8, 1e12)
#: largest |current_a - mean(sub-steps)| as a fraction of the peak current (quantisation allowed)
CURRENT_MEAN_RTOL = 1e-3


def _substep_names(log) -> list[str]:
    idx = sorted(int(m.group(1)) for k in log.extra if (m := _SUBSTEP.fullmatch(k)))
    return [f"current_sub{j}_a" for j in idx]


def convert_current(log, unit: str):
    """``log`` with its currents (``current_a`` and the sub-step columns) converted from ``unit`` to A.

    Parameters
    ----------
    log : SeekLog
    unit : str
        One of :data:`CURRENT_UNITS` (``"A"`` returns ``log`` itself).
    """
    if unit not in CURRENT_UNITS:
        raise LogError(log.source or "<arrays>", f"unknown current unit {unit!r} (expected "
                                                 f"{', '.join(CURRENT_UNITS)})")
    f = CURRENT_UNITS[unit]
    if f == 1.0:
        return log
    subs = set(_substep_names(log))
    extra = {k: (v * f if k in subs else v) for k, v in log.extra.items()}
    meta = dict(log.metadata, current_unit_in_file=unit)
    return type(log).from_arrays(log.time_s, log.current_a * f, log.position_track, log.target_track,
                               log.sample_rate_hz, track_pitch_nm=log.track_pitch_nm, metadata=meta,
                               extra=extra, source=log.source)


def _fitting_unit(peak: float) -> str | None:
    lo, hi = PLAUSIBLE_PEAK_CURRENT_A
    for unit, f in CURRENT_UNITS.items():
        if f < 1.0 and lo <= peak * f <= hi:
            return unit
    return None


def unit_warnings(log) -> list[str]:
    """One-line warnings for currents implausible for a disk drive (empty when all is plausible).

    A peak |current_a| above :data:`PLAUSIBLE_PEAK_CURRENT_A` (10 A) is almost always a log in mA
    (or uA); the warning names the unit that brings the peak into the plausible range.
    """
    name = log.source or "<arrays>"
    peak = float(np.max(np.abs(log.current_a)))
    hi = PLAUSIBLE_PEAK_CURRENT_A[1]
    if peak <= hi:
        return []
    unit = _fitting_unit(peak)
    hint = (f"is the log's current in {unit}? (then use --current-unit {unit})" if unit else
            "check the current's unit")
    return [f"{name}: current_a peaks at {peak:.4g}, implausible in A for a disk-drive actuator "
            f"(below {hi:g} A): {hint}"]


def k0_warning(k0: float, source: str = "plant") -> str | None:
    """A one-line warning if the rigid-body gain ``k0`` [track/(A s^2)] is outside :data:`PLAUSIBLE_K0`,
    naming the likely unit mistake; None when plausible."""
    lo, hi = PLAUSIBLE_K0
    if not math.isfinite(k0) or lo <= k0 <= hi:
        return None
    if k0 < lo:
        factor = 1e3 if lo <= k0 * 1e3 <= hi else 1e6 if lo <= k0 * 1e6 <= hi else None
        unit = {1e3: "mA", 1e6: "uA"}.get(factor)
        hint = (f"the current looks {factor:g} times too large: is it logged in {unit}? "
                f"(then use --current-unit {unit})" if unit else
                "is the current in A and the position in tracks?")
    else:
        hint = "the position looks too large or the current too small: is position_track in tracks " \
               "(not nm or encoder counts) and current_a in A?"
    return (f"{source}: k0 = {k0:.4g} track/(A s^2) is outside the range of disk drives "
            f"({lo:.0e} to {hi:.0e}): {hint}")


def check_current_columns(log) -> None:
    """Raise :class:`LogError` if ``current_a`` is not the mean of the sub-step current columns.

    Tolerance: :data:`CURRENT_MEAN_RTOL` of the peak current (a logger's rounding passes, a
    different signal does not).  A log without sub-step columns passes.
    """
    names = _substep_names(log)
    if len(names) < 2:
        return
    mean = np.mean(np.column_stack([log.extra[k] for k in names]), axis=1)
    dev = np.abs(log.current_a - mean)
    if not np.all(np.isfinite(dev)):
        return                      # non-finite sub-steps are reported by SeekLog.input_current
    peak = max(float(np.max(np.abs(log.current_a))), float(np.max(np.abs(mean))))
    i = int(np.argmax(dev))
    if dev[i] > CURRENT_MEAN_RTOL * peak + 1e-12:
        raise LogError(log.source or "<arrays>",
                       f"row {i + 1}: current_a = {log.current_a[i]:.6g} disagrees with the mean "
                       f"{mean[i]:.6g} of {names[0]} .. {names[-1]} (by {dev[i]:.3g} A, "
                       f"{100 * dev[i] / peak:.2g} % of the peak current); current_a must be the mean of "
                       "the sub-step currents, or drop the sub-step columns")
