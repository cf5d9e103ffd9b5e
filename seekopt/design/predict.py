"""Honest predictions: a profile played on every plant of a design's set.

A plant of the set whose gain differs from the design plant's plays the profile's current scaled by
its drive's gain calibration (``plant.meta["ff_scale"]``, see :mod:`seekopt.design.family`):
:func:`played_on` for a simulation, :func:`scale_feedforward_maps` for the design's closed-loop maps.
:func:`predict_on_set` measures the seek-settle time on every plant (the one simulator) and says which
plant settles last and which one binds; ``seekopt design`` prints that and writes it into the
profile's metadata.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identification.model.plant import ModalPlant

from seekopt.design.qp import LoopMaps

__all__ = ["set_label", "feedforward_scale", "set_identity", "calibrated", "played_plant", "played_on",
           "scale_feedforward_maps", "set_loop_maps", "SetPrediction", "predict_on_set", "superposes", "play_linear"]


def set_label(plant: ModalPlant) -> str:
    """The plant's label in a robust set (``"nominal"`` if it has none)."""
    return str((plant.meta or {}).get("set_label", "nominal"))


def feedforward_scale(plant: ModalPlant) -> float:
    """Factor the drive applies to a profile's current on ``plant`` (its gain calibration; 1 if unset)."""
    return float((plant.meta or {}).get("ff_scale", 1.0))


def set_identity(plant: ModalPlant) -> tuple:
    """What makes ``plant`` a drive of its own in a robust set: the plant (:meth:`ModalPlant.hash`, which
    leaves out ``meta``) and the drive's feedforward calibration (:func:`feedforward_scale`, 12 digits).
    Two plants of a set equal in both are one drive; equal plants played with different calibrations
    (the corners of a feedforward-gain error) are not."""
    return plant.hash(), float(f"{feedforward_scale(plant):.12g}")


def calibrated(member: ModalPlant, design_k0: float, gain_estimate: float | None = None) -> ModalPlant:
    """``member`` with the feedforward scale its drive applies: design gain / its gain estimate
    (default its own ``k0``: a member identified from its own log knows its gain)."""
    meta = dict(member.meta or {})
    meta["ff_scale"] = float(design_k0) / float(gain_estimate or member.k0)
    return member.copy(meta=meta)


def played_plant(truth: ModalPlant, design_k0: float) -> ModalPlant:
    """``truth`` as its drive plays a design made for the gain ``design_k0`` [track/(A s^2)]: a truth of
    another gain (another member of the family, relative difference above 1e-6) is :func:`calibrated` to
    it, otherwise ``truth`` itself (its own calibration, if any, kept).  Play profiles on it through
    :func:`played_on`; the bench's table, its figure and the effect bench all do."""
    return calibrated(truth, design_k0) if abs(truth.k0 / float(design_k0) - 1.0) > 1e-6 else truth


def played_on(profile, plant: ModalPlant):
    """The profile as the drive plays it on ``plant``: current x :func:`feedforward_scale` (the
    reference is unchanged)."""
    s = feedforward_scale(plant)
    if s == 1.0:
        return profile
    from seekopt.design.profiles import Profile
    return Profile(np.asarray(profile.current_a) * s, profile.reference_track, profile.sample_rate_hz, profile.tracks,
                   profile.imax_a, profile.settle_track, profile.kind, profile.seek_samples,
                   dict(profile.meta, ff_scale=round(s, 6)))


def scale_feedforward_maps(maps, plant: ModalPlant):
    """Scale the feedforward columns of ``maps`` (:class:`seekopt.design.qp.LoopMaps` of ``plant``) by the
    plant's :func:`feedforward_scale` (in place; returns ``maps``)."""
    s = feedforward_scale(plant)
    if s != 1.0:
        maps.y_u = maps.y_u * s
        maps.i_u = maps.i_u * s
    return maps


def set_loop_maps(plants: list, controller, horizon: int) -> list:
    """The closed-loop maps of a plant set as the drive plays a profile on each: one
    :class:`seekopt.design.qp.LoopMaps` per plant over ``horizon`` samples, its feedforward columns
    scaled by the plant's calibration (:func:`scale_feedforward_maps`).  The one construction of the
    maps the designers constrain (the linear designer, the effect-aware NLP's robust set, the long
    seeks' velocity steps) and the predictions play."""
    return [scale_feedforward_maps(LoopMaps(p, controller, int(horizon)), p) for p in plants]


