"""Solve a seek QP on its free variables and a working set of its rows, adding back every row the
answer violates.

Most of a seek QP never binds: variables past the seek (``u_ff``, ``r`` for ``k >= N``) are pinned
to zero, settle-band rows before the seek ends are free, and of the band and current rows of 22
robust-set plants only a few dozen touch their limits at the optimum.  :class:`WorkingSetQP` solves
the QP of one :class:`seekopt.design.qp.SeekQP` structure with

* the **fixed variables out** (``lbx = ubx``: the samples past the seek);
* the **free rows dropped** (both bounds infinite);
* the **other rows screened**: the working set starts from the equality rows, the rows that bound
  the last answer of this structure (the bisection's previous length, or the previous seek length
  of a sweep: the warm start of the active set) and the rows the warm start ``x0`` violates or comes
  within ``screen_margin`` of; the reduced QP is solved, every row the answer violates (by more than
  ``add_tol`` in the row's scaled units) is added back, and the QP re-solved, until the answer
  satisfies every row.

An answer that satisfies every dropped row is the full QP's optimum (a convex QP's optimum that
satisfies the dropped rows is optimal with them).  A reduced QP without a solution proves the full
QP has none (it has fewer rows) -- but only a *verified* proof counts: the primary's row multipliers
must pass the Farkas check :func:`seekopt.design.solvers.proves_infeasible` (daqp has reported -1 on
reduced QPs that qpOASES and HiGHS solve; its multipliers then fail the check).  Without that, a
length the answer rests on (``confirm=True``) gets, on a structure of up to 3 plants, daqp's own phase-1 QP on
the reduced rows (:func:`seekopt.design.certificates.phase1_daqp`; unverified, the rows it names seed
the least squares), else the next solver's multipliers and least squares, then a phase-1 LP on the reduced rows
(:func:`seekopt.design.solvers.farkas_certificate`, HiGHS; first the rows daqp's multipliers name,
then the whole working set) whose duals must pass the same check; only when that fails too does
the full QP decide (the primary's and fallbacks' trust level without the working set).  A search
step (``confirm=False``) returns an unverified "infeasible" marked unconfirmed.

Reduced problems are solved by the primary solver of the chain: the ``daqp`` package
(:class:`seekopt.design.solvers.DaqpQP`, the default) takes any row count and a starting active
set -- each solve starts from the active set of this structure's last answer (the previous round of
the same length, else the previous length of the search or the previous seek), mapped to the
reduced rows and variables; its "infeasible" stands only with its multipliers verified as a
Farkas certificate (``QPSolution.proven``), else as above.  A casadi primary is solved through
casadi's zero-copy buffers (:meth:`seekopt.design.solvers.ConicQP.solve`), one solver chain per
(free variables, row bucket), row counts padded to a few buckets (powers of two).  When the working set grows past
``max_fraction`` of the rows, or a reduced solve ends without an answer or a proof, the full QP is
solved as without the working set.
"""
from __future__ import annotations

import numpy as np

from seekopt.design.certificates import nnls_certificate, phase1_daqp, phase1_lp
from seekopt.design.solvers import QPSolution, QPStatus, SolverChain, farkas_certificate, proves_infeasible

__all__ = ["WorkingSetQP"]


