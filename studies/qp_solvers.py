"""Study: other QP solvers on the design's own QPs (issue 12 item 2), and PIQP as the proving fallback.

Run::

    python studies/qp_solvers.py [--mode nominal|robust] [--solvers daqp_warm,daqp_cold,piqp,proxqp,clarabel,highs]
                                 [--every 1] [--ab]

1. **Capture**: one designer (``default_truth_plant()``, ``Controller.nss()``, Imax 0.3 A, nominal or
   :class:`RobustSpec`) designs K = 1 ... 1000 tracks (the 13 lengths of ``studies/design_speed.py``) in a
   warm process; every call of :meth:`seekopt.design.daqp_solver.DaqpQP.solve` (the reduced QPs of the
   working set, with the starting active set it was given) is recorded.
2. **Bench**: each solver solves every ``--every``-th captured QP from the same data, one BLAS thread:
   ``daqp_warm`` (:class:`DaqpQP` with the recorded starting active set: what the designer does),
   ``daqp_cold`` (the package, no start), ``piqp`` (:class:`seekopt.design.piqp_solver.PiqpQP`),
   ``proxqp`` (ProxSuite dense, box constraints), ``clarabel`` (sparse, cones), ``highs`` (``casadi.conic``,
   :class:`seekopt.design.solvers.ConicQP`).  Reported: total CPU, the statuses against daqp's cold verdict
   (``opt``/``inf``; ``+cert``: the solver's multipliers pass
   :func:`seekopt.design.certificates.proves_infeasible`), the largest constraint violation of an ``opt``
   answer and the largest relative objective difference to daqp's.
3. ``--ab``: the 13-length design run twice in one process -- the default chain, then with ``piqp`` as the
   first fallback (it then proves the lengths the daqp package reports infeasible without a certificate)
   -- settle samples and CPU per length.

CPU is ``time.process_time`` (the machine is shared).  Results: ``docs/results_speed.md``.
"""
from __future__ import annotations

import argparse
import collections
import time

import numpy as np

KS = (1.0, 10.0, 50.0, 100.0, 130.0, 170.0, 220.0, 290.0, 380.0, 500.0, 650.0, 850.0, 1000.0)
BIG = 1e20          # "no bound" for solvers that take no infinities


def _designer(mode: str, **kw):
    from seekopt.design.ocp import RobustSpec, SeekDesigner
    from seekopt.drive.controller import Controller
    from seekopt.drive.presets import default_truth_plant
    return SeekDesigner(default_truth_plant(), Controller.nss(), 0.3,
                        robust=RobustSpec() if mode == "robust" else None, **kw)


def capture(mode: str) -> list:
    """Every :meth:`DaqpQP.solve` call of a 13-length run (after one warm-up design), as dicts."""
    from seekopt.design import daqp_solver
    calls, orig = [], daqp_solver.DaqpQP.solve

    def hooked(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None):
        sol = orig(self, H, g, A, lba, uba, lbx, ubx, x0=x0, lam_a0=lam_a0, lam_x0=lam_x0)
        arr = lambda v: None if v is None else np.array(v, dtype=float).ravel()     # noqa: E731
        calls.append(dict(H=np.array(H, float), A=np.array(A, float), g=arr(g), lba=arr(lba), uba=arr(uba),
                          lbx=arr(lbx), ubx=arr(ubx), lam_a0=arr(lam_a0), lam_x0=arr(lam_x0), settings=self.settings))
        return sol
    daqp_solver.DaqpQP.solve = hooked
    try:
        des = _designer(mode)
        des.design(5.0)
        calls.clear()
        for K in KS:
            des.design(K)
    finally:
        daqp_solver.DaqpQP.solve = orig
    return calls


def _out(status, x, lam, cpu):
    return dict(status=status, x=np.asarray(x, dtype=float), lam=np.asarray(lam, dtype=float), cpu=cpu)


def daqp_cold(q):
    import daqp
    bu, bl = np.r_[q["ubx"], q["uba"]], np.r_[q["lbx"], q["lba"]]
    sense = np.where(bl == bu, 5, 0).astype(np.intc)
    c = time.process_time()
    x, _, flag, info = daqp.solve(np.ascontiguousarray(q["H"]), q["g"], np.ascontiguousarray(q["A"]), bu, bl, sense,
                                  **q["settings"])
    c = time.process_time() - c
    lam = np.asarray(info["lam"])[len(q["g"]):] * (-1.0 if flag == -1 else 1.0)
    return _out({1: "opt", 2: "opt", -1: "inf"}.get(int(flag), f"flag{flag}"), x, lam, c)


