"""Dense QP solvers for seek design, with every solver status classified.

All solvers take ``min 1/2 x'Hx + g'x  s.t. lba <= A x <= uba, lbx <= x <= ubx`` with ``H`` and
``A`` as :class:`casadi.DM` (converted once by the caller, never per solve):

* :class:`DaqpQP` (``daqp_pkg``, the default) -- the ``daqp`` package (PyPI) called directly: the
  same dual active-set algorithm as casadi's daqp plugin, 2x less CPU on the design QPs, and it takes
  a starting active set (``lam_a0``/``lam_x0``: the previous length's or round's multipliers); its
  "infeasible" carries ``proven`` (its multipliers checked as a Farkas certificate on the data);
* :class:`ConicQP` -- ``casadi.conic`` with a QP plugin (``daqp``, ``qpoases``, ``highs``,
  ``osqp``, ``proxqp``, ``qrqp``), built once for a fixed size;
* :class:`IpoptQP` -- the same problem as an ``Opti`` + Ipopt NLP (``hessian_constant``,
  ``jac_c_constant``, ``jac_d_constant`` = yes) exported once with ``opti.to_function``;
* :class:`SolverChain` -- a primary solver and fallbacks, built lazily: a solve that ends in
  numerical trouble (daqp cycling, status -2), an iteration limit or an answer that fails the
  caller's constraint re-check is retried with the next solver before anything is called
  infeasible.

Every raw status is mapped to one :class:`QPStatus` (:func:`classify_status`): ``optimal``,
``infeasible`` (the solver proved it), ``numerical`` (trouble: proves nothing) or
``iteration_limit`` (proves nothing).  A solution is only used when it is ``optimal``.
"""
from __future__ import annotations

import contextlib
import os
import sys
import time
from dataclasses import dataclass, field
from enum import Enum

import casadi as ca
import numpy as np

from seekopt.design.certificates import farkas_certificate, proves_infeasible  # noqa: F401

__all__ = ["QPStatus", "classify_status", "QPSolution", "ConicQP", "DaqpQP", "IpoptQP", "make_qp_solver",
           "SolverChain", "QP_PLUGINS", "DAQP_PKG", "QP_SOLVERS", "dm", "kkt_holds", "proves_infeasible", "farkas_certificate",
           "constraint_violation"]

#: ``casadi.conic`` plugins the designer accepts.
QP_PLUGINS = ("daqp", "qpoases", "highs", "osqp", "proxqp", "qrqp")
#: The ``daqp`` package called directly (:class:`DaqpQP`).
DAQP_PKG = "daqp_pkg"
#: Every solver name :func:`make_qp_solver` accepts.
QP_SOLVERS = (DAQP_PKG,) + QP_PLUGINS + ("ipopt",)


class QPStatus(str, Enum):
    """Outcome of one QP solve."""

    OPTIMAL = "optimal"
    INFEASIBLE = "infeasible"
    NUMERICAL = "numerical"
    ITERATION_LIMIT = "iteration_limit"


#: daqp exit flags (daqp ``api.h``): 1 optimal, 2 soft optimal, -1 infeasible, -2 cycling,
#: -3 unbounded, -4 iteration limit, -5 non-convex, -6 overdetermined initial active set.
_DAQP = {1: QPStatus.OPTIMAL, 2: QPStatus.OPTIMAL, -1: QPStatus.INFEASIBLE, -2: QPStatus.NUMERICAL,
         -3: QPStatus.NUMERICAL, -4: QPStatus.ITERATION_LIMIT, -5: QPStatus.NUMERICAL, -6: QPStatus.NUMERICAL}
#: Text statuses of the other solvers (lower case, substring match, first hit wins).
_TEXT = (("primal infeasible", QPStatus.INFEASIBLE), ("infeasib", QPStatus.INFEASIBLE),
         ("max_iter", QPStatus.ITERATION_LIMIT), ("maximum iterations", QPStatus.ITERATION_LIMIT),
         ("iteration limit", QPStatus.ITERATION_LIMIT), ("maximum number of working set", QPStatus.ITERATION_LIMIT),
         ("maximum_iterations", QPStatus.ITERATION_LIMIT), ("time limit", QPStatus.ITERATION_LIMIT))


