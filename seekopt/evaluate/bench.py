"""Benchmark optimal seek profiles against the paper's sine and windowed-sine currents.

Each baseline comes twice, with the paper's 2DOF reference from the rigid model: the shortest one
within ``Imax`` and the best-length ("tuned") one, the duration that settles soonest on the evaluation
plant (both from :mod:`seekopt.design.baselines`, re-exported here); the optimal variants come from
:class:`seekopt.design.designer.SeekDesigner` on the design plant.  Every profile is then played on the
evaluation plant (a truth plant when given, else the design plant) by the one simulator
(:func:`seekopt.design.metrics.evaluate_profile`).  Figures in the style of the paper's Fig. 9/10:
current, PES and the response of one mode (default: the one nearest 1738 Hz) versus time.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from identification.model.plant import ModalPlant, Mode

from seekopt.design.baselines import TUNE_FACTORS, baseline_profile, tuned_baseline  # noqa: F401 (re-exported)
from seekopt.design.designer import DesignInfeasible, SeekDesigner
from seekopt.design.metrics import SeekMetrics, evaluate_profile, simulate_profile
from seekopt.design.problem import SeekProblem
from seekopt.design.profiles import Profile, t_bang_bang
from seekopt.design.family import Drift
from seekopt.design.predict import played_on, played_plant
from seekopt.design.robust import RobustSpec

__all__ = ["BenchRow", "BenchResult", "baseline_profile", "tuned_baseline", "perturbed_plant", "mode_response",
           "run_bench", "format_table", "played_seeks", "plot_bench", "DEFAULT_ROBUST", "TUNE_FACTORS"]

#: Robust variant of the bench: what ``seekopt design`` does by default, a
#: :class:`~seekopt.design.family.Drift` with every range from the data (reported std, the family's
#: spread, seek-induced modes +-5 %).
DEFAULT_ROBUST = Drift()
_METRIC_FIELDS = frozenset(f.name for f in fields(SeekMetrics))


@dataclass
class BenchRow:
    """One profile on the evaluation plant.

    Attributes
    ----------
    label, kind : str
        Row label; ``kind`` is ``"baseline"``, ``"tuned"`` (best-length baseline) or ``"optimal"``.
    metrics : SeekMetrics
        Measured on the evaluation plant; its fields (``settle_time_s`` [s], ``ratio_tbb``, ...) are
        also readable on the row itself (``row.settle_time_s``).
    ratio_best_baseline, ratio_tuned_baseline : float
        ``T_ss`` over that of the better shortest-within-Imax / best-length baseline.
    design_time_s : float
        Wall time of the design [s].
    """

    label: str
    kind: str
    metrics: SeekMetrics
    ratio_best_baseline: float = float("nan")
    ratio_tuned_baseline: float = float("nan")
    design_time_s: float = 0.0
    note: str = ""
    profile: Profile | None = field(default=None, repr=False)

    def __getattr__(self, name):
        if name in _METRIC_FIELDS and "metrics" in self.__dict__:
            return getattr(self.__dict__["metrics"], name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


@dataclass
class BenchResult:
    """A bench's rows; ``design_k0`` [track/(A s^2)]: the gain the profiles were designed for (the
    evaluation plant plays them through its drive's calibration to it, :func:`played_seeks`)."""

    tracks: float
    imax: float
    settle: float
    t_bb_s: float
    rows: list
    figures: list = field(default_factory=list)
    design_k0: float | None = None

    def row(self, label: str) -> BenchRow:
        return next(r for r in self.rows if r.label == label)


def perturbed_plant(plant: ModalPlant, fs: float, freq_pct: float = 2.0, gain_pct: float = 20.0,
                    delay_s: float = 3e-6, drop_above: float = 0.45) -> ModalPlant:
    """A stand-in for an identified plant: mode frequencies and gains off by alternating
    ``+-freq_pct`` / ``-+gain_pct`` %, delay off by ``delay_s``, modes above ``drop_above * fs``
    missing (deterministic)."""
    keep = [m for m in plant.modes if m.freq_hz < drop_above * fs]
    modes = [Mode(m.freq_hz * (1 + freq_pct / 100 * (-1) ** i), m.zeta, m.gain * (1 - gain_pct / 100 * (-1) ** i))
             for i, m in enumerate(keep)]
    return plant.copy(modes=modes, delay_s=max(0.0, plant.delay_s + delay_s),
                      meta={"source": f"perturbed copy: freq +-{freq_pct}%, gain +-{gain_pct}%, "
                                      f"delay {delay_s:+g} s, no modes above {drop_above} fs"})


