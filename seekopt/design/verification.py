"""The verification of a designed seek: the QP's answer unpacked to a profile at rest, played once by the
one simulator (:func:`seekopt.design.metrics.played_metrics`, or its impulse responses convolved for a
plant whose loop superposes) on the design plant -- within Imax, settled
by its sample when asked --, the honest predictions on every plant of the robust set
(:func:`seekopt.design.predict.predict_on_set`) and the unmodelled-mode guard's report
(:func:`seekopt.design.guard.guard_report`), packaged as a :class:`DesignResult`.

:func:`verified_design` is :meth:`SeekDesigner._finish <seekopt.design.designer.SeekDesigner._finish>`:
it reads the designer it verifies for (its problem, maps and built structures), and only the designer calls it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seekopt.design import guard as _guard
from seekopt.design.metrics import DEFAULT_TAIL_S, played_metrics, seek_metrics, worst_case
from seekopt.design.predict import feedforward_scale, play_linear, predict_on_set, superposes
from seekopt.design.profiles import Profile, exact_rest, finish_profile
from seekopt.design.result import DesignError, DesignResult, SolveStats

__all__ = ["verified_design", "played_design", "packaged_design", "PlayedDesign"]


def verified_design(self, qp, sol, K, N, stats: SolveStats, objective, strict, settle_n=None,
                    set_min=None) -> DesignResult:
    """Verify and package the design whose set holds the band from sample ``N`` on (its inputs are
    ``N`` plus the structure's ``input_tail`` samples long); ``settle_n`` (default ``N``): the sample the
    nominal plant's band holds from (:meth:`_nominal_first`), checked by the simulator when ``strict``;
    ``set_min`` (default ``N``): the set's minimum seek-settle sample, earlier than ``N`` when
    :attr:`SeekProblem.worst_case_slack_s` let the set settle later for the nominal plant's sake:
    :func:`played_design` then :func:`packaged_design`."""
    return packaged_design(self, played_design(self, qp, sol, K, N, objective, strict, settle_n, set_min), stats)


def played_design(self, qp, sol, K, N, objective, strict, settle_n=None, set_min=None) -> "PlayedDesign":
    """The check half of :func:`verified_design`: the profile played once by the one simulator on the
    design plant, within Imax and (``strict``) settled by its sample, else :class:`DesignError`.  What
    :func:`packaged_design` adds (the set's predictions, the guard report) decides nothing: a first
    stage that a nominal-first design replaces is checked, never packaged."""
    n_set = N
    N = N if settle_n is None else int(settle_n)
    set_min = n_set if set_min is None else int(set_min)
    slack = self.problem.worst_case_slack_s
    u, r = qp.unpack(sol.x, K, n_set)
    u = exact_rest(u, K, self.plant.k0, self.fs, self.imax)
    if u is None:
        raise DesignError(f"design misses rest at {K:g} tracks")
    meta = {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
            **({"family_hashes": ";".join(p.hash() for p in self.problem.family)} if self.problem.family else {}),
            "design_objective": objective, "solver": self.solver_name, "reference": self.reference,
            "robust": self.robust.to_string() if self.robust else "none",
            "band_margin": self.beta, "current_margin": self.gamma, "design_settle_samples": N,
            **({"design_set_settle_samples": n_set} if n_set != N else {}),
            **({"worst_case_slack_s": slack, "design_set_min_settle_samples": set_min} if slack > 0 else {})}
    if self.ignored_effects:
        meta["effects_not_in_design"] = ";".join(self.ignored_effects)
    if r is not None:   # jointly designed reference; one closing sample shows the hold (u = 0, r = K)
        prof = Profile(np.r_[u, 0.0], np.r_[r, K], self.fs, K, self.imax, self.settle, "optimal", len(u), meta)
    else:
        prof = finish_profile(u, K, self.fs, self.imax, self._reference_model(), "optimal", self.settle,
                              meta=meta)
        prof.seek_samples = len(u)
    metrics, sim = _play(self, prof)
    if not metrics.peak_current_a <= self.imax * (1 + 1e-9):
        raise DesignError(f"design exceeds Imax in simulation ({metrics.peak_current_a:.4g} A)")
    if strict and not metrics.settle_time_s * self.fs <= N + 1 + 1e-9:
        raise DesignError(f"design does not settle by sample {N} in simulation")
    return PlayedDesign(qp, sol, K, N, n_set, objective, prof, metrics, sim, set_min)


def _play(self, prof: Profile):
    """``(metrics, play)`` of ``prof`` on the design plant.  A plant whose loop superposes
    (:func:`~seekopt.design.predict.superposes`, no feedforward calibration of its own) is played by
    :func:`~seekopt.design.predict.play_linear` on the designer's maps when they are long enough (the
    one simulator's own impulse responses, convolved: the same traces without the per-sample loop;
    ``play`` is then None); any other plant by the one simulator, once -- a guard on a loop the maps
    cannot play reads that play's sub-step currents."""
    maps = self._maps
    n_play = max(prof.n + int(round(DEFAULT_TAIL_S * self.fs)), prof.n + 1)
    if maps is not None and superposes(self.plant) and feedforward_scale(self.plant) == 1.0:
        played = play_linear(maps[0], prof, n_play)
        if played is not None:
            pes, cur = played
            return seek_metrics(pes, float(np.max(np.abs(cur))), prof, self.fs, self.settle, self.plant.k0), None
    sub = bool(self.guard_bands) and (maps is None or not superposes(self.plant))
    return played_metrics(self.plant, self.controller, prof, settle=self.settle, record_substeps=sub)


@dataclass
class PlayedDesign:
    """A design that passed the simulator check (:func:`played_design`): the QP structure and answer,
    the seek ``K`` [track], the nominal plant's settle sample ``N`` and the set's ``n_set``, the
    profile, its metrics and the play (:class:`seekopt.drive.simulator.SimResult`), the set's minimum
    settle sample ``set_min`` (``n_set`` less the worst-case slack spent)."""
    qp: object
    sol: object
    K: float
    N: int
    n_set: int
    objective: str
    prof: Profile
    metrics: object
    sim: object
    set_min: int = 0


def packaged_design(self, d: PlayedDesign, stats: SolveStats) -> DesignResult:
    """The :class:`DesignResult` of a checked design: predictions on every plant of the set, the guard
    report, the solve bookkeeping."""
    qp, sol, K, N, n_set, objective = d.qp, d.sol, d.K, d.N, d.n_set, d.objective
    prof, metrics, sim = d.prof, d.metrics, d.sim
    worst, pred = None, None
    n_play = max(prof.n + int(round(DEFAULT_TAIL_S * self.fs)), prof.n + 1)
    maps = self._loop_maps(n_play) if self._maps is not None else None
    if len(self.plants) > 1:        # honest predictions: every plant of the set, by the one simulator's
        # responses (plants whose loop superposes) or the simulator itself
        pred = predict_on_set(self.plants, self.controller, prof, self.settle, self.plant.k0, first=metrics,
                              maps=maps)
        prof.meta.update(pred.to_meta())
        if self.check_robust:
            worst = worst_case(pred.metrics)
    guard = None
    if self.guard_bands:
        played = play_linear(maps[0], prof, n_play) if maps is not None and superposes(self.plant) else None
        guard = _guard.guard_report(self.plant, self.controller, prof, self.guard_bands, self.settle,
                                    curve=self.guard_curve,
                                    current_sub=sim.current_sub_a if played is None else played[1])
        prof.meta.update(guard.to_meta())
    prof.meta["design_status"] = "verified"
    return DesignResult(prof, metrics, "verified", stats.t, sol.solver or self.solver_name, objective,
                        settle_samples=N, n_solves=stats.n,
                        residual_band=max(qp.residual(sol.x, K, n_set), qp.residual(sol.x, K, N, plants=[0])), worst_metrics=worst,
                        qp_status=stats.status,
                        build_time_s=sum(q.build_time_s for q in self._qps.values()),
                        fallback_solves=stats.fallback, unresolved_solves=len(stats.unresolved),
                        prediction=pred, guard=guard, set_settle_samples=n_set,
                        set_min_settle_samples=d.set_min or n_set)
