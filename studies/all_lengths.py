"""Study: zero solver-caused failures over every seek length (issue 12), one warm designer per case.

Run::

    python studies/all_lengths.py [--n 40] [--kmax 1e5] [--kinds nominal,robust] [--plants bundled,notch]
                                  [--wall 60] [--json out.json]

Lengths: ``np.geomspace(1, kmax, n)`` rounded to 0.1 track (the issue's 40 log-spaced lengths K = 1 ... 1e5).
Design plants: ``bundled`` (:func:`seekopt.drive.presets.default_truth_plant`) and ``notch`` (the same plus a
mode in the NSS controller's 8.2 kHz notch, gain 0.1, zeta 0.01, as ``studies/operating_range.py``).
Designers: ``nominal`` and ``robust`` (``RobustSpec()``), Imax 0.3 A, band 0.1 track, dispatched as ``seekopt design``
does without ``--vmax``: :class:`seekopt.design.longseek.LongSeekDesigner` (rest-to-rest QPs below its
``long_from_track``, acceleration-step compositions from there on).

Per length, one of these outcomes:

* ``designed`` -- a verified design (``N`` settle samples; ``unresolved`` counts QPs that no solver decided,
  ``fallback`` the QPs a fallback solver answered);
* ``infeasible`` -- :class:`DesignInfeasible`: proven (a solver's proof, or ``T_bb`` beyond the design horizon);
* ``solver failure`` -- :class:`DesignError` (no verified design, no proof): what the issue forbids;
* ``wall limit`` -- the design did not finish within ``--wall`` seconds (a hang: counted as a solver failure).

Each (plant, designer) runs in a worker process that designs the lengths in turn (warm designer, as in a
sweep) and reports one JSON line per length; the parent kills a worker whose design passes the wall limit,
records the length and starts a fresh worker on the next length, so one hang cannot stop the study.  CPU is
``time.process_time`` per ``design(K)`` call (the machine is shared).
"""
from __future__ import annotations

import argparse
import json
import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTCH_MODE_HZ, NOTCH_MODE_ZETA, NOTCH_MODE_GAIN = 8200.0, 0.01, 0.1


def lengths(n: int = 40, kmax: float = 1e5) -> list:
    """The issue's log-spaced lengths [track], rounded to 0.1 track."""
    import numpy as np
    return [float(k) for k in np.unique(np.round(np.geomspace(1.0, kmax, n), 1))]


def design_plant(name: str):
    """``bundled`` or ``notch`` (module notes)."""
    from identification.model.plant import Mode
    from seekopt.drive.presets import default_truth_plant
    base = default_truth_plant()
    if name == "bundled":
        return base
    if name == "notch":
        mode = Mode(NOTCH_MODE_HZ, NOTCH_MODE_ZETA, NOTCH_MODE_GAIN)
        return base.copy(modes=sorted(base.modes + [mode], key=lambda m: m.freq_hz))
    raise ValueError(f"unknown plant {name!r} (bundled, notch)")


def worker(plant_name: str, kind: str, ks: list) -> None:
    """Design ``ks`` in turn with one designer; one JSON line per length on stdout."""
    from seekopt.design.longseek import LongSeekDesigner, LongSeekError, LongSeekSpec
    from seekopt.design.ocp import RobustSpec, SeekDesigner
    from seekopt.design.result import DesignError, DesignInfeasible
    from seekopt.drive.controller import Controller
    short = SeekDesigner(design_plant(plant_name), Controller.nss(), 0.3, 0.1,
                         robust=RobustSpec() if kind == "robust" else None)
    des = LongSeekDesigner(short.problem, LongSeekSpec(), short_designer=short)     # the CLI's dispatch
    for K in ks:
        c0, t0 = time.process_time(), time.perf_counter()
        row = dict(plant=plant_name, design=kind, K=K)
        try:
            res = des.design(K)
            row.update(outcome="designed", N=int(res.settle_samples), unresolved=int(res.unresolved_solves),
                       fallback=int(res.fallback_solves), n_solves=int(res.n_solves), path=res.profile.kind,
                       settle_s=float(res.metrics.settle_time_s), ratio_tbb=float(res.metrics.ratio_tbb),
                       peak_a=float(res.metrics.peak_current_a))
        except DesignInfeasible as exc:
            row.update(outcome="infeasible", why=str(exc)[:140])
        except (DesignError, LongSeekError) as exc:
            row.update(outcome="solver failure", why=str(exc)[:240])
        row.update(cpu_s=time.process_time() - c0, wall_s=time.perf_counter() - t0)
        print(json.dumps(row), flush=True)


