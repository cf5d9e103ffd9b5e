"""Dense QP solvers for seek design, with every solver status classified.

All solvers take ``min 1/2 x'Hx + g'x  s.t. lba <= A x <= uba, lbx <= x <= ubx`` with ``H`` and
``A`` as :class:`casadi.DM` (converted once by the caller, never per solve):

* :class:`DaqpQP` (``daqp_pkg``, the default) -- the ``daqp`` package (PyPI) called directly: the
  same dual active-set algorithm as casadi's daqp plugin, 2x less CPU on the design QPs, and it takes
  a starting active set (``lam_a0``/``lam_x0``: the previous length's or round's multipliers); its
  "infeasible" carries ``proven`` (its multipliers checked as a Farkas certificate on the data);
* ``daqp_prox`` -- :class:`DaqpQP` with proximal iterations (:data:`PROX_OPTIONS`), a fallback for
  ill-conditioned Hessians where both daqps cycle;
* :class:`ConicQP` -- ``casadi.conic`` with a QP plugin (``daqp``, ``qpoases``, ``highs``,
  ``osqp``, ``proxqp``, ``qrqp``), built once for a fixed size;
* :class:`PiqpQP` (``piqp``, a dependency; the default first fallback) -- PIQP's dense interface: no faster than the
  ``daqp`` package on these QPs, but its "infeasible" carries multipliers that usually pass the Farkas
  check (``proven``), so as the first fallback it proves the lengths the package reports infeasible
  without a certificate (:mod:`seekopt.design.piqp_solver`);
* :class:`IpoptQP` -- the same problem as an ``Opti`` + Ipopt NLP (``hessian_constant``,
  ``jac_c_constant``, ``jac_d_constant`` = yes) exported once with ``opti.to_function``;
* :class:`SolverChain` -- a primary solver and fallbacks, built lazily: a solve that ends in
  numerical trouble (daqp cycling, status -2), an iteration limit or an answer that fails the
  caller's constraint re-check is retried with the next solver before anything is called
  infeasible.

Every raw status is mapped to one :class:`QPStatus` (:func:`classify_status`): ``optimal``,
``infeasible`` (the solver proved it), ``numerical`` (trouble: proves nothing) or
``iteration_limit`` (proves nothing).  A solution is only used when it is ``optimal``.

The shared result and status types live in :mod:`seekopt.design.qp_status`, :class:`DaqpQP` in
:mod:`seekopt.design.daqp_solver`; every name is re-exported here.
"""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from seekopt.design.certificates import farkas_certificate, proves_infeasible  # noqa: F401
from seekopt.design.daqp_solver import PROX_OPTIONS, DaqpQP, kkt_holds  # noqa: F401
from seekopt.design.piqp_solver import PIQP, PiqpQP, piqp_available, piqp_installed  # noqa: F401
from seekopt.design.qp_status import (DAQP_PKG, DAQP_PROX, QPSolution, QPStatus, _nan_safe, _quiet_stdout,  # noqa: F401
                                      classify_status, dm)

__all__ = ["QPStatus", "classify_status", "QPSolution", "ConicQP", "DaqpQP", "IpoptQP", "make_qp_solver",
           "SolverChain", "QP_PLUGINS", "DAQP_PKG", "DAQP_PROX", "PIQP", "PiqpQP", "piqp_available", "piqp_installed",
           "QP_SOLVERS", "dm", "kkt_holds", "proves_infeasible", "farkas_certificate", "constraint_violation",
           "violation_of"]

#: ``casadi.conic`` plugins the designer accepts.
QP_PLUGINS = ("daqp", "qpoases", "highs", "osqp", "proxqp", "qrqp")
#: Time limit [s] of a HiGHS solve (``time_limit``): a fallback that does not finish proves nothing
#: and the search moves on.
FALLBACK_LIMIT_S = 2.0
#: qpOASES working-set recalculations per (variable + row) (``nWSR``; casadi 3.8.2's qpOASES does not
#: honour its ``CPUtime`` option: measured 15.7 s CPU with ``CPUtime=2``).  With casadi's default, qpOASES took
#: 15-25 s per solve on the ill-conditioned (cond(H) ~ 7e10) whole-row QP of nominal K = 3888 on the truth
#: plant (222 variables, 1072 rows) where both daqps cycle, and the design ran for minutes; with
#: 1000 recalculations it stops after 0.6 s CPU.
QPOASES_NWSR_PER_DIM = 2
#: Every solver name :func:`make_qp_solver` accepts (``DAQP_PKG``: :class:`DaqpQP`).
QP_SOLVERS = (DAQP_PKG, DAQP_PROX, PIQP) + QP_PLUGINS + ("ipopt",)
#: Solvers that take any row count (never padded to the chain's size).
ANY_SIZE = (DAQP_PKG, DAQP_PROX, PIQP)


