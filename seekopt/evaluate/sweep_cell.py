"""One cell of a sweep, computed where it runs (in process, in a pool or a Dask worker): the optimal
design and the baselines at one ``(tpi, tracks)``, each played in the one simulator
(:func:`seekopt.design.metrics.evaluate_profile`), as table rows.

:class:`CellRunner` holds one warm designer per ``(configuration, TPI)``; there is no module-level
cache.  A failing design or evaluation is a row with ``status`` ``error`` / ``infeasible``, not a crash.
"""
from __future__ import annotations

import importlib
import os
import socket
import threading
import time
import uuid

from identification.model.plant import ModalPlant

from seekopt.design.profiles import t_bang_bang
from seekopt.drive.controller import Controller
from seekopt.evaluate.bench import baseline_profile as _bench_baseline, tuned_baseline
from seekopt.evaluate.engines import one_line, worker_held
from seekopt.evaluate.sweep_config import (METRICS, TUNE_FACTORS, SweepError, cell_key, controller_at_tpi,
                                           controller_factor)

__all__ = ["BaselineDesigner", "OCP_SPECS", "designer_problem", "designer_factory", "baseline_profile", "evaluate",
           "CellRunner", "compute_cell", "run_cell_in_worker"]


# ------------------------------------------------------------------ designers
class BaselineDesigner:
    """Stand-in designer: the shortest bang-bang profile within ``imax``.

    Used to test the sweep machinery without the optimiser; returns an object
    with the :class:`seekopt.design.ocp.DesignResult` fields the sweep reads.
    """

    def __init__(self, plant, controller, imax, settle=0.1):
        self.plant, self.fs, self.imax, self.settle = plant, controller.sample_rate_hz, imax, settle

    def design(self, tracks):
        t0 = time.perf_counter()
        prof = baseline_profile(self.plant, self.fs, "bang_bang", tracks, self.imax, self.settle)
        from types import SimpleNamespace
        return SimpleNamespace(profile=prof, metrics=None, status="baseline", solver="bang_bang",
                               objective="shortest_bang_bang", solve_time_s=time.perf_counter() - t0)


#: the designer specs built on :class:`seekopt.design.designer.SeekDesigner` (nominal / robust)
OCP_SPECS = ("ocp", "ocp-robust")


def designer_problem(spec: str, plant, controller, imax: float, settle: float, family=None, drift: str | None = None,
                     **options):
    """The :class:`seekopt.design.problem.SeekProblem` of a built-in designer ``spec`` (None for any other):
    ``ocp`` the nominal plant, ``ocp-robust`` the default :class:`seekopt.design.family.Drift` (or
    ``drift``); both hold the ``family`` members (already at the plant's TPI).  ``options``: further
    :class:`SeekProblem` fields (e.g. ``current_margin``).  The one place the sweep, its cells and the
    export build a designer's problem."""
    if spec not in OCP_SPECS:
        return None
    from seekopt.design.family import Drift
    from seekopt.design.problem import SeekProblem
    robust = Drift.from_string(drift) if spec == "ocp-robust" else None
    return SeekProblem(plant, controller, imax, settle, robust=robust, family=list(family or []), **options)


def designer_factory(spec: str, family=None, drift: str | None = None, long_seeks: bool = True, **options):
    """``f(plant, controller, imax, settle) -> designer``; the built-in ``ocp`` (nominal) and ``ocp-robust``
    designs are :class:`~seekopt.design.longseek.LongSeekDesigner` of :func:`designer_problem` (``family``,
    ``drift`` and the problem ``options``): the dispatch of ``seekopt design`` (rest-to-rest QP for short
    seeks, the acceleration step for long ones, the plant's velocity limit and stroke from its metadata);
    with ``LongSeekSpec.compare_below_long`` (the composition below ``long_from_track`` where it settles
    within 1.15x the rest-to-rest prediction: a sweep's designer serves many lengths);
    ``long_seeks=False``: the rest-to-rest :class:`~seekopt.design.designer.SeekDesigner` at every length
    (the export's anchors; its long-seek classes are built apart).  ``baseline`` and ``module:attr``
    designers take no options."""
    if spec in OCP_SPECS:
        from seekopt.design.designer import SeekDesigner
        from seekopt.design.longseek import LongSeekDesigner, LongSeekSpec

        def build(plant, controller, imax, settle):
            short = SeekDesigner(designer_problem(spec, plant, controller, imax, settle, family, drift, **options))
            if not long_seeks:
                return short
            # one warm designer serves every length of a TPI: the composition below long_from_track
            # when it settles within 1.15x the rest-to-rest prediction (LongSeekSpec.compare_below_long)
            ls_spec = LongSeekSpec.from_plant(plant, imax, compare_below_long=True)
            return LongSeekDesigner(short.problem, ls_spec, short_designer=short)
        return build
    if spec == "baseline":
        return BaselineDesigner
    mod, _, attr = spec.partition(":")
    if not attr:
        raise SweepError(f"designer {spec!r}: expected 'ocp', 'ocp-robust', 'baseline' or 'module:attr'")
    return getattr(importlib.import_module(mod), attr)