def run_case(plant_name: str, kind: str, ks: list, wall_s: float, log=print) -> list:
    """All lengths of one case, a fresh worker after each hang (module notes)."""
    rows, i = [], 0
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    while i < len(ks):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", plant_name, kind,
               ",".join(f"{k:g}" for k in ks[i:])]
        proc = subprocess.Popen(cmd, env=env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        lines: queue.Queue = queue.Queue()
        threading.Thread(target=lambda f=proc.stdout: [lines.put(x) for x in f] + [lines.put(None)],
                         daemon=True).start()
        limit = wall_s + 30.0           # the first length also pays the imports and the designer's build
        deadline = time.monotonic() + limit
        while i < len(ks):
            try:
                line = lines.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                line = ""
            if not line:                # past the wall limit (""), or the worker died (None)
                proc.kill()
                proc.wait()
                if line is None:
                    rows.append(dict(plant=plant_name, design=kind, K=ks[i], outcome="solver failure",
                                     why=f"worker exited {proc.returncode}", cpu_s=float("nan"), wall_s=float("nan")))
                else:
                    rows.append(dict(plant=plant_name, design=kind, K=ks[i], outcome="wall limit",
                                     cpu_s=float("nan"), wall_s=limit))
                log(json.dumps(rows[-1]))
                i += 1
                break
            if not line.startswith('{"plant"'):      # a solver's banner on stdout (qpOASES): not a result
                continue
            rows.append(json.loads(line))
            log(line.strip())
            i += 1
            limit = wall_s
            deadline = time.monotonic() + limit
        else:
            proc.wait()
    return rows


def summary(rows: list) -> str:
    """One markdown table row per case: outcome counts, unresolved QPs, median / max CPU of the designs."""
    import statistics
    out = ["| plant | design | lengths | designed | infeasible | solver failure | wall limit | unresolved QPs | "
           "median CPU s | max CPU s | longest designed K |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    cases = dict.fromkeys((r["plant"], r["design"]) for r in rows)
    for p, d in cases:
        rs = [r for r in rows if (r["plant"], r["design"]) == (p, d)]
        count = lambda o: sum(r["outcome"] == o for r in rs)      # noqa: E731
        des = [r for r in rs if r["outcome"] == "designed"]
        cpu = [r["cpu_s"] for r in des]
        out.append(f"| {p} | {d} | {len(rs)} | {len(des)} | {count('infeasible')} | {count('solver failure')} | "
                   f"{count('wall limit')} | {sum(r['unresolved'] for r in des)} | "
                   f"{statistics.median(cpu) if cpu else float('nan'):.3f} | {max(cpu, default=float('nan')):.3f} | "
                   f"{max((r['K'] for r in des), default=float('nan')):g} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--kmax", type=float, default=1e5)
    ap.add_argument("--kmin", type=float, default=0.0, help="skip lengths below this (a partial run)")
    ap.add_argument("--kupto", type=float, default=float("inf"), help="skip lengths above this (a partial run)")
    ap.add_argument("--kinds", default="nominal,robust")
    ap.add_argument("--plants", default="bundled,notch")
    ap.add_argument("--wall", type=float, default=60.0, help="wall limit per design [s]")
    ap.add_argument("--json", help="write every row here")
    ap.add_argument("--worker", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    if a.worker:
        worker(a.worker[0], a.worker[1], [float(k) for k in a.worker[2].split(",")])
        return 0
    ks = [k for k in lengths(a.n, a.kmax) if a.kmin <= k <= a.kupto]
    rows = []
    for p in a.plants.split(","):
        for d in a.kinds.split(","):
            rows += run_case(p, d, ks, a.wall)
            if a.json:
                Path(a.json).write_text(json.dumps(rows, indent=1))
    print(f"\nload average {os.getloadavg()}")
    print(summary(rows))
    bad = [r for r in rows if r["outcome"] in ("solver failure", "wall limit")
           or r.get("unresolved", 0)]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
