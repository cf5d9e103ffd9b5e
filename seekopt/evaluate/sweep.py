"""Sweeps of seek designs over track density (TPI) and seek length.

One *cell* is a pair ``(tpi, tracks)``.  For each cell the plant is re-expressed
at that TPI (:meth:`identification.model.plant.ModalPlant.at_tpi`: the physical gain in
m/(A s^2) is kept, ``k0`` in track/(A s^2) scales with TPI, the settle band stays
in tracks; the controller's gain in A/track is scaled with the track pitch so the
physical loop is the same, see :func:`controller_at_tpi`), the optimal profile is
designed (one pluggable call, default :class:`seekopt.design.ocp.SeekDesigner`), and the
optimal, sine and windowed-sine profiles (optionally also the baselines at their
best duration, :data:`ALL_KINDS`) are evaluated side by side with
:func:`seekopt.design.metrics.evaluate_profile` (the one simulator,
:func:`seekopt.drive.simulator.simulate_2dof`).

Results folder layout
---------------------
``sweep.json``
    The sweep's configuration (plant, controller, grid, current limit, ...).
``cells/<key>.json``
    One file per finished cell, written atomically (temporary file, fsync,
    ``os.replace``) by the driving process as soon as the cell completes: the
    table rows of that cell, the optimal profile and a computation id.
``journal.log``
    Append-only, fsync'ed audit: ``run <config> engine=... todo=... t=<unix time>`` per run and
    ``computed <key> <id> t=<unix time>`` per computed cell.
``results.csv``
    The tidy table assembled from ``cells/`` (one row per cell x profile kind).
``profiles/``, ``figures/``
    Optimal profiles as CSV; the sweep figures (:mod:`seekopt.app.report`).

Re-running a sweep into the same folder resumes it: saved cells are read, not
recomputed.  The grid may change between runs (cells are keyed by TPI and
length); everything else (plant, controller, current limit, settle band,
designer, kinds) must match, or :class:`SweepError` is raised; cells computed by
other code (:func:`code_hash`) are reused with a warning.

Engines (:mod:`seekopt.evaluate.engines`): ``serial`` (in process), ``process`` (default; a local
:class:`concurrent.futures.ProcessPoolExecutor`; Ipopt/MUMPS is not thread-safe,
so processes, and a lock serialises cells within any one process), and Dask
(``local`` starts a loopback :class:`dask.distributed.LocalCluster`, or a
scheduler address ``tcp://HOST:PORT``).  Each worker process keeps the designer
it built for a TPI and reuses it.  The numbers do not depend on the engine or
the order; only the timing columns (:data:`TIMING_COLUMNS`) do.
"""
from __future__ import annotations

import importlib
import json
import math
import os
import sys
import threading
import time
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identification.fileio import atomic_write_text as write_atomic
from identification.model.plant import TRACK_PITCH_PER_TPI_NM, ModalPlant

from seekopt.evaluate.bench import baseline_profile as _bench_baseline, tuned_baseline
from seekopt.drive.controller import Controller
from seekopt.evaluate.engines import EngineError, iter_dask, iter_pool, iter_serial, make_pool, one_line
from seekopt.design.profiles import t_bang_bang

__all__ = ["SweepError", "SweepConfig", "SweepSummary", "parse_tpi", "parse_tracks", "cell_key",
           "compute_cell", "run_sweep", "evaluate", "make_pool", "assemble", "load_cells",
           "BaselineDesigner", "baseline_profile", "controller_at_tpi", "write_atomic",
           "code_hash", "KINDS", "ALL_KINDS", "TUNE_FACTORS", "TIMING_COLUMNS", "COLUMNS"]

#: Default profile kinds of a sweep, in table order.
KINDS = ("optimal", "sine", "windowed_sine")
#: All kinds: ``*_tuned`` are the baselines at the duration (from :data:`TUNE_FACTORS` times the
#: shortest within Imax) that minimises their seek-settle time on the design plant.
ALL_KINDS = KINDS + ("sine_tuned", "windowed_sine_tuned")
TUNE_FACTORS = (1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)
#: Columns whose values depend on the machine and load (excluded from determinism checks).
TIMING_COLUMNS = ("solve_time_s", "eval_time_s")
_METRICS = ("seek_time_s", "settle_time_s", "peak_pes_after_track", "rms_pes_after_track",
            "peak_current_a", "ratio_tbb", "settled")
