"""Presets from the IEEJ NSS HDD benchmark (``seekopt/data/nss_hdd_benchmark.json``).

* :func:`nss_plant` — the benchmark's plant (v1 or v2) in seek mode: the 90 Hz
  stand-in is replaced by the double integrator, ``k0 = (Kf/m)/Tp``.
* :func:`default_truth_plant` — v2 plus the seek-induced modes the paper is about
  (a flex-cable mode at a few hundred Hz and a coil mode at 1.7 kHz, both with
  gains below the rigid body), a small bias: the synthetic drive's default truth.
* :func:`nss_disturbances` — sensor and force noise, flutter and RRO of the benchmark.
* The benchmark's PID + notch controller is ``seekopt.drive.controller.Controller.nss()``.
"""
from __future__ import annotations

import json
import math
from functools import lru_cache
from importlib import resources

import numpy as np

from identification.model.plant import ModalPlant, Mode

from seekopt.drive.simulator import Disturbances

__all__ = ["benchmark_data", "nss_plant", "default_truth_plant", "SEEK_MODES", "nss_disturbances",
           "nss_controller_single_rate",
           "PES_RATE_HZ"]

#: The benchmark's servo (PES) rate: 7200 rpm x 220 sectors = 26.4 kHz.
PES_RATE_HZ = 26400.0

#: Seek-induced modes added to the benchmark plant (gain below the rigid body at resonance:
#: |g| / (2 zeta) < 1).  Flex-cable mode and coil mode (the paper's 1738 Hz).
SEEK_MODES = (Mode(420.0, 0.06, 0.0015), Mode(1738.0, 0.03, 0.02))


@lru_cache(maxsize=1)
def benchmark_data() -> dict:
    """The benchmark JSON shipped with seekopt."""
    text = resources.files("seekopt").joinpath("data/nss_hdd_benchmark.json").read_text()
    return json.loads(text)


def nss_plant(version: str = "v2") -> ModalPlant:
    """The benchmark plant in seek mode (double integrator instead of the 90 Hz mode)."""
    d = benchmark_data()
    c = d["common"]
    p = d[f"plant_{version}"]
    pitch_m = c["track_pitch_m"]
    k0 = p["force_constant_N_per_A"] / c["equivalent_mass_kg"] / pitch_m
    m = p["modes"]
    modes = [Mode(f, z, g) for f, z, g in zip(m["freq_hz"], m["zeta"], m["gain"])][1:]
    return ModalPlant(k0=k0, modes=modes, bias_a=0.0, delay_s=c["input_delay_s"],
                      sample_rate_hz=1.0 / c["pes_sample_period_s"], track_pitch_nm=pitch_m * 1e9,
                      meta={"source": f"IEEJ NSS HDD benchmark plant {version}, seek mode"})


def default_truth_plant(bias_a: float = 0.004) -> ModalPlant:
    """NSS v2 plant + :data:`SEEK_MODES` + a bias force: the synthetic drive's default truth."""
    p = nss_plant("v2")
    modes = sorted(list(SEEK_MODES) + p.modes, key=lambda m: m.freq_hz)
    return p.copy(modes=[Mode(m.freq_hz, m.zeta, m.gain) for m in modes], bias_a=bias_a,
                  meta={"source": "NSS v2 seek mode + seek-induced flex and coil modes"})


def nss_disturbances(seed: int = 0, rro: bool = True, scale_rro: float = 1.0) -> Disturbances:
    """Sensor noise, force noise, flutter and RRO of the benchmark (``seed`` draws RRO phases)."""
    d = benchmark_data()["disturbances"]
    rng = np.random.default_rng(seed + 7919)
    fl = d["flutter"]
    flutter = [{"freq_hz": f, "zeta": z, "peak_gain_track": a}
               for f, z, a in zip(fl["freq_hz"], fl["zeta"], fl["peak_gain_track"])]
    harmonics, seq = [], None
    spindle_hz = benchmark_data()["common"]["spindle_rpm"] / 60.0
    if rro:
        r = d["rro"]
        harmonics = [(h, scale_rro * a, float(rng.uniform(0, 2 * math.pi)))
                     for h, a in zip(r["harmonics_of_rotation"], r["amplitude_track"])]
        text = resources.files("seekopt").joinpath("data/nss_rro_sequence.txt").read_text()
        seq = scale_rro * np.array([float(line) for line in text.splitlines()
                                    if line.strip() and not line.lstrip().startswith("#")])
    return Disturbances(sensor_noise_track=d["sensor_noise_sigma_track"],
                        force_noise_a=d["force_noise_sigma_A"], flutter=flutter,
                        rro_harmonics=harmonics, rro_sequence_track=seq, spindle_hz=spindle_hz,
                        seed=seed)


def nss_controller_single_rate():
    """The NSS PID with its notches (4.1, 5, 7, 12.3 kHz) redesigned at the PES rate (no multirate
    section, :func:`scipy.signal.iirnotch`): a drive whose current changes only at the log's
    samples, so the logged current is exactly the current the plant saw.  For studies and tests
    that separate the multirate hold from the identification method."""
    from scipy import signal
    from seekopt.drive.controller import Controller
    nss = Controller.nss()
    fs = float(nss.sample_rate_hz)
    secs = nss.to_dict()["sections"][:1]
    for f0, q in ((4100, 2.0), (5000, 3.0), (7000, 2.0), (12300, 2.0)):
        b, a = signal.iirnotch(f0, q, fs)
        secs.append({"kind": "tf", "num": list(b), "den": list(a), "rate_multiple": 1})
    return Controller.from_json({"schema": 1, "name": "PID + notches, single rate", "sample_rate_hz": fs,
                                 "sections": secs})
