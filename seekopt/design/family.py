"""Families of plants and drift in physical terms: the robust set of a seek design.

A drive is not one plant.  Its resonances move together with temperature (a benchmark drive family
specifies every VCM resonance x1.04 at low and x0.96 at high temperature, damping x0.8 / x1.2), its
gain (torque constant over mass) moves a few percent, its delay by a fraction of a sample, and the
seek-induced modes (flex cable, coil) move on their own with head position.  Logs of one drive taken
at several temperatures, heads or zones identify to a **family** of plants.

Gain and the drive's feedforward calibration.  A profile is a current; played uncorrected on a plant
with 5 % more gain it moves the head 5 % too far (10 tracks at K = 200, measured 9 T_bb for the
optimal profile and for the sine alike; 2 % already 6 T_bb).  Drives therefore scale their seek
feedforward by their own gain estimate (seek-gain / torque-constant calibration), and so does this
model: a plant of the set whose gain differs from the design plant's plays the profile's current
scaled by ``plant.meta["ff_scale"]`` = design gain / its gain (:func:`feedforward_scale`,
:func:`played_on`; the closed-loop maps of the design are scaled the same way,
:func:`scale_feedforward_maps`).  What the gain drift still changes is the loop gain.  The
calibration's own error is the uncompensated ``ffgain`` range (default: ``n_sigma`` standard
deviations of the identified ``k0``).

:class:`Drift` states the drift in those physical terms (``temp=+-4%,zeta=+-20%,gain=+-5%,delay=+-1us``,
per-mode ranges ``f1738=+-5%``, ``f1738.zeta=+-30%``); what it does not state comes from the data
(:meth:`Drift.ranges`): every parameter's range is at least ``n_sigma`` of the standard deviation
the identification reports, and with a family the spread of the members about the nominal one -- the
common frequency and damping scale and the gain that best map the nominal plant onto each member, and
what each mode does beyond that.

:func:`drift_set` samples the drift with few plants: the nominal plant, every family member, the
corners of the correlated (common) drifts -- a common frequency scale is one parameter, not one per
mode, so temperature, damping scale, gain and delay give at most 16 corners -- and a few rows of a
strength-2 orthogonal array over the independent per-mode ranges (each mode's frequency, damping and
gain at +- its range; the residual vibration is linear in the gains and its worst case over a box
sits on vertices).  Each plant carries a label (``plant.meta["set_label"]``) so a design can say which plant of
the set binds; :mod:`seekopt.design.predict` plays a profile on every plant of the set.
"""
from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field

import numpy as np

from identification.model.plant import ModalPlant, Mode

from seekopt.design.predict import (SetPrediction, calibrated, feedforward_scale, played_on,  # noqa: F401
                                    predict_on_set, scale_feedforward_maps, set_label)

__all__ = ["DriftError", "Drift", "DriftRanges", "ModeRange", "family_spread", "drift_set", "drifted", "match_modes",
           "label_set", "set_label", "SetPrediction", "predict_on_set", "feedforward_scale", "calibrated", "played_on",
           "scale_feedforward_maps"]


class DriftError(ValueError):
    """A drift statement that cannot be read (one-line message)."""


def _seek_induced(mode: Mode) -> bool:
    from seekopt.design.robust import seek_induced
    return seek_induced(mode)


_NUM = r"(?:\+-|±|\+/-)?\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*"
_UNITS_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


def _percent(key: str, text: str) -> float:
    """``+-4%``, ``±4%`` or ``4`` -> 4.0 [%]."""
    m = re.fullmatch(_NUM + r"%?", text.strip())
    if not m:
        raise DriftError(f"drift {key}={text!r}: expected a half-width in percent such as +-4%")
    return float(m.group(1))


def _seconds(key: str, text: str) -> float:
    """``+-1us``, ``±0.5 us``, ``1e-6`` (s) -> seconds."""
    m = re.fullmatch(_NUM + r"(s|ms|us|µs|ns)?", text.strip())
    if not m:
        raise DriftError(f"drift {key}={text!r}: expected a time such as +-1us")
    return float(m.group(1)) * _UNITS_S[m.group(2) or "s"]