def _from_solution(sol):
    return _out({"optimal": "opt", "infeasible": "inf"}.get(sol.outcome.value, sol.outcome.value), sol.x, sol.lam_a,
                sol.cpu_time_s)


def daqp_warm(q):
    from seekopt.design.daqp_solver import DaqpQP
    s = DaqpQP(len(q["g"]), len(q["A"]))
    return _from_solution(s.solve(q["H"], q["g"], q["A"], q["lba"], q["uba"], q["lbx"], q["ubx"],
                                  lam_a0=q["lam_a0"], lam_x0=q["lam_x0"]))


def piqp_(q):
    from seekopt.design.piqp_solver import PiqpQP
    return _from_solution(PiqpQP(len(q["g"]), len(q["A"])).solve(q["H"], q["g"], q["A"], q["lba"], q["uba"],
                                                                 q["lbx"], q["ubx"]))


def proxqp(q):
    import proxsuite
    eq = q["lba"] == q["uba"]
    iq = ~eq
    c = time.process_time()
    P = proxsuite.proxqp.dense.QP(len(q["g"]), int(eq.sum()), int(iq.sum()), True)
    P.settings.eps_abs, P.settings.eps_rel, P.settings.verbose, P.settings.max_iter = 1e-9, 0.0, False, 10000
    cl = lambda v: np.clip(v, -BIG, BIG)     # noqa: E731
    P.init(q["H"], q["g"], q["A"][eq], q["lba"][eq], q["A"][iq], cl(q["lba"][iq]), cl(q["uba"][iq]),
           cl(q["lbx"]), cl(q["ubx"]))
    P.solve()
    c = time.process_time() - c
    S = proxsuite.proxqp.QPSolverOutput
    st = P.results.info.status
    lam = np.zeros(len(q["A"]))
    lam[eq], lam[iq] = P.results.y, P.results.z[:iq.sum()]
    return _out("opt" if st == S.PROXQP_SOLVED else "inf" if st == S.PROXQP_PRIMAL_INFEASIBLE
                else str(st).split(".")[-1], P.results.x, lam, c)


def clarabel_(q):
    import clarabel
    from scipy import sparse
    A, lba, uba, lbx, ubx = q["A"], q["lba"], q["uba"], q["lbx"], q["ubx"]
    n = len(q["g"])
    c = time.process_time()
    eq = lba == uba
    up, lo = ~eq & np.isfinite(uba), ~eq & np.isfinite(lba)
    eye = np.eye(n)
    M = np.vstack([A[eq], A[up], -A[lo], eye[np.isfinite(ubx)], -eye[np.isfinite(lbx)]])
    b = np.r_[uba[eq], uba[up], -lba[lo], ubx[np.isfinite(ubx)], -lbx[np.isfinite(lbx)]]
    cones = [clarabel.ZeroConeT(int(eq.sum())), clarabel.NonnegativeConeT(len(b) - int(eq.sum()))]
    st = clarabel.DefaultSettings()
    st.verbose, st.tol_gap_abs, st.tol_gap_rel, st.tol_feas = False, 1e-9, 1e-9, 1e-9
    r = clarabel.DefaultSolver(sparse.triu(sparse.csc_matrix(q["H"])).tocsc(), q["g"], sparse.csc_matrix(M), b,
                               cones, st).solve()
    c = time.process_time() - c
    z, k, lam = np.asarray(r.z), 0, np.zeros(len(A))
    for mask, sign in ((eq, 1.0), (up, 1.0), (lo, -1.0)):
        lam[mask] += sign * z[k:k + mask.sum()]
        k += int(mask.sum())
    s = str(r.status)
    return _out("opt" if s == "Solved" else "inf" if s == "PrimalInfeasible" else s, r.x, lam, c)


_HIGHS: dict = {}


def highs(q):
    from seekopt.design.solvers import ConicQP
    key = (len(q["g"]), len(q["A"]))
    if key not in _HIGHS:
        _HIGHS[key] = ConicQP(*key, "highs")      # built once per size, outside the timing
    return _from_solution(_HIGHS[key].solve(q["H"], q["g"], q["A"], q["lba"], q["uba"], q["lbx"], q["ubx"]))