@dataclass
class SetPrediction:
    """A profile's predicted seek-settle times on every plant of a design's set.

    Attributes
    ----------
    labels : list of str
        ``set_label`` of each plant (nominal first).
    metrics : list of SeekMetrics
        Measured by the one simulator on each plant (effects included).
    worst : int
        Index of the plant that settles last (ties: the larger residual after the seek).
    binding : int
        Index of the plant closest to the settle band after the seek (largest peak ``|PES|`` from the
        end of the seek on): the plant whose band constraint binds the design.
    """

    labels: list
    metrics: list
    worst: int
    binding: int

    @property
    def nominal(self):
        return self.metrics[0]

    @property
    def worst_metrics(self):
        return self.metrics[self.worst]

    def members(self) -> list:
        """``(label, metrics)`` of the nominal plant and the family members."""
        return [(lab, m) for lab, m in zip(self.labels, self.metrics) if lab == "nominal" or lab.startswith("member")]

    def to_meta(self) -> dict:
        ms = lambda m: round(m.settle_time_s * 1e3, 4)     # noqa: E731
        return {"predicted_settle_nominal_ms": ms(self.nominal),
                "predicted_settle_worst_ms": ms(self.worst_metrics),
                "predicted_worst_plant": self.labels[self.worst],
                "predicted_binding_plant": self.labels[self.binding],
                "predicted_settle_members_ms": ";".join(f"{lab}={ms(m)}" for lab, m in self.members()),
                "robust_set_size": len(self.labels)}


def superposes(plant: ModalPlant) -> bool:
    """True when the closed loop of ``plant`` played from its pre-seek steady state is exactly its
    linear part's (:meth:`ModalPlant.linear_part`): structural effects only (the bias is cancelled by
    the hold current; a pivot's rest offset is not)."""
    if not plant.is_linear:
        return False
    return all(float(getattr(e, "rest_track", 0.0) or 0.0) == 0.0 for e in plant.effects)


def play_linear(maps, profile, n: int):
    """``(pes [track], total sub-step currents (n, L) [A])`` of ``profile`` played for ``n`` samples from
    rest on the loop whose impulse responses are ``maps`` (:class:`seekopt.design.qp.LoopMaps`, from the
    one simulator, feedforward scaled by the plant's calibration), or None when ``n`` exceeds the maps'
    horizon.  Superposition of the simulator's own responses (the loop is linear time-invariant)::

        y = h_yu * u_ff + h_yr * (r - K) + K s_yr,    i = h_iu * u_ff + h_ir * (r - K) + K s_ir + i_hold
    """
    if n > maps.horizon:
        return None
    K = float(profile.tracks)
    u = np.asarray(profile.current_a, dtype=float)
    dr = np.asarray(profile.reference_track, dtype=float) - K
    y, cur = maps.response(u, dr, n)
    y = y + K * maps.s_yr[:n]
    cur = cur + K * maps.s_ir[:n] + maps.hold_a
    return y - K, cur


def predict_on_set(plants: list, controller, profile, settle: float, k0_for_tbb: float | None = None,
                   first=None, maps=None) -> SetPrediction:
    """Play ``profile`` on every plant of ``plants`` (:func:`seekopt.design.metrics.evaluate_profile`, the
    current scaled by each plant's feedforward calibration, :func:`played_on`); ``first`` reuses the
    metrics already measured on ``plants[0]``.  ``maps`` (one :class:`seekopt.design.qp.LoopMaps` per
    plant, long enough): a plant whose loop superposes (:func:`superposes`) is played by
    :func:`play_linear` on its maps (the same traces as the simulator, without the per-sample loop)."""
    from seekopt.design.metrics import DEFAULT_TAIL_S, evaluate_profile, seek_metrics
    fs = float(controller.sample_rate_hz)
    n = max(profile.n + int(round(DEFAULT_TAIL_S * fs)), profile.n + 1)

    def one(i, p):
        if i == 0 and first is not None:
            return first
        if maps is not None and superposes(p):
            played = play_linear(maps[i], profile, n)
            if played is not None:
                pes, cur = played
                return seek_metrics(pes, float(np.max(np.abs(cur))), profile, fs, settle, k0_for_tbb or p.k0)
        return evaluate_profile(p, controller, played_on(profile, p), settle=settle, k0_for_tbb=k0_for_tbb)
    ms = [one(i, p) for i, p in enumerate(plants)]
    worst = max(range(len(ms)), key=lambda i: (ms[i].settle_time_s, ms[i].peak_pes_after_track))
    binding = max(range(len(ms)), key=lambda i: ms[i].peak_pes_after_track)
    return SetPrediction([set_label(p) for p in plants], ms, worst, binding)