class ConicQP:
    """``casadi.conic`` for a dense QP of fixed size ``(n, m)``, built once and reused.

    Parameters
    ----------
    n, m : int
        Variables and linear constraints.
    plugin : str
        ``daqp`` (default), ``qpoases``, ``highs``, ``osqp``, ``proxqp``, ``qrqp``.
    options : dict, optional
        Plugin options (merged over quiet defaults).
    """

    def __init__(self, n: int, m: int, plugin: str = "daqp", options: dict | None = None):
        if plugin not in QP_PLUGINS:
            raise ValueError(f"unknown QP plugin {plugin!r} (choose from {', '.join(QP_PLUGINS)})")
        self.n, self.m, self.plugin = int(n), int(m), plugin
        opts = {"error_on_fail": False, "verbose": False}
        quiet = {"qpoases": {"printLevel": "none", "nWSR": QPOASES_NWSR_PER_DIM * (self.n + self.m)},
                 "highs": {"highs": {"output_flag": False, "time_limit": FALLBACK_LIMIT_S}},
                 "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "max_iter": 50000,
                                   "polishing": True}},
                 "proxqp": {"proxqp": {"backend": "dense", "eps_abs": 1e-9}},
                 "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
                 "daqp": {"daqp": {"iter_limit": 5000, "primal_tol": 1e-9}}}
        opts.update(quiet.get(plugin, {}))
        opts.update(options or {})
        self.options = opts             # as built (plugin options included)
        sp = {"h": ca.Sparsity.dense(self.n, self.n), "a": ca.Sparsity.dense(self.m, self.n)}
        with _quiet_stdout(plugin == "qpoases"):      # qpOASES prints its licence banner at construction
            self._solver = ca.conic(f"seek_qp_{plugin}", plugin, sp, opts)
        self.name = plugin
        self._buf = None

    def _buffers(self):
        """casadi's zero-copy evaluation buffer (``Function.buffer``): numpy arrays the solver reads and
        writes in place, so numeric data never goes through ``casadi.DM`` (0.2 us per entry)."""
        if self._buf is None:
            f = self._solver
            buf, run = f.buffer()
            ins = {f.name_in(i): np.zeros(f.nnz_in(i)) for i in range(f.n_in())}
            outs = {f.name_out(i): np.zeros(f.nnz_out(i)) for i in range(f.n_out())}
            for i in range(f.n_in()):
                buf.set_arg(i, memoryview(ins[f.name_in(i)]))
            for i in range(f.n_out()):
                buf.set_res(i, memoryview(outs[f.name_out(i)]))
            self._buf = (buf, run, ins, outs)
        return self._buf

    def _solve_numpy(self, H, g, A, lba, uba, lbx, ubx, x0=None) -> QPSolution:
        """:meth:`solve` for numpy ``H`` (n, n) and ``A`` (m, n), through :meth:`_buffers`."""
        with _quiet_stdout(self.plugin == "qpoases"):   # qpOASES prints its banner when its memory is made
            return self._solve_buffers(H, g, A, lba, uba, lbx, ubx, x0)

    def _solve_buffers(self, H, g, A, lba, uba, lbx, ubx, x0):
        buf, run, ins, outs = self._buffers()
        ins["h"].reshape(self.n, self.n, order="F")[:] = H
        ins["a"].reshape(self.m, self.n, order="F")[:] = A
        for k, v in (("g", g), ("lba", lba), ("uba", uba), ("lbx", lbx), ("ubx", ubx)):
            ins[k][:] = np.asarray(v, dtype=float).ravel()
        ins["x0"][:] = 0.0 if x0 is None else np.nan_to_num(np.asarray(x0, dtype=float).ravel())
        t0, c0 = time.perf_counter(), time.process_time()
        for o in outs.values():
            o[:] = np.nan
        try:
            run()
            st = buf.stats()
            raw, ok = st.get("return_status", st.get("unified_return_status", "?")), bool(st.get("success", False))
        except RuntimeError as exc:       # ill-posed data or a solver crash: numerical trouble, not a proof
            raw, ok = f"error: {str(exc).splitlines()[-1]}", False
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x = outs["x"].copy()
        ok = ok and bool(np.all(np.isfinite(x)))
        outcome = classify_status(self.plugin, raw, ok)
        if outcome is QPStatus.OPTIMAL and not np.all(np.isfinite(x)):
            outcome = QPStatus.NUMERICAL
        return QPSolution(x, outs["lam_a"].copy(), outs["lam_x"].copy(), outcome is QPStatus.OPTIMAL, str(raw),
                          dt, dc, outcome, self.plugin)

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None) -> QPSolution:
        """Solve with numeric data: ``H``, ``A`` as numpy arrays (zero-copy buffers) or :class:`casadi.DM`;
        ``x0``/``lam_*0`` warm-start plugins that use them."""
        if isinstance(H, np.ndarray) and isinstance(A, np.ndarray) and lam_a0 is None and lam_x0 is None:
            return self._solve_numpy(H, g, A, lba, uba, lbx, ubx, x0)
        args = dict(h=H, g=g, a=A, lba=lba, uba=uba, lbx=lbx, ubx=ubx)
        if x0 is not None:
            args["x0"] = x0
        if lam_a0 is not None:
            args["lam_a0"] = lam_a0
        if lam_x0 is not None:
            args["lam_x0"] = lam_x0
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            with _quiet_stdout(self.plugin == "qpoases"):
                res = self._solver(**args)
            st = self._solver.stats()
            raw, ok = st.get("return_status", st.get("unified_return_status", "?")), bool(st.get("success", False))
        except RuntimeError as exc:       # ill-posed data or a solver crash: numerical trouble, not a proof
            res, raw, ok = {"x": np.nan, "lam_a": np.nan, "lam_x": np.nan}, f"error: {str(exc).splitlines()[-1]}", False
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x = _nan_safe(res["x"], self.n)
        ok = ok and bool(np.all(np.isfinite(x)))
        outcome = classify_status(self.plugin, raw, ok)
        if outcome is QPStatus.OPTIMAL and not np.all(np.isfinite(x)):
            outcome = QPStatus.NUMERICAL
        return QPSolution(x, _nan_safe(res["lam_a"], self.m), _nan_safe(res["lam_x"], self.n),
                          outcome is QPStatus.OPTIMAL, str(raw), dt, dc, outcome, self.plugin)