#: Columns of ``results.csv``.
COLUMNS = ("tpi", "track_pitch_nm", "k0_track", "controller_gain", "tracks", "kind", "status", "error",
           "designer", "design_status", "solver", "objective", "t_bb_s", "n_samples") + _METRICS + TIMING_COLUMNS


class SweepError(ValueError):
    """Bad sweep input or results folder (one-line message)."""


# ------------------------------------------------------------------ grid parsing
def _num(text: str, what: str) -> float:
    t = text.strip().lower()
    mult = {"k": 1e3, "m": 1e6}.get(t[-1:], 1.0)
    try:
        v = float(t[:-1] if mult != 1.0 else t) * mult
    except ValueError:
        raise SweepError(f"{what}: {text!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise SweepError(f"{what}: {text!r} must be positive")
    return v


def parse_tpi(spec: str) -> list[float]:
    """``"200k:1000k:9"`` (start:stop:count, linear) or ``"200k,500k"`` -> TPI values."""
    if ":" in spec:
        parts = spec.split(":")
        if len(parts) != 3:
            raise SweepError(f"--tpi {spec!r}: expected start:stop:count, e.g. 200k:1000k:9")
        a, b = _num(parts[0], "--tpi"), _num(parts[1], "--tpi")
        try:
            n = int(parts[2])
        except ValueError:
            raise SweepError(f"--tpi {spec!r}: count {parts[2]!r} is not an integer") from None
        if n < 1:
            raise SweepError(f"--tpi {spec!r}: count must be >= 1")
        vals = [a] if n == 1 else [float(v) for v in np.linspace(a, b, n)]
    else:
        vals = [_num(p, "--tpi") for p in spec.split(",") if p.strip()]
    if not vals:
        raise SweepError(f"--tpi {spec!r}: no values")
    return sorted(set(round(v, 6) for v in vals))


def parse_tracks(spec) -> list[float]:
    """``"1,2,5,10"`` (or a sequence) -> sorted unique seek lengths [track]."""
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    vals = [_num(str(p), "--tracks") for p in items if str(p).strip()]
    if not vals:
        raise SweepError(f"--tracks {spec!r}: no values")
    return sorted(set(vals))


def _fmt(x: float) -> str:
    return format(float(x), ".10g").replace(".", "p").replace("+", "")


def cell_key(tpi: float, tracks: float) -> str:
    """File-name-safe key of a cell, e.g. ``tpi200000_k10``."""
    return f"tpi{_fmt(tpi)}_k{_fmt(tracks)}"


_CODE = ("seekopt.design.ocp", "seekopt.design.qp", "seekopt.design.metrics", "seekopt.drive.simulator", "seekopt.design.profiles",
         "seekopt.evaluate.bench", "seekopt.drive.controller", "identification.model.plant", "identification.model.effects")


def code_hash() -> str:
    """Hash of the sources that produce a cell's numbers (provenance; a resumed sweep warns when
    its saved cells came from other code)."""
    import hashlib
    import importlib.util
    h = hashlib.sha256()
    for name in _CODE:
        spec = importlib.util.find_spec(name)
        if spec and spec.origin and os.path.exists(spec.origin):
            h.update(name.encode() + Path(spec.origin).read_bytes())
    return h.hexdigest()[:12]


# ------------------------------------------------------------------ configuration
@dataclass
class SweepConfig:
    """What a sweep computes.

    Parameters
    ----------
    plant : ModalPlant
        Design (and evaluation) plant; needs ``track_pitch_nm`` (re-expressed per TPI).
    controller : Controller
    tpis : list of float
        Track densities [track/inch].
    tracks : list of float
        Seek lengths [track].
    imax : float
        Current limit [A].
    settle : float
        Settle band [track] (the same in tracks at every TPI).
    designer : str
        ``"ocp"`` (:class:`seekopt.design.ocp.SeekDesigner`, nominal), ``"ocp-robust"`` (the same with the
        default :class:`seekopt.design.ocp.RobustSpec`: what ``seekopt design`` does), ``"baseline"``
        (:class:`BaselineDesigner`, for testing the machinery) or ``"module:attr"``,
        a factory ``f(plant, controller, imax, settle) -> obj`` with ``obj.design(tracks)``.
    kinds : tuple of str
        Subset of :data:`ALL_KINDS` (default :data:`KINDS`).
    family : list of ModalPlant
        Further members of the drive's plant family (``plant`` is the nominal one): the optimal
        designs (``ocp``, ``ocp-robust``) hold every member; the table evaluates on ``plant``.
    drift : str or None
        Drift of the ``ocp-robust`` designer in physical terms (:meth:`seekopt.design.family.Drift.from_string`;
        None: from the data).
    """

    plant: ModalPlant
    controller: Controller
    tpis: list
    tracks: list
    imax: float
    settle: float = 0.1
    designer: str = "ocp"
    kinds: tuple = KINDS
    horizon_s: float | None = None
    scale_controller: bool = True
    family: list = field(default_factory=list)
    drift: str | None = None

    def __post_init__(self):
        if self.plant.track_pitch_nm is None:
            raise SweepError("plant has no track_pitch_nm; a TPI sweep needs the physical gain")
        if not (self.imax > 0 and self.settle > 0):
            raise SweepError("--imax and --settle must be positive")
        bad = [k for k in self.kinds if k not in ALL_KINDS]
        if bad:
            raise SweepError(f"unknown profile kind {bad[0]!r} (known: {', '.join(ALL_KINDS)})")
        self.tpis, self.tracks = parse_tpi(",".join(map(repr, self.tpis))), parse_tracks(self.tracks)
        self.family = list(self.family or [])
        if any(p.track_pitch_nm is None for p in self.family):
            raise SweepError("a family member has no track_pitch_nm; a TPI sweep needs the physical gain")
        if self.drift:
            from seekopt.design.family import Drift, DriftError
            try:
                Drift.from_string(self.drift).check_modes(self.plant)
            except DriftError as exc:
                raise SweepError(f"--drift: {exc}") from None

    def identity(self) -> dict:
        """Everything but the grid: what saved cells must agree on to be reused."""
        d = {"plant": self.plant.to_dict(), "controller": self.controller.to_dict(),
             "imax": float(self.imax), "settle": float(self.settle), "designer": self.designer,
             "kinds": list(self.kinds), "horizon_s": self.horizon_s,
             "scale_controller": bool(self.scale_controller)}
        if self.family:              # only when used: sweeps of one plant keep their hash
            d["family"] = [p.to_dict() for p in self.family]
        if self.drift:
            d["drift"] = self.drift
        return d

    def hash(self) -> str:
        import hashlib
        text = json.dumps(self.identity(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    def to_dict(self) -> dict:
        from seekopt import __version__
        d = self.identity()
        d.update(tpis=list(self.tpis), tracks=list(self.tracks), config_hash=self.hash(),
                 plant_hash=self.plant.hash(), controller_hash=self.controller.hash(),
                 **({"family_hashes": [p.hash() for p in self.family]} if self.family else {}),
                 tool_version=__version__, code_hash=code_hash(), schema=1)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SweepConfig":
        return cls(ModalPlant.from_dict(d["plant"]), Controller.from_json(d["controller"]),
                   d["tpis"], d["tracks"], d["imax"], d["settle"], d["designer"],
                   tuple(d["kinds"]), d.get("horizon_s"), d.get("scale_controller", True),
                   [ModalPlant.from_dict(p) for p in d.get("family", [])], d.get("drift"))

    def cells(self) -> list[tuple[float, float]]:
        """Cells in submission order: by TPI (designer reuse), longest seeks first (balance)."""
        return [(tpi, k) for tpi in self.tpis for k in sorted(self.tracks, reverse=True)]


def controller_factor(plant0: ModalPlant, tpi: float) -> float:
    """``pitch_tpi / pitch_0``: the controller gain factor that keeps the physical loop at ``tpi``."""
    return (TRACK_PITCH_PER_TPI_NM / tpi) / plant0.track_pitch_nm


def controller_at_tpi(controller: Controller, plant0: ModalPlant, tpi: float) -> Controller:
    """The controller re-expressed at ``tpi``: the same physical loop.

    ``C`` maps a PES in tracks to A; at ``tpi`` a track is ``pitch_tpi / pitch_0`` of the
    plant's native track, so ``C_tpi = C * pitch_tpi / pitch_0`` keeps ``C(z) P(z)`` (crossover,
    margins) unchanged, as a drive's loop-gain calibration does.  Without it the NSS loop is
    unstable beyond about twice its native 100k TPI.
    """
    factor = controller_factor(plant0, tpi)
    secs = [dict(s) for s in controller.sections]
    first = secs[0]
    if first["kind"] == "tf":
        first["num"] = [factor * v for v in first["num"]]
    else:
        first["C"] = [factor * v for v in first["C"]]
        first["D"] = factor * first["D"]
    return Controller(f"{controller.name} (x{factor:.6g} for {tpi:.6g} TPI)", controller.sample_rate_hz, secs)


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


def _designer_factory(spec: str, family=None, drift: str | None = None):
    """``f(plant, controller, imax, settle) -> designer``; the built-in ``ocp`` (nominal) and ``ocp-robust``
    (the default :class:`seekopt.design.family.Drift`, or ``drift``) designs also hold the ``family``
    members (already at the cell's TPI)."""
    if spec in ("ocp", "ocp-robust"):
        from seekopt.design.designer import SeekDesigner
        from seekopt.design.family import Drift
        from seekopt.design.problem import SeekProblem
        robust = Drift.from_string(drift) if spec == "ocp-robust" else None
        return lambda plant, controller, imax, settle: SeekDesigner(SeekProblem(
            plant, controller, imax, settle, robust=robust, family=list(family or [])))
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
_LOCK = threading.Lock()          # Ipopt/MUMPS is not thread-safe: one cell at a time per process
_OBJECTS: dict = {}                # per process: plants and controllers per (config, TPI)
_DESIGNERS: OrderedDict = OrderedDict()   # per process: the designer of the last few TPIs
_N_DESIGNERS = 3


def _cached(key, make):
    if key[0] != "designer":
        if key not in _OBJECTS:
            _OBJECTS[key] = make()
        return _OBJECTS[key]
    if key in _DESIGNERS:
        _DESIGNERS.move_to_end(key)
        return _DESIGNERS[key]
    value = _DESIGNERS[key] = make()
    while len(_DESIGNERS) > _N_DESIGNERS:
        _DESIGNERS.popitem(last=False)
    return value


def evaluate(plant, controller, profile, settle, horizon_s, k0) -> dict:
    """:func:`seekopt.design.metrics.evaluate_profile` as a dict (the one simulator)."""
    from seekopt.design.metrics import evaluate_profile
    return evaluate_profile(plant, controller, profile, settle=settle, horizon_s=horizon_s,
                            k0_for_tbb=k0).to_dict()


def compute_cell(payload: dict) -> dict:
    """Design and evaluate one cell; never raises for design or evaluation failures.

    Parameters
    ----------
    payload : dict
        ``{"config": SweepConfig.to_dict(), "tpi": float, "tracks": float}``.

    Returns
    -------
    dict
        ``key, tpi, tracks, config_hash, computation_id, pid, rows`` (one per kind)
        and ``optimal_profile`` (a :meth:`Profile.to_dict` or None).
    """
    with _LOCK:
        cfgd, tpi, tracks = payload["config"], float(payload["tpi"]), float(payload["tracks"])
        h = cfgd["config_hash"]
        base = _cached(("cfg", h), lambda: (ModalPlant.from_dict(cfgd["plant"]),
                                            Controller.from_json(cfgd["controller"])))
        plant0, ctrl = base
        plant = _cached(("plant", h, tpi), lambda: plant0.at_tpi(tpi))
        if cfgd.get("scale_controller", True):
            ctrl = _cached(("ctrl", h, tpi), lambda: controller_at_tpi(base[1], plant0, tpi))
        fs, imax, settle = ctrl.sample_rate_hz, float(cfgd["imax"]), float(cfgd["settle"])
        common = {"tpi": tpi, "track_pitch_nm": plant.track_pitch_nm, "k0_track": plant.k0,
                  "controller_gain": (controller_factor(plant0, tpi)
                                      if cfgd.get("scale_controller", True) else 1.0),
                  "tracks": tracks, "designer": cfgd["designer"],
                  "t_bb_s": t_bang_bang(tracks, plant.k0, imax)}
        rows, opt, tuned = [], None, {}
        for kind in cfgd["kinds"]:
            row = dict(common, kind=kind, status="ok", error="", design_status="", solver="",
                       objective=None, solve_time_s=None, n_samples=None, eval_time_s=None)
            row.update({m: None for m in _METRICS})
            try:
                if kind == "optimal":
                    members = [_cached(("member", h, tpi, i), lambda m=m: ModalPlant.from_dict(m).at_tpi(tpi))
                               for i, m in enumerate(cfgd.get("family", []))]
                    designer = _cached(("designer", h, tpi), lambda: _designer_factory(
                        cfgd["designer"], members, cfgd.get("drift"))(plant, ctrl, imax, settle))
                    res = designer.design(tracks)
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
                row.update({k: (bool(m[k]) if k == "settled" else _f(m[k])) for k in _METRICS})
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


def _f(x):
    return None if x is None else float(x)


# ------------------------------------------------------------------ persistence
def _journal(outdir: Path, line: str) -> None:
    fd = os.open(outdir / "journal.log", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, f"{line.rstrip()} t={time.time():.3f}\n".encode())
        os.fsync(fd)
    finally:
        os.close(fd)


def load_cells(outdir) -> dict:
    """All saved cells of a results folder, keyed by cell key (unreadable files skipped)."""
    out = {}
    for p in sorted((Path(outdir) / "cells").glob("*.json")):
        try:
            d = json.loads(p.read_text())
            out[d["key"]] = d
        except (OSError, ValueError, KeyError):
            continue
    return out


def _prepare(cfg: SweepConfig, outdir: Path) -> dict:
    """Create or check the results folder; return the saved cells of this configuration."""
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / "cells").mkdir(exist_ok=True)
    meta = outdir / "sweep.json"
    if meta.exists():
        try:
            old = json.loads(meta.read_text())
        except ValueError:
            raise SweepError(f"{meta}: not valid JSON; remove it or use another results folder") from None
        if old.get("config_hash") != cfg.hash():
            raise SweepError(f"{outdir}: holds a sweep with another plant/controller/imax/settle/designer "
                             f"({old.get('config_hash')} != {cfg.hash()}); use another results folder")
        if old.get("code_hash") not in (None, code_hash()):
            print(f"sweep: warning: {outdir} was computed with other seekopt code (code hash "
                  f"{old.get('code_hash')} != {code_hash()}); its saved cells are reused as they are - "
                  "use a new results folder to recompute them", file=sys.stderr)
    write_atomic(meta, json.dumps(cfg.to_dict(), indent=1))
    return {k: c for k, c in load_cells(outdir).items() if c.get("config_hash") == cfg.hash()}


# ------------------------------------------------------------------ engines
@dataclass
class SweepSummary:
    """What a :func:`run_sweep` call did."""

    total: int
    skipped: int
    computed: int
    failed_cells: list = field(default_factory=list)    # saved, with an error row
    engine_errors: dict = field(default_factory=dict)   # not saved (retried on the next run)
    wall_s: float = 0.0
    engine: str = ""
    table: Path | None = None
    figures: list = field(default_factory=list)

    @property
    def cells_per_s(self) -> float:
        return self.computed / self.wall_s if self.wall_s > 0 else float("nan")


def _engine_errors_as_sweep_errors(it):
    try:
        yield from it
    except EngineError as exc:
        raise SweepError(str(exc)) from None


def run_sweep(cfg: SweepConfig, outdir, *, engine: str = "process", workers: int | None = None,
              progress: bool = True, client=None, executor=None, figures: bool = True) -> SweepSummary:
    """Run (or resume) a sweep into ``outdir`` and assemble its table and figures.

    Parameters
    ----------
    cfg : SweepConfig
    outdir : path
        Results folder (created; resumed if it holds cells of the same configuration).
    engine : str
        ``"serial"``, ``"process"`` (local process pool), ``"local"`` (Dask LocalCluster on
        127.0.0.1) or a Dask scheduler address ``"tcp://HOST:PORT"``.
    workers : int, optional
        Processes for ``process``/``local`` (default: CPU count, at most the cells to do).
    client : dask.distributed.Client, optional
        Use this Dask client (``engine`` is then ignored).
    executor : concurrent.futures.Executor, optional
        Use this (process) pool and leave it running (see :func:`make_pool`); its workers keep
        their designers between sweeps.
    """
    from tqdm.auto import tqdm
    outdir = Path(outdir)
    try:
        _designer_factory(cfg.designer)        # a bad designer is an input error, before anything is written
    except SweepError:
        raise
    except Exception as exc:  # noqa: BLE001 - module:attr that cannot be imported
        raise SweepError(f"designer {cfg.designer!r}: {one_line(exc)}") from None
    saved = _prepare(cfg, outdir)
    todo = [(t, k) for t, k in cfg.cells() if cell_key(t, k) not in saved]
    total = len(cfg.cells())
    cfgd = cfg.to_dict()
    payloads = [{"config": cfgd, "tpi": t, "tracks": k} for t, k in todo]
    workers = workers or os.cpu_count() or 1
    if client is not None:
        engine = "dask-client"
    elif executor is not None:
        engine = "process"
    elif engine not in ("serial", "process", "local") and not engine.startswith(("tcp://", "tls://")):
        raise SweepError(f"engine {engine!r}: expected serial, process, local or tcp://HOST:PORT")
    if engine == "process" and executor is None and (workers <= 1 or len(payloads) <= 1):
        engine = "serial"
    summary = SweepSummary(total=total, skipped=total - len(todo), computed=0, engine=engine)
    t0 = time.perf_counter()
    if payloads:
        _journal(outdir, f"run {cfg.hash()} engine={engine} todo={len(todo)} saved={len(saved)}")
        it = (iter_serial(compute_cell, payloads) if engine == "serial" else
              iter_pool(compute_cell, payloads, min(workers, len(payloads)), executor) if engine == "process" else
              iter_dask(compute_cell, payloads, engine, workers, client,
                        key=lambda p: f"cell-{p['config']['config_hash']}-{cell_key(p['tpi'], p['tracks'])}"))
        with tqdm(total=total, initial=summary.skipped, unit="cell", desc="sweep", file=sys.stderr,
                  disable=not progress, dynamic_ncols=True, smoothing=0.1) as bar:
            for p, cell, exc in _engine_errors_as_sweep_errors(it):
                key = cell_key(p["tpi"], p["tracks"])
                if exc is not None:
                    summary.engine_errors[key] = one_line(exc)
                else:
                    write_atomic(outdir / "cells" / f"{key}.json", json.dumps(cell))
                    _journal(outdir, f"computed {key} {cell['computation_id']}")
                    summary.computed += 1
                    saved[key] = cell
                bar.update(1)
                bar.set_postfix_str(f"{key} {'engine error' if exc else 'ok'}", refresh=False)
    summary.wall_s = time.perf_counter() - t0
    summary.failed_cells = sorted(k for k, c in saved.items()
                                  if any(r["status"] != "ok" for r in c["rows"]))
    summary.table = assemble(outdir, cfg)
    if figures:
        import pandas as pd
        from seekopt.app.report import plot_sweep
        try:
            summary.figures = plot_sweep(pd.read_csv(summary.table), outdir / "figures")
        except Exception as exc:  # noqa: BLE001 - the table is saved; say so, do not lose the run
            print(f"sweep: figures failed ({one_line(exc)}); the table {summary.table} is complete",
                  file=sys.stderr)
    return summary


# ------------------------------------------------------------------ assembly
def assemble(outdir, cfg: SweepConfig | None = None) -> Path:
    """Build ``results.csv`` (and ``profiles/*.csv``) from the saved cells of the grid in ``sweep.json``."""
    import pandas as pd
    from seekopt.design.profiles import Profile
    outdir = Path(outdir)
    cfgd = cfg.to_dict() if cfg is not None else json.loads((outdir / "sweep.json").read_text())
    cells = load_cells(outdir)
    rows = []
    (outdir / "profiles").mkdir(exist_ok=True)
    for tpi in cfgd["tpis"]:
        for k in cfgd["tracks"]:
            c = cells.get(cell_key(tpi, k))
            if c is None or c.get("config_hash") != cfgd["config_hash"]:
                continue
            rows += sorted(c["rows"], key=lambda r: ALL_KINDS.index(r["kind"]))
            if c.get("optimal_profile"):
                p = outdir / "profiles" / f"optimal_{c['key']}.csv"
                if not p.exists():
                    Profile.from_dict(c["optimal_profile"]).to_csv(p)
    df = pd.DataFrame(rows, columns=list(COLUMNS))
    path = outdir / "results.csv"
    write_atomic(path, df.to_csv(index=False))
    return path
