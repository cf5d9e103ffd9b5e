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
:class:`~seekopt.evaluate.engines.WorkerPool` of processes that have one BLAS thread and die with
the sweep; Ipopt/MUMPS is not thread-safe, so processes), and Dask (``local`` starts a loopback
:class:`dask.distributed.LocalCluster`, or a scheduler address ``tcp://HOST:PORT``).  Every
worker holds one :class:`CellRunner` with one warm designer per (plant, controller, TPI), built
once and reused for the following cells of that TPI, which go to the same worker
(:mod:`seekopt.evaluate.sweep_lanes`); there is no module-level cache.  The
numbers do not depend on the engine or the order; only the timing columns
(:data:`TIMING_COLUMNS`) do.  Each cell also records the CPU it took in its worker and the designers that
worker had built (``cpu_s``, ``designers_built``, ``pid``, ``host``, and the BLAS threads it may use,
``blas_threads``; gathered in :class:`SweepSummary`).
"""
from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from seekopt.evaluate.engines import EngineError, make_engine, make_pool, one_line
from seekopt.evaluate.sweep_cell import (BaselineDesigner, CellRunner, baseline_profile, compute_cell,
                                         designer_factory, evaluate, run_cell_in_worker)
from seekopt.evaluate.sweep_config import (ALL_KINDS, COLUMNS, KINDS, TIMING_COLUMNS, TUNE_FACTORS,  # noqa: F401
                                           SweepConfig, SweepError, cell_key, code_hash, controller_at_tpi,
                                           controller_factor, parse_tpi, parse_tracks)
from seekopt.evaluate.sweep_store import assemble, journal, load_cell, load_cells, prepare, write_atomic

__all__ = ["SweepError", "SweepConfig", "SweepSummary", "parse_tpi", "parse_tracks", "cell_key",
           "compute_cell", "run_sweep", "evaluate", "make_pool", "assemble", "load_cells", "CellRunner",
           "run_cell_in_worker", "check_inputs",
           "BaselineDesigner", "baseline_profile", "controller_at_tpi", "write_atomic",
           "code_hash", "KINDS", "ALL_KINDS", "TUNE_FACTORS", "TIMING_COLUMNS", "COLUMNS"]


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
    cell_cpu_s: float = 0.0                              # CPU [s] the computed cells took in their workers
    designers_built: dict = field(default_factory=dict)  # (host, pid) of a worker -> designers it has built
    blas_threads: dict = field(default_factory=dict)     # (host, pid) of a worker -> most BLAS threads seen
    first_submit: float = 0.0                            # perf_counter [s] of the first submission
    last_result: float = 0.0                             # perf_counter [s] of the last result saved

    @property
    def cells_per_s(self) -> float:
        return self.computed / self.wall_s if self.wall_s > 0 else float("nan")

    @property
    def compute_wall_s(self) -> float:
        """Wall time [s] from the first cell submitted to the last result saved (without the engine's
        start and the table's assembly)."""
        return max(self.last_result - self.first_submit, 0.0)

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
        designer_factory(cfg.designer)
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


def run_sweep(cfg: SweepConfig, outdir, *, engine: str = "process", workers: int | None = None,
              progress: bool = True, client=None, executor=None, figures: bool = True) -> SweepSummary:
    """Run (or resume, or join) a sweep into ``outdir`` and assemble its table and figures.

    Cells are submitted lazily, each worker given the neighbouring lengths of one TPI in turn
    (:class:`seekopt.evaluate.sweep_lanes.LanePlan`: its designer stays warm; the longest lengths
    first and the last TPIs shared, so the workers finish together), at most ``Engine.depth`` cells
    queued per worker, each claimed just before (:class:`seekopt.evaluate.claims.Claims`): a second
    sweep of the same configuration into the same folder computes the cells the first has not claimed and waits for
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
    saved = prepare(cfg, outdir)
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
        journal(outdir, f"run {h} engine={engine} todo={len(todo)} saved={len(saved)} pid={os.getpid()}")
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
    """The driving loop of :func:`run_sweep`: keep every lane of the engine ``eng.depth`` cells deep,
    each cell of the lane's TPI (:class:`~seekopt.evaluate.sweep_lanes.LanePlan`) and claimed just
    before it is submitted; save each result as it arrives; wait for cells claimed by another live
    sweep (take them over if it dies)."""
    from seekopt.evaluate.sweep_lanes import LanePlan
    h = cfgd["config_hash"]
    plan, inflight, elsewhere = LanePlan(todo, eng.lanes), {}, {}
    queued = [0] * eng.lanes
    builds: dict = summary.designers_built

    def done(key, cell, by=""):
        saved[key] = cell
        bar.update(1)
        bar.set_postfix_str(f"{key} {by or 'ok'}", refresh=False)

    def fill(lane) -> None:
        while queued[lane] < eng.depth:
            nxt = plan.next(lane)
            if nxt is None:
                return
            tpi, k = nxt
            key = cell_key(tpi, k)
            cell = load_cell(outdir, key, h)
            if cell is None:
                holder = claims.claim(key)
                if holder is not None:
                    elsewhere[key] = (tpi, k, holder)
                    continue
                cell = load_cell(outdir, key, h)      # saved between the look and the claim?
                if cell is None:
                    try:
                        inflight[eng.submit({"config": cfgd, "tpi": tpi, "tracks": k}, lane)] = (key, lane)
                        queued[lane] += 1
                        summary.first_submit = summary.first_submit or time.perf_counter()
                    except Exception as exc:  # noqa: BLE001 - e.g. a broken pool: this cell is not computed
                        claims.release(key)
                        summary.engine_errors[key] = one_line(exc)
                        bar.update(1)
                    continue
                claims.release(key)
            summary.by_others += 1
            done(key, cell, "by another sweep")

    last_scan = 0.0
    while plan or inflight or elsewhere:
        for lane in range(eng.lanes):
            fill(lane)
        if inflight:
            for handle, cell, exc in eng.wait(list(inflight), timeout=poll_s if elsewhere else None):
                key, lane = inflight.pop(handle)
                queued[lane] -= 1
                if exc is not None:
                    summary.engine_errors[key] = one_line(exc)
                    bar.update(1)
                    bar.set_postfix_str(f"{key} engine error", refresh=False)
                else:
                    write_atomic(outdir / "cells" / f"{key}.json", json.dumps(cell))
                    journal(outdir, f"computed {key} {cell['computation_id']}")
                    summary.computed += 1
                    summary.cell_cpu_s += float(cell.get("cpu_s") or 0.0)
                    worker = (cell.get("host", ""), cell["pid"])
                    builds[worker] = max(builds.get(worker, 0), int(cell.get("designers_built") or 0))
                    blas = summary.blas_threads
                    blas[worker] = max(blas.get(worker, 0), int(cell.get("blas_threads") or 0))
                    summary.last_result = time.perf_counter()
                    done(key, cell)
                claims.release(key)
                fill(lane)                             # this lane's next cell before anything else
        elif elsewhere:
            time.sleep(poll_s)
        if elsewhere and time.perf_counter() - last_scan >= poll_s:
            last_scan = time.perf_counter()
            for key, (tpi, k, holder) in list(elsewhere.items()):
                cell = load_cell(outdir, key, h)
                if cell is not None:
                    del elsewhere[key]
                    summary.by_others += 1
                    done(key, cell, "by another sweep")
                elif not claims.holder_alive(key):
                    del elsewhere[key]
                    plan.give_back(tpi, k)             # its sweep died: take the cell over
            if elsewhere and not inflight and not plan:
                holders = sorted({v[2].split()[0] for v in elsewhere.values()})
                bar.set_postfix_str(f"waiting for {len(elsewhere)} cells claimed by pid {', '.join(holders)}",
                                    refresh=True)
