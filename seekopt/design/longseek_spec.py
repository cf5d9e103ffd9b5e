"""Long-seek settings: the velocity limit and the stroke, from the user or the plant's metadata, and the
rigid-body time optimum they allow (:mod:`seekopt.design.longseek`).

Velocity limit from the plant (``ModalPlant.meta`` keys, SI units)
------------------------------------------------------------------
``vmax_mps``
    Velocity limit at the head [m/s].
``back_emf_v_per_mps`` and ``supply_v`` (optional ``coil_resistance_ohm``, default 0)
    Back-EMF constant at the head [V/(m/s)] and amplifier supply [V]: the amplifier still drives ``Imax``
    up to ``vmax = (supply_v - coil_resistance_ohm * Imax) / back_emf_v_per_mps``.
``stroke_mm`` (or ``stroke_track``)
    Full stroke [mm] (or [track] at the plant's track pitch).
Velocities in m/s become track/s with the plant's ``track_pitch_nm``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from identification.model.plant import ModalPlant

__all__ = ["I0_FRACTION", "LongSeekError", "LongSeekSpec", "vmax_from_plant", "stroke_from_plant",
           "t_accel_coast_decel"]


#: The acceleration step's constant current as a fraction of the seek's current limit ``gamma Imax - |bias|``
#: (the rest is the feedback's room on the way).
I0_FRACTION = 0.98


class LongSeekError(ValueError):
    """Bad long-seek settings (one-line message)."""


def _pos(v, what):
    if v is not None and not (math.isfinite(v) and v > 0):
        raise LongSeekError(f"{what} must be a positive number (got {v})")
    return None if v is None else float(v)


def vmax_from_plant(plant: ModalPlant, imax: float) -> float | None:
    """Velocity limit [track/s] from the plant's metadata (module notes), or None."""
    m, pitch = plant.meta or {}, plant.track_pitch_nm
    try:
        if "vmax_mps" in m:
            v = float(m["vmax_mps"])
        elif "back_emf_v_per_mps" in m and "supply_v" in m:
            v = (float(m["supply_v"]) - float(m.get("coil_resistance_ohm", 0.0)) * imax) / float(
                m["back_emf_v_per_mps"])
        else:
            return None
    except (TypeError, ValueError):
        raise LongSeekError("plant meta: velocity-limit keys must be numbers") from None
    if not pitch:
        raise LongSeekError("plant meta gives a velocity limit in m/s but the plant has no track_pitch_nm")
    if not (math.isfinite(v) and v > 0):
        raise LongSeekError(f"plant meta: velocity limit {v:g} m/s is not positive (supply below R*Imax?)")
    return v / (pitch * 1e-9)


def stroke_from_plant(plant: ModalPlant) -> float | None:
    """Full stroke [track] from ``meta["stroke_track"]`` or ``meta["stroke_mm"]`` (module notes), or None."""
    m = plant.meta or {}
    try:
        if "stroke_track" in m:
            return _pos(float(m["stroke_track"]), "plant meta stroke_track")
        if "stroke_mm" in m and plant.track_pitch_nm:
            return _pos(float(m["stroke_mm"]) * 1e6 / plant.track_pitch_nm, "plant meta stroke_mm")
    except (TypeError, ValueError):
        raise LongSeekError("plant meta: stroke must be a number") from None
    return None


def t_accel_coast_decel(tracks: float, k0: float, imax: float, vmax: float | None) -> float:
    """Rigid-body minimum seek time [s] with current limit ``imax`` and velocity limit ``vmax`` [track/s]:
    ``K / vmax + vmax / (k0 Imax)`` when the seek reaches ``vmax``, else ``T_bb = 2 sqrt(K / (k0 Imax))``."""
    a, K = k0 * imax, abs(tracks)
    if vmax is None or K <= vmax * vmax / a:
        return 2.0 * math.sqrt(K / a)
    return K / vmax + vmax / a


@dataclass
class LongSeekSpec:
    """Long-seek settings.

    Parameters
    ----------
    vmax_track_s : float, optional
        Velocity limit [track/s] (None: none; :meth:`from_plant` reads the plant's metadata).
    stroke_track : float, optional
        Full stroke [track]: longer seeks are refused.
    rest_to_rest_up_to_track : float, optional
        Seeks up to this length [track] are designed by the rest-to-rest QP even where the acceleration
        step could build them (None: from the step's shortest seek on, ``long_from_track``).  The
        rest-to-rest design settles sooner (nominal bundled drive, 1700-3888 tracks: 0.80-0.82x the
        step's settle) but its cost grows with the length (1.3-47 s CPU there, robust > 4 min at 2894).
    compare_below_long : bool
        Below ``long_from_track``, from ``compare_from_track`` on, take the composition when it settles
        within 1.15x the rest-to-rest settle predicted from one reference design
        (:mod:`seekopt.design.longseek`, rule 2).  Worth it for a designer that serves many lengths (sweeps
        turn it on): it designs the acceleration step and the reference seek first (cold robust
        K = 1000 on the bundled drive: 8.1 s CPU against 4.3 s without).
    """

    vmax_track_s: float | None = None
    stroke_track: float | None = None
    rest_to_rest_up_to_track: float | None = None
    compare_below_long: bool = False

    def __post_init__(self):
        self.vmax_track_s = _pos(self.vmax_track_s, "vmax")
        self.stroke_track = _pos(self.stroke_track, "stroke")
        self.rest_to_rest_up_to_track = _pos(self.rest_to_rest_up_to_track, "rest-to-rest limit")

    @classmethod
    def from_plant(cls, plant: ModalPlant, imax: float, vmax_track_s=None, stroke_track=None,
                   rest_to_rest_up_to_track=None, compare_below_long: bool = False):
        """Explicit values win over the plant's metadata (module notes)."""
        v = vmax_track_s if vmax_track_s is not None else vmax_from_plant(plant, imax)
        s = stroke_track if stroke_track is not None else stroke_from_plant(plant)
        return cls(v, s, rest_to_rest_up_to_track, bool(compare_below_long))

    def to_dict(self) -> dict:
        return {"vmax_track_s": self.vmax_track_s, "stroke_track": self.stroke_track,
                "rest_to_rest_up_to_track": self.rest_to_rest_up_to_track,
                "compare_below_long": self.compare_below_long}

    @classmethod
    def from_dict(cls, d: dict) -> "LongSeekSpec":
        return cls(d.get("vmax_track_s"), d.get("stroke_track"), d.get("rest_to_rest_up_to_track"),
                   bool(d.get("compare_below_long", False)))