SOLVERS = {"daqp_warm": daqp_warm, "daqp_cold": daqp_cold, "piqp": piqp_, "proxqp": proxqp, "clarabel": clarabel_,
           "highs": highs}


def bench(calls: list, names, every: int = 1) -> None:
    """Print the table of step 2 for every ``every``-th QP of ``calls``."""
    from seekopt.design.certificates import proves_infeasible
    from seekopt.design.solvers import constraint_violation
    sel = calls[::every]
    tot, worst, verdicts = collections.defaultdict(float), collections.defaultdict(float), collections.Counter()
    for q in sel:
        ref = daqp_cold(q)
        fref = 0.5 * ref["x"] @ q["H"] @ ref["x"] + q["g"] @ ref["x"] if ref["status"] == "opt" else None
        for nm in names:
            r = SOLVERS[nm](q)
            tot[nm] += r["cpu"]
            if r["status"] == "opt":
                worst[nm, "viol"] = max(worst[nm, "viol"], constraint_violation(q["A"], r["x"], q["lba"], q["uba"],
                                                                                q["lbx"], q["ubx"]))
                if fref is not None:
                    f = 0.5 * r["x"] @ q["H"] @ r["x"] + q["g"] @ r["x"]
                    worst[nm, "dobj"] = max(worst[nm, "dobj"], abs(f - fref) / max(1.0, abs(fref)))
            cert = r["status"] == "inf" and proves_infeasible(q["A"], q["lba"], q["uba"], q["lbx"], q["ubx"], r["lam"])
            verdicts[nm, ref["status"], r["status"] + ("+cert" if cert else "")] += 1
    print(f"{len(sel)} QPs (every {every}), n = {min(len(q['g']) for q in sel)}-{max(len(q['g']) for q in sel)}, "
          f"rows {min(len(q['A']) for q in sel)}-{max(len(q['A']) for q in sel)}")
    print("| solver | CPU total [ms] | max violation | max rel. obj. diff | daqp cold verdict -> solver's |")
    print("|---|---|---|---|---|")
    for nm in names:
        v = ", ".join(f"{a}->{b}: {c}" for (n2, a, b), c in sorted(verdicts.items()) if n2 == nm)
        print(f"| {nm} | {tot[nm] * 1e3:.0f} | {worst[nm, 'viol']:.1e} | {worst[nm, 'dobj']:.1e} | {v} |")


def ab(mode: str) -> None:
    """Step 3: settle samples and CPU per length, default chain vs ``piqp`` first fallback, one process."""
    from seekopt.design.problem import SolverSettings
    res = {}
    for tag, fb in (("default", None), ("piqp first", ("piqp",) + SolverSettings().fallbacks)):
        des = _designer(mode, **({} if fb is None else {"fallbacks": fb}))
        des.design(5.0)
        res[tag] = []
        for K in KS:
            c = time.process_time()
            r = des.design(K)
            res[tag].append((r.settle_samples, time.process_time() - c))
    print(f"{mode}: K | N default | N piqp first | CPU default [ms] | CPU piqp first [ms]")
    for K, a, b in zip(KS, res["default"], res["piqp first"]):
        print(f"{K:6.0f} | {a[0]} | {b[0]} | {a[1] * 1e3:.1f} | {b[1] * 1e3:.1f}")
    for tag, v in res.items():
        print(f"{tag}: median {np.median([c for _, c in v]) * 1e3:.1f} ms, total {sum(c for _, c in v) * 1e3:.0f} ms")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("nominal", "robust"), default="nominal")
    ap.add_argument("--solvers", default="daqp_warm,daqp_cold,piqp,proxqp,clarabel,highs")
    ap.add_argument("--every", type=int, default=1, help="bench every n-th captured QP")
    ap.add_argument("--ab", action="store_true", help="only the design A/B run (step 3)")
    a = ap.parse_args(argv)
    from seekopt.design.blas import limit_blas
    with limit_blas(1):
        if a.ab:
            ab(a.mode)
        else:
            bench(capture(a.mode), a.solvers.split(","), a.every)


if __name__ == "__main__":
    main()