def baseline_profile(plant: ModalPlant, fs: float, kind: str, tracks: float, imax: float, settle: float = 0.1):
    """The bench's baseline (:func:`seekopt.evaluate.bench.baseline_profile`: shortest ``kind`` within ``imax``,
    rigid-model 2DOF reference as in the paper), so sweep and bench compare the same profiles."""
    return _bench_baseline(plant, fs, kind, tracks, imax, settle)


# ------------------------------------------------------------------ one cell (runs in workers)
def evaluate(plant, controller, profile, settle, horizon_s, k0) -> dict:
    """:func:`seekopt.design.metrics.evaluate_profile` as a dict (the one simulator)."""
    from seekopt.design.metrics import evaluate_profile
    return evaluate_profile(plant, controller, profile, settle=settle, horizon_s=horizon_s,
                            k0_for_tbb=k0).to_dict()


class CellRunner:
    """Computes cells (:meth:`__call__`) and holds what it built for them.

    It keeps the plant, the controller and ONE warm designer per ``(configuration, TPI)`` it computes,
    built on the first cell of that TPI and reused for every following cell of it (a sweep sends a
    worker the neighbouring lengths of one TPI in turn, :mod:`seekopt.evaluate.sweep_lanes`); the
    :data:`HELD` most recent TPIs are kept.  The serial engine holds one runner in the driving process;
    each pool or Dask worker holds its own (:func:`run_cell_in_worker`,
    :func:`seekopt.evaluate.engines.worker_held`).  A lock makes one runner compute one cell at a time
    (Ipopt/MUMPS is not thread-safe).

    Attributes
    ----------
    designers_built : int
        Designers built so far (one per TPI visited; reported with each cell, for reuse tests and studies).
    """

    #: TPIs whose designers a runner keeps (a worker that takes over part of another TPI and comes
    #: back finds its designer warm; each holds its QP structures, so not every TPI of a sweep)
    HELD = 2

    def __init__(self):
        self._lock = threading.Lock()
        self._held: dict = {}           # (config hash, tpi) -> plant, controller, designer; most recent last
        self.designers_built = 0

    def _objects(self, cfgd: dict, tpi: float) -> dict:
        key = (cfgd["config_hash"], tpi)
        held = self._held.pop(key, None)
        if held is None:
            plant0 = ModalPlant.from_dict(cfgd["plant"])
            ctrl = Controller.from_json(cfgd["controller"])
            scaled = cfgd.get("scale_controller", True)
            held = {"plant0": plant0, "plant": plant0.at_tpi(tpi),
                    "ctrl": controller_at_tpi(ctrl, plant0, tpi) if scaled else ctrl,
                    "gain": controller_factor(plant0, tpi) if scaled else 1.0, "designer": None,
                    "family": [ModalPlant.from_dict(m).at_tpi(tpi) for m in cfgd.get("family", [])]}
            while len(self._held) >= self.HELD:
                self._held.pop(next(iter(self._held)))
        self._held[key] = held
        return held

    def designer(self, cfgd: dict, tpi: float):
        """The warm designer of ``(configuration, tpi)`` (built on first use)."""
        held = self._objects(cfgd, tpi)
        if held["designer"] is None:
            slack = float(cfgd.get("worst_case_slack_s", 0.0))
            held["designer"] = designer_factory(cfgd["designer"], held["family"], cfgd.get("drift"),
                                                **({"worst_case_slack_s": slack} if slack else {}))(
                held["plant"], held["ctrl"], float(cfgd["imax"]), float(cfgd["settle"]))
            self.designers_built += 1
        return held["designer"]

    def __call__(self, payload: dict) -> dict:
        with self._lock:
            cpu, start = time.process_time(), time.time()
            cell = self._compute(payload)
            cell.update(cpu_s=time.process_time() - cpu, designers_built=self.designers_built,
                        host=socket.gethostname(), blas_threads=blas_threads(), started=start, ended=time.time())
            return cell

    def _compute(self, payload: dict) -> dict:
        cfgd, tpi, tracks = payload["config"], float(payload["tpi"]), float(payload["tracks"])
        h = cfgd["config_hash"]
        held = self._objects(cfgd, tpi)
        plant, ctrl = held["plant"], held["ctrl"]
        fs, imax, settle = ctrl.sample_rate_hz, float(cfgd["imax"]), float(cfgd["settle"])
        common = {"tpi": tpi, "track_pitch_nm": plant.track_pitch_nm, "k0_track": plant.k0,
                  "controller_gain": held["gain"], "tracks": tracks, "designer": cfgd["designer"],
                  "t_bb_s": t_bang_bang(tracks, plant.k0, imax)}
        rows, opt, tuned = [], None, {}
        for kind in cfgd["kinds"]:
            row = dict(common, kind=kind, status="ok", error="", design_status="", solver="",
                       objective=None, solve_time_s=None, n_samples=None, eval_time_s=None)
            row.update({m: None for m in METRICS})
            try:
                if kind == "optimal":
                    res = self.designer(cfgd, tpi).design(tracks)
                    prof = res.profile
                    row.update(design_status=str(res.status), solver=str(res.solver),
                               objective=str(res.objective), solve_time_s=_f(res.solve_time_s))
                    opt = prof
                elif kind.endswith("_tuned"):
                    t0 = time.perf_counter()
                    prof, sm = tuned_baseline(plant, ctrl, kind[:-6], tracks, imax, settle,
                                              factors=TUNE_FACTORS, horizon_s=cfgd.get("horizon_s"))
                    m = sm.to_dict()
                    tuned[kind] = prof
                    row.update(design_status="baseline", solver="duration_scan",
                               objective=f"best of {len(TUNE_FACTORS)} durations", eval_time_s=time.perf_counter() - t0)
                else:
                    prof = baseline_profile(plant, fs, kind, tracks, imax, settle)
                    row.update(design_status="baseline", solver="shortest_baseline")
                row["n_samples"] = int(prof.n)
                if not kind.endswith("_tuned"):
                    t0 = time.perf_counter()
                    m = evaluate(plant, ctrl, prof, settle, cfgd.get("horizon_s"), plant.k0)
                    row["eval_time_s"] = time.perf_counter() - t0
                row.update({k: (bool(m[k]) if k == "settled" else _f(m[k])) for k in METRICS})
            except Exception as exc:  # noqa: BLE001 - a failing cell is data, not a crash
                row.update(status="infeasible" if type(exc).__name__ == "DesignInfeasible" else "error",
                           error=one_line(exc))
            rows.append(row)
        if opt is not None:
            opt.meta.update(plant_hash=plant.hash(), controller_hash=ctrl.hash(), tpi=tpi)
        return {"key": cell_key(tpi, tracks), "tpi": tpi, "tracks": tracks, "config_hash": h,
                "code_hash": cfgd.get("code_hash"), "computation_id": uuid.uuid4().hex, "pid": os.getpid(),
                "rows": rows, "optimal_profile": None if opt is None else opt.to_dict(),
                "tuned_profiles": {k: p.to_dict() for k, p in tuned.items()}}