class IpoptQP:
    """The same dense QP as an ``Opti`` problem solved by Ipopt, exported once with
    ``opti.to_function`` (the general NLP path; QP structure declared to Ipopt)."""

    def __init__(self, n: int, m: int, options: dict | None = None):
        self.n, self.m, self.name = int(n), int(m), "ipopt"
        opti = ca.Opti()
        x = opti.variable(self.n)
        H, g = opti.parameter(self.n, self.n), opti.parameter(self.n)
        A = opti.parameter(self.m, self.n)
        lba, uba = opti.parameter(self.m), opti.parameter(self.m)
        lbx, ubx = opti.parameter(self.n), opti.parameter(self.n)
        opti.minimize(0.5 * ca.bilin(H, x, x) + ca.dot(g, x))
        opti.subject_to(opti.bounded(lba, A @ x, uba))
        opti.subject_to(opti.bounded(lbx, x, ubx))
        ipopt = {"print_level": 0, "sb": "yes", "hessian_constant": "yes", "jac_c_constant": "yes",
                 "jac_d_constant": "yes", "tol": 1e-9, "max_iter": 500, "mu_strategy": "adaptive"}
        ipopt.update(options or {})
        opti.solver("ipopt", {"print_time": False, "error_on_fail": False}, ipopt)
        self._f = opti.to_function("seek_qp_ipopt", [H, g, A, lba, uba, lbx, ubx, x], [x, opti.lam_g])

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None) -> QPSolution:
        lbx, ubx = np.asarray(lbx, float), np.asarray(ubx, float)
        x0 = np.clip(np.zeros(self.n) if x0 is None else np.asarray(x0, float), lbx, ubx)
        lba, uba = np.asarray(lba, float), np.asarray(uba, float)
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            x, lam = self._f(H, g, A, lba, uba, lbx, ubx, x0)
            st = self._f.stats()
            status = str(st.get("return_status", "?"))
            ok = bool(st.get("success", False))
        except RuntimeError as exc:  # ill-posed data (e.g. lb > ub)
            x, lam, status, ok = np.full(self.n, np.nan), np.full(2 * self.m, np.nan), str(exc)[:80], False
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        x = _nan_safe(x, self.n)
        lam = np.asarray(lam, float).ravel()
        ok = ok and bool(np.all(np.isfinite(x)))
        return QPSolution(x, lam[:self.m] if lam.size >= self.m else np.full(self.m, np.nan),
                          np.zeros(self.n), ok, status, dt, dc, classify_status("ipopt", status, ok), "ipopt")


