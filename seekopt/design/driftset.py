"""The robust set of a drift (:func:`drift_set`): the nominal plant, the family's members, the nominal
plant at each member's drift, the corners and axial points of the common (correlated) drifts, the per-mode corners and a
few strength-2 orthogonal-array rows over the per-mode ranges; and :func:`drifted`, one plant drifted in
physical terms.  Each plant carries its ``meta["set_label"]`` and, where its gain differs from the
design plant's, the drive's feedforward calibration ``meta["ff_scale"]`` (see :mod:`seekopt.design.family`).
"""
from __future__ import annotations

import itertools

import numpy as np

from identification.model.plant import ModalPlant, Mode

from seekopt.design.blind_pes import ID_ERROR_ROLE
from seekopt.design.members import family_spread, member
from seekopt.design.predict import set_identity, set_label
from seekopt.design.robust import orthogonal_array_signs   # the one Sylvester-Hadamard construction (robust vertices too)

__all__ = ["drifted", "drift_set"]


def drifted(plant: ModalPlant, temp: float = 0.0, zeta: float = 0.0, gain: float = 0.0, delay_s: float = 0.0,
            label: str | None = None) -> ModalPlant:
    """``plant`` drifted in physical terms: every mode frequency x ``(1 + temp)``, every damping ratio
    x ``(1 + zeta)``, ``k0`` x ``(1 + gain)`` (fractions), delay + ``delay_s`` [s].  (A plant, as a truth
    is: no feedforward scale.)"""
    p = _vary(plant, label or f"temp{temp:+.3g} zeta{zeta:+.3g} gain{gain:+.3g}", temp, zeta, gain, delay_s)
    p.meta.pop("ff_scale", None)
    return p


def _vary(nominal: ModalPlant, label: str, temp=0.0, zeta=0.0, gain=0.0, delay=0.0, sf=None, sz=None, sg=None,
          ffgain=0.0, role=None):
    """A vertex: drifted plant; its gain drift ``gain`` compensated by the drive's feedforward calibration,
    ``ffgain`` the calibration's error (``meta["ff_scale"] = (1 + ffgain) / (1 + gain)``); ``role``: its
    ``meta["set_role"]`` (None: an operating condition, none)."""
    n = len(nominal.modes)
    sf = np.zeros(n) if sf is None else sf
    sz = np.zeros(n) if sz is None else sz
    sg = np.zeros(n) if sg is None else sg
    # damping: the common scale as stated (x0.8 / x1.2), each mode's own range multiplicatively
    # (x(1 + dz) or /(1 + dz): never negative however wide the data makes it)
    modes = [Mode(m.freq_hz * (1 + temp) * (1 + a), m.zeta * max(1 + zeta, 0.1) * (1 + abs(b)) ** np.sign(b),
                  m.gain * (1 + c), m.std) for m, a, b, c in zip(nominal.modes, sf, sz, sg)]
    meta = dict(nominal.meta or {})
    meta["set_label"] = label
    meta.pop("set_role", None)
    if role:
        meta["set_role"] = role
    scale = (1 + ffgain) / (1 + gain)
    if scale != 1.0:
        meta["ff_scale"] = scale
    else:
        meta.pop("ff_scale", None)
    return nominal.copy(modes=modes, k0=nominal.k0 * (1 + gain), delay_s=max(0.0, nominal.delay_s + delay), meta=meta)



def _common_points(r, fs):
    """Plants of the common (correlated) drifts of the ranges ``r`` (:class:`seekopt.design.drift.DriftRanges`)
    at the sample rate ``fs`` [Hz]: ``(levels, _vary keywords, label)``, each level -1, 0 or +1.

    Temperature is one parameter: every frequency x ``(1 + temp T)`` and, when a damping range is
    stated with it, every damping ratio x ``(1 - zeta T)`` (cold: stiffer and less damped, as the
    benchmark family's x1.04 / x0.8); a damping range without temperature is its own parameter.  Gain
    (compensated), feedforward calibration error and delay are further parameters.

    The points: the corners (full factorial up to four parameters, a resolution-V half fraction for
    five) and, with two parameters or more, the axial points (one parameter at +-1, the others at
    their nominal value) -- a face-centred design.  Corners alone are not enough: the seek's residual
    is not monotone along a common frequency scale (the lightly damped low modes' phase at the settle
    sample turns with it), so a design held on the corners only can leave the band in the middle of a
    face (measured on the NSS-like plant, ``temp=4%,zeta=20%,gain=5%``, K = 200, band margin 0.9:
    the set's worst 34 samples, temperature +4 % at nominal gain 38, gain -5 % at temperature -3 ... +3 %
    35; on the identified plant at margin 0.95, gain +5 % at temperature 0 ... +3 % 66 against 33; with
    the axial points no point of a 9 x 3 grid settles after the set's worst).  Ranges too small to
    change a seek (a 3-std ``k0`` of 0.005 %, a delay of 0.1 % of a sample) add no point."""
    params = []
    if r.temp >= 1e-4:
        params.append(("temp", {"temp": r.temp, "zeta": -r.zeta},
                       lambda s: f"temp{'+' if s > 0 else '-'}{100 * r.temp:.3g}%"
                       + (f" (zeta{'-' if s > 0 else '+'}{100 * r.zeta:.3g}%)" if r.zeta else "")))
    elif r.zeta >= 1e-3:
        params.append(("zeta", {"zeta": r.zeta}, lambda s: f"zeta{'+' if s > 0 else '-'}{100 * r.zeta:.3g}%"))
    for nm, w, lo in (("gain", r.gain, 1e-3), ("ffgain", r.ffgain, 1e-3), ("delay", r.delay, 1e-3 / (fs or 1e4))):
        if w >= lo:
            params.append((nm, {nm: w}, (lambda s, nm=nm, w=w: f"{nm}{'+' if s > 0 else '-'}{w * 1e6:.3g}us"
                                         if nm == "delay" else f"{nm}{'+' if s > 0 else '-'}{100 * w:.3g}%")))
    if not params:
        return []
    n = len(params)
    if n <= 4:
        rows = list(itertools.product((1, -1), repeat=n))
    else:
        rows = [t + (int(np.prod(t)),) for t in itertools.product((1, -1), repeat=4)]
    if n >= 2:
        rows += [tuple(s if i == j else 0 for i in range(n)) for j in range(n) for s in (1, -1)]
    out = []
    for levels in rows:
        kw = {}
        for (_, d, _), sg in zip(params, levels):
            for k, v in d.items():
                kw[k] = kw.get(k, 0.0) + sg * v
        out.append((levels, kw, " ".join(lab(sg) for (_, _, lab), sg in zip(params, levels) if sg)))
    return out


