"""The minimum seek-settle search of :class:`~seekopt.design.designer.SeekDesigner` (objective (b)): from
the predicted length, galloping and bisection (:mod:`seekopt.design.search`) over one size class's QP, and
the lexicographic nominal-first refinement over a plant set.

The structures, the solves and the simulator check stay in :mod:`seekopt.design.designer`.
"""
from __future__ import annotations

from seekopt.design.result import DesignError, SolveStats
from seekopt.design.search import bisect_length, gallop_length, predict_length, prior_length

__all__ = ["SettleSearch"]


class SettleSearch:
    """The length search of a :class:`~seekopt.design.designer.SeekDesigner` (a mixin: its structures,
    ``_solve``, ``_classes``, ``_history`` and ``_finish`` are the designer's)."""

    def _probe(self, qp, K, stats: SolveStats):
        """``probe(n, warm, confirm)``: the band-constrained QP at ``n`` seek samples (for :mod:`search`)."""
        return lambda n, warm=None, confirm=True: self._solve(qp, K, n, self.beta, stats, warm=warm, confirm=confirm)

    def _bisect(self, qp, K, lo, hi, best, stats, floor=None):
        """:func:`~seekopt.design.search.bisect_length` on structure ``qp``."""
        def unconfirmed(n):
            key = (id(qp), n)
            found = key in stats.unconfirmed
            stats.unconfirmed.discard(key)
            return found
        return bisect_length(self._probe(qp, K, stats), lo, hi, best, unconfirmed, floor)

    def _predict(self, n_rigid: int) -> int:
        """Settle samples predicted from this designer's earlier designs (:func:`predict_length`), else
        from the rigid bang-bang samples alone (:func:`prior_length`)."""
        n = predict_length(self._history, n_rigid)
        return prior_length(n_rigid) if n is None else n

    def _predicted_search(self, K, n_rigid, first, lo, stats):
        """Search from the predicted length (:meth:`_predict`): in the size class the old scan would end
        in, probe the predicted length and its neighbour, gallop (steps 1, 2, 4, ...) towards the
        boundary, then bisect.  When the class holds no feasible length, its longest seek is solved
        with ``confirm=True``: a proof moves the search on to the next class (from the length after
        it, as the scan would end there), anything else returns None and the class scan decides.
        Without an earlier design nearby the prediction is :func:`prior_length`'s.
        Returns ``(qp, class, N, answer)`` or None (the class scan decides)."""
        n_pred = self._predict(n_rigid)
        classes = self._classes(first)
        # a prediction one past a class's longest seek starts in that class (its answers there are often
        # one sample shorter: the class above would be built and searched, then left again)
        c = next((x for x in classes if x >= n_pred - 1), classes[-1])
        went_down = False
        while True:
            qp = self._structure(c, False)
            tops = {}

            def probe(n, warm=None, confirm=True, _p=self._probe(qp, K, stats), _c=c, _tops=tops):
                sol = _p(n, warm, confirm)
                if n == _c and confirm:
                    _tops[n] = sol
                return sol
            found = gallop_length(probe, lo, min(max(n_pred, lo + 1), c), c)
            if found is None:   # nothing in this class (search steps): is its longest seek proven infeasible?
                later = [x for x in classes if x > c]
                if went_down or not later or c <= lo:
                    return None
                top = tops.get(c) or self._solve(qp, K, c, self.beta, stats)   # gallop confirmed it
                if not top.infeasible:
                    return None     # feasible after all, or undecided: the class scan decides
                lo, c, n_pred = c, later[0], c + 1
                continue
            lo_c, hi, best = found
            hi, best = self._bisect(qp, K, lo_c, hi, best, stats, floor=lo)
            # the scan takes the first class whose longest seek is feasible: a smaller class that holds
            # this length is that class (re-searched there, from this length)
            prev = [x for x in classes if x < c]
            if prev and hi <= prev[-1] and prev[-1] >= first:
                c, n_pred, went_down = prev[-1], hi, True
                continue
            return qp, c, hi, best

    def _nominal_first(self, qp, best, K, N, stats: SolveStats, lo: int):
        """Lexicographic second stage of the minimum seek-settle design over a plant set: the set's worst
        seek-settle ``N`` (the first stage, every plant's band from ``N`` on) is kept, and among the
        designs that hold it, the one whose nominal plant settles first (its band rows from ``n0 < N``
        on, the seek still ``N`` samples long; every other plant keeps its rows from ``N``).  The worst
        case over the set is no later than the first stage's, the nominal plant no later; the same margins,
        guard and currents.  Returns the verified design, or None (nothing earlier: keep the first stage's).

        With :attr:`SeekProblem.worst_case_slack_s` (``s`` samples, :meth:`SeekProblem.worst_case_slack_samples`)
        the set may settle up to ``s`` samples after its minimum: ``n0`` is searched with the set's band
        rows from ``N + s`` (the seek that long; a bigger size class when ``N + s`` exceeds this one, cold
        started), then, holding ``n0``, the set's length is brought back to the shortest in ``[N, N + s]``
        that keeps it (:meth:`_set_length`): slack that buys the nominal plant nothing is not spent.

        Every probe here is a search step (``confirm=False``): a working set's unproven "infeasible" ends
        the refinement without the re-check and certificate a length the set's ``N`` rests on gets
        (10-250 ms each, a third of a robust design's CPU).  Nothing is declared infeasible from it:
        the design returned is verified either way, at worst the first stage's or a nominal settle one
        sample later than a proof would have found (none in ``studies/design_speed.py``'s 26 robust cells:
        every such verdict the confirmation re-checked was proven infeasible).  The chain's next solver
        gives its opinion first (``WorkingSetQP.solve(second_opinion=True)``: one solve, no certificate): the
        ``daqp`` package has called feasible reduced QPs of long robust seeks infeasible (cond(H) ~ 3e11),
        which ended the refinement one sample late (600k TPI, 5456 tracks: nominal settle 89 against 88)."""
        if len(self.plants) < 2 or not self.problem.nominal_first or N - 1 <= lo:
            return None
        n_top = min(N + self.problem.worst_case_slack_samples(), self.max_samples)
        warm = best.x
        if n_top > qp.N:       # the set's rows from N + slack: a structure whose seeks are that long
            qp, warm = self._structure(self._classes(n_top)[0], False), None

        def solve(n_set, n0, warm=None):
            return self._solve(qp, K, n_set, self.beta, stats, warm=warm, confirm=False, nominal_from=n0,
                               second_opinion=True)

        def probe(n0, warm=None, _confirm=None):     # the search's protocol; never confirmed here (above)
            return solve(n_top, n0, warm)
        s = probe(N - 1, warm)
        if not s.success:
            return None
        hi, best, step, low = N - 1, s, 1, lo         # gallop down (1, 2, 4, ...), then bisect
        while hi - step > lo:
            t = probe(hi - step, best.x)
            if not t.success:
                low = hi - step
                break
            hi, best, step = hi - step, t, 2 * step
        n0, best = bisect_length(probe, low, hi, best, lambda n: False, floor=lo)
        n_set, best = self._set_length(solve, N, n_top, n0, best)
        for n in range(n0, N):            # the simulator decides; step up on failure
            if n != n0:
                best = solve(n_set, n, best.x)
                if not best.success:
                    continue
            try:
                return self._finish(qp, best, K, n_set, stats, f"min_settle/{self.objective_kind}/nominal_first",
                                    strict=True, settle_n=n, set_min=N)
            except DesignError:
                continue
        return None

    @staticmethod
    def _set_length(solve, N, n_top, n0, best):
        """``(n_set, answer)``: the shortest set length in ``[N, n_top]`` whose QP holds the nominal plant's
        band from ``n0`` (``n_top`` does, with answer ``best``; bisection: a longer seek can always wait)."""
        if n_top <= N:
            return n_top, best
        return bisect_length(lambda m, warm=None, _c=None: solve(m, n0, warm), N - 1, n_top, best,
                             lambda n: False, floor=N - 1)