def constraint_violation(A: np.ndarray, x: np.ndarray, lba, uba, lbx, ubx, abs_A=None) -> float:
    """Largest violation of ``lba <= A x <= uba, lbx <= x <= ubx`` by ``x``, each row relative to the
    size of the terms it sums (``max(1, sum_j |a_ij x_j|)``: the cancellation level); ``inf`` for a
    non-finite ``x``.  Re-checks a solver's answer against the data (never trust a status alone).
    ``abs_A``: ``|A|`` when the caller keeps it (checks of many answers on one matrix)."""
    if not np.all(np.isfinite(x)):
        return float("inf")
    return violation_of(A @ x, (np.abs(A) if abs_A is None else abs_A) @ np.abs(x), x, lba, uba, lbx, ubx)


def violation_of(ax, size, x, lba, uba, lbx, ubx) -> float:
    """:func:`constraint_violation` from the row products ``ax = A x`` and their term sizes
    ``size = |A| |x|`` (formed by the caller, e.g. :class:`seekopt.design.qp_rows.SeekRows`)."""
    scale = np.maximum(1.0, size)
    v = np.concatenate([(lba - ax) / scale, (ax - uba) / scale, lbx - x, x - ubx])
    v = v[np.isfinite(v)]
    return float(max(np.max(v), 0.0)) if v.size else 0.0


def make_qp_solver(n: int, m: int, solver: str = DAQP_PKG, options: dict | None = None, prox_retry: bool = True):
    """:class:`DaqpQP` for ``solver="daqp_pkg"`` (and, proximal, ``"daqp_prox"``), :class:`PiqpQP` for ``"piqp"``
    (:class:`ImportError` without the package), :class:`IpoptQP` for ``"ipopt"``, else :class:`ConicQP` with that plugin.
    ``prox_retry``: :class:`DaqpQP`'s own proximal retry of a cycling solve (``daqp_pkg`` only)."""
    if solver == PIQP:
        return PiqpQP(n, m, options)
    if solver == DAQP_PKG:
        return DaqpQP(n, m, options, prox_retry=prox_retry)
    if solver == DAQP_PROX:
        return DaqpQP(n, m, dict(PROX_OPTIONS, **(options or {})), name=DAQP_PROX)
    return IpoptQP(n, m, options) if solver == "ipopt" else ConicQP(n, m, solver, options)


