"""Study: solve time per design with solver reuse vs a naive rebuild per design; QP plugins vs Ipopt.

Run::

    python studies/solver_reuse.py

1. Reuse: one :class:`seekopt.design.designer.SeekDesigner` (closed-loop maps, condensed matrices converted to
   ``casadi.DM`` and the ``casadi.conic`` solver built once per seek-size class) designs a list of
   seeks; naive: a new designer (everything rebuilt) per seek.  Same answers, wall time per design.
2. Solvers on the designer's own condensed QP (a bisection sequence of the K = 200 design, nominal
   and robust, and min-residual QPs of a 1000-track seek, N = 120, 110, 100): ``casadi.conic``
   plugins daqp, qpoases, highs, osqp, proxqp and the ``Opti`` + Ipopt path
   (``hessian_constant``/``jac_*_constant`` = yes, ``opti.to_function``), each built once and fed
   the changing data (repeating identical data would flatter hot-starting solvers); also Opti
   rebuilt for one solve.

CPU times are process times (the machine is shared; wall times are noisier).  Writes the section
between the ``solver_reuse`` markers of ``docs/results_design.md``.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from seekopt.design import solvers as qpmod  # noqa: E402
from seekopt.design.designer import SeekDesigner  # noqa: E402
from seekopt.design.problem import SeekProblem  # noqa: E402
from seekopt.evaluate.bench import perturbed_plant  # noqa: E402
from seekopt.drive.controller import Controller  # noqa: E402
from seekopt.drive.presets import default_truth_plant  # noqa: E402

sys.path.insert(0, str(ROOT / "studies"))
from paper_seek_settling import write_section  # noqa: E402

IMAX = 0.3
TRACKS = (30.0, 40.0, 50.0, 60.0, 80.0, 100.0, 150.0, 200.0)


def timed(f):
    t0, c0 = time.perf_counter(), time.process_time()
    out = f()
    return out, time.perf_counter() - t0, time.process_time() - c0


def reuse_vs_rebuild(plant, ctrl, robust=None):
    """One designer for every length (its solver builds counted by ``solver_builds``) against a new
    designer per length."""
    problem = SeekProblem(plant, ctrl, IMAX, robust=robust)
    d = SeekDesigner(problem)
    reuse, rebuild = [], []
    for K in TRACKS:
        r, w, c = timed(lambda: d.design(K))
        reuse.append((K, w, c, r.solve_time_s, r.settle_samples))
    builds_reuse = sum(d.solver_builds.values())
    builds_rebuild = 0
    for K in TRACKS:
        fresh = SeekDesigner(problem)
        r, w, c = timed(lambda: fresh.design(K))
        builds_rebuild += sum(fresh.solver_builds.values())
        rebuild.append((K, w, c, r.solve_time_s, r.settle_samples))
    return reuse, rebuild, builds_reuse, builds_rebuild


def solver_table(plant, ctrl, K, Ns, nclass, beta, epigraph, robust=None):
    """Every solver on the designer's own condensed QP, built once, then a bisection-like sequence of
    solves with changing data (settle sample ``N`` in ``Ns``): first (cold) solve and the rest."""
    d = SeekDesigner(SeekProblem(plant, ctrl, IMAX, robust=robust))
    s = d._structure(nclass, epigraph)
    seq = [s.data(K, N, None if epigraph else beta, d.gamma, d.hf_tol, None) for N in Ns]
    rows, ref = [], None
    for name in ("daqp", "qpoases", "highs", "osqp", "proxqp", "ipopt"):
        try:
            solver, tb, _ = timed(lambda: qpmod.make_qp_solver(s.n, s.m, name))
        except Exception as exc:  # noqa: BLE001
            rows.append((name, f"build failed: {exc}"[:60], *[float("nan")] * 7))
            continue
        sols = [solver.solve(*data) for data in seq]
        last, data = sols[-1], seq[-1]
        viol = s.violation(last.x, K, *data[3:]) if last.success else float("nan")
        obj = (float(0.5 * last.x @ (np.array(data[0]) @ last.x) + np.asarray(data[1]) @ last.x)
               if last.success else float("nan"))
        if name == "daqp" and last.success:
            ref = last.x
        dx = float(np.max(np.abs(last.x - ref))) if (ref is not None and last.success) else float("nan")
        ok = "/".join("ok" if x.success else ("inf" if x.infeasible else "FAIL") for x in sols)
        rows.append((name, ok, tb, sols[0].cpu_time_s, statistics.mean(x.cpu_time_s for x in sols[1:]),
                     statistics.mean(x.solve_time_s for x in sols[1:]), viol, obj, dx))
    # Opti + Ipopt rebuilt for every solve (no reuse), last data set
    (_, w, c) = timed(lambda: qpmod.IpoptQP(s.n, s.m).solve(*seq[-1]))
    return s, rows, (w, c)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a = ap.parse_args(argv)
    truth, ctrl = default_truth_plant(), Controller.nss()
    plant = perturbed_plant(truth, ctrl.sample_rate_hz)
    out = ["## Solver reuse and QP solvers (`studies/solver_reuse.py`)", "",
           f"Design plant: perturbed copy of the truth; NSS controller; Imax {IMAX} A; seeks {', '.join(f'{k:g}' for k in TRACKS)} tracks. "
           "Wall and CPU (process) time per design, including the bisection's QP solves and the simulator check.", ""]
    for label, robust in (("nominal", None), ("robust freq=3,gain=25,delay=3e-6,n=4", "freq=3,zeta=30,gain=25,delay=3e-6,n=4")):
        reuse, rebuild, br, bn = reuse_vs_rebuild(plant, ctrl, robust)
        wr, wn = sum(r[1] for r in reuse), sum(r[1] for r in rebuild)
        cr, cn = sum(r[2] for r in reuse), sum(r[2] for r in rebuild)
        same = all(a[4] == b[4] for a, b in zip(reuse, rebuild))
        out += [f"### Reuse vs rebuild ({label})", "",
                "| K | reuse wall s | reuse QP s | rebuild wall s | rebuild QP s | N_s |", "|---|---|---|---|---|---|"]
        out += [f"| {a[0]:g} | {a[1]:.3f} | {a[3]:.3f} | {b[1]:.3f} | {b[3]:.3f} | {a[4]} |" for a, b in zip(reuse, rebuild)]
        out += ["", f"Total: reuse {wr:.2f} s wall / {cr:.2f} s CPU with {br} solver builds; rebuild {wn:.2f} s wall / "
                f"{cn:.2f} s CPU with {bn} builds: **rebuild / reuse = {wn / wr:.1f}x wall, {cn / cr:.1f}x CPU**; "
                f"identical seek-settle samples: {same}.", ""]
        print("\n".join(out[-(len(TRACKS) + 6):]), flush=True)
    cases = (("K = 200, min seek-settle bisection (band QP, class 48), nominal", 200.0, (48, 35, 41, 38, 39, 40), 48, False, None),
             ("K = 200, band QP bisection, robust set of 11 plants", 200.0, (64, 40, 52, 46, 49, 48), 64, False,
              "freq=3,zeta=30,gain=25,delay=3e-6,n=4"),
             ("K = 1000, min-residual (epigraph) QP, N = 120, 110, 100, nominal", 1000.0, (120, 110, 100), 128, True, None))
    for title, K, Ns, ncls, epi, robust in cases:
        s, rows, (rw, rc) = solver_table(plant, ctrl, K, Ns, ncls, 0.7, epi, robust)
        out += [f"### QP solvers: {title}", "", f"Dense QP: n = {s.n} variables, m = {s.m} rows; solves for N = "
                f"{', '.join(map(str, Ns))} with one solver object (statuses: ok / inf = proven infeasible).", "",
                "| solver | statuses | build s | first solve CPU ms | later solves CPU ms (mean) | later wall ms | "
                "rel. violation (last) | objective (last) | max abs dx vs daqp |",
                "|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            out.append(f"| {r[0]} | {r[1]} | {r[2]:.3f} | {r[3] * 1e3:.1f} | {r[4] * 1e3:.1f} | {r[5] * 1e3:.1f} | "
                       f"{r[6]:.1e} | {r[7]:.6g} | {r[8]:.1e} |")
        d = {r[0]: r for r in rows}
        if "daqp" in d and "ipopt" in d:
            out += ["", f"Ipopt (Opti, `to_function`, reused) / daqp CPU per solve: {d['ipopt'][4] / d['daqp'][4]:.0f}x; "
                    f"Opti + Ipopt rebuilt for one solve: {rc * 1e3:.0f} ms CPU ({rw * 1e3:.0f} ms wall).", ""]
        print("\n".join(out[-(len(rows) + 8):]), flush=True)
    write_section("solver_reuse", "\n".join(out))
    print("wrote docs/results_design.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
