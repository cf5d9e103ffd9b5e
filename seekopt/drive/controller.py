"""Feedback controller as data: JSON cascade, NSS preset, multirate runtime, lifting, frequency response.

Conventions
-----------
The controller maps the position error ``e = r - y`` [track] (sampled at the PES rate
``fs = sample_rate_hz``) to the feedback current [A]; the 2DOF law is
``u(k) = u_ff(k) + C(z) e(k)``.  ``C`` is a series cascade of discrete SISO sections
(error -> section 1 -> ... -> current).  Section ``i`` runs at ``m_i * fs`` with an integer
``rate_multiple`` ``m_i >= 1``, non-decreasing along the cascade; its input is the output of
the slower section before it, held (zero-order hold).  ``L = max m_i`` (``fast_multiple``)
sub-step currents are produced per PES sample.  Sections sharing a rate are realised as one
combined state space ``x+ = A x + B v, w = C x + D v`` (series connection).

The section forms are :mod:`seekopt.drive.sections`; the open-loop analysis of ``P C`` is
:mod:`seekopt.drive.openloop` (re-exported here).
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from seekopt.drive.openloop import LoopAnalysis, loop_analysis, plot_loop_analysis, print_loop_analysis  # noqa: F401
from seekopt.drive.sections import ControllerError, normalise_section, section_freqresp, section_ss, series

__all__ = ["ControllerError", "Controller", "ControllerRuntime", "LoopAnalysis",
           "loop_analysis", "print_loop_analysis", "plot_loop_analysis"]


@dataclass
class Controller:
    """Discrete (multirate) cascade controller ``e [track] -> current [A]``.

    Attributes
    ----------
    name : str
    sample_rate_hz : float
        PES sample rate ``fs`` [Hz]; a section with ``rate_multiple`` m runs at ``m * fs``.
    sections : list of dict
        Treat as immutable after construction.  Canonical sections, ``{"kind": "tf", "num", "den", "rate_multiple"}`` (descending powers
        of z) or ``{"kind": "ss", "A", "B", "C", "D", "rate_multiple"}``; optional ``"label"``.
    """

    name: str
    sample_rate_hz: float
    sections: list
    source: str = field(default="<memory>", compare=False, repr=False)

    def __post_init__(self):
        src = self.source
        fs = self.sample_rate_hz
        if isinstance(fs, bool) or not isinstance(fs, (int, float)) or not math.isfinite(fs) or fs <= 0:
            raise ControllerError(f"{src}: sample_rate_hz {fs!r} is not a positive number")
        self.sample_rate_hz = float(fs)
        if not isinstance(self.sections, (list, tuple)) or not self.sections:
            raise ControllerError(f"{src}: controller has no sections")
        self.sections = [normalise_section(s, 1, f"{src}: section {i}") for i, s in enumerate(self.sections, 1)]
        ms = [s["rate_multiple"] for s in self.sections]
        bad = [i for i in range(1, len(ms)) if ms[i] < ms[i - 1]]
        if bad:
            raise ControllerError(f"{src}: rate_multiple decreases along the cascade "
                                  f"(section {bad[0] + 1}: {ms[bad[0]]} after {ms[bad[0] - 1]})")
        self._groups = []  # [(m, A, B, C, D)] one combined state space per rate
        for m in sorted(set(ms)):
            parts = [section_ss(s) for s in self.sections if s["rate_multiple"] == m]
            for ss in parts[1:]:
                parts[0] = series(parts[0], ss)
            self._groups.append((m,) + tuple(parts[0]))

    # ---------------------------------------------------------------- construction / IO
    @classmethod
    def from_json(cls, path_or_dict) -> "Controller":
        """Load from a JSON file path or an already-parsed dict.

        Accepted forms: ``{"schema": 1, "name", "sample_rate_hz", "sections": [...]}``, or the
        issue form with ``"cascade": [{"num", "den"}, ...]`` or ``"state_space": {A, B, C, D}``
        (rate 1), each optionally followed by ``"multirate": {"rate_multiple": m, "sections": [...]}``
        (or a list of such blocks).  ``"sample_period_s"`` may replace ``sample_rate_hz``.
        """
        if isinstance(path_or_dict, dict):
            d, src = path_or_dict, f"<dict {path_or_dict.get('name', '')!s}>"
        else:
            src = str(path_or_dict)
            try:
                d = json.loads(Path(path_or_dict).read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise ControllerError(f"{src}: cannot read controller JSON ({str(exc).splitlines()[0]})") from None
            if not isinstance(d, dict):
                raise ControllerError(f"{src}: top level is not a JSON object")
        if d.get("schema", 1) != 1:
            raise ControllerError(f"{src}: unsupported schema {d.get('schema')!r} (expected 1)")
        if "sample_rate_hz" in d:
            fs = d["sample_rate_hz"]
        elif isinstance(d.get("sample_period_s"), (int, float)) and d["sample_period_s"] > 0:
            fs = 1.0 / d["sample_period_s"]
        else:
            raise ControllerError(f"{src}: missing key 'sample_rate_hz'")
        forms = [k for k in ("sections", "cascade", "state_space") if k in d]
        if len(forms) > 1:
            raise ControllerError(f"{src}: give only one of 'sections', 'cascade', 'state_space' (got {forms})")
        if not forms and "multirate" not in d:
            raise ControllerError(f"{src}: missing key 'sections' (or 'cascade' / 'state_space')")
        secs = []
        if forms:
            base = d[forms[0]]
            if forms[0] == "state_space":
                base = [base]
            if not isinstance(base, list):
                raise ControllerError(f"{src}: '{forms[0]}' has the wrong type")
            secs += [normalise_section(s, 1, f"{src}: section {i}") for i, s in enumerate(base, 1)]
        mr = d.get("multirate", [])
        if not isinstance(mr, (dict, list)):
            raise ControllerError(f"{src}: 'multirate' must be an object or a list of objects")
        for blk in ([mr] if isinstance(mr, dict) else mr):
            if not isinstance(blk, dict) or not isinstance(blk.get("sections"), list):
                raise ControllerError(f"{src}: 'multirate' needs 'rate_multiple' and a 'sections' list")
            secs += [normalise_section(s, blk.get("rate_multiple", 1), f"{src}: section {i}")
                     for i, s in enumerate(blk["sections"], len(secs) + 1)]
        return cls(str(d.get("name", "controller")), fs, secs, source=src)

    @classmethod
    def nss(cls) -> "Controller":
        """NSS HDD benchmark ``controller_v1``: PID at fs = 26.4 kHz + four notches at 2 fs."""
        ref = resources.files("seekopt") / "data" / "nss_controller.json"
        with resources.as_file(ref) as p:
            return cls.from_json(p)

    def to_dict(self) -> dict:
        """Canonical schema-1 dict (deep copy)."""
        return {"schema": 1, "name": self.name, "sample_rate_hz": self.sample_rate_hz,
                "sections": copy.deepcopy(self.sections)}

    def to_json(self, path=None) -> str:
        """Return the canonical JSON text; also write it to ``path`` if given."""
        text = json.dumps(self.to_dict(), indent=1) + "\n"
        if path is not None:
            Path(path).write_text(text)
        return text

    def hash(self) -> str:
        """First 12 hex digits of sha256 of the canonical (sorted, compact) JSON."""
        canon = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canon.encode()).hexdigest()[:12]

    # ---------------------------------------------------------------- dynamics
    @property
    def fast_multiple(self) -> int:
        """``L = max rate_multiple``: number of current sub-steps per PES sample."""
        return self._groups[-1][0]

    @property
    def n_states(self) -> int:
        return sum(g[1].shape[0] for g in self._groups)

    def _multirate_step(self, x, e):
        """Reference multirate step: (state, error) -> (next state, L sub-step currents).

        Group g (rate m_g) runs m_g sub-steps; at sub-step j its input is the previous group's
        output at sub-step floor(j m_{g-1} / m_g) (zero-order hold); the input of the first
        group is the PES error (m_0 = 1).
        """
        xn, v, mprev, off = np.empty_like(x), np.array([e], dtype=x.dtype), 1, 0
        for m, A, B, C, D in self._groups:
            n = A.shape[0]
            xg = x[off:off + n].copy()
            w = np.empty(m, dtype=x.dtype)
            for j in range(m):
                vj = v[(j * mprev) // m]
                w[j] = C @ xg + D * vj
                xg = A @ xg + B * vj
            xn[off:off + n] = xg
            v, mprev, off = w, m, off + n
        return xn, v

    def lifted_ss(self):
        """Controller lifted to the PES rate: ``x[k+1] = A x[k] + B e[k]``, ``u[k] = C x[k] + D e[k]``.

        Returns
        -------
        A : (n, n), B : (n, 1), C : (L, n), D : (L, 1) ndarray
            ``u[k][j]`` is the current [A] applied during fast sub-step j of PES sample k,
            i.e. on ``[k + j/L, k + (j+1)/L) / fs``.  This is exactly the map of ``runtime().step``.
        """
        n, L = self.n_states, self.fast_multiple
        cols = [self._multirate_step(col, 0.0) for col in np.eye(n)]
        xe, ue = self._multirate_step(np.zeros(n), 1.0)
        A = np.array([c[0] for c in cols]).T.reshape(n, n)
        C = np.array([c[1] for c in cols]).T.reshape(L, n)
        return A, xe.reshape(n, 1), C, ue.reshape(L, 1)

    def runtime(self, lifted: bool = True) -> "ControllerRuntime":
        """Stepping object for the time-domain simulator (see :class:`ControllerRuntime`)."""
        return ControllerRuntime(self, lifted)

    def freqresp(self, freqs_hz) -> np.ndarray:
        """Single-rate-equivalent frequency response ``C(f) = prod_i H_i(exp(j 2 pi f / (m_i fs)))``.

        Approximation: each section is evaluated at its own rate and the holds between rates
        and the resulting aliasing are ignored (valid well below the PES Nyquist frequency).
        """
        f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
        out = np.ones(f.shape, dtype=complex)
        for s in self.sections:
            out *= section_freqresp(s, np.exp(2j * np.pi * f / (s["rate_multiple"] * self.sample_rate_hz)))
        return out


class ControllerRuntime:
    """Per-PES-sample stepping of a :class:`Controller` (state starts at zero).

    ``step(e)`` takes the error ``e = r - y`` [track] of PES sample k and returns the
    ``L`` feedback currents [A] for the fast sub-steps of that sample.  With ``lifted=True``
    (default) one matrix-vector product ``[x+; u] = [[A, B], [C, D]] [x; e]`` with the
    lifted matrices is used (~2 us); ``lifted=False`` runs the rate groups one by one
    (slow sections once, fast ones L times on held inputs), for reference.
    """

    def __init__(self, controller: Controller, lifted: bool = True):
        self.controller, self.lifted = controller, lifted
        A, B, C, D = controller.lifted_ss()
        self.n, self.L = A.shape[0], C.shape[0]
        self._M = np.ascontiguousarray(np.block([[A, B], [C, D]]))
        self._v = np.zeros(self.n + 1)
        self._w = np.zeros(self.n + self.L)

    def reset(self) -> None:
        """Zero the controller state."""
        self._v[:] = 0.0

    @property
    def state(self) -> np.ndarray:
        """Copy of the stacked group states (slowest group first)."""
        return self._v[:self.n].copy()

    def step(self, e: float) -> np.ndarray:
        """Advance one PES sample; return the ``L`` sub-step currents [A] (new array)."""
        v, n = self._v, self.n
        if not self.lifted:
            v[:n], u = self.controller._multirate_step(v[:n], float(e))
            return u
        v[n] = e
        w = np.dot(self._M, v, out=self._w)
        v[:n] = w[:n]
        return w[n:].copy()

