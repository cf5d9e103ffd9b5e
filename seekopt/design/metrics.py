"""Seek-settle metrics of a profile played in the closed loop (one simulator).

A seek of ``K`` tracks starts at rest at track 0 at ``t = 0``; the drive plays
``u_ff = profile.current_a`` and ``r = profile.reference_track`` and then holds
``r = K``, ``u_ff = 0`` (:meth:`seekopt.design.profiles.Profile.padded`).  The position
error is ``PES(k) = y(k) - K`` [track] (position minus target), and

* seek time ``T_sk = seek_samples / fs`` (samples of non-zero feedforward);
* seek-settle time ``T_ss = k_s / fs`` with ``k_s`` the earliest sample after which
  ``|PES| <= band`` for every remaining sample of the horizon (:func:`settle_time`);
* ``ratio_tbb = T_ss / T_bb`` with ``T_bb = 2 sqrt(K / (k0 Imax))`` the rigid-body
  bang-bang time at the profile's current limit.

Before the seek the drive is in steady state: its integrator holds the bias force.
For a linear controller with integral action that steady state is exactly a constant
hold current ``-bias_a`` added to the feedforward (the loop then starts at equilibrium);
:func:`evaluate_profile` runs :func:`seekopt.drive.simulator.simulate_2dof` that way.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from identification.model.plant import ModalPlant

from seekopt.design.profiles import Profile, t_bang_bang
from seekopt.drive.simulator import Disturbances, SimResult, simulate_2dof

__all__ = ["SeekMetrics", "settle_time", "settle_index", "evaluate_profile", "played_metrics", "simulate_profile",
           "seek_metrics", "worst_case", "DEFAULT_TAIL_S"]

#: Default simulated time after the end of the profile [s].
DEFAULT_TAIL_S = 0.015


@dataclass
class SeekMetrics:
    """Figures of one seek (times from the seek start).

    Attributes
    ----------
    seek_time_s : float
        Feedforward length ``T_sk`` [s].
    settle_time_s : float
        Seek-settle time ``T_ss`` [s] (``inf`` if the PES never stays in the band).
    peak_pes_after_track, rms_pes_after_track : float
        Peak and RMS of ``|PES|`` after the seek (``k >= seek_samples``) [track].
    peak_current_a : float
        Peak total current ``max |u|`` over all sub-steps, feedback and hold included [A].
    ratio_tbb : float
        ``T_ss / T_bb``.
    settled : bool
        True if the PES stays in the band up to the end of the simulated horizon.
    """

    seek_time_s: float
    settle_time_s: float
    peak_pes_after_track: float
    rms_pes_after_track: float
    peak_current_a: float
    ratio_tbb: float
    settled: bool

    def to_dict(self) -> dict:
        d = asdict(self)
        d["settled"] = bool(d["settled"])
        return {k: (v if k == "settled" else float(v)) for k, v in d.items()}


def settle_index(pes, band: float = 0.1) -> int | None:
    """Earliest sample ``k`` with ``|pes[j]| <= band`` for all ``j >= k`` (None if the last
    sample is outside the band).  Non-finite samples count as outside."""
    pes = np.asarray(pes, dtype=float)
    inside = np.abs(pes) <= band          # NaN compares False: outside
    if pes.size == 0:
        return 0
    if not inside[-1]:
        return None
    bad = np.nonzero(~inside)[0]
    return int(bad[-1]) + 1 if bad.size else 0


def settle_time(pes, fs: float, band: float = 0.1) -> float:
    """Seek-settle time [s]: the earliest time ``k / fs`` after which ``|PES| <= band``
    on every remaining sample (``inf`` if the last sample is outside the band)."""
    k = settle_index(pes, band)
    return math.inf if k is None else k / float(fs)


def simulate_profile(plant: ModalPlant, controller, profile: Profile, *, horizon_s: float | None = None,
                     disturbances: Disturbances | None = None, hold: bool = True,
                     record_substeps: bool = False) -> SimResult:
    """Play ``profile`` from rest at track 0 in the closed loop (:func:`simulate_2dof`).

    ``horizon_s`` is the total simulated time [s] (default: the profile plus
    :data:`DEFAULT_TAIL_S`); ``hold`` adds the plant's hold current ``-bias_a`` to the
    feedforward (the drive's pre-seek steady state, see the module notes); ``record_substeps``
    also returns the sub-step currents (``SimResult.current_sub_a``, A).
    """
    fs = float(controller.sample_rate_hz)
    if abs(fs - profile.sample_rate_hz) > 1e-9 * fs:
        raise ValueError(f"profile sampled at {profile.sample_rate_hz} Hz, controller runs at {fs} Hz")
    n = profile.n + int(round(DEFAULT_TAIL_S * fs)) if horizon_s is None else int(round(horizon_s * fs))
    n = max(n, profile.n + 1)
    u, r = profile.padded(n)
    if hold:
        u = u - plant.bias_a
    return simulate_2dof(plant, controller, u, r, position0=0.0, disturbances=disturbances,
                         record_substeps=record_substeps)


def evaluate_profile(plant: ModalPlant, controller, profile: Profile, *, settle: float = 0.1,
                     horizon_s: float | None = None, disturbances: Disturbances | None = None,
                     k0_for_tbb: float | None = None) -> SeekMetrics:
    """Seek metrics of ``profile`` on ``plant`` under ``controller``.

    Parameters
    ----------
    plant : ModalPlant
        The plant the profile is played on (a truth plant for acceptance, the model for design
        checks); effects included.
    controller : Controller
    profile : Profile
        Reference relative to the seek start; target ``profile.tracks``.
    settle : float
        Settle band [track]: ``|PES| <= settle``.
    horizon_s : float, optional
        Total simulated time [s] (default: the profile plus 15 ms).
    disturbances : Disturbances, optional
        Noise, flutter, run-out (default none: deterministic).
    k0_for_tbb : float, optional
        Rigid-body gain for ``T_bb`` (default ``plant.k0``).
    """
    return played_metrics(plant, controller, profile, settle=settle, horizon_s=horizon_s, disturbances=disturbances,
                          k0_for_tbb=k0_for_tbb)[0]


def played_metrics(plant: ModalPlant, controller, profile: Profile, *, settle: float = 0.1,
                   horizon_s: float | None = None, disturbances: Disturbances | None = None,
                   k0_for_tbb: float | None = None, record_substeps: bool = False) -> tuple[SeekMetrics, SimResult]:
    """``(metrics, play)``: :func:`evaluate_profile`'s metrics and the :func:`simulate_profile` play they
    were measured on (``record_substeps``: with its sub-step currents), for callers that need both."""
    res = simulate_profile(plant, controller, profile, horizon_s=horizon_s, disturbances=disturbances,
                           record_substeps=record_substeps)
    return seek_metrics(res.true_position_track - profile.tracks, res.peak_current_a, profile,
                        float(controller.sample_rate_hz), settle, k0_for_tbb or plant.k0), res


def seek_metrics(pes, peak_current_a: float, profile: Profile, fs: float, settle: float, k0: float) -> SeekMetrics:
    """:class:`SeekMetrics` of a played profile from its PES [track] and peak total current [A]
    (``k0`` for ``T_bb``); :func:`evaluate_profile` measures both with the one simulator."""
    pes = np.asarray(pes, dtype=float)
    ts = settle_time(pes, fs, settle)
    after = pes[min(profile.seek_samples, len(pes) - 1):]
    finite = np.all(np.isfinite(after))
    tbb = t_bang_bang(profile.tracks, k0, profile.imax_a)
    return SeekMetrics(
        seek_time_s=profile.seek_time_s,
        settle_time_s=ts,
        peak_pes_after_track=float(np.max(np.abs(after))) if finite else math.inf,
        rms_pes_after_track=float(np.sqrt(np.mean(after ** 2))) if finite else math.inf,
        peak_current_a=float(peak_current_a) if math.isfinite(peak_current_a) else math.inf,
        ratio_tbb=ts / tbb if tbb > 0 else math.inf,
        settled=bool(math.isfinite(ts)))


def worst_case(metrics: list) -> SeekMetrics:
    """Element-wise worst of several :class:`SeekMetrics` (e.g. over a robust plant set)."""
    if not metrics:
        raise ValueError("worst_case of no metrics")
    return SeekMetrics(
        seek_time_s=max(m.seek_time_s for m in metrics),
        settle_time_s=max(m.settle_time_s for m in metrics),
        peak_pes_after_track=max(m.peak_pes_after_track for m in metrics),
        rms_pes_after_track=max(m.rms_pes_after_track for m in metrics),
        peak_current_a=max(m.peak_current_a for m in metrics),
        ratio_tbb=max(m.ratio_tbb for m in metrics),
        settled=all(m.settled for m in metrics))
