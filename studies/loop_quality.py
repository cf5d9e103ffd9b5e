"""Study: the loop's own quality on independent drives (issue 10, item 6).

For each library effect (and a combination) a fit log and a separate validation log are made
on an **independent drive simulator** (:mod:`tests.drives`: its own continuous plant integrated
by RK4 between the exact break points of the delayed, held commands, its own controller
stepping, seek profiles and noise -- no dynamics code shared with the package), then the loop
runs exactly as ``seekopt loop FIT --validate VAL`` does: ``identify(fit, method="robust")``,
then :func:`identification.loop.closing.close_loop` with the validation log.  Printed per case:
validation RMS before the loop (the identified plant), after the loop, the clean drive's floor
(the same schedules and noise seeds without the effect, after the loop), their ratio, the
effects the loop named and an amplifier lag's bandwidth::

    python studies/loop_quality.py [--drive 50k|nss1] [--cases clean,bias,...] [--seeks 60]
        [--out docs/loop_quality] [--refresh]

Drives: ``50k`` -- :func:`tests.drives.drive_50k` (single-rate 50.4 kHz servo, PID with lead and
a 2x notch filter, modes 260 Hz ... 19.5 kHz, 14 us delay, run-out at the 120 Hz spindle with
``rpm``/``sectors`` in the log's metadata); ``nss1`` -- the NSS hardware (26.4 kHz) with its PID
and the notches redesigned at the PES rate (single rate, so no sub-step columns).

Results are cached per case in ``<out>/<drive>/<case>.json`` (``--refresh`` recomputes).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from identification.estimate.identify import identify  # noqa: E402
from identification.loop.closing import close_loop, evaluate, split_data  # noqa: E402
from tests.drives import (Schedule, drive_50k, make_log, modal_plant, nss_drive,  # noqa: E402
                          nss_single_rate_controller, nss_truth, truth_50k)

STROKE = (0.0, 60000.0)
_X = np.linspace(*STROKE, 7)

#: the library's effects as a drive would have them (plant-JSON form, read by tests.drives)
EFFECTS = {
    "kt": [{"effect": "torque_constant_variation",           # Kt/Kt0 0.84 ... 1.16 over the stroke
            "params": {"coeffs": [0.12, -0.04], "center_track": 30000.0, "scale_track": 30000.0}}],
    "bias": [{"effect": "position_bias",                       # flex-cable bias, non-linear in position
              "params": {"knots_track": list(_X), "bias_a": [-0.012, -0.005, 0.001, 0.004, 0.003, 0.007, 0.016]}}],
    "friction": [{"effect": "friction", "params": {"coulomb_a": 0.0015, "viscous_a_per_tps": 1e-9}}],
    "lag": [{"effect": "amplifier_lag", "params": {"bandwidth_hz": 3000.0}}],
    "delay": [{"effect": "input_delay", "params": {"delay_s": 12e-6}}],
}
EFFECTS["combo"] = EFFECTS["bias"] + EFFECTS["delay"] + EFFECTS["lag"]
EFFECTS["kt_bias_friction"] = EFFECTS["kt"] + EFFECTS["bias"] + EFFECTS["friction"]
CASES = ["clean"] + list(EFFECTS)
RATIO_TARGET = 1.5


def make_drive(name: str, effects: list, seed: int):
    if name == "50k":
        return drive_50k(truth_50k().with_effects(effects), seed=seed)
    if name == "nss1":
        return nss_drive(nss_truth().with_effects(effects), nss_single_rate_controller(), seed=seed)
    raise ValueError(f"unknown drive {name!r} (50k, nss1)")


def logs(drive: str, case: str, n_seeks: int, seed: int = 7):
    """(fit log, validation log, truth ModalPlant) of ``case`` on ``drive``: the same schedules and
    noise seeds for every case (so the clean case is the floor of the others)."""
    eff = [] if case == "clean" else EFFECTS[case]
    d = make_drive(drive, eff, seed)
    sch = dict(n_seeks=n_seeks, stroke_track=STROKE)
    fit = make_log(d, Schedule(seed=seed, **sch))
    val = make_log(d, Schedule(seed=seed + 1, **sch))
    return fit, val, modal_plant(d)


def run_case(drive: str, case: str, n_seeks: int, progress=None) -> dict:
    t0 = time.time()
    fit, val, truth = logs(drive, case, n_seeks)
    tg = time.time() - t0
    ts = time.time()
    plant = identify(fit, method="robust").plant
    ti = time.time() - ts
    ts = time.time()
    R = close_loop(fit, plant, validation=val, progress=progress)
    tl = time.time() - ts
    fd, vd, same = split_data(fit, val)
    truth_rms = float(evaluate(truth, vd, same).rms)         # the truth in the package's own model, for scale
    lag = [e for e in R.plant.effects if e.name == "amplifier_lag"]
    delays = [e for e in R.plant.effects if e.name == "input_delay"]
    pd = [e for e in R.plant.effects if e.name == "periodic_disturbance"]
    vo = R.info["validation_outside_range"]
    return {"drive": drive, "case": case, "declared": [] if case == "clean" else EFFECTS[case],
            "rms_before": float(R.error_before["rms_track"]), "rms_after": float(R.error_after["rms_track"]),
            "rms_truth_model": truth_rms,
            "seeks_outside_range": vo["seeks"], "rms_outside_range_before": vo["rms_before_track"],
            "rms_outside_range_after": vo["rms_after_track"], "validation_seeks": int(R.val.windows.n_groups),
            "fit_range_track": vo["position_range_track"], "accepted": list(R.accepted),
            "effects": [e.name for e in R.plant.effects],
            "lag_bandwidth_hz": float(lag[0].params["bandwidth_hz"]) if lag else None,
            "delay_identified_us": 1e6 * float(plant.total_delay_s), "delay_after_us": 1e6 * float(R.plant.total_delay_s),
            "delay_truth_us": 1e6 * float(truth.total_delay_s),
            "extra_delay_us": [1e6 * float(e.params["delay_s"]) for e in delays],
            "spindle_hz": float(pd[0].spindle_hz) if pd else None,
            "spindle_analysis_hz": R.analysis_after.get("spindle_hz"), "spindle_source": R.analysis_after.get("spindle_source"),
            "modes_hz": [round(m.freq_hz, 1) for m in R.plant.modes], "modes_truth_hz": [m.freq_hz for m in truth.modes],
            "unexplained": list(R.unexplained), "notes": list(R.notes),
            "seconds": {"logs": tg, "identify": ti, "loop": tl}}


def table(rows: list[dict]) -> str:
    """Markdown table.  The validation RMS is over the validation seeks that stay inside the
    positions the fit log settled on (where the augmented plant is defined); the seeks left out
    are counted with their RMS after the loop."""
    clean = {r["drive"]: r for r in rows if r["case"] == "clean"}

    def g(x):
        return "-" if x is None else f"{x:.4g}"
    out = ["| drive | effect | val RMS before loop [track] | after loop | clean floor | after / floor | "
           "named by the loop | lag bandwidth [Hz] | total delay identified / after / truth [us] | "
           "validation seeks used (left out: RMS after) |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = clean.get(r["drive"], {}).get("rms_after", float("nan"))
        bw = "-" if r["lag_bandwidth_hz"] is None else f"{r['lag_bandwidth_hz']:.0f}"
        out.append(f"| {r['drive']} | {r['case']} | {r['rms_before']:.4g} | {r['rms_after']:.4g} | {f:.4g} | "
                   f"{r['rms_after'] / f:.2f} | {', '.join(r['accepted']) or 'none'} | {bw} | "
                   f"{r['delay_identified_us']:.1f} / {r['delay_after_us']:.1f} / {r['delay_truth_us']:.1f} | "
                   f"{r['validation_seeks']} ({r['seeks_outside_range']}: {g(r['rms_outside_range_after'])}) |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drive", default="50k", choices=["50k", "nss1"])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--seeks", type=int, default=60)
    ap.add_argument("--out", default=str(ROOT / "docs" / "loop_quality"))
    ap.add_argument("--refresh", action="store_true")
    ap.add_argument("--verbose", action="store_true")
    a = ap.parse_args(argv)
    cases = [c for c in a.cases.split(",") if c]
    if "clean" not in cases:
        cases.insert(0, "clean")
    out = Path(a.out) / a.drive
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for c in cases:
        p = out / f"{c}.json"
        if p.exists() and not a.refresh:
            row = json.loads(p.read_text())
        else:
            print(f"[{a.drive}/{c}] ...", flush=True)
            row = run_case(a.drive, c, a.seeks, progress=print if a.verbose else None)
            p.write_text(json.dumps(row, indent=1))
        rows.append(row)
        print(f"[{a.drive}/{c}] {row['rms_before']:.4g} -> {row['rms_after']:.4g} track, accepted "
              f"{row['accepted']}, lag {row['lag_bandwidth_hz']}, {sum(row['seconds'].values()):.0f} s", flush=True)
    print(table(rows))
    c = [r for r in rows if r["case"] == "clean"][0]
    worst = max(r["rms_after"] / c["rms_after"] for r in rows)
    print(f"worst after/floor: {worst:.2f} (target <= {RATIO_TARGET})")
    return 0 if math.isfinite(worst) else 1


if __name__ == "__main__":
    raise SystemExit(main())
