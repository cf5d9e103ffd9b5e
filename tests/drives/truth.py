"""The truth of an independent drive as the package's plant data class, for comparisons in tests.

Only the data classes (:class:`identification.model.plant.ModalPlant`, ``Mode`` and the effects'
JSON form) are used here, never their dynamics: the drive simulates its own :class:`TruthPlant`.
The drive's computation delay is part of the plant's input delay as an identification sees it.
"""
from __future__ import annotations

from identification.model.plant import ModalPlant, Mode

from .drive import Drive
from .plant import TruthPlant

__all__ = ["modal_plant", "from_modal_plant", "effect_dicts"]


def effect_dicts(p: TruthPlant, base: TruthPlant | None = None) -> list[dict]:
    """The effects ``p`` has beyond ``base`` (default: beyond its linear eq. (1) part) in the plant-JSON form."""
    out = []
    b = base or TruthPlant(k0=p.k0)
    if p.extra_delay_s != b.extra_delay_s:
        out.append({"effect": "input_delay", "params": {"delay_s": p.extra_delay_s - b.extra_delay_s}})
    if p.amplifier_bandwidth_hz is not None and p.amplifier_bandwidth_hz != b.amplifier_bandwidth_hz:
        out.append({"effect": "amplifier_lag", "params": {"bandwidth_hz": p.amplifier_bandwidth_hz}})
    if p.pivot is not None and p.pivot != b.pivot:
        out.append({"effect": "pivot_spring_damper",
                    "params": dict(zip(("freq_hz", "zeta", "rest_track"), p.pivot))})
    for m in p.extra_modes[len(b.extra_modes):]:
        out.append({"effect": "extra_mode", "params": {"freq_hz": m.freq_hz, "zeta": m.zeta, "gain": m.gain}})
    if p.current_limit_a is not None and p.current_limit_a != b.current_limit_a:
        out.append({"effect": "current_saturation", "params": {"limit_a": p.current_limit_a}})
    if p.kt_coeffs and p.kt_coeffs != b.kt_coeffs:
        out.append({"effect": "torque_constant_variation",
                    "params": {"coeffs": list(p.kt_coeffs), "center_track": p.kt_center_track,
                               "scale_track": p.kt_scale_track}})
    if p.bias_knots_track and p.bias_knots_track != b.bias_knots_track:
        out.append({"effect": "position_bias", "params": {"knots_track": list(p.bias_knots_track),
                                                          "bias_a": list(p.bias_table_a)}})
    if (p.coulomb_a or p.viscous_a_per_tps) and (p.coulomb_a, p.viscous_a_per_tps) != (b.coulomb_a, b.viscous_a_per_tps):
        out.append({"effect": "friction", "params": {"coulomb_a": p.coulomb_a, "viscous_a_per_tps": p.viscous_a_per_tps}})
    if p.runout is not None and p.runout != b.runout:
        f0, hs, cs, ss = p.runout
        out.append({"effect": "periodic_disturbance", "params": {"spindle_hz": f0, "harmonics": list(hs),
                                                                 "cos_track": list(cs), "sin_track": list(ss)}})
    return out


def modal_plant(x: Drive | TruthPlant, effects: bool = True) -> ModalPlant:
    """The truth as a :class:`ModalPlant` (delay = plant delay + computation delay; the effects in the
    library's JSON form when ``effects``)."""
    drive = x if isinstance(x, Drive) else None
    p = drive.plant if drive else x
    delay = p.delay_s + (drive.computation_delay_s if drive else 0.0)
    d = {"k0": p.k0, "modes": [Mode(m.freq_hz, m.zeta, m.gain).to_dict() for m in p.modes], "bias_a": p.bias_a,
         "delay_s": delay, "track_pitch_nm": p.track_pitch_nm,
         "sample_rate_hz": drive.sample_rate_hz if drive else None,
         "effects": effect_dicts(p) if effects else [], "meta": {"source": "tests.drives truth"}}
    return ModalPlant.from_dict(d)


def from_modal_plant(mp: ModalPlant) -> TruthPlant:
    """Read a ModalPlant's numbers (fields and effect JSON) into a :class:`TruthPlant`."""
    base = TruthPlant(k0=mp.k0, modes=tuple((m.freq_hz, m.zeta, m.gain) for m in mp.modes), bias_a=mp.bias_a,
                      delay_s=mp.delay_s, track_pitch_nm=mp.track_pitch_nm)
    return base.with_effects([e.to_dict() for e in mp.effects])
