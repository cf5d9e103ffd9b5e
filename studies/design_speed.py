"""Study: design results and per-design CPU, this tree against an older commit, measured in one run.

Run::

    python studies/design_speed.py [--against REV] [--ks 1,10,50,200,1000] [--identified PLANT.json]

The same worker (``--worker``) runs in fresh processes, once on ``git archive REV`` (default
``37b8cdb``, the commit issue 12 measured; ``e6b5b6e`` works too) and on this tree (and with
``--working-set`` once more), with one BLAS thread set by the environment (``--blas-default``: the library's default thread
count, where this tree's designer limits BLAS to ``SolverSettings.blas_threads`` itself).  Each
worker builds ONE designer per (design plant, nominal/robust) and designs every length in turn (the
designer of a sweep: warm process, structures reused), recording:

* the seek-settle samples the design claims (``N``) and the settle time measured by the one simulator
  on the design plant and on the truth (``default_truth_plant()``);
* the same on this tree with ``SolverSettings(working_set=True)`` (:mod:`seekopt.design.working_set`);
* CPU [s] of each ``design(K)`` call (``time.process_time``: the machine is shared, CPU is the
  reliable figure) and its wall time.

Design plants: the plant identified from the bundled sample log (``seekopt/data/sample_log.npz``,
identified once by this tree and given to both workers as JSON) and the stand-in perturbed copy of
the truth (``perturbed_plant``).  Prints one table: settle samples before/after (must agree within one
sample), truth settle times, CPU per design and the ratio before/after.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Lengths designed in turn by one designer, as in a sweep (log-spaced neighbours from 100 tracks on).
KS = (1.0, 10.0, 50.0, 100.0, 130.0, 170.0, 220.0, 290.0, 380.0, 500.0, 650.0, 850.0, 1000.0)


def worker(plants_json: str, ks: list, out: str, variant: str = "default") -> None:
    """Runs inside the tree under test (its ``PYTHONPATH``); only API common to all revisions
    (``variant="working_set"``: this tree's designer with ``SolverSettings(working_set=True)``)."""
    import inspect
    import numpy as np
    tree = Path.cwd().resolve()
    # the layout is read from the tree on disk, not from what imports: with an editable install of another
    # tree, a module the older tree lacks (seekopt.design) is found in the installed tree instead
    if (tree / "identification" / "model").is_dir():
        from identification.model.plant import ModalPlant
    else:                                   # flat layout (37b8cdb)
        from identification.plant import ModalPlant
    if (tree / "seekopt" / "design").is_dir():
        from seekopt.design.ocp import RobustSpec, SeekDesigner
        from seekopt.design.metrics import evaluate_profile
        from seekopt.drive.controller import Controller
    else:                                   # flat layout (37b8cdb)
        from seekopt.ocp import RobustSpec, SeekDesigner
        from seekopt.metrics import evaluate_profile
        from seekopt.controller import Controller
    for obj in (ModalPlant, SeekDesigner, evaluate_profile, Controller):
        src = Path(inspect.getsourcefile(obj)).resolve()
        if tree not in src.parents:
            raise SystemExit(f"design_speed worker: {obj.__name__} imported from {src}, not from the tree under test {tree}")
    spec = json.loads(Path(plants_json).read_text())
    truth = ModalPlant.from_dict(spec["truth"])
    ctrl = Controller.nss()
    rows = []
    for pname in ("identified", "stand-in"):
        plant = ModalPlant.from_dict(spec[pname])
        for dname, robust in (("nominal", None), ("robust", RobustSpec())):
            c0 = time.process_time()
            if variant == "working_set":
                from seekopt.design.problem import SeekProblem, SolverSettings
                des = SeekDesigner(SeekProblem(plant, ctrl, spec["imax"], robust=robust,
                                               solver=SolverSettings(working_set=True)))
            else:
                des = SeekDesigner(plant, ctrl, spec["imax"], robust=robust)
            build = time.process_time() - c0
            for K in ks:
                c0, t0 = time.process_time(), time.perf_counter()
                try:
                    res = des.design(K)
                except Exception as exc:    # noqa: BLE001 - recorded
                    rows.append(dict(plant=pname, design=dname, K=K, error=f"{type(exc).__name__}: {exc}"[:160],
                                     cpu_s=time.process_time() - c0))
                    print(pname, dname, K, "FAILED", exc, flush=True)
                    continue
                cpu, wall = time.process_time() - c0, time.perf_counter() - t0
                mt = evaluate_profile(truth, ctrl, res.profile, k0_for_tbb=plant.k0)
                rows.append(dict(plant=pname, design=dname, K=K, N=int(res.settle_samples),
                                 settle_design_s=float(res.metrics.settle_time_s),
                                 settle_truth_s=float(mt.settle_time_s), ratio_tbb_truth=float(mt.ratio_tbb),
                                 peak_a=float(mt.peak_current_a), n_solves=int(res.n_solves),
                                 cpu_s=cpu, wall_s=wall, designer_build_cpu_s=build,
                                 u_ff_checksum=float(np.sum(np.abs(res.profile.current_a)))))
                print(pname, dname, K, rows[-1]["N"], f"{cpu:.3f} s CPU", flush=True)
    Path(out).write_text(json.dumps(rows, indent=1))


def run_tree(tree: Path, plants_json: Path, ks, out: Path, variant: str = "default",
             one_thread: bool = True) -> list:
    env = dict(os.environ, PYTHONPATH=str(tree))
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        if one_thread:
            env[k] = "1"
        else:
            env.pop(k, None)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", str(plants_json), ",".join(map(str, ks)),
           str(out), variant]
    subprocess.run(cmd, env=env, cwd=tree, check=True)
    return json.loads(out.read_text())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default="37b8cdb", help="git revision to compare with")
    ap.add_argument("--working-set", action="store_true", help="also run SolverSettings(working_set=True)")
    ap.add_argument("--ks", default=",".join(f"{k:g}" for k in KS))
    ap.add_argument("--identified", help="identified plant JSON (default: identify the bundled sample log)")
    ap.add_argument("--before-json", help="reuse the older revision's worker output (skip that run)")
    ap.add_argument("--blas-default", action="store_true",
                    help="leave the BLAS thread count to the library (default: 1 thread by environment)")
    ap.add_argument("--worker", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        worker(a.worker[0], [float(k) for k in a.worker[1].split(",")], a.worker[2], a.worker[3])
        return 0
    sys.path.insert(0, str(ROOT))
    from identification.model.plant import ModalPlant
    from seekopt.drive.controller import Controller
    from seekopt.drive.presets import default_truth_plant
    from seekopt.evaluate.bench import perturbed_plant
    ks = [float(k) for k in a.ks.split(",")]
    truth, ctrl = default_truth_plant(), Controller.nss()
    if a.identified:
        ident = ModalPlant.load(a.identified)
    else:
        from identification.estimate.identify import identify
        from identification.logs.formats import read_log
        ident = identify(read_log(ROOT / "seekopt" / "data" / "sample_log.npz")).plant
    tmp = Path(tempfile.mkdtemp(prefix="design_speed_"))
    plants = tmp / "plants.json"
    plants.write_text(json.dumps({"truth": truth.to_dict(), "identified": ident.to_dict(),
                                  "stand-in": perturbed_plant(truth, ctrl.sample_rate_hz).to_dict(), "imax": 0.3}))
    if a.before_json:
        before = json.loads(Path(a.before_json).read_text())
    else:
        old = tmp / "old"
        old.mkdir()
        arch = subprocess.run(["git", "-C", str(ROOT), "archive", a.against], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(old)], input=arch, check=True)
        before = run_tree(old, plants, ks, tmp / "before.json", one_thread=not a.blas_default)
    after = run_tree(ROOT, plants, ks, tmp / "after.json", one_thread=not a.blas_default)
    wset = {(r["plant"], r["design"], r["K"]): r
            for r in (run_tree(ROOT, plants, ks, tmp / "working_set.json", "working_set", not a.blas_default)
                      if a.working_set else [])}
    key = {(r["plant"], r["design"], r["K"]): r for r in before}
    print(f"\nagainst {a.against}; BLAS threads: {'library default' if a.blas_default else '1 (environment)'}; "
          f"worker outputs in {tmp}")
    print("| design plant | design | K | N before | N after | truth T_ss ms before | after | "
          "CPU s before | after | before/after | N working set | CPU s working set |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    worst, ratios, wratios = 0, {}, {}
    for r in after:
        b = key.get((r["plant"], r["design"], r["K"]), {})
        if "error" in r or "error" in b:
            print(f"| {r['plant']} | {r['design']} | {r['K']:g} | {b.get('N', b.get('error', '?'))} | "
                  f"{r.get('N', r.get('error'))} | | | | | |")
            continue
        w = wset.get((r["plant"], r["design"], r["K"]), {})
        worst = max(worst, abs(r["N"] - b["N"]), abs(w.get("N", r["N"]) - b["N"]))
        ratio = b["cpu_s"] / max(r["cpu_s"], 1e-9)
        ratios.setdefault(r["design"], []).append(ratio)
        if "N" in w:
            wratios.setdefault(r["design"], []).append(b["cpu_s"] / max(w["cpu_s"], 1e-9))
        print(f"| {r['plant']} | {r['design']} | {r['K']:g} | {b['N']} | {r['N']} | "
              f"{b['settle_truth_s'] * 1e3:.3f} | {r['settle_truth_s'] * 1e3:.3f} | {b['cpu_s']:.3f} | "
              f"{r['cpu_s']:.3f} | {ratio:.2f} | {w.get('N', w.get('error', '?'))} | "
              f"{w.get('cpu_s', float('nan')):.3f} |")
    import statistics
    print(f"\nlargest change of the designed settle samples: {worst}; load average {os.getloadavg()}")
    for d in ("nominal", "robust"):
        for tree, rows in (("before", before), ("after", after)):
            cpu = [r["cpu_s"] for r in rows if r.get("design") == d and "cpu_s" in r and "error" not in r]
            if cpu:
                print(f"{d}, {tree}: median CPU per design {statistics.median(cpu) * 1e3:.1f} ms "
                      f"(max {max(cpu) * 1e3:.1f} ms, {len(cpu)} designs)")
    for name, rat in (("default", ratios), ("working set", wratios)):
        for d, rs in rat.items():
            print(f"{d}, {name}: CPU before/after per design, median {statistics.median(rs):.2f}x "
                  f"(min {min(rs):.2f}, max {max(rs):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
