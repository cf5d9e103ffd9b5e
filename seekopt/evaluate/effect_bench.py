"""Bench of one seek on a plant with effects, played from its start track on the full plant.

``seekopt bench --plant AUGMENTED.json`` lands here when the plant carries input or force effects
(:func:`seekopt.design.nlp.needs_nlp`): the paper's sine and windowed-sine profiles (shortest within
``Imax``, rigid-model reference; :func:`seekopt.evaluate.bench.baseline_profile`), the linear design
(:class:`seekopt.design.designer.SeekDesigner` on the plant's linear part) and the effect-aware design
(:class:`seekopt.design.nlp.EffectAwareDesigner`), each played by the one simulator from the start
track on the evaluation plant (the design plant with its effects, or ``truth``)
(:func:`seekopt.design.feasibility.play_seek`).  The table is :func:`seekopt.evaluate.bench.format_table`'s.
"""
from __future__ import annotations

import math
import time

from identification.model.plant import ModalPlant

from seekopt.design.feasibility import play_seek, resolve_start
from seekopt.design.metrics import SeekMetrics
from seekopt.design.nlp import EffectAwareDesigner, NLPSettings
from seekopt.design.predict import played_on, played_plant
from seekopt.design.profiles import t_bang_bang
from seekopt.evaluate.bench import BenchResult, BenchRow, baseline_profile

__all__ = ["run_effect_bench"]


def run_effect_bench(plant: ModalPlant, controller, tracks: float, imax: float, settle: float = 0.1, *,
                     start_track: float | None = None, truth: ModalPlant | None = None, robust=None,
                     settings: NLPSettings | None = None, designer: EffectAwareDesigner | None = None,
                     progress=None) -> BenchResult:
    """Sine, windowed sine, linear and effect-aware designs of one seek, played from the start track.

    Parameters
    ----------
    plant : ModalPlant
        Design plant with its effects (e.g. the loop's augmented plant).
    tracks : float
        Signed seek length [track] (negative: towards lower track numbers).
    start_track : float, optional
        Default: the middle of the plant's fitted range (:func:`seekopt.design.feasibility.resolve_start`).
    truth : ModalPlant, optional
        Evaluation plant (default: ``plant``); one of another gain plays every profile through its drive's
        calibration (:func:`seekopt.design.predict.played_plant`), as :func:`seekopt.evaluate.bench.run_bench`.
    robust : RobustSpec, optional
        Robust set of both designs.

    The rows' ``note`` carries the designs' solver figures; an effect-aware design that fails is a row
    with infinite settle time and the error in its note (never a profile).
    """
    fs = float(controller.sample_rate_hz)
    played = played_plant(truth or plant, plant.k0)
    T0 = resolve_start(plant, tracks, start_track)
    rows = []

    def add(label, kind, prof, dt=0.0, note=""):
        m, _ = play_seek(played, controller, played_on(prof, played), T0, settle=settle, k0_for_tbb=plant.k0)
        rows.append(BenchRow(label, kind, m, design_time_s=dt, note=note, profile=prof))

    for kind in ("sine", "windowed_sine"):
        add(kind, "baseline", baseline_profile(plant, fs, kind, tracks, imax, settle))
    des = designer or EffectAwareDesigner(plant, controller, imax, settle, robust, settings)
    t0 = time.perf_counter()
    lin = des.linear.design(tracks)
    add("optimal (linear)", "optimal", lin.profile, time.perf_counter() - t0,
        note=f"{lin.n_solves} QPs {lin.solve_time_s * 1e3:.0f} ms")
    t0 = time.perf_counter()
    try:
        res = des.design(tracks, T0, progress=progress, linear=lin)
    except (ValueError, RuntimeError) as exc:
        failed = SeekMetrics(math.nan, math.inf, math.nan, math.nan, math.nan, math.inf, False)
        rows.append(BenchRow("optimal (effects)", "optimal", failed,
                             note=f"{type(exc).__name__}: {str(exc).splitlines()[0]}"[:200]))
    else:
        add("optimal (effects)", "optimal", res.profile, time.perf_counter() - t0,
            note=f"{len(res.solves)} NLPs, Ipopt {res.ipopt_iterations} it {res.ipopt_time_s:.1f} s")
    best = min(r.settle_time_s for r in rows if r.kind == "baseline")
    for r in rows:
        r.ratio_best_baseline = r.settle_time_s / best if best > 0 else math.inf
    return BenchResult(float(tracks), float(imax), float(settle), t_bang_bang(tracks, plant.k0, imax), rows,
                       design_k0=float(plant.k0))
