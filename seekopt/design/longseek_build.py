"""A long seek built from the steps of a :class:`~seekopt.design.longseek.LongSeekDesigner` and verified by
simulation: the velocity step and its mirror, or four copies of the acceleration step (the composition and
the dispatch rule: :mod:`seekopt.design.longseek`, module notes).

Every seek is simulated once on the full design plant by :func:`seekopt.design.metrics.evaluate_profile`
(the one simulator) and kept only within Imax and settled by the sample its composition predicts.
"""
from __future__ import annotations

import time

import numpy as np

from seekopt.design import guard as _guard

__all__ = ["SeekBuild", "rigid_peak_velocity"]


def rigid_peak_velocity(current_a, k0: float, fs: float) -> float:
    """Largest ``|rigid velocity|`` [track/s] of a feedforward (ZOH double integrator)."""
    return float(np.max(np.abs(np.cumsum(current_a)))) * k0 / fs


class SeekBuild:
    """Seeks from the kept steps (a mixin of :class:`~seekopt.design.longseek.LongSeekDesigner`: the problem's
    data, ``spec`` and the steps are its)."""

    def _verified(self, K: float, u, r, meta: dict, k_pred: int):
        """``(profile, metrics)`` of the seek ``(u, r)`` of ``K`` tracks, simulated on the design plant;
        :class:`~seekopt.design.designer.DesignError` when it exceeds Imax or does not settle by ``k_pred``
        [samples] (one sample of slack: the settle is counted on the sample grid)."""
        from seekopt.design.designer import DesignError
        from seekopt.design.metrics import evaluate_profile
        from seekopt.design.profiles import Profile
        prof = Profile(np.r_[u, 0.0], np.r_[r, K], self.fs, K, self.imax, self.settle, "long_seek",
                       int(np.max(np.nonzero(u)[0]) + 1), meta)
        metrics = evaluate_profile(self.plant, self.controller, prof, settle=self.settle)
        if not metrics.peak_current_a <= self.imax * (1 + 1e-9):
            raise DesignError(f"long seek of {K:g} tracks exceeds Imax in simulation ({metrics.peak_current_a:.4g} A)")
        if not metrics.settle_time_s * self.fs <= k_pred + 1 + 1e-9:
            raise DesignError(f"long seek of {K:g} tracks does not settle by sample {k_pred} "
                              f"({metrics.settle_time_s * self.fs:.1f})")
        prof.meta["design_status"] = "verified"
        return prof, metrics

    def _design_velocity(self, K: float, step, t0: float):
        """The seek of ``K`` tracks from the velocity step ``step`` and its mirror, verified by simulation."""
        from seekopt.design.designer import DesignResult
        u, r, m, s = step.compose(K)
        k_pred = m + step.settle_samples
        meta = {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
                "design_objective": "long_seek/accelerate-coast-arrive", "coast_samples": m,
                "coast_velocity_track_s": s * step.velocity_track_s, "vmax_track_s": self.spec.vmax_track_s,
                "step_samples": step.n, "robust": step.meta["robust"], "design_settle_samples": k_pred}
        prof, metrics = self._verified(K, u, r, meta, k_pred)
        return DesignResult(prof, metrics, "verified", time.process_time() - t0, self.solver,
                            "long_seek", settle_samples=k_pred, n_solves=int(step.meta["qp_solves"]))

    def _design_accel(self, K: float, n: int, m: int, k_pred: int, k_set: int, t0: float, fresh: bool):
        """The seek of ``K`` tracks from four acceleration steps (``n`` samples at ``I0``, spacing ``m``;
        predicted settle ``k_pred`` on the nominal, ``k_set`` on the set), verified by simulation; the
        unmodelled-mode guard's residual measured and reported (not a constraint of the step)."""
        from seekopt.design.designer import DesignError, DesignResult
        st = self.accel_step()
        u, r, s = st.compose(K, n, m)
        vpk = rigid_peak_velocity(u, self.plant.k0, self.fs)
        vmax = self.spec.vmax_track_s
        if vmax is not None and vpk > vmax * (1 + 1e-9):
            raise DesignError(f"long seek of {K:g} tracks: rigid velocity {vpk:.4g} track/s above vmax")
        meta = {"plant_hash": self.plant.hash(), "controller_hash": self.controller.hash(),
                "design_objective": "long_seek/accelerate-coast-arrive (acceleration steps)",
                "accel_samples": n, "coast_samples": m - n, "coast_velocity_track_s": vpk, "vmax_track_s": vmax,
                "step_samples": st.n, "robust": self.robust.to_string() if self.robust else "none",
                "design_settle_samples": k_pred, "set_settle_samples_predicted": k_set,
                "peak_rigid_velocity_track_s": vpk}
        prof, metrics = self._verified(K, u, r, meta, k_pred)
        guard = None
        if self.guard_bands:
            guard = _guard.guard_report(self.plant, self.controller, prof, self.guard_bands, self.settle,
                                        curve=self.guard_curve)
            prof.meta.update(guard.to_meta())
        n_solves = int(st.meta["qp_solves"]) if fresh else 0
        return DesignResult(prof, metrics, "verified", time.process_time() - t0, self.solver,
                            "long_seek", settle_samples=k_pred, n_solves=n_solves, set_settle_samples=k_set,
                            guard=guard)
