"""Study: long seeks under a velocity limit (issue 12): design time and settle against the time optimum.

Run::

    python studies/vmax_seeks.py [--vmax 2e6] [--kinds nominal,robust] [--n 6] [--paths dispatch,step,accel]

Lengths ``np.geomspace(1e4, 1e5, n)`` on the bundled drive (Imax 0.3 A, band 0.1 track), one warm
:class:`seekopt.design.longseek.LongSeekDesigner` per (kind, path):

* ``dispatch`` -- ``LongSeekDesigner.design``, the rule of ``seekopt design --vmax`` (module notes of
  :mod:`seekopt.design.longseek`: the velocity step on one plant, the acceleration step on a set);
* ``step`` -- :meth:`~seekopt.design.longseek.LongSeekDesigner.design_velocity_step`: the velocity step to
  ``vmax`` (one QP bisection, kept), composed with its mirror;
* ``accel`` -- :meth:`~seekopt.design.longseek.LongSeekDesigner.design_accel_step`: the acceleration step
  (one QP bisection, kept), four shifted copies with the samples at ``I0`` capped by ``vmax`` and the
  dispatch's current limit on overlapping transitions.

Per length: CPU (``time.process_time``) and wall of ``design(K)`` (the first also designs the step),
the settle time measured by the one simulator on the design plant, and the bound of the issue
``1.1 T_acd + (settle(K = 1000) - T_bb(1000))`` with ``T_acd`` the rigid-body accelerate-coast-decelerate
time (:func:`seekopt.design.longseek.t_accel_coast_decel`) and the K = 1000 rest-to-rest design of the same
kind.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(kind: str, path: str, vmax: float, ks: list, overhead: float, log=print) -> list:
    from seekopt.design.longseek import LongSeekDesigner, LongSeekSpec, t_accel_coast_decel
    from seekopt.drive.controller import Controller
    from seekopt.drive.presets import default_truth_plant
    plant = default_truth_plant()
    ls = LongSeekDesigner(plant, Controller.nss(), 0.3, 0.1, "default" if kind == "robust" else None,
                          LongSeekSpec(vmax_track_s=vmax))
    design = {"dispatch": ls.design, "step": ls.design_velocity_step, "accel": ls.design_accel_step}[path]
    rows = []
    for K in ks:
        c0, w0 = time.process_time(), time.perf_counter()
        res = design(K)
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        t_opt = t_accel_coast_decel(K, plant.k0, 0.3, vmax)
        bound = 1.1 * t_opt + overhead
        row = dict(kind=kind, path=path, K=K, cpu_s=cpu, wall_s=wall, settle_ms=res.metrics.settle_time_s * 1e3,
                   t_acd_ms=t_opt * 1e3, bound_ms=bound * 1e3, ok=res.metrics.settle_time_s <= bound,
                   peak_a=res.metrics.peak_current_a, built=res.profile.meta.get("design_objective", ""))
        log(f"| {kind} | {path} | {K:.0f} | {cpu:.3f} | {wall:.3f} | {row['settle_ms']:.4f} | {row['t_acd_ms']:.4f} | "
            f"{row['bound_ms']:.4f} | {'yes' if row['ok'] else 'NO'} | {row['peak_a']:.4f} | "
            f"{'velocity' if row['built'].endswith('arrive') else 'accel'} |", flush=True)
        rows.append(row)
    return rows


def k1000_overhead(kind: str) -> float:
    from seekopt.design.designer import SeekDesigner
    from seekopt.design.profiles import t_bang_bang
    from seekopt.drive.controller import Controller
    from seekopt.drive.presets import default_truth_plant
    plant = default_truth_plant()
    r = SeekDesigner(plant, Controller.nss(), 0.3, 0.1, "default" if kind == "robust" else None).design(1000.0)
    return r.metrics.settle_time_s - t_bang_bang(1000.0, plant.k0, 0.3)


def main(argv=None) -> int:
    import numpy as np
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vmax", type=float, default=2e6)
    ap.add_argument("--kinds", default="nominal,robust")
    ap.add_argument("--paths", default="dispatch,step,accel")
    ap.add_argument("--n", type=int, default=6)
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from seekopt.design.blas import limit_blas
    limit_blas(1)
    ks = [float(k) for k in np.round(np.geomspace(1e4, 1e5, a.n))]
    print("| design | path | K | CPU s | wall s | settle ms | T_acd ms | bound ms | within | peak A | built from |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for kind in a.kinds.split(","):
        over = k1000_overhead(kind)
        print(f"<!-- {kind}: K = 1000 rest-to-rest overhead {over * 1e3:.4f} ms -->")
        for path in a.paths.split(","):
            rows += run(kind, path, a.vmax, ks, over)
    print(f"load average {os.getloadavg()}")
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
