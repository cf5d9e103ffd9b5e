"""Are the robust identification's standard deviations honest?  A Monte-Carlo over noise seeds.

For each seed a synthetic log of the default truth (benchmark noise: sensor, force noise, flutter,
run-out) is identified with ``identify(log)`` (robust); for every required truth mode (pooled
settle-window SNR >= 3, ``tests/test_identify.py::required_modes``) matched within 1 % in
frequency, and for ``k0`` and the bias, the normalised error ``z = (estimate - truth) / std`` is
collected.  If the reported std are right, ``z`` has RMS 1 (issue 11 item 5: within 1.2).  The
table gives, per parameter, the number of values, RMS, mean and largest ``|z|``, then the RMS per
truth mode, and the bias both from the whole log (reported) and from the per-seek fit.

Run: ``PYTHONPATH=. python studies/std_calibration.py [--seeds 16] [--seeks 100] [--drive single-rate]``
(``--quick``: 8 seeds of 60 seeks).  The single-rate drive (notches at the PES rate) keeps the
multirate hold error out, so what remains is noise and the model's own structure.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, "tests")]

PARAMS = ("freq_hz", "zeta", "gain", "k0", "bias_a", "bias_a per seek")


def _log(seed, n_seeks, drive, cache_dir):
    from identification.logs import read_log, write_log
    from identification.model.plant import ModalPlant
    from seekopt.drive.presets import nss_controller_single_rate
    from seekopt.evaluate.synth import SynthConfig, synthesize
    name = os.path.join(cache_dir, f"e2e_{drive}_{seed}_{n_seeks}") if cache_dir else None
    if name and os.path.exists(name + ".npz"):
        return read_log(name + ".npz"), ModalPlant.load(name + ".json")
    log, truth = synthesize(SynthConfig(n_seeks=n_seeks, seed=seed),
                            controller=nss_controller_single_rate() if drive == "single-rate" else None)
    if name:
        os.makedirs(cache_dir, exist_ok=True)
        write_log(log, name + ".npz")
        truth.to_json(name + ".json")
    return log, truth


def calibration(seeds=range(16), n_seeks: int = 100, drive: str = "single-rate", cache_dir=None, verbose=True):
    """``{"z": {param: [z...]}, "by_mode": {freq: [[zf, zz, zg], ...]}, "seconds": [...]}`` over ``seeds``."""
    from identification.estimate.identify import identify
    from test_identify import required_modes
    z = {k: [] for k in PARAMS}
    by_mode, secs = {}, []
    for seed in seeds:
        log, truth = _log(seed, n_seeks, drive, cache_dir)
        t = time.perf_counter()
        res = identify(log)
        secs.append(time.perf_counter() - t)
        p, d = res.plant, res.diagnostics
        z["k0"].append((p.k0 - truth.k0) / p.std["k0"])
        z["bias_a"].append((p.bias_a - truth.bias_a) / p.std["bias_a"])
        ps = d["bias_per_seek"]
        z["bias_a per seek"].append((ps["bias_a"] - truth.bias_a) / ps["std"])
        for m, _snr in required_modes(log, truth):
            e = min(p.modes, key=lambda q: abs(np.log(q.freq_hz / m.freq_hz)))
            if abs(e.freq_hz / m.freq_hz - 1) > 0.01:
                continue
            row = [(getattr(e, k) - getattr(m, k)) / e.std[k] for k in ("freq_hz", "zeta", "gain")]
            for k, v in zip(("freq_hz", "zeta", "gain"), row):
                z[k].append(v)
            by_mode.setdefault(m.freq_hz, []).append(row)
        if verbose:
            print(f"seed {seed}: {secs[-1]:.1f} s, z k0 {z['k0'][-1]:+.2f}, bias {z['bias_a'][-1]:+.2f} "
                  f"(per seek {z['bias_a per seek'][-1]:+.2f})", file=sys.stderr, flush=True)
    return {"z": z, "by_mode": by_mode, "seconds": secs}


def table(result, title: str = "") -> str:
    """Markdown tables of :func:`calibration`'s result."""
    out = [title, "", "| parameter | n | RMS z | mean z | max abs z |", "|---|---|---|---|---|"]
    for k, v in result["z"].items():
        v = np.asarray(v)
        if len(v):
            out.append(f"| {k} | {len(v)} | {np.sqrt(np.mean(v ** 2)):.2f} | {v.mean():+.2f} | {np.abs(v).max():.2f} |")
    out += ["", "| truth mode | n | RMS z freq | RMS z zeta | RMS z gain |", "|---|---|---|---|---|"]
    for f, rows in sorted(result["by_mode"].items()):
        r = np.sqrt(np.mean(np.square(rows), axis=0))
        out.append(f"| {f:g} Hz | {len(rows)} | {r[0]:.2f} | {r[1]:.2f} | {r[2]:.2f} |")
    out += ["", f"identify: {np.mean(result['seconds']):.1f} s per log (mean)"]
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=16, help="number of noise seeds (0..N-1)")
    ap.add_argument("--seeks", type=int, default=100, help="seeks per log")
    ap.add_argument("--drive", choices=("single-rate", "multirate"), default="single-rate")
    ap.add_argument("--cache", default=None, help="folder to keep the synthesised logs (shared with identification_accuracy.py)")
    ap.add_argument("--quick", action="store_true", help="8 seeds of 60 seeks")
    a = ap.parse_args(argv)
    seeds, seeks = (range(8), 60) if a.quick else (range(a.seeds), a.seeks)
    res = calibration(seeds, seeks, a.drive, a.cache)
    print(table(res, f"**Normalised errors z = (estimate - truth) / std**, {a.drive} drive, default truth, "
                     f"benchmark noise, {seeks} seeks, seeds 0..{len(seeds) - 1}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
