"""Study: sweep throughput and scaling of the engines (serial, process pool, Dask LocalCluster).

Runs the same robust TPI x length sweep (fresh folder each time) on each engine and prints, per run:
wall time, cells/s, the CPU the cells took in the workers (``cell_cpu_s``, summed over cells; the
machine may be shared, so CPU is the load-independent figure), the designers each worker built, the
``uptime`` load averages before and after, and the scaling efficiency of each parallel run against
its one-worker reference (``serial`` for the process pool, the 1-worker Dask cluster for Dask)::

    efficiency = (cells/s with N workers) / (N x cells/s with 1 worker)

and, as the wall-time figure means little on a loaded machine, from CPU and idle time::

    efficiency (CPU) = (CPU per cell, 1 worker) / (CPU per cell, N workers) x busy share

(CPU of every process of the run, start-up and driving process included; busy share: the workers'
time computing cells over N x the time from the first cell started to the last one ended).

Dask clusters are started before the timed sweep (their start-up is printed apart), so the figure
is the sweep's, not the cluster's.  Usage::

    python studies/sweep_scaling.py [--tpi 200k:1000k:3] [--tracks 1,3,10,...] [--runs serial,process2,dask1,dask2]
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seekopt.drive.controller import Controller  # noqa: E402
from seekopt.drive.presets import default_truth_plant  # noqa: E402
from seekopt.evaluate.sweep import ALL_KINDS, SweepConfig, load_cells, parse_tpi, parse_tracks, run_sweep  # noqa: E402

#: 20 log-spaced seek lengths, 1 ... 10000 tracks
TRACKS20 = "1,2,3,4,7,11,17,26,43,70,113,183,298,483,785,1274,2069,3360,5456,8859"


def tree_cpu() -> float:
    """CPU [s] of this process and of its finished (reaped) child processes."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def busy_fraction(folder: Path) -> float:
    """Share of the workers' time from the first cell started to the last one ended that they spent
    computing cells (1: no worker idles, none waits for the driving process or for the others)."""
    cells = list(load_cells(folder).values())
    if not cells or "started" not in cells[0]:
        return float("nan")
    window = max(c["ended"] for c in cells) - min(c["started"] for c in cells)
    workers = {(c.get("host"), c["pid"]) for c in cells}
    return sum(c["ended"] - c["started"] for c in cells) / (len(workers) * window)


def load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def one_run(cfg: SweepConfig, name: str, folder: Path) -> dict:
    """Run the sweep of ``cfg`` on engine ``name`` (serial, process<N>, dask<N>) into a fresh folder."""
    shutil.rmtree(folder, ignore_errors=True)
    before, cluster, client, start_s = load(), None, None, 0.0
    kw = {}
    if name == "serial":
        kw = dict(engine="serial")
    elif name.startswith("process"):
        kw = dict(engine="process", workers=int(name[7:]))
    elif name.startswith("dask"):
        from dask.distributed import Client, LocalCluster
        t = time.perf_counter()
        cluster = LocalCluster(n_workers=int(name[4:]), threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
        client = Client(cluster)
        start_s = time.perf_counter() - t
        kw = dict(client=client)
    cpu0 = tree_cpu()
    try:
        t = time.perf_counter()
        s = run_sweep(cfg, folder, progress=False, figures=False, **kw)
        wall = time.perf_counter() - t
    finally:
        if client is not None:
            client.close()
            cluster.close()
    tree = tree_cpu() - cpu0
    cpu = getattr(s, "cell_cpu_s", float("nan"))      # (not recorded before the sweep's lanes)
    built = getattr(s, "designers_built", {})
    return dict(run=name, cells=s.computed, wall_s=wall, compute_s=getattr(s, "compute_wall_s", float("nan")),
                cells_per_s=s.computed / wall, cell_cpu_s=cpu, cpu_per_cell_s=cpu / max(s.computed, 1),
                tree_cpu_s=tree, builds=sum(built.values()) if built else float("nan"), workers=len(built),
                blas=sorted(set(getattr(s, "blas_threads", {}).values())), busy=busy_fraction(folder),
                start_s=start_s, load=f"{before} -> {load()}", ok=s.ok)


def line(name: str, r: dict, eff: float, eff_cpu: float) -> str:
    """One run's figures on one line."""
    return (f"{name:9s} {r['cells']:4d} cells  wall {r['wall_s']:7.1f} s (cells {r['compute_s']:.1f} s)  "
            f"{r['cells_per_s']:6.3f} cells/s  efficiency {eff:6.1%} (from CPU and busy share {eff_cpu:6.1%})  "
            f"busy {r['busy']:.1%}  cell CPU {r['cell_cpu_s']:7.1f} s ({r['cpu_per_cell_s']:.3f} s/cell)  "
            f"all processes' CPU {r['tree_cpu_s']:.1f} s  designers built {r['builds']} on {r['workers']} workers "
            f"(BLAS threads {r['blas']})  cluster start {r['start_s']:.1f} s  load {r['load']}  ok={r['ok']}")

def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tpi", default="200k:1000k:3")
    p.add_argument("--tracks", default="1,3,10,30,100,300,600,1000")
    p.add_argument("--designer", default="ocp-robust")
    p.add_argument("--runs", default="serial,process2,dask1,dask2")
    p.add_argument("-o", "--output", default=None, help="folder for the sweep folders (default: a temporary one)")
    a = p.parse_args(argv)
    cfg = SweepConfig(default_truth_plant(), Controller.nss(), parse_tpi(a.tpi), parse_tracks(a.tracks), 0.3, 0.1,
                      designer=a.designer, kinds=ALL_KINDS)
    base = Path(a.output or tempfile.mkdtemp(prefix="sweep_scaling_"))
    print(f"grid {len(cfg.tpis)} TPI x {len(cfg.tracks)} lengths = {len(cfg.cells())} cells, designer {a.designer}, "
          f"{os.cpu_count()} CPUs", flush=True)
    rows = {}
    for name in a.runs.split(","):
        r = rows[name] = one_run(cfg, name, base / name)
        ref = rows.get("serial") if name.startswith("process") else rows.get("dask1") if name.startswith("dask") \
            else None
        n = int(name[7:] if name.startswith("process") else name[4:] if name.startswith("dask") else 1)
        eff = r["cells_per_s"] / (n * ref["cells_per_s"]) if ref is not None and ref is not r else float("nan")
        # on a loaded machine: CPU per cell (every process of the run) against the reference, times the
        # share of the time the workers computed
        eff_cpu = (ref["tree_cpu_s"] / ref["cells"]) / (r["tree_cpu_s"] / r["cells"]) * r["busy"] \
            if ref is not None and ref is not r else float("nan")
        print(line(name, r, eff, eff_cpu), flush=True)
    if a.output is None:
        shutil.rmtree(base, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