class SolverChain:
    """A primary QP solver and fallbacks for one problem size, each built on first use.

    :meth:`solve` returns the first ``optimal`` answer that passes ``check`` (the caller's
    constraint re-check: a status is never trusted alone); an answer that fails it counts as
    ``numerical``.  ``infeasible`` from a solver ends the chain (the solver proved it) -- except an
    ``infeasible`` whose own multipliers failed the Farkas check (``proven is False``, :class:`DaqpQP`):
    with ``prove=True`` the next solvers are asked (a second opinion); with ``prove=False`` it is
    returned as it is (the caller proves it, e.g. :class:`seekopt.design.working_set.WorkingSetQP`).
    Any other outcome (``numerical``, ``iteration_limit``) moves on to the next solver.  When every
    solver has failed without a proof, the answer is the last one, with its outcome (never
    ``infeasible``).

    Parameters
    ----------
    n, m : int
    names : sequence of str
        Primary first, e.g. ``("daqp", "qpoases")``.
    options : dict, optional
        ``{solver name: options}``.
    builds : callable, optional
        Called with the solver name at each construction (build counting by the owner).
    """

    def __init__(self, n: int, m: int, names, options: dict | None = None, builds=None):
        self.n, self.m = int(n), int(m)
        self.names = tuple(dict.fromkeys(names))
        self.options = options or {}
        self._solvers: dict = {}
        self._on_build = builds
        self.get(self.names[0])          # the primary is built with the structure

    @property
    def name(self) -> str:
        return self.names[0]

    @property
    def warm_duals(self) -> bool:
        """The primary takes a starting active set (``lam0`` of :meth:`solve`)."""
        return bool(getattr(self.get(self.names[0]), "warm_duals", False))

    def get(self, name: str):
        if name not in self._solvers:
            # the package's proximal retry of a cycling solve is left to PIQP when PIQP is asked next (it
            # answers those QPs in 0.02-0.2 s where the retry took up to 19 s CPU and failed)
            i = self.names.index(name) if name in self.names else -1
            nxt = self.names[i + 1] if 0 <= i < len(self.names) - 1 else None
            kw = {"prox_retry": False} if name == DAQP_PKG and nxt == PIQP else {}
            self._solvers[name] = make_qp_solver(self.n, self.m, name, self.options.get(name), **kw)
            if self._on_build is not None:
                self._on_build(name)
        return self._solvers[name]

    def _padded(self, solver, data, x0) -> QPSolution:
        """A solver built for ``self.m`` rows on data with fewer: free zero rows appended, multipliers
        trimmed back."""
        H, g, A, lba, uba, lbx, ubx = data
        k = len(A)
        Ap = np.zeros((self.m, A.shape[1]))
        Ap[:k] = A
        lp = np.full(self.m, -np.inf); lp[:k] = lba
        up = np.full(self.m, np.inf); up[:k] = uba
        sol = solver.solve(H, g, Ap, lp, up, lbx, ubx, x0=x0)
        sol.lam_a = sol.lam_a[:k]
        return sol

    def solve(self, *data, x0=None, check=None, start: int = 0, lam0=None, prove: bool = True) -> QPSolution:
        """Solve ``data = (H, g, A, lba, uba, lbx, ubx)``; ``x0`` warm-starts the first solver only, as
        ``lam0 = (lam_a0, lam_x0)`` (a starting active set) does a first solver that takes one;
        ``check(x)`` returns a note (str) when ``x`` fails the caller's re-check, else ''; ``start``
        skips the first solvers of the chain (a second opinion); ``prove``: see the class."""
        attempts, sol, wall, cpu = [], None, 0.0, 0.0
        for i, name in enumerate(self.names[start:]):
            solver = self.get(name)
            if i == 0 and lam0 is not None and getattr(solver, "warm_duals", False):
                sol = solver.solve(*data, x0=x0, lam_a0=lam0[0], lam_x0=lam0[1])
            elif name not in ANY_SIZE and isinstance(data[2], np.ndarray) and len(data[2]) < self.m:
                sol = self._padded(solver, data, x0 if i == 0 else None)
            else:
                sol = solver.solve(*data, x0=x0 if i == 0 else None)
            wall, cpu = wall + sol.solve_time_s, cpu + sol.cpu_time_s
            if sol.outcome is QPStatus.OPTIMAL and check is not None:
                note = check(sol.x)
                if note:
                    sol.success, sol.outcome, sol.status = False, QPStatus.NUMERICAL, f"{sol.status}; {note}"
            unproven = sol.outcome is QPStatus.INFEASIBLE and sol.proven is False
            attempts.append((name, sol.status + (" (unverified)" if unproven else ""), sol.outcome.value))
            if sol.outcome is QPStatus.OPTIMAL or (sol.outcome is QPStatus.INFEASIBLE and not (prove and unproven)):
                break
        if prove and sol.outcome is QPStatus.INFEASIBLE and sol.proven is False:
            sol.outcome, sol.status = QPStatus.NUMERICAL, f"{sol.status}; infeasible without a verified certificate"
        sol.attempts, sol.solve_time_s, sol.cpu_time_s = attempts, wall, cpu
        return sol
