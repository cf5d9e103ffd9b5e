"""The members of a family of plants (logs of one drive at several temperatures, heads or zones):
their modes matched to the nominal plant's, their spread about it in physical terms (common frequency
and damping scale, gain, delay, each mode beyond that) and their labels in a robust set.
"""
from __future__ import annotations

import math

import numpy as np

from identification.model.plant import ModalPlant

from seekopt.design.predict import calibrated

__all__ = ["match_modes", "family_spread", "member", "label_set"]


def match_modes(a: ModalPlant, b: ModalPlant, tol: float = 0.15, scale: float = 1.0) -> list:
    """Index pairs ``(i, j)``: mode ``i`` of ``a`` and mode ``j`` of ``b``, nearest in log frequency
    after scaling ``a``'s frequencies by ``scale``, within ``tol`` (relative), one-to-one (greedy by
    distance)."""
    cand = sorted((abs(math.log(mb.freq_hz / (scale * ma.freq_hz))), i, j) for i, ma in enumerate(a.modes)
                  for j, mb in enumerate(b.modes) if abs(mb.freq_hz / (scale * ma.freq_hz) - 1) <= tol)
    used_a, used_b, out = set(), set(), []
    for _, i, j in cand:
        if i not in used_a and j not in used_b:
            used_a.add(i); used_b.add(j); out.append((i, j))
    return sorted(out)


def member(p: ModalPlant, k: int, design_k0: float) -> ModalPlant:
    """Family member ``k``: labelled, and played with its drive's gain calibration (:func:`seekopt.design.predict.calibrated`)."""
    q = calibrated(p, design_k0)
    q.meta["set_label"] = f"member {k}" + (f": {q.meta['family_name']}" if q.meta.get("family_name") else "")
    return q


def label_set(plants: list, family=()) -> list:
    """Label a plant set built without :class:`Drift` (nominal, ``RobustSpec`` vertices) and append the
    family members ("nominal", "vertex 1", ..., "member 1: <name>", ...)."""
    out = []
    for i, p in enumerate(plants):
        meta = dict(p.meta or {})
        meta["set_label"] = "nominal" if i == 0 else f"vertex {i}"
        out.append(p.copy(meta=meta))
    return out + [member(p, k, plants[0].k0) for k, p in enumerate(family, 1)]


def family_spread(nominal: ModalPlant, family) -> dict:
    """Spread of a family of plants about the nominal one.

    For each member: the common frequency scale (median of the matched modes' log frequency ratios:
    temperature moves every resonance; modes matched within 15 %, then again within 5 % of that
    scale), the common damping scale (median log ratio), the gain ``k0`` ratio and the delay
    difference; then each matched mode's own deviation beyond the common scales (a mode one member
    lacks or has extra adds nothing: the member itself is in the set).  Returns half-widths: ``{"temp", "zeta", "gain"}`` [fraction], ``"delay"`` [s] and
    ``"modes"`` (per nominal mode ``(df, dz, dg)`` [fraction]) -- the largest over the members --
    plus ``"members"`` (per member ``(temp, zeta, gain, delay)``)."""
    out = {"temp": 0.0, "zeta": 0.0, "gain": 0.0, "delay": 0.0,
           "modes": [[0.0, 0.0, 0.0] for _ in nominal.modes], "members": []}
    for p in family:
        pairs = match_modes(nominal, p)             # first pass: within 15 %, for the common scale
        lf = np.array([math.log(p.modes[j].freq_hz / nominal.modes[i].freq_hz) for i, j in pairs])
        if lf.size:                                 # second pass: within 5 % of the common scale
            pairs = match_modes(nominal, p, tol=0.05, scale=math.exp(float(np.median(lf))))
        lf = np.array([math.log(p.modes[j].freq_hz / nominal.modes[i].freq_hz) for i, j in pairs])
        lz = np.array([math.log(max(p.modes[j].zeta, 1e-9) / max(nominal.modes[i].zeta, 1e-9)) for i, j in pairs])
        sf = float(np.median(lf)) if lf.size else 0.0
        sz = float(np.median(lz)) if lz.size else 0.0
        sk = p.k0 / nominal.k0 - 1.0
        dd = p.delay_s - nominal.delay_s
        out["members"].append((math.expm1(sf), math.expm1(sz), sk, dd))
        out["temp"] = max(out["temp"], abs(math.expm1(sf)))
        out["zeta"] = max(out["zeta"], abs(math.expm1(sz)))
        out["gain"] = max(out["gain"], abs(sk))
        out["delay"] = max(out["delay"], abs(dd))
        for (i, j), a, b in zip(pairs, lf, lz):
            g0, g1 = nominal.modes[i].gain, p.modes[j].gain
            r = out["modes"][i]
            r[0] = max(r[0], abs(math.expm1(a - sf)))
            r[1] = max(r[1], abs(math.expm1(b - sz)))
            r[2] = max(r[2], abs(g1 / g0 - 1.0) if g0 else 0.0)
    return out


