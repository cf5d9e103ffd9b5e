"""The modal plant of an HDD head/actuator and the one discretisation that steps it.

Continuous-time model (current ``u`` in A to head position ``y`` in tracks)::

    P(s) = k0 * [ 1/s^2 + sum_r g_r / (s^2 + 2 zeta_r w_r s + w_r^2) ] * exp(-s * delay_s)

``k0`` is the rigid-body gain in track/(A s^2), ``w_r = 2 pi freq_hz`` the
*natural* frequency and ``g_r`` the mode's gain relative to the rigid body (its
high-frequency asymptote is ``g_r`` times the rigid body's).  The paper's eq. (1)
writes the same modes as ``a_r w_dr / (s^2 + 2 zeta'_r w_dr s + (1 + zeta'_r^2) w_dr^2)``
with ``w_dr`` the damped frequency and ``zeta'_r w_dr`` the decay rate (ERRATA
item 2); :meth:`ModalPlant.to_eq1` and :meth:`ModalPlant.from_eq1` convert.

The constant bias force ``bias_a`` is expressed as a current added, undelayed, at
the plant input (the holding current is ``-bias_a``).  Effects
(:mod:`identification.model.effects`) extend the model; the plant, effects included,
steps itself through :class:`DiscretePlant`, the single discretisation used by
the open-loop simulation here and by the closed-loop simulator in
``seekopt.drive.simulator``.

Discretisation: zero-order hold on the command over each step ``dt`` with a
fractional input delay ``tau = (m + f) dt`` handled exactly (modified
z-transform)::

    x[k+1] = Phi x[k] + Gamma_old u[k-m-1] + Gamma_new u[k-m] + Gamma_f f[k]
    Gamma_new = int_0^{(1-f)dt} e^{A s} ds B,   Gamma_old = int_0^{dt} e^{A s} ds B - Gamma_new

where ``f[k]`` is the undelayed force channel (bias, state-dependent forces).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identification.model.effects import (AmplifierLag, Effect, ExtraMode, InputDelay, PivotSpringDamper,
                      effect_from_dict)
from identification.fileio import atomic_write_text

__all__ = ["Mode", "ModalPlant", "DiscretePlant", "PlantError", "TRACK_PITCH_PER_TPI_NM",
           "atomic_write_text", "block_tf"]

from identification.model.discrete import DiscretePlant, block_tf  # noqa: E402

#: track pitch [nm] = TRACK_PITCH_PER_TPI_NM / TPI (25.4 mm per inch)
TRACK_PITCH_PER_TPI_NM = 25.4e6


class PlantError(ValueError):
    """A plant file or description that cannot be used (one-line message)."""


def _json_number(value, key: str, source: str, none_ok: bool = False):
    """A JSON number as float; a string, bool or list is a :class:`PlantError`, not converted."""
    if value is None and none_ok:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        what = f"the string {value!r}" if isinstance(value, str) else type(value).__name__
        raise PlantError(f"{source}: {key} must be a number, got {what}"[:200])
    return float(value)


@dataclass
class Mode:
    """One vibration mode ``k0 * gain / (s^2 + 2 zeta w s + w^2)``, ``w = 2 pi freq_hz``.

    ``std`` holds one standard deviation of each identified parameter, or None.
    """

    freq_hz: float
    zeta: float
    gain: float
    std: dict | None = None

    @property
    def omega(self) -> float:
        """Natural frequency [rad/s]."""
        return 2.0 * math.pi * self.freq_hz

    def to_dict(self) -> dict:
        d = {"freq_hz": float(self.freq_hz), "zeta": float(self.zeta), "gain": float(self.gain)}
        d["std"] = None if self.std is None else {k: float(v) for k, v in self.std.items()}
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Mode":
        return cls(float(d["freq_hz"]), float(d["zeta"]), float(d["gain"]), d.get("std"))


@dataclass
class ModalPlant:
    """Rigid body + vibration modes + bias + input delay (+ effects).

    Parameters
    ----------
    k0 : float
        Rigid-body gain [track/(A s^2)].
    modes : list of Mode
    bias_a : float
        Bias force as an input current [A] (holding current is ``-bias_a``).
    delay_s : float
        Input delay [s]; fractional samples allowed.
    sample_rate_hz : float or None
        Servo (PES) sample rate the plant was identified at [Hz].
    track_pitch_nm : float or None
        Track pitch [nm]; gives the physical gain ``k0 * pitch`` [m/(A s^2)].
    effects : list of Effect
        Extensions beyond eq. (1) (see :mod:`identification.model.effects`).
    std : dict
        Standard deviations of ``k0``, ``bias_a``, ``delay_s`` where known.
    meta : dict
        Free-form provenance (method, log name, ...).
    """

    k0: float
    modes: list = field(default_factory=list)
    bias_a: float = 0.0
    delay_s: float = 0.0
    sample_rate_hz: float | None = None
    track_pitch_nm: float | None = None
    effects: list = field(default_factory=list)
    std: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        return {
            "schema": 1,
            "sample_rate_hz": self.sample_rate_hz,
            "track_pitch_nm": self.track_pitch_nm,
            "k0": float(self.k0),
            "bias_a": float(self.bias_a),
            "delay_s": float(self.delay_s),
            "modes": [m.to_dict() for m in self.modes],
            "effects": [e.to_dict() for e in self.effects],
            "std": {k: float(v) for k, v in self.std.items()},
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "plant") -> "ModalPlant":
        """Build a plant from its JSON dict; numbers must be JSON numbers (a quoted ``"3.9e9"`` is
        refused, not converted), then :meth:`validate`.  Raises :class:`PlantError` (one line)."""
        if not isinstance(d, dict):
            raise PlantError(f"{source}: plant JSON must be an object")
        try:
            if d.get("schema", 1) != 1:
                raise PlantError(f"{source}: unsupported plant schema {d.get('schema')!r}")
            if "k0" not in d:
                raise PlantError(f"{source}: missing key 'k0' (rigid-body gain, track/(A s^2))")
            num = _json_number
            modes = d.get("modes", [])
            if not isinstance(modes, list):
                raise PlantError(f"{source}: 'modes' must be a list of objects")
            for i, m in enumerate(modes, 1):
                if not isinstance(m, dict):
                    raise PlantError(f"{source}: mode {i} is not an object")
                for key in ("freq_hz", "zeta", "gain"):
                    if key not in m:
                        raise PlantError(f"{source}: mode {i}: missing key {key!r}")
                    num(m[key], f"mode {i} {key}", source)
            plant = cls(
                k0=num(d["k0"], "k0", source),
                modes=[Mode.from_dict(m) for m in modes],
                bias_a=num(d.get("bias_a", 0.0), "bias_a", source),
                delay_s=num(d.get("delay_s", 0.0), "delay_s", source),
                sample_rate_hz=num(d.get("sample_rate_hz"), "sample_rate_hz", source, none_ok=True),
                track_pitch_nm=num(d.get("track_pitch_nm"), "track_pitch_nm", source, none_ok=True),
                effects=[effect_from_dict(e) for e in d.get("effects", [])],
                std=dict(d.get("std") or {}),
                meta=dict(d.get("meta") or {}),
            )
        except PlantError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise PlantError(f"{source}: not a valid plant ({type(exc).__name__}: {exc})") from None
        plant.validate(source)
        return plant

    def validate(self, source: str = "plant") -> None:
        """Refuse a plant no drive can have (one-line :class:`PlantError` naming ``source``).

        Checked: every parameter finite; ``k0 > 0``; ``delay_s >= 0``; ``sample_rate_hz`` and
        ``track_pitch_nm`` positive when given; each mode ``freq_hz > 0``, ``zeta >= 0``; and for a
        plant identified from a log (``meta["method"]`` set by ``identify``) every mode below the
        Nyquist frequency of ``sample_rate_hz`` -- a sampled log cannot show a mode at or above it.
        (A physical or truth model may keep modes above Nyquist: the simulator samples them.)
        """
        vals = [self.k0, self.bias_a, self.delay_s] + [v for m in self.modes for v in (m.freq_hz, m.zeta, m.gain)]
        try:
            finite = all(math.isfinite(v) for v in vals)
        except TypeError:
            raise PlantError(f"{source}: plant parameters must be numbers") from None
        if not finite:
            raise PlantError(f"{source}: plant has a non-finite parameter")
        if self.k0 <= 0:
            raise PlantError(f"{source}: k0 must be > 0 track/(A s^2) (got {self.k0:g})")
        if self.delay_s < 0:
            raise PlantError(f"{source}: delay_s must be >= 0 s (got {self.delay_s:g})")
        for key, unit in (("sample_rate_hz", "Hz"), ("track_pitch_nm", "nm")):
            v = getattr(self, key)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise PlantError(f"{source}: {key} must be a positive number of {unit} or null (got {v:g})")
        for i, m in enumerate(self.modes, 1):
            if m.freq_hz <= 0 or m.zeta < 0:
                raise PlantError(f"{source}: mode {i} at {m.freq_hz:g} Hz needs freq_hz > 0 and zeta >= 0")
        fs = self.sample_rate_hz
        if fs is not None and (self.meta or {}).get("method"):
            for i, m in enumerate(self.modes, 1):
                if m.freq_hz >= fs / 2:
                    raise PlantError(f"{source}: mode {i} at {m.freq_hz:g} Hz is at or above the Nyquist "
                                     f"frequency {fs / 2:g} Hz of sample_rate_hz {fs:g}: a log sampled at "
                                     f"that rate cannot identify it (check freq_hz and sample_rate_hz)")

    def to_json(self, path: str | Path | None = None) -> str:
        text = json.dumps(self.to_dict(), indent=2)
        if path is not None:
            atomic_write_text(path, text)
        return text

    @classmethod
    def load(cls, path: str | Path) -> "ModalPlant":
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError) as exc:
            raise PlantError(f"{path}: cannot read plant file ({exc.__class__.__name__})") from None
        except json.JSONDecodeError as exc:
            raise PlantError(f"{path}: not valid JSON (line {exc.lineno})") from None
        if not isinstance(d, dict):
            raise PlantError(f"{path}: plant JSON must be an object")
        return cls.from_dict(d, source=str(path))

    def hash(self) -> str:
        """First 12 hex digits of the SHA-256 of the canonical JSON."""
        d = self.to_dict()
        d.pop("meta", None)
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:12]

    # ------------------------------------------------------------- variants
    def copy(self, **changes) -> "ModalPlant":
        d = self.to_dict()
        plant = ModalPlant.from_dict(d)
        for k, v in changes.items():
            setattr(plant, k, v)
        return plant

    @property
    def physical_gain(self) -> float | None:
        """Rigid-body gain in m/(A s^2) (needs ``track_pitch_nm``)."""
        return None if self.track_pitch_nm is None else self.k0 * self.track_pitch_nm * 1e-9

    def at_tpi(self, tpi: float) -> "ModalPlant":
        """The same mechanics at another track density: k0 re-expressed in tracks."""
        if self.track_pitch_nm is None:
            raise PlantError("plant has no track_pitch_nm; cannot re-express it per TPI")
        pitch = TRACK_PITCH_PER_TPI_NM / tpi
        return self.copy(k0=self.k0 * self.track_pitch_nm / pitch, track_pitch_nm=pitch)

    def linear_part(self) -> "ModalPlant":
        """The linear map current -> position (for linear design): structural effects only, no
        bias and no pivot rest offset (both are constant forces, affine terms of the model)."""
        keep = [dataclasses.replace(e, rest_track=0.0) if isinstance(e, PivotSpringDamper) else e
                for e in self.effects if e.kind == "structural"]
        return self.copy(effects=keep, bias_a=0.0)

    @property
    def is_linear(self) -> bool:
        return all(e.kind == "structural" for e in self.effects)

    @property
    def total_delay_s(self) -> float:
        return self.delay_s + sum(e.delay_s for e in self.effects if isinstance(e, InputDelay))

    def all_modes(self) -> list:
        """Declared modes plus ``extra_mode`` effects."""
        extra = [Mode(e.freq_hz, e.zeta, e.gain) for e in self.effects if isinstance(e, ExtraMode)]
        return list(self.modes) + extra

    # ---------------------------------------------------------- eq. (1) form
    def to_eq1(self) -> tuple[float, list[dict]]:
        """Paper eq. (1) parameters: ``(k0, [{"a": a_r, "omega": w_dr, "zeta": zeta'_r}])``.

        ``w_dr = w_n sqrt(1 - zeta^2)`` (damped, rad/s), ``zeta'_r = zeta w_n / w_dr``,
        ``a_r = k0 g / w_dr`` (so that ``a_r w_dr = k0 g``).  Needs zeta < 1.
        """
        out = []
        for m in self.modes:
            wd = m.omega * math.sqrt(1.0 - m.zeta ** 2)
            out.append({"a": self.k0 * m.gain / wd, "omega": wd, "zeta": m.zeta * m.omega / wd})
        return self.k0, out

    @classmethod
    def from_eq1(cls, k0: float, modes_eq1: list[dict], **kw) -> "ModalPlant":
        """Inverse of :meth:`to_eq1`: ``w_n^2 = (1 + zeta'^2) w_d^2``, ``zeta = zeta' w_d / w_n``."""
        modes = []
        for r in modes_eq1:
            wn = r["omega"] * math.sqrt(1.0 + r["zeta"] ** 2)
            modes.append(Mode(wn / (2 * math.pi), r["zeta"] * r["omega"] / wn, r["a"] * r["omega"] / k0))
        return cls(k0=k0, modes=modes, **kw)

    # ------------------------------------------------------- linear systems
    def state_space(self):
        """Continuous linear dynamics ``(A, B, Bf, C)`` without the delay.

        States: rigid position [track] and velocity [track/s], then each mode's
        deflection and rate, then (with ``amplifier_lag``) the delivered current.
        ``B`` is the command input (through the amplifier lag), ``Bf`` the
        undelayed force input (current-equivalent).
        """
        modes = self.all_modes()
        lag = [e for e in self.effects if isinstance(e, AmplifierLag)]
        pivot = [e for e in self.effects if isinstance(e, PivotSpringDamper)]
        n = 2 + 2 * len(modes) + (1 if lag else 0)
        A = np.zeros((n, n)); Bf = np.zeros(n); C = np.zeros(n)
        A[0, 1] = 1.0; Bf[1] = self.k0; C[0] = 1.0
        if pivot:
            wp = 2 * math.pi * pivot[0].freq_hz
            A[1, 0] = -wp ** 2; A[1, 1] = -2 * pivot[0].zeta * wp
        for i, m in enumerate(modes):
            j = 2 + 2 * i
            A[j, j + 1] = 1.0
            A[j + 1, j] = -m.omega ** 2; A[j + 1, j + 1] = -2 * m.zeta * m.omega
            Bf[j + 1] = self.k0 * m.gain
            C[j] = 1.0
        if lag:
            wa = 2 * math.pi * lag[0].bandwidth_hz
            A[:, n - 1] = Bf; A[n - 1, n - 1] = -wa
            B = np.zeros(n); B[n - 1] = wa
        else:
            B = Bf.copy()
        return A, B, Bf, C

    def frf(self, freqs_hz) -> np.ndarray:
        """Frequency response ``P(j 2 pi f)`` [track/A], delay included."""
        A, B, _, C = self.state_space()
        s = 2j * np.pi * np.atleast_1d(np.asarray(freqs_hz, dtype=float))
        eye = np.eye(A.shape[0])
        h = np.array([C @ np.linalg.solve(si * eye - A, B) for si in s])
        return h * np.exp(-s * self.total_delay_s)

    def to_control(self, pade_order: int | None = None):
        """python-control continuous system (delay as a Pade approximant if asked)."""
        import control
        A, B, _, C = self.state_space()
        sys = control.ss(A, B.reshape(-1, 1), C.reshape(1, -1), 0.0)
        if pade_order and self.total_delay_s > 0:
            num, den = control.pade(self.total_delay_s, pade_order)
            sys = sys * control.tf(num, den)
        return sys

    def to_control_discrete(self, dt: float | None = None):
        """python-control discrete system: ZOH at ``dt`` (default the log rate), delay included
        exactly as extra states (the delay line of :class:`DiscretePlant`)."""
        import control
        dt = dt or 1.0 / self.sample_rate_hz
        A, B, C, D = self.discretize(dt).augmented_ss()
        return control.ss(A, B, C, D, dt)

    def discretize(self, dt: float) -> "DiscretePlant":
        return DiscretePlant(self, dt)

    def simulate_open_loop(self, current_a, dt: float, position0: float = 0.0,
                           velocity0: float = 0.0, t0: float = 0.0, history_a=None) -> np.ndarray:
        """Position [track] from a current sequence (ZOH at ``dt``), starting at rest
        in the modes, from ``position0``/``velocity0``.  ``history_a`` fills the delay line
        (default: the first current sample)."""
        dp = self.discretize(dt)
        u = np.asarray(current_a, dtype=float)
        dp.reset(position0, velocity0, current=(u[0] if history_a is None else history_a), t0=t0)
        y = np.empty(len(u))
        for k in range(len(u)):
            y[k] = dp.output()
            dp.step(u[k])
        return y