def _mode_corners(plant: ModalPlant, r, label: str) -> list:
    """The per-mode corners about ``plant`` (its feedforward calibration kept): every mode's frequency at
    + its range ``r.df``, at -; every gain at + ``r.dg``, at - (``r``: :class:`seekopt.design.drift.DriftRanges`)."""
    out = []
    for what, arr in (("freq", r.df), ("gain", r.dg)):
        if np.any(arr > 0):
            for sgn in (1, -1):
                modes = [Mode(m.freq_hz * (1 + sgn * a) if what == "freq" else m.freq_hz, m.zeta,
                              m.gain * (1 + sgn * a) if what == "gain" else m.gain, m.std)
                         for m, a in zip(plant.modes, arr)]
                meta = dict(plant.meta or {})
                meta["set_label"] = f"{label} {what} {'+' if sgn > 0 else '-'}"
                meta["set_role"] = ID_ERROR_ROLE        # the identification's error (blind_pes_plants)
                out.append(plant.copy(modes=modes, meta=meta))
    return out


def drift_set(nominal: ModalPlant, family, drift) -> list:
    """The robust set of ``drift`` (a :class:`seekopt.design.drift.Drift`) about ``nominal`` with the members
    of ``family``.

    Order: the nominal plant (``set_label`` "nominal"), the family members ("member 1", ...), the
    nominal plant moved by each member's common drift (frequency and damping scale, gain, delay:
    "nominal at member 1's drift"), the corners and axial points of the common drifts (:func:`_common_points`:
    temperature with its damping, gain, feedforward gain error, delay: "temp+4% (zeta-20%) gain-5%",
    "gain+5%"), the per-mode corners (every mode's frequency at + its range, at -; every gain at +, at -:
    "modes freq +"), the same about each member with its own ranges (its reported std and the seek-induced
    modes' range: "member 1: cold modes gain -"), then ``drift.n_samples`` orthogonal-array rows
    ("oa 1", ...) over the per-mode ranges (each mode's frequency, damping and gain at +- its
    range: columns of a Sylvester-Hadamard array, strength 2).  Plants that coincide as drives
    (:func:`~seekopt.design.predict.set_identity`: the plant and its feedforward calibration) are kept once.
    The per-mode corners and the array rows stand for the identification's own error and carry
    ``meta["set_role"]`` :data:`~seekopt.design.blind_pes.ID_ERROR_ROLE` (no blind-band mode's PES rows on
    them: :func:`seekopt.design.blind_pes.blind_pes_plants`); the others are operating conditions.
    """
    rng_ = drift.ranges(nominal, family)
    nom = _vary(nominal, "nominal")
    out = [nom]
    out += [member(p, k, nominal.k0) for k, p in enumerate(family, 1)]
    # the nominal plant moved to each member's common drift: covers what one member's identification
    # missed or got wrong (a mode another temperature's log shows is there at this one too)
    if family:
        for k, (t, z, g, d) in enumerate(family_spread(nominal, family)["members"], 1):
            out.append(_vary(nominal, f"nominal at member {k}'s drift", temp=t, zeta=z, gain=g, delay=d))
    for _, kw, label in _common_points(rng_, nominal.sample_rate_hz):
        out.append(_vary(nominal, label, **kw))
    n = len(nominal.modes)
    out += _mode_corners(nominal, rng_, "modes")
    # each member is an identified plant too: its own reported uncertainty (and the seek-induced modes'
    # own range) about it, as about the nominal plant -- the band margin is not what covers a member's
    # identification error (:data:`seekopt.design.problem.DRIFT_BAND_MARGIN`)
    for p in out[1:1 + len(family)]:
        out += _mode_corners(p, drift.ranges(p), f"{set_label(p)} modes")
    factors = [(kind, i) for kind, arr in (("f", rng_.df), ("z", rng_.dz), ("g", rng_.dg)) for i in range(n) if arr[i] > 0]
    if drift.n_samples and factors:
        rows = orthogonal_array_signs(factors, drift.n_samples, {"f": n, "z": n, "g": n},
                                      np.random.default_rng(drift.seed))
        for r, s in enumerate(rows, 1):
            out.append(_vary(nominal, f"oa {r}", sf=s["f"] * rng_.df, sz=s["z"] * rng_.dz, sg=s["g"] * rng_.dg,
                             role=ID_ERROR_ROLE))
    uniq, seen = [], set()
    for p in out:
        h = set_identity(p)
        if h not in seen:
            seen.add(h); uniq.append(p)
    return uniq