@dataclass
class ModeRange:
    """A range the user states for one mode (half-widths [%]; None: from the data)."""

    freq_pct: float | None = None
    zeta_pct: float | None = None
    gain_pct: float | None = None


@dataclass
class Drift:
    """Drift of a drive's plant in physical terms (half-widths around the nominal plant).

    Parameters
    ----------
    temp_pct : float or None
        Common scale of every resonance frequency [%] (temperature: all modes move together, one
        parameter).  None: from the data (a family's members are in the set: they are the drift the
        data shows; a single plant shows none).
    zeta_pct : float or None
        Scale of every damping ratio [%], moving with temperature when ``temp`` is stated (the
        damping falls as the frequencies rise: cold x1.04 / x0.8, hot x0.96 / x1.2), else on its own.
        None: from the data.
    gain_pct : float or None
        Drive gain ``k0`` (the whole plant with it) [%], compensated in the feedforward by the drive's
        gain calibration (see the module notes): it changes the loop gain.  None: from the data (the
        family's spread; 0 for a single plant).
    ffgain_pct : float or None
        Error of that calibration [%]: the feedforward is off by this much, uncompensated.  None:
        ``n_sigma`` std of the identified ``k0``.
    delay_s : float or None
        Delay half-width [s].  None: from the data.
    seek_pct : float
        Frequency of each seek-induced mode (gain below the rigid body at resonance:
        :func:`seekopt.design.robust.seek_induced`), each on its own [%]: flex-cable and coil modes
        move with head position and cable shape by a few percent, far more than any log of one
        temperature shows.
    modes : dict
        ``{freq_hz: ModeRange}``: ranges the user knows better for the identified mode nearest
        ``freq_hz`` (within 10 %).
    n_sigma : float
        Floor of every range in reported standard deviations.
    n_samples : int
        Orthogonal-array rows over the independent per-mode ranges (default 0: the per-mode corners --
        every mode at + its range, every mode at - -- only; on the NSS-like drive and its temperature
        family 7 rows cost 2 samples at K = 200 and no truth plant, shifted or not, needed them).
    nyquist_guard : float
        Modes above ``nyquist_guard * fs / 2`` get no per-mode range (aliased near Nyquist, their
        reported std says little; the unmodelled-mode guard covers that band); the common drifts still
        move them.
    objective : {"worst", "mean"}
        As :class:`seekopt.design.robust.RobustSpec`.
    seed : int
        Column draw of the orthogonal array.
    """

    temp_pct: float | None = None
    zeta_pct: float | None = None
    gain_pct: float | None = None
    delay_s: float | None = None
    seek_pct: float = 5.0
    modes: dict = field(default_factory=dict)
    ffgain_pct: float | None = None
    n_sigma: float = 3.0
    n_samples: int = 0
    nyquist_guard: float = 0.9
    objective: str = "worst"
    seed: int = 0

    _KEYS = {"temp": "temp_pct", "freq": "temp_pct", "zeta": "zeta_pct", "damping": "zeta_pct",
             "gain": "gain_pct", "k0": "gain_pct", "ffgain": "ffgain_pct", "delay": "delay_s", "seek": "seek_pct",
             "sigma": "n_sigma", "n": "n_samples", "objective": "objective", "seed": "seed",
             "nyq": "nyquist_guard"}

    def __post_init__(self):
        if self.objective not in ("worst", "mean"):
            raise DriftError(f"drift objective must be 'worst' or 'mean', not {self.objective!r}")
        self.modes = {float(k): (v if isinstance(v, ModeRange) else ModeRange(**v)) for k, v in (self.modes or {}).items()}
        vals = [self.temp_pct, self.zeta_pct, self.gain_pct, self.ffgain_pct, self.delay_s, self.seek_pct, self.n_sigma,
                self.nyquist_guard] + [x for r in self.modes.values() for x in (r.freq_pct, r.zeta_pct, r.gain_pct)]
        if any(v is not None and (not math.isfinite(v) or v < 0) for v in vals) or self.n_samples < 0:
            raise DriftError("drift ranges must be finite and >= 0")

    # ------------------------------------------------------------------ text form
    @classmethod
    def from_string(cls, text: str | None) -> "Drift":
        """``"temp=±4%,zeta=±20%,gain=±5%,delay=±1us,seek=±5%,f1738=±5%,f1738.zeta=±30%,sigma=3"``
        (``+-`` or ``±`` or nothing before the number; % for relative, s/ms/us/ns for the delay;
        ``data`` for a common range taken from the data).
        ``""``, ``"default"`` or None: everything from the data (:class:`Drift` defaults)."""
        kw, modes = {}, {}
        for item in filter(None, (text or "").replace(" ", "").split(",")):
            if item in ("default", "data"):
                continue
            k, eq, v = item.partition("=")
            if not eq:
                raise DriftError(f"drift {text!r}: item {item!r} is not key=value")
            mm = re.fullmatch(r"f([0-9]*\.?[0-9]+)(?:hz)?(?:\.(freq|zeta|gain))?", k.lower())
            if mm:
                r = modes.setdefault(float(mm.group(1)), ModeRange())
                setattr(r, f"{mm.group(2) or 'freq'}_pct", _percent(k, v))
                continue
            if k not in cls._KEYS:
                raise DriftError(f"drift {text!r}: unknown item {k!r} (keys: {', '.join(sorted(cls._KEYS))}, "
                                 f"f<Hz>[.zeta|.gain])")
            name = cls._KEYS[k]
            if v == "data" and name in ("temp_pct", "zeta_pct", "gain_pct", "ffgain_pct", "delay_s"):
                kw[name] = None                     # from the data (the default)
            elif name == "objective":
                kw[name] = v
            elif name in ("n_samples", "seed"):
                try:
                    kw[name] = int(float(v))
                except ValueError:
                    raise DriftError(f"drift {text!r}: {k} is not a number") from None
            elif name == "delay_s":
                kw[name] = _seconds(k, v)
            elif name in ("n_sigma", "nyquist_guard"):
                try:
                    kw[name] = float(v)
                except ValueError:
                    raise DriftError(f"drift {text!r}: {k} is not a number") from None
            else:
                kw[name] = _percent(k, v)
        return cls(modes=modes, **kw)

    @classmethod
    def merged(cls, texts) -> "Drift":
        """Several ``--drift`` options, later items overriding earlier ones."""
        return cls.from_string(",".join(t for t in texts if t))

    def to_string(self) -> str:
        def p(v, unit="%"):
            return "data" if v is None else (f"±{v * 1e6:g}us" if unit == "s" else f"±{v:g}%")
        parts = [f"temp={p(self.temp_pct)}", f"zeta={p(self.zeta_pct)}", f"gain={p(self.gain_pct)}",
                 f"ffgain={p(self.ffgain_pct)}", f"delay={p(self.delay_s, 's')}", f"seek=±{self.seek_pct:g}%"]
        for f0, r in sorted(self.modes.items()):
            for what in ("freq", "zeta", "gain"):
                v = getattr(r, f"{what}_pct")
                if v is not None:
                    parts.append(f"f{f0:g}{'' if what == 'freq' else '.' + what}=±{v:g}%")
        parts += [f"sigma={self.n_sigma:g}", f"n={self.n_samples}"]
        if self.objective != "worst":
            parts.append(f"objective={self.objective}")
        return ",".join(parts)

    def to_dict(self) -> dict:
        return {"kind": "drift", "temp_pct": self.temp_pct, "zeta_pct": self.zeta_pct, "gain_pct": self.gain_pct,
                "ffgain_pct": self.ffgain_pct, "delay_s": self.delay_s, "seek_pct": self.seek_pct,
                "modes": {str(k): vars(v).copy() for k, v in self.modes.items()}, "n_sigma": self.n_sigma,
                "n_samples": self.n_samples, "nyquist_guard": self.nyquist_guard, "objective": self.objective,
                "seed": self.seed}

    @classmethod
    def from_dict(cls, d: dict) -> "Drift":
        d = {k: v for k, v in d.items() if k != "kind"}
        d["modes"] = {float(k): ModeRange(**v) for k, v in (d.get("modes") or {}).items()}
        return cls(**d)

    # ------------------------------------------------------------------ ranges from the data
    def ranges(self, nominal: ModalPlant, family=()) -> "DriftRanges":
        """The ranges used: stated ones, else the data's (family spread, ``n_sigma`` std)."""
        spread = family_spread(nominal, family) if family else None
        ns = self.n_sigma
        fs = nominal.sample_rate_hz
        fny = self.nyquist_guard * 0.5 * fs if fs else math.inf
        src = {}

        def common(stated, key):
            # a family's members are in the set themselves: they are where the data puts the common
            # drift (on the line the temperatures trace, not at the corners of a box around it)
            if stated is not None:
                src[key] = "stated"
                return stated / 100.0 if key != "delay" else stated
            src[key] = (f"family members (spread ±{100 * spread[key]:.3g}%)" if key != "delay" else
                        f"family members (spread ±{1e6 * spread[key]:.3g} us)") if spread is not None else "none"
            return 0.0
        temp, zeta = common(self.temp_pct, "temp"), common(self.zeta_pct, "zeta")
        gain = common(self.gain_pct, "gain")
        src["ffgain"] = "stated" if self.ffgain_pct is not None else "std"
        ffgain = (self.ffgain_pct / 100.0 if self.ffgain_pct is not None
                  else ns * float(nominal.std.get("k0", 0.0)) / nominal.k0)
        delay = max(common(self.delay_s, "delay"), ns * float(nominal.std.get("delay_s", 0.0)))
        df, dz, dg = [], [], []
        resid = spread["modes"] if spread is not None else None
        for i, m in enumerate(nominal.modes):
            sd = m.std or {}
            user = self._user_range(m)
            if m.freq_hz >= fny:
                df.append(0.0); dz.append(0.0); dg.append(0.0)
                continue
            fr = [ns * sd.get("freq_hz", 0.0) / m.freq_hz, self.seek_pct / 100.0 if _seek_induced(m) else 0.0]
            zr = [ns * sd.get("zeta", 0.0) / m.zeta if m.zeta else 0.0]
            gr = [ns * sd.get("gain", 0.0) / abs(m.gain) if m.gain else 0.0]
            if resid is not None:
                fr.append(resid[i][0]); zr.append(resid[i][1]); gr.append(resid[i][2])
            for lst, v in ((fr, user.freq_pct), (zr, user.zeta_pct), (gr, user.gain_pct)):
                if v is not None:
                    lst[:] = [v / 100.0]          # the user knows better: the stated range replaces the data's
            df.append(max(fr)); dz.append(max(zr)); dg.append(max(gr))
        return DriftRanges(temp, zeta, gain, delay, np.array(df), np.array(dz), np.array(dg), src, ffgain)

    def _user_range(self, mode: Mode) -> ModeRange:
        best = None
        for f0, r in self.modes.items():
            if abs(mode.freq_hz - f0) <= 0.1 * f0 and (best is None or abs(mode.freq_hz - f0) < abs(mode.freq_hz - best[0])):
                best = (f0, r)
        return best[1] if best else ModeRange()

    def check_modes(self, nominal: ModalPlant) -> None:
        """Every per-mode range must name an identified mode (within 10 %)."""
        for f0 in self.modes:
            if not any(abs(m.freq_hz - f0) <= 0.1 * f0 for m in nominal.modes):
                have = ", ".join(f"{m.freq_hz:.0f}" for m in nominal.modes) or "none"
                raise DriftError(f"drift f{f0:g}: no identified mode within 10 % of {f0:g} Hz (modes: {have} Hz)")

    def plants(self, nominal: ModalPlant, family=()) -> list:
        """The robust set (:func:`drift_set`)."""
        return drift_set(nominal, family, self)