def mode_response(plant: ModalPlant, mode: Mode, current_a, fs: float) -> np.ndarray:
    """Response [track] of one mode ``k0 g / (s^2 + 2 zeta w s + w^2)`` (plant delay) to a current
    sequence: the paper's Fig. 9/10 lower trace (same ZOH discretisation as the plant)."""
    with_mode = ModalPlant(k0=plant.k0, modes=[mode], delay_s=plant.total_delay_s)
    rigid = ModalPlant(k0=plant.k0, delay_s=plant.total_delay_s)
    return (with_mode.simulate_open_loop(current_a, 1.0 / fs, history_a=0.0)
            - rigid.simulate_open_loop(current_a, 1.0 / fs, history_a=0.0))


def run_bench(plant: ModalPlant, controller, tracks: float, imax: float, settle: float = 0.1, *,
              truth: ModalPlant | None = None, robust=DEFAULT_ROBUST, figures=None,
              designers: dict | None = None, horizon_s: float | None = None, mode_hz: float = 1738.0,
              tuned: bool = True, family=()) -> BenchResult:
    """Sine, windowed sine and optimal profiles for one seek, evaluated on ``truth`` (or ``plant``).

    Parameters
    ----------
    plant : ModalPlant
        Design plant (identified).
    truth : ModalPlant, optional
        Evaluation plant (default: ``plant``).  A truth whose ``k0`` differs from ``plant``'s (another
        member of the family) plays every profile through its drive's gain calibration (feedforward x
        ``plant.k0 / truth.k0``); the best-length baselines are tuned on it without that scaling.
    robust : Drift, RobustSpec, str or None
        Uncertainty of the robust optimal variant (default :data:`DEFAULT_ROBUST`; a string is read as
        a ``RobustSpec``; None: nominal only).
    family : sequence of ModalPlant
        Further members of the plant family the robust variant holds (``plant`` is the nominal one).
    figures : path, optional
        Folder for the Fig. 9/10-style plot.
    designers : dict, optional
        ``{label: SeekDesigner}`` to reuse (default: nominal and robust designers built here).
    tuned : bool
        Also the best-length baselines (:func:`tuned_baseline`, tuned on the evaluation plant).
    """
    fs = float(controller.sample_rate_hz)
    evalp = truth or plant
    # a truth of another gain (another member of the family) plays every profile through its drive's
    # seek-gain calibration: feedforward x design gain / its gain (seekopt.design.family, module notes)
    played = played_plant(evalp, plant.k0)
    tbb = t_bang_bang(tracks, plant.k0, imax)
    rows = []

    def add(label, kind, prof, dt=0.0, note=""):
        m = evaluate_profile(played, controller, played_on(prof, played), settle=settle, horizon_s=horizon_s,
                             k0_for_tbb=plant.k0)
        rows.append(BenchRow(label, kind, m, design_time_s=dt, note=note, profile=prof))

    for kind in ("sine", "windowed_sine"):
        add(kind, "baseline", baseline_profile(plant, fs, kind, tracks, imax, settle))
    if tuned:
        for kind in ("sine", "windowed_sine"):
            t0 = time.perf_counter()
            prof = tuned_baseline(plant, controller, kind, tracks, imax, settle, tune_on=evalp, horizon_s=horizon_s)[0]
            add(f"{kind} tuned", "tuned", prof, time.perf_counter() - t0, note=f"{prof.seek_samples} samples")
    if designers is None:
        designers = {"optimal": SeekDesigner(SeekProblem(plant, controller, imax, settle))}
        if robust or family:
            spec = RobustSpec.from_string(robust) if isinstance(robust, str) else robust
            designers["optimal robust"] = SeekDesigner(SeekProblem(plant, controller, imax, settle, robust=spec,
                                                                   family=list(family)))
    for label, des in designers.items():
        t0 = time.perf_counter()
        try:
            res = des.design(tracks)
        except (DesignInfeasible, RuntimeError) as exc:
            failed = SeekMetrics(math.nan, math.inf, math.nan, math.nan, math.nan, math.inf, False)
            rows.append(BenchRow(label, "optimal", failed, note=f"{type(exc).__name__}: {exc}"[:200]))
            continue
        add(label, "optimal", res.profile, time.perf_counter() - t0,
            note=f"{res.objective}, {res.n_solves} QPs {res.solve_time_s * 1e3:.0f} ms; " + _predicted(res))
    for attr, kind in (("ratio_best_baseline", "baseline"), ("ratio_tuned_baseline", "tuned")):
        ref = [r.settle_time_s for r in rows if r.kind == kind]
        if ref:
            best = min(ref)
            for r in rows:
                setattr(r, attr, r.settle_time_s / best if best > 0 else math.inf)
    out = BenchResult(float(tracks), float(imax), float(settle), tbb, rows, design_k0=float(plant.k0))
    if figures:
        out.figures.append(plot_bench(out, evalp, controller, Path(figures), mode_hz=mode_hz))
    return out


