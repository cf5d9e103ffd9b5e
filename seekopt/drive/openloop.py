"""Open-loop analysis of the drive's loop ``L = P C``: crossover, phase and gain margins, sensitivity
peak (:func:`loop_analysis`), as a text table and a Bode plot (cf. the paper's Fig. 8).
"""
from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


__all__ = ["LoopAnalysis", "loop_analysis", "print_loop_analysis", "plot_loop_analysis"]


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


def loop_analysis(controller, plant_frf, freqs_hz, zoh: bool = True) -> LoopAnalysis:
    """Loop figures for a continuous plant under the (single-rate-equivalent) controller.

    Parameters
    ----------
    controller : seekopt.drive.controller.Controller
        The feedback controller (its ``freqresp``, ``fast_multiple``, ``sample_rate_hz``, ``name``, ``hash``).
    plant_frf : callable
        ``f_hz -> P(j 2 pi f)`` [track/A] (vectorised or scalar).
    freqs_hz : array_like
        Increasing frequency grid [Hz]; crossings are bracketed on it and refined exactly.
    zoh : bool
        Include the zero-order hold of the current DAC at the fast rate ``L fs`` (sampler
        included): ``H(f) = sinc(f Tu) exp(-j pi f Tu)``, ``Tu = 1/(L fs)``.

    Notes
    -----
    ``L(f) = P(f) H(f) C(f)`` with ``C`` from :meth:`seekopt.drive.controller.Controller.freqresp` — an approximation
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

    from scipy.optimize import brentq    # imported on first use (~0.2 s of a seekopt design start-up)

    def roots(g, mask):  # refine each bracketing grid interval exactly
        return [brentq(lambda x: g(Lfun(x)[0]), f[i], f[i + 1], xtol=1e-9 * f[i])
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
