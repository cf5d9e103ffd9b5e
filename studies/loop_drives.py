"""Drives for checking closing the loop beyond the default synthetic drive.

Two things the default synthetic drive (``seekopt.evaluate.synth``) shares with the loop and
that a real drive does not:

* **Effects evaluated once per plant step.**  The synthetic drive steps its plant at the
  controller's sub-step with every effect held over the step -- the same rule as the loop's
  model.  A real head moves continuously: :func:`fine_controller` adds a pass-through section
  ``oversample`` times faster, so the drive's plant is stepped (and its state-dependent
  effects evaluated) ``oversample`` times per current sub-step while the current keeps the
  controller's hold; :func:`synthesize_drive` writes the log with the controller's own
  sub-step columns only, as the drive would.
* **One sample rate, one resonance set.**  :func:`drive_50k` is a second configuration: a
  single-rate 50.4 kHz servo (7200 rpm x 420 sectors), other modes, another gain, delay,
  PID and notches, flutter and run-out at the 120 Hz spindle, with ``rpm``/``sectors`` in the
  log's metadata.

Used by ``tests/test_closing.py`` and the reproductions in ``docs/results_loop.md``.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import signal

from identification.model.plant import ModalPlant, Mode
from seekopt.drive.controller import Controller
from seekopt.drive.simulator import Disturbances
from seekopt.evaluate.synth import SynthConfig, synthesize

__all__ = ["fine_controller", "synthesize_drive", "drive_50k"]

FS_50K = 50400.0     #: 7200 rpm x 420 sectors


def fine_controller(controller: Controller, oversample: int) -> Controller:
    """``controller`` followed by a unit pass-through at ``oversample`` times its fastest rate:
    the simulator then steps the plant ``oversample`` times per current sub-step, the current
    held (the controller's own zero-order hold)."""
    d = controller.to_dict()
    L = controller.fast_multiple
    d["sections"].append({"kind": "ss", "A": [[0.0]], "B": [0.0], "C": [0.0], "D": 1.0,
                          "rate_multiple": L * int(oversample), "label": "plant oversampling (pass-through)"})
    d["name"] = f"{controller.name} (plant stepped x{oversample})"
    return Controller.from_json(d)


def synthesize_drive(cfg: SynthConfig, plant: ModalPlant | None = None, controller: Controller | None = None,
                     disturbances: Disturbances | None = None, oversample: int = 8, metadata: dict | None = None):
    """:func:`seekopt.evaluate.synth.synthesize` with the plant stepped ``oversample`` times per
    current sub-step; the log keeps the controller's ``L`` sub-step columns (``current_sub1_a`` ..
    ``current_subL_a``) and ``metadata`` is added to its metadata.  Returns ``(log, truth)``."""
    controller = controller or Controller.nss()
    L = controller.fast_multiple
    fine = fine_controller(controller, oversample) if oversample > 1 else controller
    log, truth = synthesize(cfg, plant=plant, controller=fine, disturbances=disturbances)
    subs = {k: v for k, v in log.extra.items() if k.startswith("current_sub")}
    for k in subs:
        del log.extra[k]
    if L > 1 and subs:
        for j in range(L):
            log.extra[f"current_sub{j + 1}_a"] = subs[f"current_sub{j * oversample + 1}_a"]
    log.metadata.update({k: str(v) for k, v in (metadata or {}).items()})
    return log, truth


def drive_50k(seed: int = 0, rro: bool = True):
    """``(plant, controller, disturbances, metadata)`` of a second drive: single-rate 50.4 kHz,
    modes at 650 Hz / 2.3 / 5.6 / 8.2 / 15.5 kHz, k0 0.8x the benchmark's, 6 us delay, a lead-lag
    PID (1 kHz crossover) with notches at the three large modes, flutter at 900 Hz-4 kHz and
    run-out at the 120 Hz spindle (harmonics 1-3)."""
    k0 = 0.8 * 3.937007874015748e9
    modes = [Mode(650.0, 0.05, 0.002), Mode(2300.0, 0.03, 0.015), Mode(5600.0, 0.02, -0.6),
             Mode(8200.0, 0.015, 0.4), Mode(15500.0, 0.01, -0.8)]
    plant = ModalPlant(k0=k0, modes=modes, bias_a=-0.003, delay_s=6e-6, sample_rate_hz=FS_50K, track_pitch_nm=254.0,
                       meta={"source": "loop_drives.drive_50k"})
    wc = 2 * math.pi * 1000.0
    kp = wc ** 2 / k0 / 3.0                        # |C(j wc)| = wc^2 / k0 with the lead's x3 gain
    wz, wp, wi = wc / 3, 3 * wc, wc / 10
    num = kp * np.polymul([1 / wz, 1], [1, wi])   # kp (1 + s/wz)/(1 + s/wp) (s + wi)/s
    den = np.polymul([1 / wp, 1], [1, 0])
    bz, az, _ = signal.cont2discrete((num, den), 1 / FS_50K, method="bilinear")
    secs = [{"kind": "tf", "num": list(np.ravel(bz)), "den": list(az), "rate_multiple": 1, "label": "lead-lag PID"}]
    for f0, q in ((5600.0, 2.0), (8200.0, 2.0), (15500.0, 2.0)):
        b, a = signal.iirnotch(f0, q, FS_50K)
        secs.append({"kind": "tf", "num": list(b), "den": list(a), "rate_multiple": 1, "label": f"notch {f0:g} Hz"})
    ctrl = Controller.from_json({"schema": 1, "name": "50.4 kHz lead-lag PID + notches", "sample_rate_hz": FS_50K,
                                 "sections": secs})
    rng = np.random.default_rng(seed + 31)
    rro_h = [(h, a, float(rng.uniform(0, 2 * math.pi))) for h, a in ((1, 0.12), (2, 0.04), (3, 0.01))] if rro else []
    dist = Disturbances(sensor_noise_track=0.012, force_noise_a=1.5e-4,
                        flutter=[{"freq_hz": f, "zeta": z, "peak_gain_track": a}
                                 for f, z, a in ((900.0, 0.01, 0.12), (1500.0, 0.008, 0.1), (4000.0, 0.003, 0.08))],
                        rro_harmonics=rro_h, spindle_hz=120.0, seed=seed)
    return plant, ctrl, dist, {"rpm": 7200, "sectors": 420}
