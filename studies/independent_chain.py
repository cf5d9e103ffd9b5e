"""Study: the loop -> plant -> effect-aware design chain, checked on the INDEPENDENT drive (issue 10, "held-out drives").

``studies/loop_to_design.py`` makes its logs and plays its profiles with seekopt's own simulator, so a
modelling error of the package can cancel.  Here the drive is :mod:`tests.drives` (its own continuous
plant integrated by RK4 between the exact break points of the delayed held commands, its own controller
stepping, seek schedule and noise).  Per case (the drive's effects), through the CLI as a user would::

    log.npz        <- tests.drives.make_log(drive with effects, Schedule)     (write_log)
    seekopt identify log.npz -o plant.json
    seekopt loop log.npz --plant plant.json --report report.json -o aug.json
    seekopt design --plant aug.json --controller ctrl.json --tracks K --start-track T --imax I -o aware.csv
    seekopt design --plant linear.json --controller ctrl.json --tracks K --robust none ... -o linear.csv
                   (linear.json: aug.json's linear part)

``ctrl.json`` is the drive's own controller (:meth:`tests.drives.DigitalController.to_json`).  Every
profile is played on the independent drive with its effects, noise-free, from rest at ``T`` with the
drive's own holding current (its integrator's pre-seek state, added to the feedforward throughout, as
the firmware does): settle = earliest time after which ``|PES| <= band`` (0.1 track) for good, counted
from the start of the seek; peak = the largest sub-step command ``|c|``.  The reference is the same
seek designed (QP, the same ``--robust`` as the effect-aware design) for the plant ``seekopt identify`` gives on a log of the
effect-free drive, played on the effect-free drive.  Starts at 20/50/80 % of the
``position_range_track`` the loop wrote.  Target: aware <= 1.3 x reference, peak <= Imax.

Diagnostics per row: the design's predicted settle (``design_settle_samples``) and the aware profile
played by seekopt's own simulator on aug.json (what the designer believed) next to the independent
drive; the loop's accepted effects vs the truth's at the start and end tracks (Kt(x)/Kt0, bias(x)).

Results are cached per case and per (case, K, T) as JSON under ``--out`` (resumes)::

    python studies/independent_chain.py [--cases kt,bias,combo] [--tracks 200] [--starts 0.2,0.5,0.8]
        [--seeks 40] [--out docs/independent_chain] [--robust default|none|SPEC]
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from identification.logs.formats import write_log  # noqa: E402
from identification.model.plant import ModalPlant  # noqa: E402
from seekopt.design.metrics import settle_time  # noqa: E402
from seekopt.design.profiles import Profile  # noqa: E402
from tests.drives import Schedule, make_log, nss_drive, nss_truth, run  # noqa: E402

sys.path.insert(0, str(ROOT / "studies"))
from loop_to_design import cli  # noqa: E402  (the CLI as a user runs it: one definition for both studies)

IMAX = 0.3
BAND = 0.1
STROKE = (0.0, 60000.0)
_X = np.linspace(*STROKE, 7)
KT = [{"effect": "torque_constant_variation",            # Kt/Kt0 0.8 ... 1.2 over the logged stroke
       "params": {"coeffs": [0.2], "center_track": 30000.0, "scale_track": 30000.0}}]
BIAS = [{"effect": "position_bias",                        # flex-cable bias table, non-linear in position
         "params": {"knots_track": list(_X), "bias_a": [-0.012, -0.005, 0.001, 0.004, 0.003, 0.007, 0.016]}}]
LAG = [{"effect": "amplifier_lag", "params": {"bandwidth_hz": 3000.0}}]
EFFECTS = {"clean": [], "kt": KT, "bias": BIAS, "combo": KT + BIAS + LAG}


def truth(case: str):
    return nss_truth().with_effects(EFFECTS[case])


def ensure(cp: subprocess.CompletedProcess, what: str) -> None:
    if cp.returncode != 0:
        tail = (cp.stderr or cp.stdout).strip().splitlines()[-3:]
        raise RuntimeError(f"{what} failed ({cp.returncode}): {' | '.join(tail)}")


def last_line(cp: subprocess.CompletedProcess) -> str:
    s = (cp.stderr or cp.stdout).strip().splitlines()
    return s[-1][:200] if s else f"exit {cp.returncode}"


def prepare(case: str, out: Path, seeks: int, seed: int = 7) -> dict:
    """Log, identify, loop (and the controller JSON) for one case; cached in ``<out>/<case>/case.json``."""
    d = out / case
    d.mkdir(parents=True, exist_ok=True)
    info_p = d / "case.json"
    if info_p.exists():
        return json.loads(info_p.read_text())
    drive = nss_drive(truth(case), seed=seed)
    ctrl = d / "ctrl.json"
    ctrl.write_text(json.dumps(drive.controller.to_json(), indent=1))
    sec = {}
    t = time.process_time()
    write_log(make_log(drive, Schedule(n_seeks=seeks, seed=seed, stroke_track=STROKE)), d / "log.npz")
    sec["log"] = time.process_time() - t
    t = time.time()
    ensure(cli("identify", "-q", d / "log.npz", "-o", d / "plant.json"), f"{case}: identify")
    sec["identify"] = time.time() - t
    info = {"case": case, "declared": EFFECTS[case], "seeks": seeks, "seed": seed}
    if case != "clean":
        t = time.time()
        ensure(cli("loop", "-q", d / "log.npz", "--plant", d / "plant.json", "--report", d / "report.json",
                   "-o", d / "aug.json"), f"{case}: loop")
        sec["loop"] = time.time() - t
        aug = ModalPlant.load(d / "aug.json")
        aug.linear_part().to_json(d / "linear.json")
        rep = json.loads((d / "report.json").read_text())
        info.update(accepted=[e.name for e in aug.effects], effects=[e.to_dict() for e in aug.effects],
                    position_range_track=aug.meta.get("position_range_track"),
                    rms_before=rep.get("error_before", {}).get("rms_track"),
                    rms_after=rep.get("error_after", {}).get("rms_track"))
    info["seconds_wall"] = sec
    info_p.write_text(json.dumps(info, indent=1, default=str))
    return info


def play(case: str, prof: Profile, T0: float, tail_s: float = 0.015, with_pes: bool = False) -> dict:
    """Play ``prof`` on the independent drive of ``case`` (noise-free) from rest at ``T0``: settle [ms],
    peak sub-step command [A], the drive's holding current [A] (and the PES [track] if ``with_pes``)."""
    drive = nss_drive(truth(case), noise=False)
    fs = drive.sample_rate_hz
    if abs(fs - prof.sample_rate_hz) > 1e-9 * fs:
        raise ValueError(f"profile at {prof.sample_rate_hz} Hz, drive at {fs} Hz")
    uff, r = prof.padded(prof.n + int(round(tail_s * fs)))
    hold = drive.plant.holding_current(T0)
    tr = run(drive, uff + hold, r + T0, position0=T0, current0=hold)
    pes = tr.true_position_track - (T0 + prof.tracks)
    ts = settle_time(pes, fs, BAND)
    out = {"settle_ms": ts * 1e3, "peak_a": float(np.max(np.abs(tr.current_sub_a))), "hold_a": hold,
           "final_pes_track": float(pes[-1])}
    if with_pes:
        out["pes"] = pes
    return out


