"""Feedback controller as data: JSON cascade, multirate runtime, lifting, loop analysis.

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
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
from scipy import optimize, signal

__all__ = ["ControllerError", "Controller", "ControllerRuntime", "LoopAnalysis",
           "loop_analysis", "print_loop_analysis", "plot_loop_analysis"]

_STAB_TOL = 1e-9  # poles with |p| <= 1 + tol are accepted (integrators allowed)


class ControllerError(ValueError):
    """Invalid controller description; the message is one line naming the source file."""


def _arr(x, what, src):
    try:
        a = np.array(x, dtype=float)
    except (TypeError, ValueError):
        raise ControllerError(f"{src}: {what} is not numeric") from None
    if not np.all(np.isfinite(a)):
        raise ControllerError(f"{src}: {what} contains non-finite values")
    return a


def _normalise_section(sec, default_m, where):
    """Return a canonical section dict (validated) from any accepted section form."""
    if not isinstance(sec, dict):
        raise ControllerError(f"{where}: section is not a JSON object")
    kind = sec.get("kind") or ("tf" if "num" in sec or "den" in sec else
                               "ss" if any(k in sec for k in "AaBbCcDd") else None)
    if kind not in ("tf", "ss"):
        raise ControllerError(f"{where}: " + (f"unknown kind {kind!r}" if kind else "missing keys") +
                              " (need kind 'tf' with num, den or 'ss' with A, B, C, D)")
    m = sec.get("rate_multiple", default_m)
    if isinstance(m, bool) or not isinstance(m, (int, float)) or not float(m).is_integer() or m < 1:
        raise ControllerError(f"{where} ({kind}): rate_multiple {m!r} is not an integer >= 1")
    out = {"kind": kind}
    if kind == "tf":
        if "num" not in sec or "den" not in sec:
            raise ControllerError(f"{where} (tf): missing key 'num' or 'den'")
        num, den = _arr(sec["num"], "tf num", where), _arr(sec["den"], "tf den", where)
        if num.ndim != 1 or den.ndim != 1:
            raise ControllerError(f"{where} (tf): bad shapes, num and den must be flat lists "
                                  "(descending powers of z)")
        num, den = np.trim_zeros(num, "f"), np.trim_zeros(den, "f")
        if den.size == 0:
            raise ControllerError(f"{where} (tf): denominator is zero")
        num = num if num.size else np.zeros(1)
        if num.size > den.size:
            raise ControllerError(f"{where} (tf): improper (numerator degree {num.size - 1} > "
                                  f"denominator degree {den.size - 1})")
        poles = np.roots(den)
        out.update(num=num.tolist(), den=den.tolist())
    else:
        try:
            A, B, C, D = (sec[k] if k in sec else sec[k.lower()] for k in "ABCD")
        except KeyError:
            raise ControllerError(f"{where} (ss): missing key (needs A, B, C, D)") from None
        A = _arr(A, "ss A", where)
        n = 0 if A.size == 0 else (A.shape[0] if A.ndim == 2 else -1)
        A = A.reshape(n, n) if A.size == 0 else A
        if A.ndim != 2 or A.shape != (n, n):
            raise ControllerError(f"{where} (ss): A has shape {A.shape}, expected square")
        B, C, D = (_arr(v, f"ss {k}", where) for v, k in ((B, "B"), (C, "C"), (D, "D")))
        if B.shape not in ((n,), (n, 1)) or C.shape not in ((n,), (1, n)) or D.size != 1:
            raise ControllerError(f"{where} (ss): bad shapes A {A.shape}, B {B.shape}, C {C.shape}, "
                                  f"D {D.shape} (SISO with {n} states expected)")
        poles = np.linalg.eigvals(A) if n else np.zeros(0)
        out.update(A=A.tolist(), B=B.ravel().tolist(), C=C.ravel().tolist(), D=float(D.ravel()[0]))
    if poles.size and np.max(np.abs(poles)) > 1 + _STAB_TOL:
        raise ControllerError(f"{where} ({kind}): unstable (pole magnitude "
                              f"{np.max(np.abs(poles)):.6g} > 1)")
    out["rate_multiple"] = int(m)
    if isinstance(sec.get("label"), str):
        out["label"] = sec["label"]
    return out


def _section_ss(sec):
    """(A, B[n], C[n], D) numpy realisation of one canonical section."""
    if sec["kind"] == "tf":
        num, den = np.asarray(sec["num"]), np.asarray(sec["den"])
        if den.size == 1:
            return np.zeros((0, 0)), np.zeros(0), np.zeros(0), float(num[-1] / den[0])
        A, B, C, D = signal.tf2ss(num, den)
        return A, B.ravel(), C.ravel(), float(D.ravel()[0])
    return (np.asarray(sec["A"], float).reshape(len(sec["B"]), len(sec["B"])),
            np.asarray(sec["B"], float), np.asarray(sec["C"], float), float(sec["D"]))


def _series(s1, s2):
    """Series connection s1 -> s2 of SISO (A, B, C, D): x = [x1; x2]."""
    A1, B1, C1, D1 = s1
    A2, B2, C2, D2 = s2
    n1, n2 = A1.shape[0], A2.shape[0]
    A = np.block([[A1, np.zeros((n1, n2))], [np.outer(B2, C1), A2]])
    return A, np.concatenate([B1, B2 * D1]), np.concatenate([D2 * C1, C2]), D2 * D1


def _section_freqresp(sec, z):
    """Frequency response of one section at complex points ``z``."""
    if sec["kind"] == "tf":
        return np.polyval(sec["num"], z) / np.polyval(sec["den"], z)
    A, B, C, D = _section_ss(sec)
    n = A.shape[0]
    if n == 0:
        return np.full(z.shape, D, dtype=complex)
    M = z[:, None, None] * np.eye(n) - A
    x = np.linalg.solve(M, np.broadcast_to(B[:, None], (z.size, n, 1)))
    return x[:, :, 0] @ C + D


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
        self.sections = [_normalise_section(s, 1, f"{src}: section {i}") for i, s in enumerate(self.sections, 1)]
        ms = [s["rate_multiple"] for s in self.sections]
        bad = [i for i in range(1, len(ms)) if ms[i] < ms[i - 1]]
        if bad:
            raise ControllerError(f"{src}: rate_multiple decreases along the cascade "
                                  f"(section {bad[0] + 1}: {ms[bad[0]]} after {ms[bad[0] - 1]})")
        self._groups = []  # [(m, A, B, C, D)] one combined state space per rate
        for m in sorted(set(ms)):
            parts = [_section_ss(s) for s in self.sections if s["rate_multiple"] == m]
            for ss in parts[1:]:
                parts[0] = _series(parts[0], ss)
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
            secs += [_normalise_section(s, 1, f"{src}: section {i}") for i, s in enumerate(base, 1)]
        mr = d.get("multirate", [])
        if not isinstance(mr, (dict, list)):
            raise ControllerError(f"{src}: 'multirate' must be an object or a list of objects")
        for blk in ([mr] if isinstance(mr, dict) else mr):
            if not isinstance(blk, dict) or not isinstance(blk.get("sections"), list):
                raise ControllerError(f"{src}: 'multirate' needs 'rate_multiple' and a 'sections' list")
            secs += [_normalise_section(s, blk.get("rate_multiple", 1), f"{src}: section {i}")
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
            out *= _section_freqresp(s, np.exp(2j * np.pi * f / (s["rate_multiple"] * self.sample_rate_hz)))
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


# -------------------------------------------------------------------- loop analysis
@dataclass
class LoopAnalysis:
    """Open-loop figures of ``L = P C`` (negative feedback, ``e = r - y``).

    ``S = 1/(1+L)``, ``T = L/(1+L)``.  ``crossover_hz`` is the lowest frequency with ``|L| = 1``
    and ``phase_margin_deg = 180 deg + angle L`` there (wrapped to [-180, 180)).  Gain crossovers
    at lightly damped resonances above it (phase-stabilised modes) are listed in
    ``gain_crossovers_hz`` / ``phase_margins_deg`` (same wrapping; ``min |.|`` over them is the
    smallest phase rotation that makes L touch -1).  ``gain_margin_db`` is ``-20 log10 |L|``
    minimised over the crossings of the negative real axis with ``|L| < 1``.
    """

    freqs_hz: np.ndarray
    L: np.ndarray
    S: np.ndarray
    T: np.ndarray
    crossover_hz: float
    phase_margin_deg: float
    gain_margin_db: float
    phase_crossover_hz: float
    sensitivity_peak: float
    sensitivity_peak_db: float
    sensitivity_peak_hz: float
    gain_crossovers_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    phase_margins_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    controller_name: str = ""
    controller_hash: str = ""


def _eval(fun, f):
    f = np.atleast_1d(np.asarray(f, dtype=float))
    try:
        val = np.asarray(fun(f), dtype=complex)
        if val.shape == f.shape:
            return val
    except Exception:  # scalar-only callable
        pass
    return np.array([complex(fun(float(x))) for x in f])


def loop_analysis(controller: Controller, plant_frf, freqs_hz, zoh: bool = True) -> LoopAnalysis:
    """Loop figures for a continuous plant under the (single-rate-equivalent) controller.

    Parameters
    ----------
    controller : Controller
    plant_frf : callable
        ``f_hz -> P(j 2 pi f)`` [track/A] (vectorised or scalar).
    freqs_hz : array_like
        Increasing frequency grid [Hz]; crossings are bracketed on it and refined exactly.
    zoh : bool
        Include the zero-order hold of the current DAC at the fast rate ``L fs`` (sampler
        included): ``H(f) = sinc(f Tu) exp(-j pi f Tu)``, ``Tu = 1/(L fs)``.

    Notes
    -----
    ``L(f) = P(f) H(f) C(f)`` with ``C`` from :meth:`Controller.freqresp` — an approximation
    that ignores aliasing of the sampled loop (good well below ``fs/2``).
    """
    f = np.asarray(freqs_hz, dtype=float)
    Tu = 1.0 / (controller.fast_multiple * controller.sample_rate_hz)

    def Lfun(x):
        x = np.atleast_1d(x)
        h = np.sinc(x * Tu) * np.exp(-1j * np.pi * x * Tu) if zoh else 1.0
        return _eval(plant_frf, x) * h * controller.freqresp(x)

    Lf = Lfun(f)
    S = 1.0 / (1.0 + Lf)
    T = Lf * S

    def roots(g, mask):  # refine each bracketing grid interval exactly
        return [optimize.brentq(lambda x: g(Lfun(x)[0]), f[i], f[i + 1], xtol=1e-9 * f[i])
                for i in np.nonzero(mask)[0]]

    lm = np.log(np.abs(Lf))
    wc = roots(lambda v: np.log(abs(v)), np.sign(lm[:-1]) != np.sign(lm[1:]))
    pm = [float((np.degrees(np.angle(Lfun(x)[0])) + 360.0) % 360.0 - 180.0) for x in wc]
    neg = (np.sign(Lf.imag[:-1]) != np.sign(Lf.imag[1:])) & (Lf.real[:-1] < 0) & (Lf.real[1:] < 0)
    wp = [x for x in roots(lambda v: v.imag, neg) if abs(Lfun(x)[0]) < 1.0]
    gm = [-20 * np.log10(abs(Lfun(x)[0])) for x in wp]
    k = int(np.argmax(np.abs(S)))
    return LoopAnalysis(
        freqs_hz=f, L=Lf, S=S, T=T,
        crossover_hz=wc[0] if wc else float("nan"),
        phase_margin_deg=pm[0] if pm else float("inf"),
        gain_crossovers_hz=np.array(wc), phase_margins_deg=np.array(pm),
        gain_margin_db=float(min(gm)) if gm else float("inf"),
        phase_crossover_hz=float(wp[int(np.argmin(gm))]) if gm else float("nan"),
        sensitivity_peak=float(abs(S[k])), sensitivity_peak_db=float(20 * np.log10(abs(S[k]))),
        sensitivity_peak_hz=float(f[k]), controller_name=controller.name,
        controller_hash=controller.hash())


def print_loop_analysis(res: LoopAnalysis, file=sys.stdout) -> str:
    """Print (to ``file``, unless None) and return a text table of the loop figures."""
    rows = [("controller", f"{res.controller_name} [{res.controller_hash}]"),
            ("open-loop crossover", f"{res.crossover_hz:9.1f} Hz"),
            ("phase margin", f"{res.phase_margin_deg:9.1f} deg"),
            ("all gain crossovers", ", ".join(f"{a:.0f} Hz ({b:+.0f} deg)" for a, b in
                                              zip(res.gain_crossovers_hz, res.phase_margins_deg))),
            ("gain margin", f"{res.gain_margin_db:9.2f} dB at {res.phase_crossover_hz:.0f} Hz"),
            ("sensitivity peak |S|max", f"{res.sensitivity_peak_db:9.2f} dB ({res.sensitivity_peak:.3f}) "
                                        f"at {res.sensitivity_peak_hz:.0f} Hz"),
            ("frequency grid", f"{res.freqs_hz[0]:.3g}-{res.freqs_hz[-1]:.4g} Hz, {res.freqs_hz.size} points")]
    text = "\n".join(f"{k:<26}{v}" for k, v in rows)
    if file is not None:
        print(text, file=file)
    return text


def plot_loop_analysis(res: LoopAnalysis, path) -> Path:
    """Bode plot of the open loop and |S| (cf. the paper's Fig. 8), saved as PNG at ``path``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 8), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots(3, 1, sharex=True)
    f = res.freqs_hz
    ax[0].semilogx(f, 20 * np.log10(np.abs(res.L)))
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].axvline(res.crossover_hz, color="r", ls="--", lw=0.8, label=f"crossover {res.crossover_hz:.0f} Hz")
    ax[0].set_ylabel("|L| [dB]")
    ax[0].legend(loc="upper right")
    ax[0].set_title(f"Open loop L = P C  [{res.controller_name[:40]}]\nPM {res.phase_margin_deg:.1f} deg, "
                    f"GM {res.gain_margin_db:.1f} dB", fontsize=10)
    ph = np.degrees(np.unwrap(np.angle(res.L)))
    k = min(int(np.searchsorted(f, res.crossover_hz)), f.size - 1) if np.isfinite(res.crossover_hz) else 0
    ax[1].semilogx(f, ph - 360.0 * np.ceil(ph[k] / 360.0))  # phase at crossover in (-360, 0]
    ax[1].axhline(-180, color="k", lw=0.5)
    ax[1].set_ylabel("phase L [deg]")
    ax[2].semilogx(f, 20 * np.log10(np.abs(res.S)))
    ax[2].axhline(0, color="k", lw=0.5)
    ax[2].set_ylabel("|S| [dB]")
    ax[2].set_title(f"Sensitivity, peak {res.sensitivity_peak_db:.1f} dB at {res.sensitivity_peak_hz:.0f} Hz")
    ax[2].set_xlabel("frequency [Hz]")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
    fig.savefig(path, dpi=110)
    return Path(path)