@dataclass
class DriftRanges:
    """Half-widths actually used: common ``temp``, ``zeta``, ``gain`` (compensated), ``ffgain``
    (feedforward calibration error) [fraction], ``delay`` [s]; per mode ``df``, ``dz``, ``dg``
    [fraction]; ``source`` says where each common range came from."""

    temp: float
    zeta: float
    gain: float
    delay: float
    df: np.ndarray
    dz: np.ndarray
    dg: np.ndarray
    source: dict
    ffgain: float = 0.0

    def describe(self) -> str:
        return (f"temp ±{100 * self.temp:.3g}% ({self.source.get('temp')}), zeta ±{100 * self.zeta:.3g}% "
                f"({self.source.get('zeta')}), gain ±{100 * self.gain:.3g}% ({self.source.get('gain')}), "
                f"feedforward gain ±{100 * self.ffgain:.3g}% ({self.source.get('ffgain')}), delay "
                f"±{self.delay * 1e6:.3g} us; per mode freq ±{100 * np.max(self.df, initial=0):.3g}% max")


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


def _member(p: ModalPlant, k: int, design_k0: float) -> ModalPlant:
    """Family member ``k``: labelled, and played with its drive's gain calibration (:func:`calibrated`)."""
    meta = dict(p.meta or {})
    meta["set_label"] = f"member {k}" + (f": {meta['family_name']}" if meta.get("family_name") else "")
    meta["ff_scale"] = float(design_k0) / float(p.k0)
    return p.copy(meta=meta)