class WorkingSetQP:
    """Working-set solver for one seek-QP structure (built once per structure, reused).

    Parameters
    ----------
    qp : SeekQP
    chain : callable
        ``(n, m) -> SolverChain`` for a reduced problem of ``n`` variables and ``m`` rows.
    screen_margin : float
        Rows within this distance of a bound at the warm start join the first working set [row units:
        bands for band rows, ``Imax`` for current rows].
    add_tol : float
        Violation beyond which a dropped row is added back [row units].
    max_rounds : int
    max_fraction : float
        Working sets larger than this fraction of the rows go to the full QP.
    max_add : float
        At most ``max_add * n`` violated rows (the most violated) join per round.
    near : float
        With the violated rows, rows within ``near`` of their bound join too (fewer rounds).
    pad : bool
        Pad the reduced data's rows to the chain's size (casadi solvers are built per size); False for a
        primary that takes any size (:class:`seekopt.design.solvers.DaqpQP`), whose padding rows would
        only cost (the chain pads for its casadi fallbacks itself).
    phase1_first : bool
        Prove a reduced "infeasible" of the primary with :func:`~seekopt.design.certificates.phase1_daqp`
        before asking the next solver (the designer: sets of up to 3 plants; on the 3-plant robust set of
        ``seekopt design --robust`` K = 1000 it proved in 0.2 s what casadi's re-solve, the least squares and
        scipy.optimize's import took 0.45 s for; one-plant structures: the nominal K = 50-1000 lengths' proofs
        took 4-110 ms, 11 of 13 proven, where the re-solve and least squares took 20-280 ms; on a
        22-plant set's working sets the phase-1 QP took 2-5x the re-solve and least squares).
    warm : bool
        Start each solve from the active set of the last answer of this structure (the previous round
        of this length, else the previous length's or seek's), mapped to the reduced rows and variables,
        when the primary takes one (``SolverChain.warm_duals``).
    """

    def __init__(self, qp, chain, *, screen_margin: float = 0.02, add_tol: float = 1e-7, max_rounds: int = 40,
                 max_fraction: float = 0.5, max_add: float = 1.0, near: float = 0.02, pad: bool = True,
                 warm: bool = True, phase1_first: bool = False):
        self.qp, self._make_chain = qp, chain
        self.pad, self.warm, self.phase1_first = bool(pad), bool(warm), bool(phase1_first)
        self._lam = None                         # (lam_a, lam_x) of the last answer, full rows and variables
        self.screen_margin, self.add_tol, self.near = float(screen_margin), float(add_tol), float(near)
        self.max_rounds, self.max_fraction, self.max_add = int(max_rounds), float(max_fraction), float(max_add)
        self._chains: dict = {}
        self._hint = np.zeros(0, dtype=int)      # rows that bound the last answer
        self._unproven: dict = {}                # problem -> working set of its unconfirmed "infeasible"
        self.rounds = 0                          # reduced solves (statistics)
        self.full_solves = 0
        self.proofs = 0                          # reduced 'infeasible' with a verified certificate
        self.lp_proofs = 0                       # reduced 'infeasible' proven by the phase-1 LP
        self.phase1_proofs = 0                   # reduced 'infeasible' proven by daqp's phase-1 QP
        self.second_opinions = 0                 # reduced 'infeasible' without one: fallbacks asked
        self.rechecks = 0                        # DaqpQP 'infeasible' re-solved by the chain's next solver

    def _chain(self, n: int, m: int, step: int | None = None) -> SolverChain:
        """Solver chain for ``n`` variables and ``m`` rows, padded to a power of two (``step``: to a
        multiple of ``step`` rows instead: the whole-row solves, whose padding rows daqp would carry
        through every iteration).  Without ``self.pad`` the data keep their exact row count (the chain
        pads it for its casadi solvers only)."""
        if step:
            bucket = -(-m // step) * step
        else:
            bucket = 32
            while bucket < m:
                bucket *= 2
        key = (n, bucket)
        if key not in self._chains:
            self._chains[key] = self._make_chain(n, bucket)
        return self._chains[key]

    def solve(self, K: float, nseek: int, beta, gamma: float, hf_tol, slew_a_per_s=None, x0=None,
              check=None, confirm: bool = True, screen: bool = True,
              nominal_from: int | None = None, second_opinion: bool = False) -> QPSolution:
        """The QP of ``SeekQP.data(K, nseek, beta, gamma, hf_tol, slew_a_per_s, nominal_from)``; ``check(x, A)``
        (full-problem re-check, returns a note or '') as in :meth:`SolverChain.solve`.

        ``confirm=False``: a reduced "infeasible" of the primary that fails the Farkas check is
        returned as it is, marked ``sol.unconfirmed = True`` (a search step; the caller confirms the
        lengths its answer rests on with ``confirm=True``: the full QP decides).  With
        ``second_opinion=True`` the chain's next solver re-solves that reduced QP first, and its answer,
        if it finds one, continues the rounds (a search step whose "infeasible" nothing will confirm:
        the nominal-first refinement; on the long robust seeks' reduced QPs, cond(H) ~ 3e11, the ``daqp``
        package called feasible QPs infeasible there, which PIQP solved in 0.08 s).

        ``screen=False``: no row screening -- one solve of the QP on its free variables with every
        row that has a bound (the fixed variables substituted, the free rows dropped).  That QP is the
        full QP without what cannot change its answer (same optimum, same feasibility), so its answer
        and its solvers' "infeasible" stand as the full QP's would (nominal structures of 1300-1800
        rows: 2-3x less CPU than the full QP, where the pinned samples past the seek are a third of
        the variables)."""
        qp = self.qp
        g, lba, uba, lbx, ubx = qp.bounds(K, nseek, beta, gamma, hf_tol, slew_a_per_s, nominal_from)
        H, A = qp.hessian(K), qp.row_operator(K)       # A: rows as an operator (seekopt.design.qp_rows)
        fv = np.flatnonzero(lbx < ubx)                          # free variables
        xfix = np.where(lbx == ubx, lbx, 0.0)
        cand = np.flatnonzero(np.isfinite(lba) | np.isfinite(uba))
        lc, uc = lba[cand], uba[cand]
        Hr = H[np.ix_(fv, fv)]
        gr = g[fv] + H[np.ix_(fv, np.flatnonzero(lbx == ubx))] @ xfix[lbx == ubx]
        lbr, ubr = lbx[fv], ubx[fv]
        work = np.zeros(len(cand), dtype=bool)
        work |= lc == uc                                       # equalities
        if not screen:
            work[:] = True
        work |= np.isin(cand, self._hint)                      # rows that bound the last answer
        key = (float(K), int(nseek), beta, float(gamma), hf_tol, slew_a_per_s)
        seen = self._unproven.pop(key, None)
        if seen is not None and seen.shape == work.shape:     # confirming a search step's "infeasible":
            work |= seen                                       # start from the rows it ended on
        x = None
        if x0 is not None and np.all(np.isfinite(x0)):
            x = np.clip(x0, lbx, ubx)
            r = A.matvec(x)[cand]       # not A[cand] @ x: that copies the whole matrix
            self._add(work, np.maximum(r - uc, lc - r) + self.screen_margin, len(fv))
        wall = cpu = 0.0
        attempts = []
        A_fixed = A.matvec(xfix) if np.any(xfix) else None     # xfix is zero on the free variables
        why = "rounds"
        for _ in range(self.max_rounds):
            if screen and work.sum() > self.max_fraction * len(cand):
                why = f"working set {work.sum()} of {len(cand)} rows"
                break
            rows = np.flatnonzero(work)
            chain = self._chain(len(fv), len(rows), None if screen else 64)
            mb = chain.m if self.pad else len(rows)
            Ar = np.zeros((mb, len(fv)))
            Ar[:len(rows)] = A.take(cand[rows], fv)
            shift = 0.0 if A_fixed is None else A_fixed[cand[rows]]
            lr = np.full(mb, -np.inf); lr[:len(rows)] = lc[rows] - shift
            ur = np.full(mb, np.inf); ur[:len(rows)] = uc[rows] - shift
            data = (Hr, gr, Ar, lr, ur, lbr, ubr)
            xr0 = None if x is None else x[fv]
            lam0 = None
            if self._lam is not None and self.warm and chain.warm_duals:
                la = np.zeros(mb)
                la[:len(rows)] = self._lam[0][cand[rows]]
                lam0 = (la, self._lam[1][fv])
            sol = chain.solve(*data, x0=xr0, lam0=lam0, prove=False)
            self.rounds += 1
            wall, cpu = wall + sol.solve_time_s, cpu + sol.cpu_time_s
            attempts += sol.attempts
            if (second_opinion and not confirm and screen and sol.outcome is QPStatus.INFEASIBLE
                    and sol.proven is False and sol.solver == chain.name and len(chain.names) > 1):
                alt = chain.solve(*data, start=1, prove=False)      # the next solver's verdict first
                wall, cpu = wall + alt.solve_time_s, cpu + alt.cpu_time_s
                attempts += alt.attempts
                if alt.outcome is QPStatus.OPTIMAL:
                    sol = alt
            if sol.outcome is QPStatus.INFEASIBLE:
                # a fallback's "infeasible" (asked after the primary's trouble), or a casadi solver's on
                # every row, stands at that solver's trust as before; the primary's needs a verified
                # certificate on a subset of the rows (DaqpQP checks its own multipliers: ``proven``)
                if sol.proven is None and (sol.solver != chain.name or not screen):
                    return self._done(self._full(sol, fv, xfix, rows, cand), attempts, wall, cpu)
                proved = sol.proven if sol.proven is not None else proves_infeasible(Ar, lr, ur, lbr, ubr, sol.lam_a)
                if proved:
                    self.proofs += 1
                    return self._done(self._full(sol, fv, xfix, rows, cand), attempts, wall, cpu)
                if not confirm:
                    self._unproven = {key: work.copy()}
                    out = self._full(sol, fv, xfix, rows, cand)
                    out.unconfirmed = True
                    return self._done(out, attempts, wall, cpu)
                if screen and sol.proven is False and self.phase1_first:
                    # first the package's own phase-1 QP on the working set (its multipliers verified as
                    # a Farkas certificate): about one daqp solve, where the next solver's re-solve and
                    # the least squares on the rows it named took 1.5-3 (and scipy's import, cold)
                    k = len(rows)
                    lam, named = phase1_daqp(Ar[:k], lr[:k], ur[:k], lbr, ubr)
                    if lam is None and named is not None and np.any(named):
                        # not verified: the rows its multipliers name seed the least squares (with cutting
                        # planes), as the next solver's would
                        lam = nnls_certificate(Ar[:k], lr[:k], ur[:k], lbr, ubr, np.flatnonzero(named),
                                               cap=max(Ar.shape[1] // 2, 10))
                    if lam is not None:
                        self.phase1_proofs += 1
                        sol.lam_a = np.zeros(len(Ar))
                        sol.lam_a[:k] = lam
                        return self._done(self._full(sol, fv, xfix, rows, cand), attempts, wall, cpu)
                if sol.proven is False and len(chain.names) > 1:
                    # DaqpQP: the package returns no usable multipliers with its "infeasible"; the next
                    # solver of the chain (casadi's daqp by default) re-solves this QP: on every row
                    # its agreeing "infeasible" is the re-check (main trusted casadi's daqp alone
                    # there); on a working set its multipliers seed the certificate below
                    self.rechecks += 1
                    sol = chain.solve(*data, start=1, prove=False)
                    wall, cpu = wall + sol.solve_time_s, cpu + sol.cpu_time_s
                    attempts += sol.attempts
                    if sol.outcome is QPStatus.INFEASIBLE and (not screen or (
                            sol.proven is not False and proves_infeasible(Ar, lr, ur, lbr, ubr, sol.lam_a))):
                        self.proofs += screen
                        return self._done(self._full(sol, fv, xfix, rows, cand), attempts, wall, cpu)
                if sol.outcome is QPStatus.INFEASIBLE:
                    # a phase-1 LP on the rows the multipliers name, then on the whole working set: a
                    # verified Farkas certificate on a subset of the rows proves the full QP infeasible
                    # (10-60 ms on the named rows, 0.3-0.5 s on the working set, ~1 s for the full QP)
                    lam = self._certificate(Ar, lr, ur, lbr, ubr, len(rows), sol.lam_a)
                    if lam is not None:
                        self.lp_proofs += 1
                        sol.lam_a = lam
                        return self._done(self._full(sol, fv, xfix, rows, cand), attempts, wall, cpu)
                    # unproven: the full QP decides (the fallbacks on the reduced QP were slower:
                    # qpOASES hit its iteration limit after 1-3 s on robust K = 850)
                    self.second_opinions += 1
                    why = "reduced infeasible without a certificate"
                    break
            if sol.outcome is not QPStatus.OPTIMAL:
                why = f"reduced {sol.outcome.value}"
                break
            x = xfix.copy()
            x[fv] = sol.x
            full = self._full(sol, fv, xfix, rows, cand)
            self._lam = (full.lam_a, full.lam_x)           # the next round's or length's starting active set
            r = A.matvec(x)[cand]
            viol = np.maximum(r - uc, lc - r)
            if not np.any((viol > self.add_tol) & ~work):
                self._hint = cand[rows[np.abs(np.nan_to_num(sol.lam_a[:len(rows)])) > 1e-12]]   # the active set
                if check is not None:
                    note = check(full.x, A)
                    if note:
                        full.success, full.outcome, full.status = False, QPStatus.NUMERICAL, f"{full.status}; {note}"
                        why = note
                        break
                return self._done(full, attempts, wall, cpu)
            self._add(work, viol, len(fv), near=True)
        if not screen and why != "rounds":
            # every row was in this QP: the full QP is the same problem (fixed variables substituted, free
            # rows dropped) and every solver of the chain has just failed on it: no proof, the caller's
            # search moves on (re-solving it ran the whole chain again: 15-25 s of qpOASES per length on
            # nominal K = 3888 before qpOASES had an iteration limit)
            out = self._full(sol, fv, xfix, rows, cand)
            if out.outcome in (QPStatus.OPTIMAL, QPStatus.INFEASIBLE):
                out.outcome = QPStatus.NUMERICAL
            out.success, out.status = False, f"{out.status}; {why}"
            if attempts and attempts[-1][2] != out.outcome.value:      # the re-check's verdict, as the chain's
                name, status, _ = attempts[-1]
                attempts[-1] = (name, f"{status}; {why}", out.outcome.value)
            self.last_fallback = why
            return self._done(out, attempts, wall, cpu)
        # the full QP, as without the working set
        self.full_solves += 1
        self.last_fallback = why
        full = qp.solver.solve(*qp.numeric(K, nseek, beta, gamma, hf_tol, slew_a_per_s, nominal_from), x0=None,
                               check=None if check is None else (lambda x: check(x, A)))
        if full.outcome is QPStatus.OPTIMAL:
            self._hint = np.flatnonzero(np.abs(np.nan_to_num(full.lam_a)) > 1e-12)
            self._lam = (np.nan_to_num(full.lam_a), np.nan_to_num(full.lam_x))
        return self._done(full, attempts + full.attempts, wall + full.solve_time_s, cpu + full.cpu_time_s)

    @staticmethod
    def _certificate(Ar, lr, ur, lbr, ubr, k, lam_a, max_cuts: int = 4):
        """Farkas multipliers for the first ``k`` rows of a reduced QP (padded to ``len(Ar)``), or ``None``.

        First :func:`~seekopt.design.certificates.nnls_certificate` from the rows ``lam_a`` names (least
        squares with cutting planes); then phase-1 LPs (:func:`~seekopt.design.certificates.phase1_lp`) on those rows, then
        cutting planes: the rows of the working set the LP's point violates by more than its own
        largest violation join (the most violated, at most ``max(n / 2, 10)`` per round) and the LP is
        solved again, up to ``max_cuts`` rounds; last the whole working set.  Every certificate is
        verified on its rows (:func:`~seekopt.design.certificates.proves_infeasible`).  The cuts
        prove in 100-180 rows what the whole working set (600-1100 rows, 0.3-0.6 s of HiGHS) did."""
        def padded(sub, lam):
            out = np.zeros(len(Ar))
            out[sub] = lam
            return out
        sub = np.flatnonzero(np.abs(np.nan_to_num(np.asarray(lam_a, dtype=float)[:k])) > 1e-12)
        cap = max(Ar.shape[1] // 2, 10)
        if sub.size:        # least squares with cutting planes first: 2-3x less CPU than the LPs below
            lam = nnls_certificate(Ar[:k], lr[:k], ur[:k], lbr, ubr, sub, cap=cap)
            if lam is not None:
                return padded(np.arange(k), lam)
        for _ in range(max_cuts if sub.size else 0):
            lam, x, t = phase1_lp(Ar[sub], lr[sub], ur[sub], lbr, ubr)
            if lam is not None:
                return padded(sub, lam)
            if x is None:
                break
            r = Ar[:k] @ x
            viol = np.maximum(r - ur[:k], lr[:k] - r)
            new = np.setdiff1d(np.flatnonzero(viol > t + 1e-9), sub)
            if not new.size:
                break
            sub = np.union1d(sub, new[np.argsort(-viol[new])][:cap])
        if sub.size < k:
            lam = farkas_certificate(Ar[:k], lr[:k], ur[:k], lbr, ubr)
            if lam is not None:
                return padded(np.arange(k), lam)
        return None

    def _full(self, sol: QPSolution, fv, xfix, rows, cand) -> QPSolution:
        """The reduced answer in the full problem's variables and rows."""
        x = xfix.copy()
        x[fv] = sol.x if sol.x.size == fv.size else np.nan
        lam_a = np.zeros(self.qp.m)
        lam_a[cand[rows]] = sol.lam_a[:len(rows)]
        lam_x = np.zeros(self.qp.n)
        if sol.lam_x.size == fv.size:
            lam_x[fv] = sol.lam_x
        return QPSolution(x, lam_a, lam_x, sol.success, sol.status, sol.solve_time_s, sol.cpu_time_s, sol.outcome,
                          sol.solver, sol.attempts)

    def _add(self, work, viol, n, near: bool = False) -> None:
        """Add the rows violated by more than ``add_tol`` to ``work`` (with ``near``: also the rows
        within ``self.near`` of their bound), at most ``max_add * n`` + the violated, the most violated
        first."""
        bad = (viol > self.add_tol) & ~work
        idx = np.flatnonzero(bad)
        cap = max(int(self.max_add * n), 1)
        if len(idx) > cap:
            idx = idx[np.argsort(viol[idx])[-cap:]]
        work[idx] = True
        if near and self.near > 0:
            close = np.flatnonzero((viol > -self.near) & ~work)
            room = max(cap - len(idx), 0)
            if len(close) > room:
                close = close[np.argsort(viol[close])[-room:]] if room else close[:0]
            work[close] = True

    @staticmethod
    def _done(sol: QPSolution, attempts, wall, cpu) -> QPSolution:
        sol.attempts, sol.solve_time_s, sol.cpu_time_s = attempts, wall, cpu
        return sol
