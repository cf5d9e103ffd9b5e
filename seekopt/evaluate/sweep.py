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
    Append-only, fsync'ed audit: ``run <config> engine=... todo=... pid=... t=<unix time>`` per run
    and ``computed <key> <id> t=<unix time>`` per computed cell.
``claims/<key>.claim``
    While a sweep computes a cell: its claim (``pid host start``, :mod:`seekopt.evaluate.claims`),
    so a second sweep into the same folder computes other cells and waits for this one.
``results.csv``
    The tidy table assembled from ``cells/`` (one row per cell x profile kind).
``profiles/``, ``figures/``
    Optimal profiles as CSV; the sweep figures (:mod:`seekopt.evaluate.sweep_figures`).

Re-running a sweep into the same folder resumes it: saved cells are read, not
recomputed; two sweeps running into one folder share the cells (claims).  The grid may change
between runs (cells are keyed by TPI and length); everything else (plant, controller, current
limit, settle band, designer, kinds) must match, or :class:`SweepError` is raised; cells
computed by other code (:func:`code_hash`) are reused with a warning.  Before anything is
computed, :func:`check_inputs` refuses a designer that cannot be made and a controller that
does not close a stable loop with the plant at every TPI (or runs at another sample rate).

Engines (:mod:`seekopt.evaluate.engines`): ``serial`` (in process), ``process`` (default; a local
:class:`concurrent.futures.ProcessPoolExecutor` whose workers have one BLAS thread and die with
the sweep; Ipopt/MUMPS is not thread-safe, so processes), and Dask (``local`` starts a loopback
:class:`dask.distributed.LocalCluster`, or a scheduler address ``tcp://HOST:PORT``).  Every
worker holds one :class:`CellRunner` with one warm designer, built once per (plant, controller,
TPI) and reused for the following cells of that TPI; there is no module-level cache.  The
numbers do not depend on the engine or the order; only the timing columns
(:data:`TIMING_COLUMNS`) do.
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identification.fileio import atomic_write_text as write_atomic
from identification.model.plant import TRACK_PITCH_PER_TPI_NM, ModalPlant

from seekopt.evaluate.bench import baseline_profile as _bench_baseline, tuned_baseline
from seekopt.drive.controller import Controller
from seekopt.evaluate.engines import EngineError, make_engine, make_pool, one_line, worker_held
from seekopt.design.profiles import t_bang_bang

__all__ = ["SweepError", "SweepConfig", "SweepSummary", "parse_tpi", "parse_tracks", "cell_key",
           "compute_cell", "run_sweep", "evaluate", "make_pool", "assemble", "load_cells", "CellRunner",
           "run_cell_in_worker", "check_inputs",
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
        ``"ocp-robust"`` (default: :class:`seekopt.design.ocp.SeekDesigner` with the default
        :class:`seekopt.design.ocp.RobustSpec`, what ``seekopt design`` and ``seekopt sweep`` do),
        ``"ocp"`` (the same, nominal), ``"baseline"``
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
    designer: str = "ocp-robust"
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
def evaluate(plant, controller, profile, settle, horizon_s, k0) -> dict:
    """:func:`seekopt.design.metrics.evaluate_profile` as a dict (the one simulator)."""
    from seekopt.design.metrics import evaluate_profile
    return evaluate_profile(plant, controller, profile, settle=settle, horizon_s=horizon_s,
                            k0_for_tbb=k0).to_dict()


class CellRunner:
    """Computes cells (:meth:`__call__`) and holds what it built for them.

    It keeps the plant, the controller and ONE warm designer for the current
    ``(configuration, TPI)``: built on the first cell of that TPI, reused for every following
    cell of it (cells are submitted TPI by TPI), replaced when the TPI changes.  The serial engine
    holds one runner in the driving process; each pool or Dask worker holds its own
    (:func:`run_cell_in_worker`, :func:`seekopt.evaluate.engines.worker_held`).  A lock makes one
    runner compute one cell at a time (Ipopt/MUMPS is not thread-safe).

    Attributes
    ----------
    designers_built : int
        Designers built so far (one per TPI visited; for reuse tests and studies).
    """

    def __init__(self):
        self._lock = threading.Lock()
        self._key = None
        self._held: dict = {}
        self.designers_built = 0

    def _objects(self, cfgd: dict, tpi: float) -> dict:
        key = (cfgd["config_hash"], tpi)
        if key != self._key:
            plant0 = ModalPlant.from_dict(cfgd["plant"])
            ctrl = Controller.from_json(cfgd["controller"])
            scaled = cfgd.get("scale_controller", True)
            self._held = {"plant0": plant0, "plant": plant0.at_tpi(tpi),
                          "ctrl": controller_at_tpi(ctrl, plant0, tpi) if scaled else ctrl,
                          "gain": controller_factor(plant0, tpi) if scaled else 1.0, "designer": None,
                          "family": [ModalPlant.from_dict(m).at_tpi(tpi) for m in cfgd.get("family", [])]}
            self._key = key
        return self._held

    def designer(self, cfgd: dict, tpi: float):
        """The warm designer of ``(configuration, tpi)`` (built on first use)."""
        held = self._objects(cfgd, tpi)
        if held["designer"] is None:
            held["designer"] = _designer_factory(cfgd["designer"], held["family"], cfgd.get("drift"))(
                held["plant"], held["ctrl"], float(cfgd["imax"]), float(cfgd["settle"]))
            self.designers_built += 1
        return held["designer"]

    def __call__(self, payload: dict) -> dict:
        with self._lock:
            return self._compute(payload)

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
            row.update({m: None for m in _METRICS})
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
        and ``optimal_profile`` (a :meth:`Profile.to_dict` or None).
    """
    return CellRunner()(payload)


def run_cell_in_worker(payload: dict) -> dict:
    """:func:`compute_cell` with the :class:`CellRunner` this worker holds (warm designer)."""
    return worker_held(CellRunner)(payload)


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
    skipped: int                                         # saved before this run
    computed: int                                        # computed by this run
    failed_cells: list = field(default_factory=list)    # saved, with an error or infeasible row
    engine_errors: dict = field(default_factory=dict)   # not saved (retried on the next run)
    wall_s: float = 0.0
    engine: str = ""
    table: Path | None = None
    figures: list = field(default_factory=list)
    by_others: int = 0                                   # computed meanwhile by another sweep (claims)

    @property
    def cells_per_s(self) -> float:
        return self.computed / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def ok(self) -> bool:
        """Every cell of the grid saved and without a failed row."""
        return not self.failed_cells and not self.engine_errors


def check_inputs(cfg: SweepConfig) -> None:
    """Everything a sweep can know is wrong before it computes: the designer can be made, and the
    controller closes a stable loop with the plant at every TPI (:func:`seekopt.drive.loopcheck.check_loop`:
    same sample rate, closed-loop poles inside the unit circle).  Raises :class:`SweepError`."""
    from seekopt.drive.loopcheck import LoopError, check_loop
    try:
        _designer_factory(cfg.designer)
    except SweepError:
        raise
    except Exception as exc:  # noqa: BLE001 - module:attr that cannot be imported
        raise SweepError(f"designer {cfg.designer!r}: {one_line(exc)}") from None
    for tpi in cfg.tpis:
        plant = cfg.plant.at_tpi(tpi)
        ctrl = controller_at_tpi(cfg.controller, cfg.plant, tpi) if cfg.scale_controller else cfg.controller
        try:
            check_loop(plant, ctrl, "the plant", f"controller {cfg.controller.name!r}")
        except LoopError as exc:
            raise SweepError(f"{exc} (at {tpi:g} TPI)") from None


def _load_cell(outdir: Path, key: str, config_hash: str) -> dict | None:
    try:
        c = json.loads((outdir / "cells" / f"{key}.json").read_text())
    except (OSError, ValueError):
        return None
    return c if c.get("config_hash") == config_hash else None


def run_sweep(cfg: SweepConfig, outdir, *, engine: str = "process", workers: int | None = None,
              progress: bool = True, client=None, executor=None, figures: bool = True) -> SweepSummary:
    """Run (or resume, or join) a sweep into ``outdir`` and assemble its table and figures.

    Cells are submitted lazily, TPI by TPI, at most as many as the engine has workers, each
    claimed just before (:class:`seekopt.evaluate.claims.Claims`): a second sweep of the same
    configuration into the same folder computes the cells the first has not claimed and waits for
    the others, so the two share the work; a killed sweep's claims are taken over.

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
    progress : bool
        A tqdm bar on stderr.
    client : dask.distributed.Client, optional
        Use this Dask client (``engine`` is then ignored).
    executor : concurrent.futures.Executor, optional
        Use this (process) pool and leave it running (see :func:`make_pool`); its workers keep
        their designers between sweeps.

    Raises
    ------
    SweepError
        Bad input found before anything is computed (:func:`check_inputs`), a results folder of
        another configuration, an engine that cannot start.
    """
    from tqdm.auto import tqdm
    from seekopt.evaluate.claims import Claims
    outdir = Path(outdir)
    if client is None and executor is None and engine not in ("serial", "process", "local") \
            and not engine.startswith(("tcp://", "tls://")):
        raise SweepError(f"engine {engine!r}: expected serial, process, local or tcp://HOST:PORT")
    check_inputs(cfg)
    saved = _prepare(cfg, outdir)
    h = cfg.hash()
    todo = [(t, k) for t, k in cfg.cells() if cell_key(t, k) not in saved]
    total = len(cfg.cells())
    cfgd = cfg.to_dict()
    workers = workers or os.cpu_count() or 1
    if client is not None:
        engine = "dask-client"
    elif executor is not None:
        engine = "process"
    if engine == "process" and executor is None and (workers <= 1 or len(todo) <= 1):
        engine = "serial"
    summary = SweepSummary(total=total, skipped=total - len(todo), computed=0, engine=engine)
    t0 = time.perf_counter()
    if todo:
        _journal(outdir, f"run {h} engine={engine} todo={len(todo)} saved={len(saved)} pid={os.getpid()}")
        claims = Claims(outdir / "claims")
        fn = CellRunner() if engine == "serial" else run_cell_in_worker
        try:
            eng = make_engine(engine, fn, min(workers, len(todo)), client=client, executor=executor,
                              key=lambda p: f"cell-{h}-{cell_key(p['tpi'], p['tracks'])}")
        except EngineError as exc:
            raise SweepError(str(exc)) from None
        with tqdm(total=total, initial=summary.skipped, unit="cell", desc="sweep", file=sys.stderr,
                  disable=not progress, dynamic_ncols=True, smoothing=0.1) as bar:
            try:
                with eng:
                    _drive(eng, cfgd, todo, outdir, claims, saved, summary, bar)
            finally:
                claims.release_all()
    summary.wall_s = time.perf_counter() - t0
    summary.failed_cells = sorted(k for k, c in saved.items()
                                  if any(r["status"] != "ok" for r in c["rows"]))
    summary.table = assemble(outdir, cfg)
    if figures:
        import pandas as pd
        from seekopt.evaluate.sweep_figures import plot_sweep
        try:
            summary.figures = plot_sweep(pd.read_csv(summary.table), outdir / "figures")
        except Exception as exc:  # noqa: BLE001 - the table is saved; say so, do not lose the run
            print(f"sweep: figures failed ({one_line(exc)}); the table {summary.table} is complete",
                  file=sys.stderr)
    return summary


def _drive(eng, cfgd, todo, outdir, claims, saved, summary, bar, poll_s: float = 0.5) -> None:
    """The driving loop of :func:`run_sweep`: claim and submit up to ``eng.capacity`` cells, save
    each result as it arrives, wait for cells claimed by another live sweep (take them over if it
    dies)."""
    from collections import deque
    h = cfgd["config_hash"]
    pending, inflight, elsewhere = deque(todo), {}, {}

    def done(key, cell, by=""):
        saved[key] = cell
        bar.update(1)
        bar.set_postfix_str(f"{key} {by or 'ok'}", refresh=False)

    last_scan = 0.0
    while pending or inflight or elsewhere:
        while pending and len(inflight) < eng.capacity:
            tpi, k = pending.popleft()
            key = cell_key(tpi, k)
            cell = _load_cell(outdir, key, h)
            if cell is None:
                holder = claims.claim(key)
                if holder is not None:
                    elsewhere[key] = (tpi, k, holder)
                    continue
                cell = _load_cell(outdir, key, h)      # saved between the look and the claim?
                if cell is None:
                    try:
                        inflight[eng.submit({"config": cfgd, "tpi": tpi, "tracks": k})] = key
                    except Exception as exc:  # noqa: BLE001 - e.g. a broken pool: this cell is not computed
                        claims.release(key)
                        summary.engine_errors[key] = one_line(exc)
                        bar.update(1)
                    continue
                claims.release(key)
            summary.by_others += 1
            done(key, cell, "by another sweep")
        if inflight:
            for handle, cell, exc in eng.wait(list(inflight), timeout=poll_s if elsewhere else None):
                key = inflight.pop(handle)
                if exc is not None:
                    summary.engine_errors[key] = one_line(exc)
                    bar.update(1)
                    bar.set_postfix_str(f"{key} engine error", refresh=False)
                else:
                    write_atomic(outdir / "cells" / f"{key}.json", json.dumps(cell))
                    _journal(outdir, f"computed {key} {cell['computation_id']}")
                    summary.computed += 1
                    done(key, cell)
                claims.release(key)
        elif elsewhere:
            time.sleep(poll_s)
        if elsewhere and time.perf_counter() - last_scan >= poll_s:
            last_scan = time.perf_counter()
            for key, (tpi, k, holder) in list(elsewhere.items()):
                cell = _load_cell(outdir, key, h)
                if cell is not None:
                    del elsewhere[key]
                    summary.by_others += 1
                    done(key, cell, "by another sweep")
                elif not claims.holder_alive(key):
                    del elsewhere[key]
                    pending.appendleft((tpi, k))       # its sweep died: take the cell over
            if elsewhere and not inflight and not pending:
                holders = sorted({v[2].split()[0] for v in elsewhere.values()})
                bar.set_postfix_str(f"waiting for {len(elsewhere)} cells claimed by pid {', '.join(holders)}",
                                    refresh=True)


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