def classify_status(solver: str, raw, success: bool) -> QPStatus:
    """Map a solver's raw ``return_status`` (and casadi's ``success``) to a :class:`QPStatus`.

    daqp reports an integer exit flag (see ``_DAQP``; -2 is cycling: numerical trouble, not
    infeasibility).  The other plugins report text: infeasibility only when the text says so,
    iteration and time limits as ``iteration_limit``; anything else that is not a success is
    ``numerical``.  Unknown statuses are never taken as proof of infeasibility.
    """
    text = str(raw).strip()
    if solver in ("daqp", DAQP_PKG):
        try:
            return _DAQP.get(int(float(text)), QPStatus.NUMERICAL)
        except ValueError:
            pass
    if success:
        return QPStatus.OPTIMAL
    low = text.lower()
    if "inaccurate" in low:
        return QPStatus.NUMERICAL
    for key, status in _TEXT:
        if key in low:
            return status
    return QPStatus.NUMERICAL


@contextlib.contextmanager
def _quiet_stdout(active: bool = True):
    """Silence the C-level stdout (file descriptor 1) inside the block."""
    if not active:
        yield
        return
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:         # no file descriptor 1 (embedded use): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def dm(a: np.ndarray) -> ca.DM:
    """numpy -> casadi.DM (dense).  Slow for big arrays (~0.1 s per million entries): do it once."""
    a = np.asarray(a, dtype=float)
    return ca.DM(a if a.ndim == 2 else a.reshape(-1, 1))


@dataclass
class QPSolution:
    """Result of one QP solve: ``x``, multipliers, raw status, wall and CPU time [s].

    ``outcome`` is the classified :class:`QPStatus` (derived from ``success``/``status`` when not
    given); ``solver`` the solver that produced it; ``attempts`` the ``(solver, raw status,
    outcome)`` of every solve a :class:`SolverChain` made for this answer.  ``proven``: for an
    ``infeasible`` of a solver that checks its own multipliers (:class:`DaqpQP`), whether they are a
    verified Farkas certificate on the data solved; ``None`` where the solver's status is all there is.
    """

    x: np.ndarray
    lam_a: np.ndarray
    lam_x: np.ndarray
    success: bool
    status: str
    solve_time_s: float
    cpu_time_s: float
    outcome: QPStatus | None = None
    solver: str = ""
    attempts: list = field(default_factory=list)
    proven: bool | None = None

    def __post_init__(self):
        if self.outcome is None:          # raw flags without a solver name: daqp's integer flags
            name = self.solver or ("daqp" if self.status.strip().lstrip("-").isdigit() else "")
            self.outcome = classify_status(name, self.status, self.success)
        if self.outcome is not QPStatus.OPTIMAL:
            self.success = False
        elif not self.success:
            self.outcome = QPStatus.NUMERICAL

    @property
    def infeasible(self) -> bool:
        """The solver proved the problem infeasible."""
        return self.outcome is QPStatus.INFEASIBLE


def _nan_safe(a, n):
    a = np.asarray(a, dtype=float).ravel()
    return a if a.size == n else np.full(n, np.nan)


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
        quiet = {"qpoases": {"printLevel": "none"}, "highs": {"highs": {"output_flag": False}},
                 "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-7, "eps_rel": 1e-7, "max_iter": 50000,
                                   "polishing": True}},
                 "proxqp": {"proxqp": {"backend": "dense", "eps_abs": 1e-9}},
                 "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
                 "daqp": {"daqp": {"iter_limit": 5000, "primal_tol": 1e-9}}}
        opts.update(quiet.get(plugin, {}))
        opts.update(options or {})
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


