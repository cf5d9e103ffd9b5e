"""Study: from a seek log with effects to a profile designed with them, through the CLI (issue 10, item 7).

For each synthetic drive (a truth other than the bundled one: flex mode 300 Hz, coil 2.2 kHz, bias
-6 mA; plus one library effect or a combination of three) the chain a user runs::

    seekopt synth --plant truth.json --effect ... -o log.npz --truth truth_fx.json
    seekopt loop log.npz --report rep.json -o plant.json
    seekopt design --plant plant.json --tracks K --start-track T -o aware.csv       (effects: Ipopt NLP)
    seekopt design --plant linear.json --tracks K --robust none -o linear.csv      (the plant's linear part, QP)

then every profile is played from ``T`` on the drive (the truth with its effects) by the one simulator
(:func:`seekopt.design.feasibility.play_seek`), and the linear design also on the same drive without
its effects; the reference the target is stated against ("the same seek on the effect-free drive") is
the seek designed (QP, ``--robust`` as given) for the effect-free drive's own plant and played on it.  Starts at 20 %, 50 % and 80 % of the logged range (``position_range_track`` the loop
wrote), seek lengths ``--tracks``.  Prints one Markdown table: settle of the linear design, the
effect-aware design and the effect-free drive, their ratio, peak current on the full plant, Ipopt
time per design.  A design that ``seekopt design`` refuses (exit 2) is a row with its message.

    python studies/loop_to_design.py [--cases kt,bias,lag,delay,combo] [--tracks 10,200,1000]
        [--starts 0.2,0.5,0.8] [--out /tmp/loop_to_design] [--seeks 80] [--robust none]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from identification.model.plant import ModalPlant, Mode  # noqa: E402
from seekopt.design.feasibility import play_seek  # noqa: E402
from seekopt.design.profiles import Profile  # noqa: E402
from seekopt.drive.controller import Controller  # noqa: E402
from seekopt.drive.presets import default_truth_plant  # noqa: E402

IMAX = 0.3
#: the drive's effects per case (``seekopt synth --effect``); Kt +-20 % over the logged stroke (0..60000)
CASES = {
    "kt": ["torque_constant_variation:coeffs=0.2,center_track=30000,scale_track=30000"],
    "bias": ["position_bias:knots_track=0;20000;40000;60000,bias_a=-0.03;-0.01;0.015;0.03"],
    "lag": ["amplifier_lag:bandwidth_hz=3000"],
    "delay": ["input_delay:delay_s=15e-6"],
    "combo": ["torque_constant_variation:coeffs=0.2,center_track=30000,scale_track=30000",
              "position_bias:knots_track=0;20000;40000;60000,bias_a=-0.03;-0.01;0.015;0.03",
              "amplifier_lag:bandwidth_hz=3000"],
}


def other_truth() -> ModalPlant:
    """Not the bundled drive: flex mode 300 Hz, coil mode 2.2 kHz, other damping/gains, bias -6 mA."""
    base = default_truth_plant()
    modes = [m for m in base.modes if m.freq_hz > 3000.0] + [Mode(300.0, 0.04, 0.003), Mode(2200.0, 0.02, 0.015)]
    return base.copy(modes=sorted(modes, key=lambda m: m.freq_hz), bias_a=-0.006,
                     meta={"source": "studies/loop_to_design other truth"})


def cli(*args) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "seekopt.app.cli", *map(str, args)], capture_output=True,
                          text=True, env=env)


def ensure(cp: subprocess.CompletedProcess, what: str) -> None:
    if cp.returncode != 0:
        raise SystemExit(f"{what} failed ({cp.returncode}): {cp.stderr.strip().splitlines()[-1:]}")


def run_case(name: str, out: Path, tracks, starts, seeks: int, robust: str) -> list:
    d = out / name
    d.mkdir(parents=True, exist_ok=True)
    truth_in, log, truth, plant, linear = (d / f for f in ("truth_in.json", "log.npz", "truth.json", "plant.json",
                                                            "linear.json"))
    other_truth().to_json(truth_in)
    if not plant.exists():
        eff = [a for e in CASES[name] for a in ("--effect", e)]
        ensure(cli("synth", "-q", "--plant", truth_in, "--seeks", seeks, "--seed", 3, "-o", log, "--truth", truth, *eff),
               f"{name}: synth")
        t = time.perf_counter()
        ensure(cli("loop", "-q", log, "--report", d / "report.json", "-o", plant), f"{name}: loop")
        print(f"[{name}] loop {time.perf_counter() - t:.0f} s", file=sys.stderr, flush=True)
    P, T = ModalPlant.load(plant), ModalPlant.load(truth)
    P.linear_part().to_json(linear)
    free = T.copy(effects=[])             # the same drive without its effects
    free.to_json(d / "free_truth.json")
    ctrl = Controller.nss()
    rng = P.meta.get("position_range_track") or [0.0, 60000.0]
    rows = []
    for K in tracks:
        lin_csv = d / f"linear_{K:g}.csv"
        if not lin_csv.exists():
            ensure(cli("design", "-q", "--plant", linear, "--tracks", K, "--imax", IMAX, "--robust", robust,
                       "-o", lin_csv), f"{name}: linear design {K}")
        lin = Profile.from_csv(lin_csv)
        # the reference: the seek designed for the effect-free drive itself (its plant known), played on it
        ref_csv = d / f"known_free_{K:g}.csv"
        if not ref_csv.exists():
            ensure(cli("design", "-q", "--plant", d / "free_truth.json", "--tracks", K, "--imax", IMAX, "--robust",
                       robust, "-o", ref_csv), f"{name}: known-plant design {K}")
        ref = Profile.from_csv(ref_csv)
        for s in starts:
            T0 = round(rng[0] + s * (rng[1] - rng[0]))
            row = {"case": name, "K": K, "start": f"{s:.0%} ({T0})", "accepted": ", ".join(e.name for e in P.effects)}
            m_lin, _ = play_seek(T, ctrl, lin, T0)
            m_free, _ = play_seek(free, ctrl, lin, T0)
            m_ref, _ = play_seek(free, ctrl, ref, T0)
            row.update(linear_ms=m_lin.settle_time_s * 1e3, free_ms=m_free.settle_time_s * 1e3,
                       known_free_ms=m_ref.settle_time_s * 1e3)
            aw_csv = d / f"aware_{K:g}_{T0}.csv"
            t = time.perf_counter()
            cp = cli("design", "-q", "--plant", plant, "--tracks", K, "--imax", IMAX, "--robust", robust,
                     "--start-track", T0, "-o", aw_csv)
            row["design_s"] = time.perf_counter() - t
            if cp.returncode != 0:
                row.update(aware_ms=math.nan, note=cp.stderr.strip().splitlines()[-1][:160] if cp.stderr else "")
            else:
                prof = Profile.from_csv(aw_csv)
                m, _ = play_seek(T, ctrl, prof, T0)
                row.update(aware_ms=m.settle_time_s * 1e3, peak_a=m.peak_current_a,
                           ipopt_s=float(prof.meta.get("ipopt_time_s", "nan")),
                           ipopt_cpu_s=float(prof.meta.get("ipopt_cpu_s", "nan")),
                           path="NLP" if prof.kind == "optimal-nlp" else "QP (linear plant)", note="")
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def table(rows) -> str:
    head = ("| drive | K | start (track) | linear design | effect-aware | effect-free | aware / free "
            "| known-plant design, effect-free | aware / known | peak A "
            "| path | Ipopt s (CPU s) | note |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    out = [head]
    for r in rows:
        ratio = r["aware_ms"] / r["free_ms"] if r["free_ms"] > 0 else math.nan
        kf = r.get("known_free_ms", math.nan)
        rk = r["aware_ms"] / kf if kf > 0 else math.nan
        out.append(f"| {r['case']} | {r['K']:g} | {r['start']} | {r['linear_ms']:.3f} ms | {r['aware_ms']:.3f} ms | "
                   f"{r['free_ms']:.3f} ms | {ratio:.2f} | {kf:.3f} ms | {rk:.2f} | {r.get('peak_a', math.nan):.3f} | "
                   f"{r.get('path', '-')} | "
                   f"{r.get('ipopt_s', math.nan):.1f} ({r.get('ipopt_cpu_s', math.nan):.1f}) | {r.get('note', '')} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--tracks", default="10,200,1000")
    ap.add_argument("--starts", default="0.2,0.5,0.8")
    ap.add_argument("--out", default="/tmp/loop_to_design")
    ap.add_argument("--seeks", type=int, default=80)
    ap.add_argument("--robust", default="none", help="--robust of both designs (default: nominal designs)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    rows = []
    for name in a.cases.split(","):
        rows += run_case(name, out, [float(k) for k in a.tracks.split(",")], [float(s) for s in a.starts.split(",")],
                         a.seeks, a.robust)
    text = table(rows)
    (out / "table.md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
