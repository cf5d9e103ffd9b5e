"""The digital controller of the independent test drive: a cascade of discrete sections, stepped here.

The cascade maps the position error ``e = r - y`` [track], sampled at the servo rate ``fs``, to the
command current [A].  Section ``i`` runs ``m_i`` times per servo period (``rate_multiple``,
non-decreasing along the cascade); its input is the previous section's latest output, held
(zero-order hold).  The last section's ``L = max m_i`` outputs are the sub-step commands, each held
for ``Ts / L``.  Sections are ``("tf", num, den)`` in descending powers of z or ``("ss", A, B, C, D)``
— the same description as seekopt's controller JSON (``seekopt/data/nss_controller.json``), read
and stepped by code written here.

Builders: :func:`from_json` (that JSON), :func:`pid_lead` (continuous PID with lead and roll-off,
Tustin), :func:`notch` (prewarped Tustin notch), and :func:`nss_json` (the bundled NSS controller).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import signal

__all__ = ["Section", "DigitalController", "from_json", "pid_lead", "notch", "nss_json", "REPO"]

REPO = Path(__file__).resolve().parents[2]


@dataclass
class Section:
    """One discrete SISO section in state-space form ``x+ = A x + B v``, ``w = C x + D v``."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: float
    rate_multiple: int = 1
    label: str = ""

    @classmethod
    def tf(cls, num, den, rate_multiple: int = 1, label: str = "") -> "Section":
        num = np.trim_zeros(np.asarray(num, dtype=float), "f")
        den = np.trim_zeros(np.asarray(den, dtype=float), "f")
        if len(den) == 1:
            return cls(np.zeros((0, 0)), np.zeros(0), np.zeros(0), float(num[-1] / den[0]), rate_multiple, label)
        A, B, C, D = signal.tf2ss(num, den)
        return cls(A, B.ravel(), C.ravel(), float(D.ravel()[0]), rate_multiple, label)

    def to_json(self) -> dict:
        return {"kind": "ss", "A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
                "D": float(self.D), "rate_multiple": int(self.rate_multiple), "label": self.label}

    def freqresp(self, f_hz, fs: float) -> np.ndarray:
        """``H(z)`` at ``z = exp(j 2 pi f / (m fs))`` (the section at its own rate)."""
        z = np.exp(2j * np.pi * np.asarray(f_hz, dtype=float) / (self.rate_multiple * fs))
        n = self.A.shape[0]
        if n == 0:
            return np.full(z.shape, self.D, dtype=complex)
        return np.array([self.C @ np.linalg.solve(zz * np.eye(n) - self.A, self.B) + self.D for zz in z])