def _predicted(res) -> str:
    """What ``design`` predicted for a profile (next to what the evaluation plant does in the table)."""
    ms = res.metrics.settle_time_s * 1e3
    txt = f"predicted {ms:.3f} ms nominal"
    if res.prediction is not None:
        w = res.prediction
        txt += f", {w.worst_metrics.settle_time_s * 1e3:.3f} ms worst of {len(w.labels)} ('{w.labels[w.worst]}')"
    if res.guard is not None:
        txt += f", guard {res.guard.worst_band:.2f} band at {res.guard.worst_hz:.0f} Hz"
    return txt


def format_table(res: BenchResult) -> str:
    """Text table of a bench (times in ms)."""
    head = (f"seek {res.tracks:g} tracks, Imax {res.imax:g} A, band {res.settle:g} track, "
            f"T_bb {res.t_bb_s * 1e3:.3f} ms")
    cols = f"{'profile':<20}{'T_seek':>9}{'T_settle':>10}{'resid pk':>10}{'resid rms':>10}{'I peak':>8}" \
           f"{'/T_bb':>7}{'/shortest':>10}{'/tuned':>8}"
    lines = [head, cols, "-" * len(cols)]
    for r in res.rows:
        lines.append(f"{r.label:<20}{r.seek_time_s * 1e3:>9.3f}{r.settle_time_s * 1e3:>10.3f}"
                     f"{r.peak_pes_after_track:>10.3f}{r.rms_pes_after_track:>10.4f}{r.peak_current_a:>8.3f}"
                     f"{r.ratio_tbb:>7.2f}{r.ratio_best_baseline:>10.2f}{r.ratio_tuned_baseline:>8.2f}"
                     + (f"  {r.note}" if r.note else ""))
    lines.append("T in ms; resid = PES after the seek [track]; I peak = total current incl. feedback [A]; "
                 "/shortest, /tuned: T_settle over the better shortest-within-Imax / best-length baseline")
    return "\n".join(lines)


def played_seeks(res: BenchResult, plant: ModalPlant, controller, horizon_s: float | None = None) -> dict:
    """``{row label: SimResult}``: every profile of ``res`` played on the evaluation ``plant`` from rest at
    track 0 (:func:`seekopt.design.metrics.simulate_profile`) as the table played it, through the drive's
    calibration to ``res.design_k0`` (:func:`seekopt.design.predict.played_plant`); ``horizon_s`` the
    simulated time [s] (default: each profile plus the metrics' tail)."""
    played = plant if res.design_k0 is None else played_plant(plant, res.design_k0)
    return {r.label: simulate_profile(played, controller, played_on(r.profile, played), horizon_s=horizon_s)
            for r in res.rows if r.profile is not None}


def plot_bench(res: BenchResult, plant: ModalPlant, controller, folder: Path, mode_hz: float = 1738.0,
               tail_s: float = 0.004) -> Path:
    """Current, PES and one mode's response vs time for every profile of ``res`` (Fig. 9/10 style), each
    played as the table played it (:func:`played_seeks`; ``plant`` the evaluation plant)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    folder.mkdir(parents=True, exist_ok=True)
    fs = float(controller.sample_rate_hz)
    modes = plant.all_modes()
    mode = min(modes, key=lambda m: abs(m.freq_hz - mode_hz)) if modes else None
    fig = Figure(figsize=(8, 9), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots(3, 1, sharex=True)
    n = max((r.profile.n for r in res.rows if r.profile is not None), default=1) + int(tail_s * fs)
    sims = played_seeks(res, plant, controller, horizon_s=n / fs)
    for r in res.rows:
        if r.profile is None:
            continue
        sim = sims[r.label]
        t = sim.time_s * 1e3
        lab = f"{r.label} (T_ss {r.settle_time_s * 1e3:.2f} ms)"
        ax[0].plot(t, sim.current_a + plant.bias_a, lw=1, label=lab)
        ax[1].plot(t, sim.true_position_track - res.tracks, lw=1, label=lab)
        if mode is not None:
            ax[2].plot(t, mode_response(plant, mode, sim.current_a + plant.bias_a, fs), lw=1, label=lab)
    ax[0].set_ylabel("current (seek part) [A]")
    ax[0].axhline(res.imax, color="k", ls=":", lw=0.7); ax[0].axhline(-res.imax, color="k", ls=":", lw=0.7)
    ax[0].legend(fontsize=8)
    ax[0].set_title(f"{res.tracks:g}-track seek, Imax {res.imax:g} A, T_bb {res.t_bb_s * 1e3:.3f} ms")
    ax[1].set_ylim(-10 * res.settle, 10 * res.settle)
    ax[1].axhline(res.settle, color="k", ls=":", lw=0.7); ax[1].axhline(-res.settle, color="k", ls=":", lw=0.7)
    ax[1].set_ylabel("PES [track]")
    if mode is not None:
        ax[2].set_ylabel(f"{mode.freq_hz:.0f} Hz mode [track]")
    ax[2].set_xlabel("time [ms]")
    for a in ax:
        a.grid(True, alpha=0.3)
    path = folder / f"bench_k{res.tracks:g}.png"
    fig.savefig(path, dpi=110)
    return path
