"""The closed-loop two-degree-of-freedom (2DOF) servo simulator (the paper's Fig. 7).

One simulator, used by the synthetic drive, the design checks, the benchmarks,
the sweeps and the tests::

    u(k) = u_ff(k) + C(z) [ r(k) - y_meas(k) ]
    y_meas(k) = y(k) + d_out(k)            (sensor noise, flutter, run-out)

``C(z)`` is a :class:`seekopt.drive.controller.Controller` (multirate sections run
``L`` times per servo sample; the plant is stepped at ``dt = Ts / L``); the plant
is an :class:`identification.model.plant.ModalPlant`, effects included, stepped by its
own :class:`identification.model.plant.DiscretePlant`.  ``u_ff`` is held over the
servo sample and added to the feedback current at every sub-step.

The servo-rate current reported is the mean of the ``L`` sub-step currents
(the servo-rate ZOH sequence with the same impulse), which is what a log at
the servo rate carries.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from identification.model.discrete import block_tf, zoh
from identification.model.plant import ModalPlant

__all__ = ["Disturbances", "SimResult", "simulate_2dof", "closed_loop_responses", "flutter_filter"]


@dataclass
class Disturbances:
    """Noise and disturbances of a drive (defaults: off).

    Parameters
    ----------
    sensor_noise_track : float
        Std of white position-measurement noise per servo sample [track].
    force_noise_a : float
        Std of white force noise (current-equivalent) per servo sample [A].
    flutter : list of dict
        Disk/arm flutter terms ``{"freq_hz", "zeta", "peak_gain_track"}``, each
        ``a 2 zeta w^2/(s^2 + 2 zeta w s + w^2)`` driven by unit white noise held over
        one servo sample, added to the measured position (NSS benchmark form).
    rro_harmonics : list of (harmonic, amplitude_track, phase_rad)
        Repeatable run-out at harmonics of the spindle frequency ``spindle_hz``.
    rro_sequence_track : array or None
        One revolution of run-out at the servo rate, repeated.
    spindle_hz : float
    seed : int
    """

    sensor_noise_track: float = 0.0
    force_noise_a: float = 0.0
    flutter: list = field(default_factory=list)
    rro_harmonics: list = field(default_factory=list)
    rro_sequence_track: np.ndarray | None = None
    spindle_hz: float = 120.0
    seed: int = 0

    def output_disturbance(self, n: int, fs: float, t0: float = 0.0, rng=None) -> np.ndarray:
        """``d_out`` [track] for ``n`` servo samples (noise, flutter, run-out)."""
        from scipy.signal import lfilter      # here: scipy.signal costs ~0.8 s to import (a design never needs it)
        rng = np.random.default_rng(self.seed) if rng is None else rng
        d = self.sensor_noise_track * rng.standard_normal(n)
        ts = 1.0 / fs
        for fl in self.flutter:
            num, den = flutter_filter(fl, ts)
            # a few hundred samples of pre-roll so the filter is in steady state
            pre = int(min(20000, 10.0 / (fl["zeta"] * 2 * math.pi * fl["freq_hz"] * ts)))
            e = rng.standard_normal(n + pre)
            d += lfilter(num, den, e)[pre:]
        t = t0 + ts * np.arange(n)
        for h, a, ph in self.rro_harmonics:
            d += a * np.sin(2 * math.pi * h * self.spindle_hz * t + ph)
        if self.rro_sequence_track is not None and len(self.rro_sequence_track):
            seq = np.asarray(self.rro_sequence_track, dtype=float)
            idx = np.round(t * fs).astype(int) % len(seq)
            d += seq[idx]
        return d

    def force_disturbance(self, n: int, rng) -> np.ndarray:
        return self.force_noise_a * rng.standard_normal(n)


def flutter_filter(term: dict, ts: float):
    """``(b, a)`` (powers of ``z^-1``) of one flutter term ``a 2 zeta w^2 / (s^2 + 2 zeta w s + w^2)``
    driven by a sample held over ``ts`` [s]: the one ZOH of :mod:`identification.model.discrete`
    (:func:`~identification.model.discrete.zoh`, :func:`~identification.model.discrete.block_tf`)."""
    w = 2 * math.pi * term["freq_hz"]
    z = term["zeta"]
    A = np.array([[0.0, 1.0], [-w * w, -2 * z * w]])
    B = np.array([[0.0], [term["peak_gain_track"] * 2 * z * w * w]])
    Phi, G = zoh(A, B, ts)
    num, den = block_tf(Phi, np.array([1.0, 0.0]), G[:, 0])
    return np.r_[0.0, num], den


@dataclass
class SimResult:
    """Servo-rate traces of one closed-loop run (length ``n``; time from ``t0``)."""

    time_s: np.ndarray
    position_track: np.ndarray      # measured (what the servo sees and a log records)
    true_position_track: np.ndarray  # head position without sensor noise / run-out
    current_a: np.ndarray           # total current, mean over sub-steps
    feedback_a: np.ndarray          # feedback part, mean over sub-steps
    ff_a: np.ndarray
    reference_track: np.ndarray
    peak_current_a: float           # max |u| over all sub-steps
    current_sub_a: np.ndarray | None = None  # (n, L) sub-step currents when recorded

    @property
    def error_track(self) -> np.ndarray:
        return self.reference_track - self.position_track


def simulate_2dof(plant: ModalPlant, controller, u_ff, r, *, position0: float | None = None,
                  current0: float | None = None, disturbances: Disturbances | None = None,
                  t0: float = 0.0, rng=None, dplant=None, record_substeps: bool = False) -> SimResult:
    """Simulate the 2DOF loop ``u = u_ff + C (r - y)`` for ``len(r)`` servo samples.

    Parameters
    ----------
    plant : ModalPlant
        The drive's plant (truth or model), effects included.
    controller : seekopt.drive.controller.Controller
        Feedback controller; its ``sample_rate_hz`` is the servo rate.
    u_ff : array_like
        Feedforward current per servo sample [A] (shorter than ``r`` is zero-padded).
    r : array_like
        Reference position per servo sample [track], absolute.
    position0 : float, optional
        Initial head position (default ``r[0]``); the plant starts at rest.
    current0 : float, optional
        Initial current in the delay line (default the holding current).
    disturbances : Disturbances, optional
    t0 : float
        Time of the first sample [s] (for periodic effects and run-out).
    dplant : DiscretePlant, optional
        A discretised plant to reuse (must match ``plant`` and the sub-step).
    record_substeps : bool
        Also return the ``(n, L)`` sub-step currents (``SimResult.current_sub_a``).
    """
    r = np.asarray(r, dtype=float)
    n = len(r)
    uff = np.zeros(n)
    u_in = np.asarray(u_ff, dtype=float)[:n]
    uff[:len(u_in)] = u_in
    fs = float(controller.sample_rate_hz)
    L = int(controller.fast_multiple)
    dt = 1.0 / (fs * L)
    dp = plant.discretize(dt) if dplant is None else dplant
    dp.reset(r[0] if position0 is None else position0, 0.0, current=current0, t0=t0)
    rt = controller.runtime()
    rt.reset()
    rng = (np.random.default_rng(disturbances.seed) if disturbances is not None else None) if rng is None else rng
    if disturbances is not None:
        d_out = disturbances.output_disturbance(n, fs, t0, rng)
        f_dist = disturbances.force_disturbance(n, rng)
    else:
        d_out = np.zeros(n)
        f_dist = np.zeros(n)
    y_meas = np.empty(n); y_true = np.empty(n); u_mean = np.empty(n); fb_mean = np.empty(n)
    peak = 0.0
    sub = np.empty((n, L)) if record_substeps else None
    step, output = dp.step, dp.output
    for k in range(n):
        yt = output()
        y_true[k] = yt
        y_meas[k] = yt + d_out[k]
        fb = rt.step(r[k] - y_meas[k])
        tot = 0.0
        for j in range(L):
            u = uff[k] + fb[j]
            step(u + f_dist[k])
            tot += u
            if sub is not None:
                sub[k, j] = u
            if abs(u) > peak:
                peak = abs(u)
        u_mean[k] = tot / L
        fb_mean[k] = u_mean[k] - uff[k]
    return SimResult(t0 + np.arange(n) / fs, y_meas, y_true, u_mean, fb_mean, uff, r, peak, sub)


def closed_loop_responses(plant: ModalPlant, controller, n: int):
    """Impulse responses of the linear closed loop, from ``u_ff`` and from ``r``.

    Returns a dict of length-``n`` arrays: ``y_uff``, ``u_uff`` (position and mean
    current per unit feedforward impulse at sample 0), ``y_r``, ``u_r`` (per unit
    reference impulse), and ``u_sub_uff``, ``u_sub_r`` of shape ``(n, L)`` (sub-step
    currents, for exact current limits).  Computed with :func:`simulate_2dof` on the
    plant's linear part (no bias, no nonlinear effects), so the design sees exactly
    the dynamics the simulator runs.  The loop is linear time-invariant at the servo
    rate, so these define the Toeplitz (convolution) maps used by the optimiser.
    """
    lin = plant.linear_part()
    out = {}
    for name in ("uff", "r"):
        imp = np.zeros(n); imp[0] = 1.0
        uff, r = (imp, np.zeros(n)) if name == "uff" else (np.zeros(n), imp)
        res = simulate_2dof(lin, controller, uff, r, position0=0.0, current0=0.0, record_substeps=True)
        out[f"y_{name}"] = res.true_position_track
        out[f"u_{name}"] = res.current_a
        out[f"u_sub_{name}"] = res.current_sub_a
    return out