class DigitalController:
    """A multirate cascade of :class:`Section` at servo rate ``sample_rate_hz`` [Hz]."""

    def __init__(self, sections, sample_rate_hz: float, name: str = "controller"):
        self.sections = list(sections)
        self.sample_rate_hz = float(sample_rate_hz)
        self.name = name
        ms = [s.rate_multiple for s in self.sections]
        if any(b < a for a, b in zip(ms, ms[1:])):
            raise ValueError("rate_multiple must not decrease along the cascade")
        self.L = max(ms)
        self.reset()

    def reset(self) -> None:
        self.x = [np.zeros(s.A.shape[0]) for s in self.sections]

    def step(self, e: float) -> np.ndarray:
        """One servo period: error ``e`` [track] -> the ``L`` sub-step commands [A]."""
        v, m_prev = np.array([float(e)]), 1
        for i, s in enumerate(self.sections):
            m = s.rate_multiple
            w = np.empty(m)
            x = self.x[i]
            for j in range(m):
                vj = v[(j * m_prev) // m]
                w[j] = s.C @ x + s.D * vj
                x = s.A @ x + s.B * vj
            self.x[i] = x
            v, m_prev = w, m
        if m_prev < self.L:
            v = np.repeat(v, self.L // m_prev)
        return v

    def freqresp(self, f_hz) -> np.ndarray:
        """Single-rate equivalent ``prod_i H_i`` (each section at its own rate; holds ignored)."""
        out = np.ones(np.shape(f_hz), dtype=complex)
        for s in self.sections:
            out = out * s.freqresp(f_hz, self.sample_rate_hz)
        return out

    def to_json(self) -> dict:
        """seekopt's controller JSON (schema 1), every section as ``ss``."""
        return {"schema": 1, "name": self.name, "sample_rate_hz": self.sample_rate_hz,
                "sections": [s.to_json() for s in self.sections]}


def from_json(d) -> DigitalController:
    """Read seekopt's controller JSON (schema 1, ``sections`` form) from a dict or a path."""
    if not isinstance(d, dict):
        d = json.loads(Path(d).read_text())
    secs = []
    for s in d["sections"]:
        m = int(s.get("rate_multiple", 1))
        if s.get("kind", "tf" if "num" in s else "ss") == "tf":
            secs.append(Section.tf(s["num"], s["den"], m, s.get("label", "")))
        else:
            B = np.asarray(s["B"], dtype=float).ravel()
            A = np.asarray(s["A"], dtype=float).reshape(len(B), len(B))
            secs.append(Section(A, B, np.asarray(s["C"], dtype=float).ravel(), float(s["D"]), m, s.get("label", "")))
    return DigitalController(secs, float(d["sample_rate_hz"]), str(d.get("name", "controller")))


def nss_json() -> dict:
    """The bundled NSS benchmark controller description (data file, read as JSON)."""
    return json.loads((REPO / "seekopt" / "data" / "nss_controller.json").read_text())


def _tustin(num_s, den_s, rate_hz: float, prewarp_hz: float | None = None):
    """Tustin discretisation at ``rate_hz``, optionally prewarped to be exact at ``prewarp_hz``."""
    fs = rate_hz
    if prewarp_hz:
        w = 2 * math.pi * prewarp_hz
        fs = w / (2 * math.tan(w / (2 * rate_hz)))        # scale so that s = 2 fs' (z-1)/(z+1) hits w
    num, den = signal.bilinear(num_s, den_s, fs=fs)
    return num / den[0], den / den[0]


def pid_lead(k0: float, fs: float, crossover_hz: float, lead_ratio: float = 12.0, integral_frac: float = 0.12,
             rolloff_factor: float = 6.0, rate_multiple: int = 1, label: str = "PID + lead") -> Section:
    """``C(s) = K (1 + wi/s) (1 + s/wz)/(1 + s/wp) / (1 + s/wr)`` for the rigid body ``k0/s^2``:
    lead centred on the crossover ``wc`` (``wz = wc/sqrt(ratio)``, ``wp = wc sqrt(ratio)``),
    ``wi = integral_frac wc``, roll-off ``wr = rolloff_factor wc``; ``K`` gives ``|C P| = 1`` at ``wc``.
    Tustin at the section's rate."""
    wc = 2 * math.pi * crossover_hz
    r = math.sqrt(lead_ratio)
    wz, wp, wi, wr = wc / r, wc * r, integral_frac * wc, rolloff_factor * wc
    num = np.polymul(np.polymul([1.0, wi], [1.0 / wz, 1.0]), [1.0])
    den = np.polymul(np.polymul([1.0, 0.0], [1.0 / wp, 1.0]), [1.0 / wr, 1.0])
    s = 1j * wc
    gain = abs(np.polyval(num, s) / np.polyval(den, s)) * k0 / wc ** 2
    nz, dz = _tustin(num / gain, den, fs * rate_multiple)
    return Section.tf(nz, dz, rate_multiple, label)


def notch(freq_hz: float, fs: float, depth_db: float = 20.0, zeta_pole: float = 0.3, rate_multiple: int = 2) -> Section:
    """``(s^2 + 2 zeta_z w s + w^2)/(s^2 + 2 zeta_p w s + w^2)``, ``zeta_z = zeta_p 10^(-depth/20)``,
    prewarped Tustin at ``rate_multiple * fs`` (exact centre frequency)."""
    w = 2 * math.pi * freq_hz
    zz = zeta_pole * 10 ** (-depth_db / 20)
    nz, dz = _tustin([1.0, 2 * zz * w, w * w], [1.0, 2 * zeta_pole * w, w * w], fs * rate_multiple, prewarp_hz=freq_hz)
    return Section.tf(nz, dz, rate_multiple, f"notch {freq_hz:.0f} Hz")