class DaqpQP:
    """The ``daqp`` package (PyPI) on a dense QP of ``n`` variables and ``m`` rows, called directly.

    Same problem form as :class:`ConicQP`; the bounds go to daqp as its simple bounds, rows and
    variables with ``lb == ub`` as equalities.  Nothing is built per size (daqp sets up its workspace
    per call), so one instance serves any ``m``.

    Warm start: ``lam_a0``/``lam_x0`` (multipliers in casadi's sign convention, e.g. a previous
    answer's mapped to these rows) give daqp its starting active set (``dual_start``: the nonzero
    entries start active).  A warm start that ends in anything but an answer or an infeasibility
    (a linearly dependent starting set: -6; cycling) is retried cold once.  ``x0`` is not used.

    On ``infeasible`` (daqp exit flag -1) the multipliers daqp returns (its Farkas direction, of
    opposite sign to casadi's convention; returned in casadi's) are checked on the data
    (:func:`proves_infeasible`): ``QPSolution.proven`` says whether they prove it.

    Parameters
    ----------
    n, m : int
        Variables and rows (``m`` informative: any row count is accepted).
    options : dict, optional
        daqp settings (``iter_limit``, ``primal_tol``, ``dual_tol``, ...), merged over
        ``iter_limit=5000, primal_tol=1e-9`` (the settings :class:`ConicQP` gives casadi's daqp).
    """

    name = DAQP_PKG
    warm_duals = True

    def __init__(self, n: int, m: int, options: dict | None = None):
        import daqp
        self._daqp = daqp
        self.n, self.m, self.plugin = int(n), int(m), DAQP_PKG
        self.settings = {"iter_limit": 5000, "primal_tol": 1e-9}
        self.settings.update(options or {})
        self.warm_retries = 0           # warm starts that failed and were solved cold (statistics)

    def _call(self, H, f, A, bu, bl, sense, dual0):
        kw = dict(self.settings)
        if dual0 is not None:
            kw["dual_start"] = dual0
        try:
            x, _, flag, info = self._daqp.solve(H, f, A, bu, bl, sense, **kw)
            return np.asarray(x, dtype=float), int(flag), np.asarray(info["lam"], dtype=float)
        except (ValueError, RuntimeError) as exc:      # ill-posed data: numerical trouble, not a proof
            return None, f"error: {exc}", None

    def solve(self, H, g, A, lba, uba, lbx, ubx, x0=None, lam_a0=None, lam_x0=None) -> QPSolution:
        """Solve with numpy data; ``lam_a0``/``lam_x0`` (length ``len(A)``/``n``) start the active set."""
        H = np.ascontiguousarray(H, dtype=float)
        A = np.ascontiguousarray(A, dtype=float)
        n, m = H.shape[0], A.shape[0]
        lba, uba = np.asarray(lba, dtype=float).ravel(), np.asarray(uba, dtype=float).ravel()
        lbx, ubx = np.asarray(lbx, dtype=float).ravel(), np.asarray(ubx, dtype=float).ravel()
        bu, bl = np.concatenate([ubx, uba]), np.concatenate([lbx, lba])
        sense = np.where(bl == bu, 5, 0).astype(np.intc)
        dual0 = None
        if lam_a0 is not None or lam_x0 is not None:
            dual0 = np.concatenate([np.zeros(n) if lam_x0 is None else np.asarray(lam_x0, dtype=float).ravel(),
                                    np.zeros(m) if lam_a0 is None else np.asarray(lam_a0, dtype=float).ravel()])
            dual0 = np.nan_to_num(dual0)
            dual0[sense == 5] = 0.0         # equalities are active from the start anyway
            if not np.any(dual0):
                dual0 = None
        t0, c0 = time.perf_counter(), time.process_time()
        x, flag, lam = self._call(H, np.asarray(g, dtype=float).ravel(), A, bu, bl, sense, dual0)
        if dual0 is not None and (flag not in (1, 2, -1) or (flag in (1, 2) and not kkt_holds(
                H, g, A, lba, uba, lbx, ubx, x, lam[n:], lam[:n]))):
            # daqp has answered a bad starting set with flag 1 and NaN (or a point that is no optimum):
            # a warm answer stands only when it satisfies the optimality conditions, else solved cold
            self.warm_retries += 1
            x, flag, lam = self._call(H, np.asarray(g, dtype=float).ravel(), A, bu, bl, sense, None)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        raw = str(flag)
        if x is None:
            x, lam, outcome = np.full(n, np.nan), np.full(n + m, np.nan), QPStatus.NUMERICAL
        else:
            outcome = classify_status(DAQP_PKG, raw, flag in (1, 2))
        ok = outcome is QPStatus.OPTIMAL and bool(np.all(np.isfinite(x)))
        if outcome is QPStatus.OPTIMAL and not ok:
            outcome = QPStatus.NUMERICAL
        proven = None
        if outcome is QPStatus.INFEASIBLE:
            lam = -lam                      # daqp's Farkas direction -> casadi's sign convention
            proven = bool(proves_infeasible(A, lba, uba, lbx, ubx, lam[n:]))
            if not proven:          # daqp 0.11 returns no usable multipliers with most "infeasible"s
                lam = np.zeros(n + m)
        return QPSolution(x, lam[n:].copy(), lam[:n].copy(), ok, raw, dt, dc, outcome, DAQP_PKG, proven=proven)