def blas_threads() -> int:
    """The most threads any BLAS/OpenMP pool loaded in this process may use now (threadpoolctl; 0 when
    none is loaded): what a cell reports, so a sweep shows its workers ran with one."""
    from threadpoolctl import threadpool_info
    return max((int(i.get("num_threads") or 0) for i in threadpool_info()), default=0)


def compute_cell(payload: dict) -> dict:
    """Design and evaluate one cell with a fresh :class:`CellRunner`; never raises for design or
    evaluation failures (they are rows with ``status`` ``error`` / ``infeasible``).

    Parameters
    ----------
    payload : dict
        ``{"config": SweepConfig.to_dict(), "tpi": float, "tracks": float}``.

    Returns
    -------
    dict
        ``key, tpi, tracks, config_hash, computation_id, pid, rows`` (one per kind)
        and ``optimal_profile`` (a :meth:`Profile.to_dict` or None); ``cpu_s`` (CPU [s] of the cell),
        ``designers_built`` (by the runner so far), ``host``, ``blas_threads`` (:func:`blas_threads`),
        ``started``, ``ended`` (unix time [s]).
    """
    return CellRunner()(payload)


def run_cell_in_worker(payload: dict) -> dict:
    """:func:`compute_cell` with the :class:`CellRunner` this worker holds (warm designer)."""
    return worker_held(CellRunner)(payload)


def _f(x):
    return None if x is None else float(x)

