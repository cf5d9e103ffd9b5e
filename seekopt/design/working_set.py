"""Solve a seek QP on a working set of its rows, adding back every row the answer violates.

Most rows of a seek QP never bind: settle-band rows before the settle sample are free, and of the
band and current rows of 22 robust-set plants only a few dozen touch their limits at the optimum.
:class:`WorkingSetQP` solves the QP of one :class:`seekopt.design.qp.SeekQP` structure with

* the **free rows dropped** (both bounds infinite: band rows before the seek ends);
* the **other rows screened**: the working set starts from the equality rows, the rows that bound
  the last answer of this structure (the bisection's previous length, or the previous seek length
  of a sweep) and the rows within ``screen_margin`` of their bound at the warm start; the reduced QP
  is solved, every row the answer violates (by more than ``add_tol`` in the row's scaled units) is
  added back, and the QP re-solved, until the answer satisfies every row.

The answer is then the full QP's optimum (a convex QP's optimum that satisfies the dropped rows is
optimal for the full problem); a reduced QP proven infeasible proves the full QP infeasible (fewer
rows) in exact arithmetic, but daqp has reported infeasibility (-1) on reduced QPs that qpOASES and
HiGHS solve, so a reduced "infeasible" is confirmed on the full QP (the primary's trust level before
the working set).  Reduced
problems are padded to a few row buckets (powers of two) so that each bucket's solver chain is built
once and reused.  When the working set grows past ``max_fraction`` of the
rows, or a reduced solve ends without an answer or proof, the full QP is solved as before.
"""
from __future__ import annotations

import numpy as np

from seekopt.design.solvers import QPSolution, QPStatus, SolverChain, dm

__all__ = ["WorkingSetQP"]


class WorkingSetQP:
    """Working-set solver for one seek-QP structure (built once per structure, reused).

    Parameters
    ----------
    qp : SeekQP
    chain : callable
        ``(n, m) -> SolverChain`` for a reduced problem of ``m`` rows.
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
    """

    def __init__(self, qp, chain, *, screen_margin: float = 0.0, add_tol: float = 1e-7, max_rounds: int = 30,
                 max_fraction: float = 0.5, max_add: float = 1.0):
        self.qp, self._make_chain = qp, chain
        self.screen_margin, self.add_tol = float(screen_margin), float(add_tol)
        self.max_rounds, self.max_fraction, self.max_add = int(max_rounds), float(max_fraction), float(max_add)
        self._chains: dict = {}
        self._hint = np.zeros(0, dtype=int)      # rows that bound the last answer
        self._K, self._H, self._Hdm, self._A = None, None, None, None
        self.rounds = 0                          # reduced solves (statistics)
        self.full_solves = 0
        self.confirmations = 0                   # reduced 'infeasible' re-solved on the full QP

    def _chain(self, m: int) -> SolverChain:
        bucket = 64
        while bucket < m:
            bucket *= 2
        if bucket not in self._chains:
            self._chains[bucket] = self._make_chain(self.qp.n, bucket)
        return self._chains[bucket]

    def _matrices(self, K: float):
        if self._K != K:
            self._H, self._A = self.qp.matrices(K)
            self._Hdm, self._K = dm(self._H), K
        return self._Hdm, self._A

    def solve(self, K: float, nseek: int, beta, gamma: float, hf_tol, slew_a_per_s=None, x0=None,
              check=None) -> QPSolution:
        """The QP of ``SeekQP.data(K, nseek, beta, gamma, hf_tol, slew_a_per_s)``; ``check(x, A)``
        (full-problem re-check, returns a note or '') as in :meth:`SolverChain.solve`."""
        qp = self.qp
        g, lba, uba, lbx, ubx = qp.bounds(K, nseek, beta, gamma, hf_tol, slew_a_per_s)
        Hdm, A = self._matrices(K)
        cand = np.flatnonzero(np.isfinite(lba) | np.isfinite(uba))
        Ac, lc, uc = A[cand], lba[cand], uba[cand]
        work = np.zeros(len(cand), dtype=bool)
        work |= lc == uc                                       # equalities
        work |= np.isin(cand, self._hint)                      # rows that bound the last answer
        if x0 is not None and np.all(np.isfinite(x0)):
            r = Ac @ np.clip(x0, lbx, ubx)
            self._add(work, np.maximum(r - uc, lc - r) + self.screen_margin, qp.n)
        wall = cpu = 0.0
        attempts = []
        for _ in range(self.max_rounds):
            if work.sum() > self.max_fraction * len(cand):
                break
            rows = np.flatnonzero(work)
            chain = self._chain(len(rows))
            mb = chain.m
            Ar = np.zeros((mb, qp.n)); Ar[:len(rows)] = Ac[rows]
            lr = np.full(mb, -np.inf); lr[:len(rows)] = lc[rows]
            ur = np.full(mb, np.inf); ur[:len(rows)] = uc[rows]
            data = (Hdm, g, dm(Ar), lr, ur, lbx, ubx)
            sol = chain.solve(*data, x0=x0)
            self.rounds += 1
            wall, cpu = wall + sol.solve_time_s, cpu + sol.cpu_time_s
            attempts += sol.attempts
            if sol.outcome is QPStatus.INFEASIBLE:
                # daqp has reported -1 on reduced QPs that qpOASES and HiGHS solve: a reduced
                # "infeasible" is confirmed on the full QP below
                self.confirmations += 1
                break
            if sol.outcome is not QPStatus.OPTIMAL:
                break
            r = Ac @ sol.x
            viol = np.maximum(r - uc, lc - r)
            if not np.any((viol > self.add_tol) & ~work):
                lam = sol.lam_a[:len(rows)]
                self._hint = cand[rows[np.abs(np.nan_to_num(lam)) > 1e-12]]       # the active set
                if check is not None:
                    note = check(sol.x, A)
                    if note:
                        sol.success, sol.outcome, sol.status = False, QPStatus.NUMERICAL, f"{sol.status}; {note}"
                        break
                return self._done(sol, attempts, wall, cpu)
            self._add(work, viol, qp.n)
            x0 = sol.x
        # the full QP, as without the working set
        self.full_solves += 1
        full = qp.solver.solve(*qp.data(K, nseek, beta, gamma, hf_tol, slew_a_per_s), x0=None,
                               check=None if check is None else (lambda x: check(x, A)))
        if full.outcome is QPStatus.OPTIMAL:
            self._hint = np.flatnonzero(np.abs(np.nan_to_num(full.lam_a)) > 1e-12)
        return self._done(full, attempts + full.attempts, wall + full.solve_time_s, cpu + full.cpu_time_s)

    def _add(self, work, viol, n) -> None:
        """Add the rows violated by more than ``add_tol`` to ``work``, at most ``max_add * n``, the
        most violated first."""
        idx = np.flatnonzero((viol > self.add_tol) & ~work)
        cap = max(int(self.max_add * n), 1)
        if len(idx) > cap:
            idx = idx[np.argsort(viol[idx])[-cap:]]
        work[idx] = True

    @staticmethod
    def _done(sol: QPSolution, attempts, wall, cpu) -> QPSolution:
        sol.attempts, sol.solve_time_s, sol.cpu_time_s = attempts, wall, cpu
        return sol