def seekopt_play(plant_json: Path, ctrl_json: Path, prof: Profile, T0: float) -> dict:
    """The same profile played by seekopt's own simulator on the design plant (what the designer believed)."""
    from seekopt.design.feasibility import play_seek
    from seekopt.drive.controller import Controller
    m, _ = play_seek(ModalPlant.load(plant_json), Controller.from_json(ctrl_json), prof, T0)
    return {"settle_ms": m.settle_time_s * 1e3, "peak_a": m.peak_current_a}


def effect_truth_vs_loop(case: str, aug_json: Path, T0: float, K: float) -> dict:
    """At the start and end of the seek, truth vs the loop's plant: the gain k0 Kt(x)/Kt0
    [track/(A s^2)], the current-equivalent force at rest as an acceleration k0 F(x) [track/s^2]
    and the holding current [mA] (the truth's own; seekopt's on aug.json)."""
    from seekopt.design.feasibility import hold_current
    tp = truth(case)
    aug = ModalPlant.load(aug_json)
    dp = aug.discretize(1e-5)
    out = {}
    for tag, x in (("start", T0), ("end", T0 + K)):
        kt_true = 1.0 + tp.state_force_a(x, 0.0, 1.0) - tp.state_force_a(x, 0.0, 0.0)
        f_true = tp.state_force_a(x, 0.0, 0.0) + tp.constant_force_a()
        kt_loop = float(dp.command(1.0, x) - dp.command(0.0, x))
        f_loop = float(dp.net_force(x, 0.0) + dp.command(0.0, x))
        out[tag] = {"track": x, "gain_true": tp.k0 * kt_true, "gain_loop": aug.k0 * kt_loop,
                    "accel_true": tp.k0 * f_true, "accel_loop": aug.k0 * f_loop,
                    "hold_true_ma": 1e3 * tp.holding_current(x), "hold_loop_ma": 1e3 * hold_current(aug, x, 1e-5)}
    return out


def robust_args(robust: str) -> list:
    """``--robust`` as given; ``default``: the flag left out (the CLI's default, the drift set from the data)."""
    return [] if robust == "default" else ["--robust", robust]


