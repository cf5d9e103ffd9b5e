"""Ready-made independent drives for the tests.

* :func:`nss_drive` — the NSS HDD benchmark's numbers (read from ``seekopt/data/nss_hdd_benchmark.json``:
  plant v2 in seek mode, 26.4 kHz, its PID + four notches at twice the rate, its noise) plus the
  seek-induced flex (420 Hz) and coil (1738 Hz) modes and a 4 mA bias: the configuration of
  seekopt's own synthetic drive, simulated here by independent code.
* :func:`nss_single_rate_controller` — the same PID with its notches redesigned at the PES rate.
* :func:`other_nss_truth` — another truth on the NSS hardware (flex 300 Hz, coil 2.2 kHz, bias -6 mA).
* :func:`drive_50k` — a drive unlike the benchmark: 50.4 kHz servo rate, another actuator
  (k0, modes at 260 Hz ... 19.5 kHz), a PID with lead designed here and a multirate (2x) notch
  filter at 5.3 / 10.6 / 14.8 kHz, a computation delay, its own noise.
"""
from __future__ import annotations

import json
import math
from functools import lru_cache

import numpy as np
from scipy import signal

from .controller import REPO, DigitalController, Section, from_json, notch, nss_json, pid_lead
from .disturbance import Noise, nss_noise
from .drive import Drive
from .plant import ModeSpec, TruthPlant

__all__ = ["benchmark", "nss_truth", "nss_drive", "nss_single_rate_controller", "other_nss_truth",
           "truth_50k", "controller_50k", "noise_50k", "drive_50k", "NSS_SEEK_MODES"]

#: seek-induced modes of seekopt's default truth (flex cable, coil), restated as data
NSS_SEEK_MODES = (ModeSpec(420.0, 0.06, 0.0015), ModeSpec(1738.0, 0.03, 0.02))


@lru_cache(maxsize=1)
def benchmark() -> dict:
    return json.loads((REPO / "seekopt" / "data" / "nss_hdd_benchmark.json").read_text())


def _nss_base(version: str = "v2") -> TruthPlant:
    c, p = benchmark()["common"], benchmark()[f"plant_{version}"]
    k0 = p["force_constant_N_per_A"] / c["equivalent_mass_kg"] / c["track_pitch_m"]
    m = p["modes"]
    modes = [ModeSpec(f, z, g) for f, z, g in zip(m["freq_hz"], m["zeta"], m["gain"])][1:]   # 90 Hz -> 1/s^2
    return TruthPlant(k0=k0, modes=tuple(modes), delay_s=c["input_delay_s"], track_pitch_nm=c["track_pitch_m"] * 1e9)


def nss_truth(bias_a: float = 0.004, seek_modes=NSS_SEEK_MODES) -> TruthPlant:
    b = _nss_base()
    modes = sorted(tuple(seek_modes) + b.modes, key=lambda m: m.freq_hz)
    return TruthPlant(k0=b.k0, modes=tuple(modes), bias_a=bias_a, delay_s=b.delay_s, track_pitch_nm=b.track_pitch_nm)


def other_nss_truth() -> TruthPlant:
    """Flex mode at 300 Hz, coil at 2.2 kHz, other damping and gains, bias -6 mA."""
    return nss_truth(-0.006, (ModeSpec(300.0, 0.04, 0.003), ModeSpec(2200.0, 0.02, 0.015)))


def nss_drive(truth: TruthPlant | None = None, controller: DigitalController | None = None, noise: bool = True,
              runout: bool = True, seed: int = 0) -> Drive:
    """The NSS-like drive; ``noise=False`` switches every disturbance off, ``runout=False`` the run-out."""
    nz = nss_noise(seed, runout=runout) if noise else Noise()
    return Drive(truth or nss_truth(), controller or from_json(nss_json()), nz, spindle_hz=120.0, name="NSS-like")


def nss_single_rate_controller() -> DigitalController:
    """The NSS PID followed by notches at 4.1, 5, 7, 12.3 kHz (Q 2, 3, 2, 2) designed at the PES rate."""
    d = nss_json()
    fs = float(d["sample_rate_hz"])
    pid = d["sections"][0]
    secs = [Section.tf(pid["num"], pid["den"], 1, "PID")]
    for f0, q in ((4100, 2.0), (5000, 3.0), (7000, 2.0), (12300, 2.0)):
        b, a = signal.iirnotch(f0, q, fs)
        secs.append(Section.tf(b, a, 1, f"notch {f0} Hz"))
    return DigitalController(secs, fs, "NSS PID + notches, single rate")


# ------------------------------------------------------------------------------------ 50.4 kHz drive
FS_50K = 50400.0


def truth_50k(bias_a: float = 0.0025) -> TruthPlant:
    """Another actuator: k0 6e9 track/(A s^2) (0.16 um pitch), seek-induced modes at 260 Hz and 2.6 kHz,
    structural modes at 5.3 (butterfly), 7.8, 10.6, 14.8 and 19.5 kHz, 6 us input delay."""
    modes = (ModeSpec(260.0, 0.07, 0.0008), ModeSpec(2600.0, 0.025, 0.012), ModeSpec(5300.0, 0.02, -0.6),
             ModeSpec(7800.0, 0.015, 0.15), ModeSpec(10600.0, 0.012, -0.4), ModeSpec(14800.0, 0.008, 0.5),
             ModeSpec(19500.0, 0.01, -0.3))
    return TruthPlant(k0=6.0e9, modes=modes, bias_a=bias_a, delay_s=6e-6, track_pitch_nm=160.0)


def controller_50k(k0: float = 6.0e9, crossover_hz: float = 1100.0) -> DigitalController:
    """PID with lead at 50.4 kHz and notches at 5.3, 10.6, 14.8 kHz run at 2x (100.8 kHz).  On
    :func:`truth_50k` with the 14 us delay: crossover 1.12 kHz, phase margin about 38 deg, |S| peak
    about 5.6 dB (measured with the drive's own frequency responses when designed)."""
    pid = pid_lead(k0, FS_50K, crossover_hz, lead_ratio=16.0, integral_frac=0.1, rolloff_factor=12.0,
                   label="PID + lead 50.4 kHz")
    secs = [pid, notch(5300.0, FS_50K, 24.0, 0.15), notch(10600.0, FS_50K, 18.0, 0.15),
            notch(14800.0, FS_50K, 20.0, 0.10)]
    return DigitalController(secs, FS_50K, "PID + lead, 2x notch filter (50.4 kHz)")


def noise_50k(seed: int = 0, runout: bool = True) -> Noise:
    """Sensor noise 0.01 track, force noise 0.1 mA, flutter at 640 ... 4200 Hz, run-out at 120 Hz harmonics."""
    rng = np.random.default_rng(seed + 3571)
    rro = [(h, a, float(rng.uniform(0, 2 * math.pi))) for h, a in ((1, 0.12), (2, 0.04), (3, 0.01))] if runout else []
    flutter = [(640.0, 0.01, 0.08), (920.0, 0.008, 0.12), (1310.0, 0.01, 0.06), (4200.0, 0.003, 0.05)]
    return Noise(0.010, 1.0e-4, flutter, rro, None, 120.0)


def drive_50k(truth: TruthPlant | None = None, noise: bool = True, runout: bool = True, seed: int = 0,
              computation_delay_s: float = 8e-6) -> Drive:
    t = truth or truth_50k()
    return Drive(t, controller_50k(t.k0), noise_50k(seed, runout) if noise else Noise(),
                 computation_delay_s=computation_delay_s, spindle_hz=120.0, name="50.4 kHz")