def label_set(plants: list, family=()) -> list:
    """Label a plant set built without :class:`Drift` (nominal, ``RobustSpec`` vertices) and append the
    family members ("nominal", "vertex 1", ..., "member 1: <name>", ...)."""
    out = []
    for i, p in enumerate(plants):
        meta = dict(p.meta or {})
        meta["set_label"] = "nominal" if i == 0 else f"vertex {i}"
        out.append(p.copy(meta=meta))
    return out + [_member(p, k, plants[0].k0) for k, p in enumerate(family, 1)]


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


def drifted(plant: ModalPlant, temp: float = 0.0, zeta: float = 0.0, gain: float = 0.0, delay_s: float = 0.0,
            label: str | None = None) -> ModalPlant:
    """``plant`` drifted in physical terms: every mode frequency x ``(1 + temp)``, every damping ratio
    x ``(1 + zeta)``, ``k0`` x ``(1 + gain)`` (fractions), delay + ``delay_s`` [s].  (A plant, as a truth
    is: no feedforward scale.)"""
    p = _vary(plant, label or f"temp{temp:+.3g} zeta{zeta:+.3g} gain{gain:+.3g}", temp, zeta, gain, delay_s)
    p.meta.pop("ff_scale", None)
    return p


def _vary(nominal: ModalPlant, label: str, temp=0.0, zeta=0.0, gain=0.0, delay=0.0, sf=None, sz=None, sg=None,
          ffgain=0.0):
    """A vertex: drifted plant; its gain drift ``gain`` compensated by the drive's feedforward calibration,
    ``ffgain`` the calibration's error (``meta["ff_scale"] = (1 + ffgain) / (1 + gain)``)."""
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
    scale = (1 + ffgain) / (1 + gain)
    if scale != 1.0:
        meta["ff_scale"] = scale
    else:
        meta.pop("ff_scale", None)
    return nominal.copy(modes=modes, k0=nominal.k0 * (1 + gain), delay_s=max(0.0, nominal.delay_s + delay), meta=meta)


