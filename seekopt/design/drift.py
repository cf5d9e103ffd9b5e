"""Drift of a drive's plant in physical terms (``temp=±4%,zeta=±20%,gain=±5%,delay=±1us``, per mode
``f1738=±5%``): :class:`Drift` (text and JSON forms) and the ranges it resolves to against the data,
:class:`DriftRanges` (stated ranges, else the family's spread and ``n_sigma`` reported standard
deviations).  The plants of the robust set are :func:`seekopt.design.driftset.drift_set`; the model of
gain drift and the drive's feedforward calibration is told in :mod:`seekopt.design.family`.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from identification.model.plant import ModalPlant, Mode

from seekopt.design.driftset import drift_set
from seekopt.design.members import family_spread
from seekopt.design.robust import seek_induced

__all__ = ["DriftError", "Drift", "DriftRanges", "ModeRange"]


class DriftError(ValueError):
    """A drift statement that cannot be read (one-line message)."""


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
            fr = [ns * sd.get("freq_hz", 0.0) / m.freq_hz, self.seek_pct / 100.0 if seek_induced(m) else 0.0]
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

