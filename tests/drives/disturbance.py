"""Noise and disturbances of the independent test drive (own generators, seeded).

* sensor noise: white, ``sensor_noise_track`` std per servo sample, added to the measured position;
* force noise: white, ``force_noise_a`` std per servo sample, held over the sample, at the plant input;
* flutter: terms ``peak * 2 zeta w^2 / (s^2 + 2 zeta w s + w^2)`` driven by unit white noise held over
  one servo sample, added to the measured position (the NSS benchmark's form), integrated exactly
  per sample by the drive's own RK4 flow (:func:`tests.drives.plant.rk4_flow`);
* run-out: ``(harmonic, amplitude_track, phase_rad)`` sines at harmonics of ``spindle_hz`` and an
  optional one-revolution sequence repeated (``runout_sequence_track``, one value per servo sample).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from .plant import rk4_flow

__all__ = ["Noise", "nss_noise"]


@dataclass
class Noise:
    sensor_noise_track: float = 0.0
    force_noise_a: float = 0.0
    flutter: list = field(default_factory=list)          # [(freq_hz, zeta, peak_track)]
    runout: list = field(default_factory=list)           # [(harmonic, amplitude_track, phase_rad)]
    runout_sequence_track: np.ndarray | None = None
    spindle_hz: float = 120.0

    def measurement(self, n: int, fs: float, rng: np.random.Generator) -> np.ndarray:
        """Sensor noise + flutter + run-out [track] for ``n`` samples from ``t = 0``."""
        d = self.sensor_noise_track * rng.standard_normal(n) if self.sensor_noise_track else np.zeros(n)
        Ts = 1.0 / fs
        for f, z, peak in self.flutter:
            w = 2 * math.pi * f
            M = np.array([[0.0, 1.0, 0.0], [-w * w, -2 * z * w, 1.0], [0.0, 0.0, 0.0]])
            E = rk4_flow(M, Ts)
            Phi, G = E[:2, :2], E[:2, 2:3]
            C = np.array([[peak * 2 * z * w * w, 0.0]])
            b, a = signal.ss2tf(Phi, G, C, np.zeros((1, 1)))
            pre = int(min(20000, 10.0 / (z * w * Ts)))            # reach the stationary state
            d += signal.lfilter(b.ravel(), a, rng.standard_normal(n + pre))[pre:]
        t = np.arange(n) * Ts
        for h, amp, ph in self.runout:
            d += amp * np.sin(2 * math.pi * h * self.spindle_hz * t + ph)
        if self.runout_sequence_track is not None and len(self.runout_sequence_track):
            seq = np.asarray(self.runout_sequence_track, dtype=float)
            d += seq[np.arange(n) % len(seq)]
        return d

    def force(self, n: int, rng: np.random.Generator) -> np.ndarray:
        return self.force_noise_a * rng.standard_normal(n) if self.force_noise_a else np.zeros(n)

    def scaled(self, factor: float) -> "Noise":
        """Every term times ``factor`` (e.g. 0 for a clean drive)."""
        return Noise(self.sensor_noise_track * factor, self.force_noise_a * factor,
                     [(f, z, a * factor) for f, z, a in self.flutter],
                     [(h, a * factor, p) for h, a, p in self.runout],
                     None if self.runout_sequence_track is None else self.runout_sequence_track * factor,
                     self.spindle_hz)


def nss_noise(seed: int = 0, runout: bool = True, runout_scale: float = 1.0) -> Noise:
    """The NSS HDD benchmark's disturbance numbers (read from the bundled data files)."""
    from .presets import benchmark
    d = benchmark()["disturbances"]
    fl = d["flutter"]
    rng = np.random.default_rng(seed + 104729)
    spindle = benchmark()["common"]["spindle_rpm"] / 60.0
    rro, seq = [], None
    if runout:
        r = d["rro"]
        rro = [(h, runout_scale * a, float(rng.uniform(0, 2 * math.pi)))
               for h, a in zip(r["harmonics_of_rotation"], r["amplitude_track"])]
        from .controller import REPO
        text = (REPO / "seekopt" / "data" / "nss_rro_sequence.txt").read_text()
        seq = runout_scale * np.array([float(line) for line in text.splitlines()
                                       if line.strip() and not line.lstrip().startswith("#")])
    return Noise(d["sensor_noise_sigma_track"], d["force_noise_sigma_A"],
                 list(zip(fl["freq_hz"], fl["zeta"], fl["peak_gain_track"])), rro, seq, spindle)