def _sylvester(nrows: int) -> np.ndarray:
    H = np.ones((1, 1))
    while H.shape[1] <= nrows:
        H = np.block([[H, H], [H, -H]])
    return H


def _common_corners(r: "DriftRanges", fs):
    """Corners of the common (correlated) drifts: ``(signs, _vary keywords, label)``.

    Temperature is one parameter: every frequency x ``(1 + temp T)`` and, when a damping range is
    stated with it, every damping ratio x ``(1 - zeta T)`` (cold: stiffer and less damped, as the
    benchmark family's x1.04 / x0.8), ``T = +-1``; a damping range without temperature is its own
    parameter.  Gain (compensated), feedforward calibration error and delay are further parameters.
    Full factorial up to four parameters, a resolution-V half fraction for five.  Ranges too small to
    change a seek (a 3-std ``k0`` of 0.005 %, a delay of 0.1 % of a sample) add no corner."""
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
    if len(params) <= 4:
        rows = list(itertools.product((1, -1), repeat=len(params)))
    else:
        rows = [t + (int(np.prod(t)),) for t in itertools.product((1, -1), repeat=4)]
    out = []
    for signs in rows:
        kw = {}
        for (_, d, _), sg in zip(params, signs):
            for k, v in d.items():
                kw[k] = kw.get(k, 0.0) + sg * v
        out.append((signs, kw, " ".join(lab(sg) for (_, _, lab), sg in zip(params, signs))))
    return out