def kkt_holds(H, g, A, lba, uba, lbx, ubx, x, lam_a, lam_x, tol: float = 1e-6) -> bool:
    """True when ``x`` and the multipliers (casadi's sign convention: > 0 upper bound active, < 0 lower)
    satisfy the optimality conditions of ``min 1/2 x'Hx + g'x, lba <= A x <= uba, lbx <= x <= ubx``
    (a convex QP: then ``x`` is its optimum) -- stationarity ``H x + g + A' lam_a + lam_x = 0``, primal
    feasibility and complementarity, each relative to the size of its terms (``tol``)."""
    if x is None or lam_a is None or not (np.all(np.isfinite(x)) and np.all(np.isfinite(lam_a))
                                          and np.all(np.isfinite(lam_x))):
        return False
    Hx, At = H @ x, A.T @ lam_a
    r = Hx + g + At + lam_x
    scale = 1.0 + np.abs(Hx) + np.abs(g) + np.abs(A).T @ np.abs(lam_a) + np.abs(lam_x)
    if np.any(np.abs(r) > tol * scale):
        return False
    ax = A @ x
    row = 1.0 + np.abs(A) @ np.abs(x)
    if np.any(ax < lba - tol * row) or np.any(ax > uba + tol * row) or np.any(x < lbx - tol) or np.any(x > ubx + tol):
        return False
    big = tol * (1.0 + float(np.max(np.abs(np.r_[lam_a, lam_x]), initial=0.0)))
    up, lo = lam_a > big, lam_a < -big
    if np.any(np.abs(ax[up] - uba[up]) > tol * row[up]) or np.any(np.abs(ax[lo] - lba[lo]) > tol * row[lo]):
        return False
    up, lo = lam_x > big, lam_x < -big
    return not (np.any(np.abs(x[up] - ubx[up]) > tol) or np.any(np.abs(x[lo] - lbx[lo]) > tol))


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
    ax = A @ x
    scale = np.maximum(1.0, (np.abs(A) if abs_A is None else abs_A) @ np.abs(x))
    v = np.concatenate([(lba - ax) / scale, (ax - uba) / scale, lbx - x, x - ubx])
    v = v[np.isfinite(v)]
    return float(max(np.max(v), 0.0)) if v.size else 0.0


def make_qp_solver(n: int, m: int, solver: str = DAQP_PKG, options: dict | None = None):
    """:class:`DaqpQP` for ``solver="daqp_pkg"``, :class:`IpoptQP` for ``"ipopt"``, else :class:`ConicQP`
    with that plugin."""
    if solver == DAQP_PKG:
        return DaqpQP(n, m, options)
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
    def sized(self) -> bool:
        """The primary is built for a fixed row count (casadi): callers pad rows to a few sizes."""
        return self.names[0] != DAQP_PKG

    @property
    def warm_duals(self) -> bool:
        """The primary takes a starting active set (``lam0`` of :meth:`solve`)."""
        return bool(getattr(self.get(self.names[0]), "warm_duals", False))

    def get(self, name: str):
        if name not in self._solvers:
            self._solvers[name] = make_qp_solver(self.n, self.m, name, self.options.get(name))
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
            elif name != DAQP_PKG and isinstance(data[2], np.ndarray) and len(data[2]) < self.m:
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
