"""Are the robust identification's standard deviations honest?  A Monte-Carlo over noise seeds.

For each seed a log is simulated on a drive, identified with ``identify(log)`` (robust, default
settings), and for every required truth mode (pooled settle-window SNR >= 3,
``tests/test_identify.py::required_modes``) matched within 1 % in frequency, and for ``k0`` and
the bias, the normalised error ``z = (estimate - truth) / std`` is collected.  If the reported std
are right, ``z`` has RMS 1 (issue 11 item 5: within 1.2).  The table gives, per drive and
parameter, the number of values, the RMS of ``z`` with its sampling uncertainty, the mean of ``z``
(an estimator bias shows as a mean far from 0: ``+-`` its standard error) and the largest ``|z|``.

Drives (the logs are simulated by code that shares no dynamics with the estimator):

* ``50k`` -- ``tests/drives``' 50.4 kHz drive: another actuator (modes 260 Hz ... 19.5 kHz), a PID
  with lead and a 2x multirate notch filter, computation delay, its own noise and run-out.
* ``36k`` -- a drive built here (:func:`drive_36k`): 36 kHz servo rate, a single-rate PID with lead
  and two notches, modes at 350 Hz ... 15.2 kHz, 9 us delay, sensor / force noise, flutter, run-out.
* ``nss`` -- seekopt's own synthetic NSS-like drive (``seekopt.evaluate.synth``, single-rate
  notches); it shares the discretisation with the estimator, so it is shown for continuity only.

Sampling uncertainty of the RMS: for ``n`` values of a normal ``z`` the RMS has relative standard
error ``1 / sqrt(2 n)``; the values of one log are not independent (modes of one fit share its
noise), so the standard error printed is the delta-method one of the per-log mean of ``z^2``
(``std(m_j) / sqrt(N)`` over the ``N`` logs, divided by ``2 RMS``).

Run: ``PYTHONPATH=. python studies/std_calibration.py [--seeds 40] [--seeks 60] [--drive 50k --drive 36k]
[--jobs 2] [--cache /tmp/seekopt_std_calibration]``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, "tests")]

PARAMS = ("freq_hz", "zeta", "gain", "k0", "bias_a")
DRIVES = ("50k", "36k", "nss")


def drive_36k(seed: int = 0):
    """A drive unlike the benchmark and unlike ``tests/drives``' 50.4 kHz one, built from the
    independent simulator's parts: 36 kHz servo rate, single-rate PID + lead (crossover 950 Hz) with
    notches at 4.7 and 11.6 kHz, k0 4.5e9 track/(A s^2), 9 us input delay, modes at 350 Hz
    (flex), 2.1 kHz (coil), 4.7 kHz (butterfly, in the notch), 8.3, 11.6 (in the notch) and
    15.2 kHz; sensor noise 0.008 track, force noise 0.15 mA, flutter at 800 and 2900 Hz, run-out
    at 120 Hz harmonics."""
    from tests.drives import Drive, DigitalController, Noise, notch, pid_lead
    from tests.drives.plant import ModeSpec, TruthPlant
    fs, k0 = 36000.0, 4.5e9
    modes = (ModeSpec(350.0, 0.05, 0.002), ModeSpec(2100.0, 0.03, 0.015), ModeSpec(4700.0, 0.025, -0.8),
             ModeSpec(8300.0, 0.012, 0.3), ModeSpec(11600.0, 0.008, -0.5), ModeSpec(15200.0, 0.01, 0.4))
    truth = TruthPlant(k0=k0, modes=modes, bias_a=-0.003, delay_s=9e-6, track_pitch_nm=120.0)
    ctrl = DigitalController([pid_lead(k0, fs, 950.0, lead_ratio=14.0, integral_frac=0.1, rolloff_factor=8.0),
                              notch(4700.0, fs, 20.0, 0.2, rate_multiple=1),
                              notch(11600.0, fs, 20.0, 0.15, rate_multiple=1)], fs, "PID + lead, notches (36 kHz)")
    rng = np.random.default_rng(seed + 9091)
    rro = [(h, a, float(rng.uniform(0, 2 * math.pi))) for h, a in ((1, 0.1), (2, 0.03))]
    noise = Noise(0.008, 1.5e-4, [(800.0, 0.05, 0.01), (2900.0, 0.04, 0.004)], rro, None, 120.0)
    return Drive(truth, ctrl, noise, spindle_hz=120.0, name="36 kHz")


def make(drive: str, seed: int, n_seeks: int):
    """``(log, truth ModalPlant)`` of one seed on ``drive``."""
    if drive == "nss":
        from seekopt.drive.presets import nss_controller_single_rate
        from seekopt.evaluate.synth import SynthConfig, synthesize
        return synthesize(SynthConfig(n_seeks=n_seeks, seed=seed), controller=nss_controller_single_rate())
    from tests.drives import Schedule, drive_50k, make_log, modal_plant
    d = drive_50k(seed=seed) if drive == "50k" else drive_36k(seed)
    return make_log(d, Schedule(n_seeks=n_seeks, seed=seed), noise_seed=seed), modal_plant(d)


def _one(args):
    """Identify one seed; returns a JSON-able record (cached in ``cache``)."""
    drive, seed, n_seeks, cache = args
    from identification.estimate.identify import identify
    from identification.model.plant import ModalPlant
    from test_identify import required_modes
    name = os.path.join(cache, f"{drive}_{seed}_{n_seeks}") if cache else None
    if name and os.path.exists(name + ".rec.json"):
        with open(name + ".rec.json") as fh:
            return json.load(fh)
    from identification.logs import read_log, write_log
    if name and os.path.exists(name + ".npz"):
        log, truth = read_log(name + ".npz"), ModalPlant.load(name + ".json")
    else:
        log, truth = make(drive, seed, n_seeks)
        if name:
            os.makedirs(cache, exist_ok=True)
            write_log(log, name + ".npz")
            truth.to_json(name + ".json")
    t = time.perf_counter()
    res = identify(log)
    secs = time.perf_counter() - t
    p = res.plant
    rec = {"drive": drive, "seed": seed, "seconds": secs,
           "k0": [p.k0, p.std["k0"], truth.k0], "bias_a": [p.bias_a, p.std["bias_a"], truth.bias_a],
           "modes": [], "missed": []}
    for m, _snr in required_modes(log, truth):
        e = min(p.modes, key=lambda q: abs(np.log(q.freq_hz / m.freq_hz)))
        if abs(e.freq_hz / m.freq_hz - 1) > 0.01:
            rec["missed"].append(m.freq_hz)
            continue
        rec["modes"].append({"truth_hz": m.freq_hz, **{k: [getattr(e, k), e.std[k], getattr(m, k)]
                                                        for k in ("freq_hz", "zeta", "gain")}})
    if name:
        os.makedirs(cache, exist_ok=True)
        with open(name + ".rec.json", "w") as fh:
            json.dump(rec, fh)
    return rec


def calibration(drive: str = "50k", seeds=range(40), n_seeks: int = 60, cache=None, jobs: int = 1, verbose=True):
    """Records of :func:`_one` over ``seeds`` (in seed order)."""
    work = [(drive, int(s), n_seeks, cache) for s in seeds]
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(jobs) as ex:
            recs = []
            for r in ex.map(_one, work):
                recs.append(r)
                if verbose:
                    print(f"{drive} seed {r['seed']}: {r['seconds']:.1f} s", file=sys.stderr, flush=True)
            return recs
    recs = []
    for w in work:
        recs.append(_one(w))
        if verbose:
            print(f"{drive} seed {w[1]}: {recs[-1]['seconds']:.1f} s", file=sys.stderr, flush=True)
    return recs


def z_values(recs):
    """``{param: [(log index, z), ...]}`` of the records."""
    out = {k: [] for k in PARAMS}
    for j, r in enumerate(recs):
        for k in ("k0", "bias_a"):
            e, s, t = r[k]
            out[k].append((j, (e - t) / s))
        for m in r["modes"]:
            for k in ("freq_hz", "zeta", "gain"):
                e, s, t = m[k]
                out[k].append((j, (e - t) / s))
    return out


def summary(recs):
    """``{param: dict(n, rms, rms_se, mean, mean_se, max)}``; the standard errors treat each log as
    one independent draw (its values may be correlated)."""
    res = {}
    for k, v in z_values(recs).items():
        if not v:
            continue
        j = np.array([a for a, _ in v])
        z = np.array([b for _, b in v])
        logs = np.unique(j)
        m2 = np.array([np.mean(z[j == i] ** 2) for i in logs])
        m1 = np.array([np.mean(z[j == i]) for i in logs])
        rms = float(np.sqrt(np.mean(z ** 2)))
        n_logs = len(logs)
        se2 = float(np.std(m2, ddof=1) / np.sqrt(n_logs)) if n_logs > 1 else float("nan")
        res[k] = {"n": len(z), "rms": rms, "rms_se": se2 / (2 * rms) if rms > 0 else float("nan"),
                  "mean": float(z.mean()),
                  "mean_se": float(np.std(m1, ddof=1) / np.sqrt(n_logs)) if n_logs > 1 else float("nan"),
                  "max": float(np.abs(z).max())}
    return res


def table(results: dict, title: str = "") -> str:
    """Markdown table of ``{drive: records}``."""
    out = [title, "", "| drive | parameter | n | RMS z (± s.e.) | mean z (± s.e.) | max abs z |",
           "|---|---|---|---|---|---|"] if title else \
          ["| drive | parameter | n | RMS z (± s.e.) | mean z (± s.e.) | max abs z |", "|---|---|---|---|---|---|"]
    for drive, recs in results.items():
        for k, s in summary(recs).items():
            out.append(f"| {drive} | {k} | {s['n']} | {s['rms']:.2f} ± {s['rms_se']:.2f} | "
                       f"{s['mean']:+.2f} ± {s['mean_se']:.2f} | {s['max']:.2f} |")
    missed = {d: sum(len(r["missed"]) for r in recs) for d, recs in results.items()}
    secs = {d: np.mean([r["seconds"] for r in recs]) for d, recs in results.items()}
    out += ["", "Logs per drive: " + ", ".join(f"{d} {len(r)}" for d, r in results.items())
            + "; required modes missed (not matched within 1 %): " + ", ".join(f"{d} {m}" for d, m in missed.items())
            + "; identify s per log: " + ", ".join(f"{d} {s:.1f}" for d, s in secs.items())]
    return "\n".join(out)


def comparison(before: dict, after: dict) -> str:
    """Markdown table of the RMS of ``z`` of two runs ``{drive: records}`` (e.g. two code versions
    on the same logs)."""
    out = ["| drive | parameter | RMS z before | RMS z after | mean z before | mean z after |", "|---|---|---|---|---|---|"]
    for drive in after:
        sb, sa = summary(before.get(drive, [])), summary(after[drive])
        for k, a in sa.items():
            b = sb.get(k)
            fb = (f"{b['rms']:.2f} ± {b['rms_se']:.2f}", f"{b['mean']:+.2f}") if b else ("-", "-")
            out.append(f"| {drive} | {k} | {fb[0]} | {a['rms']:.2f} ± {a['rms_se']:.2f} | {fb[1]} | {a['mean']:+.2f} |")
    return "\n".join(out)


def load_records(cache: str, drive: str, seeds, n_seeks: int):
    """The cached records of ``seeds`` on ``drive`` in ``cache`` (those that exist)."""
    out = []
    for sd in seeds:
        name = os.path.join(cache, f"{drive}_{sd}_{n_seeks}.rec.json")
        if os.path.exists(name):
            with open(name) as fh:
                out.append(json.load(fh))
    return out


def by_mode(recs) -> str:
    """Per truth mode: n, RMS / mean z of frequency, damping, gain."""
    rows = {}
    for r in recs:
        for m in r["modes"]:
            rows.setdefault(m["truth_hz"], []).append([(m[k][0] - m[k][2]) / m[k][1] for k in ("freq_hz", "zeta", "gain")])
    out = ["| truth mode | n | RMS z freq | RMS z zeta | RMS z gain | mean z freq | mean z zeta | mean z gain |",
           "|---|---|---|---|---|---|---|---|"]
    for f, v in sorted(rows.items()):
        v = np.array(v)
        r, mu = np.sqrt(np.mean(v ** 2, axis=0)), v.mean(axis=0)
        out.append(f"| {f:g} Hz | {len(v)} | " + " | ".join(f"{x:.2f}" for x in r) + " | "
                   + " | ".join(f"{x:+.2f}" for x in mu) + " |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=40, help="number of noise seeds (0..N-1) per drive")
    ap.add_argument("--seeks", type=int, default=60, help="seeks per log")
    ap.add_argument("--drive", action="append", choices=DRIVES, help="drive(s) (default: 50k and 36k)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--cache", default=None, help="folder for the logs and the per-seed records")
    ap.add_argument("--modes", action="store_true", help="also the per-mode table")
    ap.add_argument("--before", action="append", default=[],
                    help="folder(s) of cached records of an earlier code version, for a before/after table")
    a = ap.parse_args(argv)
    drives = a.drive or ["50k", "36k"]
    t0 = time.perf_counter()
    results = {d: calibration(d, range(a.seeds), a.seeks, a.cache, a.jobs) for d in drives}
    print(table(results, f"**Normalised errors z = (estimate - truth) / reported std**, {a.seeds} noise seeds "
                         f"per drive, {a.seeks} seeks per log"))
    whole = {d: [r for r in recs if not r["missed"]] for d, recs in results.items()}
    print("\n" + table(whole, "Only the logs whose identification found every required mode (a missed mode is "
                              "model error for the others, which no standard deviation covers):"))
    if a.before:
        before = {d: [r for c in a.before for r in load_records(c, d, range(a.seeds), a.seeks)] for d in drives}
        print("\n" + comparison(before, results))
    if a.modes:
        for d, recs in results.items():
            print(f"\n{d}:\n" + by_mode(recs))
    print(f"\nstudy wall time {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