def drift_set(nominal: ModalPlant, family, drift: Drift) -> list:
    """The robust set of ``drift`` about ``nominal`` with the members of ``family``.

    Order: the nominal plant (``set_label`` "nominal"), the family members ("member 1", ...), the
    nominal plant moved by each member's common drift (frequency and damping scale, gain, delay:
    "nominal at member 1's drift"), the corners of the common drifts (:func:`_common_corners`: temperature with its damping, gain,
    feedforward gain error, delay: "temp+4% (zeta-20%) gain-5%"), the per-mode corners (every mode's frequency at
    + its range, at -; every gain at +, at -), then ``drift.n_samples`` orthogonal-array rows
    ("oa 1", ...) over the per-mode ranges (each mode's frequency, damping and gain at +- its
    range: columns of a Sylvester-Hadamard array, strength 2).  Plants that coincide are kept once.
    """
    rng_ = drift.ranges(nominal, family)
    nom = _vary(nominal, "nominal")
    out = [nom]
    out += [_member(p, k, nominal.k0) for k, p in enumerate(family, 1)]
    # the nominal plant moved to each member's common drift: covers what one member's identification
    # missed or got wrong (a mode another temperature's log shows is there at this one too)
    if family:
        for k, (t, z, g, d) in enumerate(family_spread(nominal, family)["members"], 1):
            out.append(_vary(nominal, f"nominal at member {k}'s drift", temp=t, zeta=z, gain=g, delay=d))
    for signs, kw, label in _common_corners(rng_, nominal.sample_rate_hz):
        out.append(_vary(nominal, label, **kw))
    n = len(nominal.modes)
    for what, arr in (("freq", rng_.df), ("gain", rng_.dg)):   # per-mode corners: every mode at + / at -
        if np.any(arr > 0):
            for sgn in (1, -1):
                kw = {"sf" if what == "freq" else "sg": sgn * arr}
                out.append(_vary(nominal, f"modes {what} {'+' if sgn > 0 else '-'}", **kw))
    factors = [(kind, i) for kind, arr in (("f", rng_.df), ("z", rng_.dz), ("g", rng_.dg)) for i in range(n) if arr[i] > 0]
    if drift.n_samples and factors:
        H = _sylvester(drift.n_samples)
        rng = np.random.default_rng(drift.seed)
        cols = 1 + np.resize(rng.permutation(H.shape[1] - 1), len(factors))
        for r, row in enumerate(H[1:1 + drift.n_samples], 1):
            s = {"f": np.zeros(n), "z": np.zeros(n), "g": np.zeros(n)}
            for (kind, i), c in zip(factors, cols):
                s[kind][i] = row[c]
            out.append(_vary(nominal, f"oa {r}", sf=s["f"] * rng_.df, sz=s["z"] * rng_.dz, sg=s["g"] * rng_.dg))
    uniq, seen = [], set()
    for p in out:
        h = p.hash()
        if h not in seen:
            seen.add(h); uniq.append(p)
    return uniq