def reference(out: Path, K: float, seeks: int, robust: str) -> Path:
    """The same seek, same options, designed (QP) for the plant identified on the effect-free drive's log."""
    prepare("clean", out, seeks)
    d = out / "clean"
    csv = d / f"ref_{K:g}_{robust}.csv"
    if not csv.exists():
        ensure(cli("design", "-q", "--plant", d / "plant.json", "--controller", d / "ctrl.json", "--tracks", K,
                   "--imax", IMAX, *robust_args(robust), "-o", csv), f"reference design {K}")
    return csv


def run_cell(case: str, info: dict, out: Path, K: float, s: float, seeks: int, robust: str) -> dict:
    d = out / case
    rng = info.get("position_range_track") or list(STROKE)
    T0 = float(round(rng[0] + s * (rng[1] - rng[0])))
    p = d / f"cell_{K:g}_{T0:g}_{robust}.json"
    if p.exists():
        return json.loads(p.read_text())
    row = {"case": case, "K": K, "start_frac": s, "T0": T0, "robust": robust, "accepted": info.get("accepted", [])}
    ref = Profile.from_csv(reference(out, K, seeks, robust))
    row["ref"] = play("clean", ref, T0)
    lin_csv = d / f"linear_{K:g}.csv"
    if not lin_csv.exists():
        ensure(cli("design", "-q", "--plant", d / "linear.json", "--controller", d / "ctrl.json", "--tracks", K,
                   "--imax", IMAX, "--robust", "none", "-o", lin_csv), f"{case}: linear design {K}")
    row["linear"] = play(case, Profile.from_csv(lin_csv), T0)
    aw_csv = d / f"aware_{K:g}_{T0:g}_{robust}.csv"
    t = time.time()
    cp = cli("design", "-q", "--plant", d / "aug.json", "--controller", d / "ctrl.json", "--tracks", K,
             "--imax", IMAX, *robust_args(robust), "--start-track", T0, "-o", aw_csv)
    row["design_wall_s"] = time.time() - t
    if cp.returncode != 0:
        row["aware"] = None
        row["note"] = last_line(cp)
    else:
        prof = Profile.from_csv(aw_csv)
        row["aware"] = play(case, prof, T0)
        row["aware"].update(kind=prof.kind, predicted_ms=1e3 * float(prof.meta.get("design_settle_samples", "nan"))
                            / prof.sample_rate_hz,
                            ipopt_s=float(prof.meta.get("ipopt_time_s", "nan")))
        row["aware_on_aug"] = seekopt_play(d / "aug.json", d / "ctrl.json", prof, T0)
        row["note"] = ""
    row["effects"] = effect_truth_vs_loop(case, d / "aug.json", T0, K)
    p.write_text(json.dumps(row, indent=1, default=str))
    return row


def table(rows) -> str:
    out = ["| drive | robust | K | start (track) | loop accepted | linear design | effect-aware (predicted / seekopt sim) "
           "| reference | aware / ref | peak A (aware; linear) | note |",
           "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a = r.get("aware") or {}
        ref = r["ref"]["settle_ms"]
        aw = a.get("settle_ms", math.nan)
        sim = (r.get("aware_on_aug") or {}).get("settle_ms", math.nan)
        out.append(f"| {r['case']} | {r.get('robust', 'none')} | {r['K']:g} | {r['start_frac']:.0%} ({r['T0']:.0f}) | "
                   f"{', '.join(r['accepted']) or 'none'} | {r['linear']['settle_ms']:.3f} ms | "
                   f"{aw:.3f} ms ({a.get('predicted_ms', math.nan):.3f} / {sim:.3f}) | {ref:.3f} ms | "
                   f"{aw / ref:.2f} | {a.get('peak_a', math.nan):.4f}; {r['linear']['peak_a']:.4f} | "
                   f"{r.get('note', '')} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="kt,bias,combo")
    ap.add_argument("--tracks", default="200")
    ap.add_argument("--starts", default="0.2,0.5,0.8")
    ap.add_argument("--seeks", type=int, default=40)
    ap.add_argument("--robust", default="default",
                    help="robust option of the effect-aware and reference designs: default (the CLI's), none, or a spec")
    ap.add_argument("--out", default=str(ROOT / "docs" / "independent_chain"))
    a = ap.parse_args(argv)
    out = Path(a.out)
    rows = []
    for case in a.cases.split(","):
        t = time.time()
        try:
            info = prepare(case, out, a.seeks)
        except RuntimeError as e:
            print(f"[{case}] {e}", flush=True)
            continue
        print(f"[{case}] prepared ({time.time() - t:.0f} s): accepted {info.get('accepted')}", flush=True)
        for K in (float(k) for k in a.tracks.split(",")):
            for s in (float(x) for x in a.starts.split(",")):
                try:
                    row = run_cell(case, info, out, K, s, a.seeks, a.robust)
                except RuntimeError as e:
                    print(f"[{case} K={K:g} s={s}] {e}", flush=True)
                    continue
                rows.append(row)
                print(table([row]).splitlines()[-1], flush=True)
    text = table(rows)
    print(text)
    (out / f"table_{a.robust}.md").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
