"""The whole pipeline on one seek log (``seekopt demo``): the four recipes of ``examples/`` in sequence.

Stages, each timed (a progress line with the elapsed time on stderr; ``quiet`` silences it) and each
returning a small result object; a failing stage stops the demo with a one-line :class:`DemoError`
(the traceback goes to ``<out>/demo-error.log``):

1. **log** -- read the log (default: the bundled synthetic ``seekopt/data/sample_log.npz``, 120 seeks
   of ``seekopt synth``; its truth plant is bundled beside it);
2. **identify** -- :func:`identification.estimate.identify.identify` (``examples/identify_a_log.py``);
3. **close the loop** -- :func:`identification.loop.closing.close_loop` (``examples/close_the_loop.py``);
4. **design & bench** -- one robust :class:`seekopt.design.ocp.SeekDesigner` built once, called for each
   seek length, benched against sine / windowed sine by :func:`seekopt.evaluate.bench.run_bench` on the
   truth plant when known, else on the identified plant (``examples/design_and_bench.py``);
5. **sweep** -- a small TPI x length sweep (:func:`seekopt.evaluate.sweep.run_sweep`, local process pool);
6. **export** -- C, CSV and JSON firmware tables of the sweep's optimal profiles
   (:mod:`seekopt.export.tables`; ``examples/sweep_and_export.py``);
7. **report** -- a self-contained ``report.html`` (figures embedded) and ``report.md``
   (:func:`seekopt.app.demo_report.demo_report`).

Speed (``seekopt demo`` <= 3 min on an idle 2-core machine): the design and sweep lengths stop at 1000
tracks (a robust 3000-track design alone takes tens of seconds), the designer is built once for the
bench, and the sweep runs in a two-worker process pool while the bench runs in this process.  Each
stage's CPU time is logged beside its wall time (on a shared machine the wall time says little).
"""
from __future__ import annotations

import sys
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = ["DemoError", "DemoConfig", "DemoResult", "run_demo", "identify_plant", "close_loop",
           "sample_log_path", "sample_truth", "first_seeks", "loop_is_stable"]


class DemoError(ValueError):
    """A demo stage failed (one-line message naming the stage)."""


@dataclass
class DemoConfig:
    """What the demo does (currents in A, band in track, lengths in track).

    ``quick`` (for tests) uses the first 40 seeks (16 for the loop), two lengths and a 2 x 2 sweep."""

    log: str | None = None
    outdir: str = "seekopt-out"
    quick: bool = False
    quiet: bool = False
    imax: float = 0.3
    settle: float = 0.1
    lengths: tuple = (1, 10, 100, 1000)
    sweep_tpi_factors: tuple = (1.0, 2.0, 5.0)
    sweep_lengths: tuple = (10, 100, 1000)
    workers: int = 2
    html: bool = True
    max_seeks: int | None = None
    loop_seeks: int | None = None

    def __post_init__(self):
        if self.quick:
            self.lengths, self.sweep_lengths, self.sweep_tpi_factors = (10, 100), (10, 100), (1.0, 3.0)
            self.max_seeks, self.loop_seeks = self.max_seeks or 40, 16


# ------------------------------------------------------------------ helpers (public, used by examples/)
def sample_log_path() -> Path:
    """The bundled sample log."""
    return Path(str(resources.files("seekopt").joinpath("data/sample_log.npz")))


def sample_truth():
    """The truth plant of the bundled sample log (the synthetic drive it was recorded on)."""
    from identification.model.plant import ModalPlant
    return ModalPlant.load(sample_log_path().with_suffix(".truth.json"))


def first_seeks(log, n: int | None):
    """The log up to the start of its ``n+1``-th seek (target change); the whole log if ``n`` is None."""
    starts = np.nonzero(np.diff(log.target_track) != 0)[0] + 1
    return log if n is None or len(starts) <= n else log.slice(0, int(starts[n]))


def loop_is_stable(plant, controller, n: int = 3000) -> bool:
    """Does the linear 2DOF loop of ``plant`` and ``controller`` decay (impulse response from the
    reference over ``n`` servo samples, by the one simulator)?"""
    from seekopt.drive.simulator import closed_loop_responses
    y = closed_loop_responses(plant, controller, n)["y_r"]
    peak = float(np.max(np.abs(y))) if np.all(np.isfinite(y)) else float("inf")
    return bool(np.isfinite(peak) and np.max(np.abs(y[-n // 10:])) < 1e-3 * peak)


# ------------------------------------------------------------------ stage results
@dataclass
class IdentifyStage:
    ident: object                  # identification.estimate.identify.Identification
    plant: object                  # identified plant, track pitch and sample rate filled in
    warning: str = ""


@dataclass
class LoopStage:
    result: object                 # identification.loop.closing.LoopResult
    design_plant: object           # the augmented plant without output (disturbance) effects
    seeks: int                     # seeks fed to the loop
    dropped: list = field(default_factory=list)


@dataclass
class BenchStage:
    results: list                  # BenchResult per seek length (evaluated on ``evaluated_on``)
    evaluated_on: str              # "truth" or "identified"
    model_settle_s: dict           # {(tracks, label): seek-settle time [s] on the identified plant}
    figure: Path | None = None


@dataclass
class SweepStage:
    summary: object                # seekopt.evaluate.sweep.SweepSummary
    table: object                  # pandas.DataFrame (results.csv)
    folder: Path


@dataclass
class ExportStage:
    tables: object                 # seekopt.export.tables.TableSet
    paths: list


@dataclass
class DemoResult:
    config: DemoConfig
    log: object
    truth: object
    controller: object
    identify: IdentifyStage
    loop: LoopStage
    bench: BenchStage
    sweep: SweepStage
    export: ExportStage
    stages: list = field(default_factory=list)     # (name, status, wall s, note, CPU s of this process)
    cpu_s: float = float("nan")                    # CPU of this process and its (reaped) sweep workers [s]
    report: Path | None = None


# ------------------------------------------------------------------ stages
def identify_plant(log) -> IdentifyStage:
    """``identify(log)`` with the log's track pitch and sample rate filled into the plant."""
    from identification.estimate.identify import identify
    ident = identify(log)
    plant = ident.plant
    if plant.track_pitch_nm is None and log.track_pitch_nm is not None:
        plant = plant.copy(track_pitch_nm=log.track_pitch_nm)
    if plant.sample_rate_hz is None:
        plant = plant.copy(sample_rate_hz=log.sample_rate_hz)
    return IdentifyStage(ident, plant)


def close_loop(log, plant, seeks: int | None = None) -> LoopStage:
    """:func:`identification.loop.closing.close_loop` on the first ``seeks`` seeks (default all; odd ones
    validate).
    Output effects (disturbances such as run-out) stay in the result but not in the design plant:
    settle metrics are disturbance-free, as on the truth plant."""
    from identification.loop.closing import close_loop as augment
    part = first_seeks(log, seeks)
    res = augment(part, plant)
    dropped = [e.name for e in res.plant.effects if e.kind == "output"]
    design = res.plant.copy(effects=[e for e in res.plant.effects if e.kind != "output"])
    return LoopStage(res, design, int(np.count_nonzero(np.diff(part.target_track))), dropped)


def design_and_bench(plant, truth, controller, cfg: DemoConfig, figures: Path) -> BenchStage:
    """One robust designer (``seekopt design``'s default: :class:`~seekopt.design.family.Drift`, ranges
    from the data) built once, called per length; each length benched against sine and
    windowed sine (shortest within Imax and best length) on the truth (else the identified plant)."""
    from seekopt.design.metrics import evaluate_profile
    from seekopt.design.family import Drift
    from seekopt.design.ocp import SeekDesigner
    from seekopt.evaluate.bench import plot_bench, run_bench
    designer = SeekDesigner(plant, controller, cfg.imax, cfg.settle, Drift())    # seekopt design's default
    results, model = [], {}
    for L in cfg.lengths:
        res = run_bench(plant, controller, L, cfg.imax, cfg.settle, truth=truth, designers={"optimal": designer})
        results.append(res)
        for r in res.rows:
            if r.profile is not None:
                m = evaluate_profile(plant, controller, r.profile, settle=cfg.settle, k0_for_tbb=plant.k0)
                model[(L, r.label)] = m.settle_time_s if m.settled else float("nan")
    show = next((r for r in results if r.tracks == 1000), results[len(results) // 2])
    fs = float(controller.sample_rate_hz)
    longest = max(r.profile.n / fs for r in show.rows if r.profile is not None)
    settles = [r.settle_time_s for r in show.rows if np.isfinite(r.settle_time_s)]
    tail = max(0.004, max(settles, default=0.0) - longest + 0.002)      # axis covers every settle time
    fig = plot_bench(show, truth or plant, controller, figures, tail_s=tail)
    return BenchStage(results, "truth" if truth is not None else "identified", model, fig)


def sweep(plant, controller, cfg: DemoConfig, folder: Path, pool) -> SweepStage:
    """A small TPI x length sweep of the design plant (TPIs relative to the log's track density)."""
    import pandas as pd
    from identification.model.plant import TRACK_PITCH_PER_TPI_NM
    from seekopt.evaluate.sweep import ALL_KINDS, SweepConfig, run_sweep
    native = TRACK_PITCH_PER_TPI_NM / plant.track_pitch_nm
    scfg = SweepConfig(plant, controller, [round(native * f) for f in cfg.sweep_tpi_factors],
                       list(cfg.sweep_lengths), cfg.imax, cfg.settle, designer="ocp-robust", kinds=ALL_KINDS)
    if folder.exists():                           # an earlier demo's sweep is replaced, not resumed
        import shutil
        shutil.rmtree(folder)
    s = run_sweep(scfg, folder, executor=pool, figures=True, progress=not cfg.quiet)
    return SweepStage(s, pd.read_csv(s.table), folder)


def export(folder: Path, out: Path) -> ExportStage:
    from seekopt.export.tables import load_tables, write_tables
    ts = load_tables(folder)
    return ExportStage(ts, [p for fmt in ("c", "csv", "json") for p in write_tables(ts, fmt, out)])


@dataclass
class _Stages:
    out: Path
    quiet: bool
    done: list = field(default_factory=list)   # [name, status, wall s, note, CPU s of this process]
    n: int = 7
    t0: float = field(default_factory=time.perf_counter)

    def say(self, text):
        if not self.quiet:
            print(text, file=sys.stderr, flush=True)

    @contextmanager
    def stage(self, name: str):
        i = len(self.done) + 1
        self.say(f"[{i}/{self.n}] {name} ... (elapsed {time.perf_counter() - self.t0:.0f} s)")
        t, c = time.perf_counter(), time.process_time()
        rec = [name, "ok", 0.0, "", 0.0]
        self.done.append(rec)
        try:
            yield rec
        except DemoError:
            raise
        except Exception as exc:  # noqa: BLE001 - every stage failure becomes one clear line
            self.out.mkdir(parents=True, exist_ok=True)
            log = self.out / "demo-error.log"
            log.write_text(traceback.format_exc())
            msg = " ".join(str(exc).split())[:200]
            raise DemoError(f"stage {i} ({name}) failed: {type(exc).__name__}: {msg} "
                            f"(traceback in {log})") from None
        rec[2], rec[4] = time.perf_counter() - t, time.process_time() - c
        self.say(f"[{i}/{self.n}] {name}: {rec[1]} in {rec[2]:.1f} s, CPU {rec[4]:.1f} s "
                 f"(elapsed {time.perf_counter() - self.t0:.0f} s)"
                 + (f" - {rec[3]}" if rec[3] else ""))


def run_demo(cfg: DemoConfig) -> DemoResult:
    """Run the pipeline; returns every stage's result, the stage timings and the report path."""
    from identification.logs import read_log
    from seekopt.app.demo_report import demo_report, demo_summary
    from seekopt.drive.controller import Controller
    from seekopt.evaluate.sweep import make_pool
    out = Path(cfg.outdir)
    out.mkdir(parents=True, exist_ok=True)
    run = _Stages(out, cfg.quiet)
    controller = Controller.nss()
    truth = None

    with run.stage("read the seek log") as rec:
        path = Path(cfg.log) if cfg.log else sample_log_path()
        log = read_log(path)
        if cfg.max_seeks:
            log = first_seeks(log, cfg.max_seeks)
        if cfg.log is None:
            truth = sample_truth()
        rec[3] = f"{path.name}: {log.n} samples at {log.sample_rate_hz:g} Hz" + \
            (f" (first {cfg.max_seeks} seeks)" if cfg.max_seeks else "")
        if log.track_pitch_nm is None:
            raise DemoError(f"{path}: the log has no track_pitch_nm; the sweep needs the physical gain")

    with run.stage("identify the plant") as rec:
        ids = identify_plant(log)
        ids.plant.to_json(out / "plant.json")
        rec[3] = f"k0 = {ids.plant.k0:.4g} track/(A s^2), {len(ids.plant.modes)} modes"
        if not loop_is_stable(ids.plant, controller):
            ids.warning = (f"the closed loop of the identified plant with `{controller.name}` does not decay "
                           "(unstable model loop): designs and benches on it are not trustworthy")
            rec[1], rec[3] = "warning", rec[3] + "; UNSTABLE model loop with the drive's controller"

    with run.stage("close the loop" + (f" (first {cfg.loop_seeks} seeks)" if cfg.loop_seeks else "")) as rec:
        lps = close_loop(log, ids.plant, cfg.loop_seeks)
        lps.result.plant.to_json(out / "plant.json")
        rec[3] = (f"validation RMS {lps.result.error_before['rms_track']:.4g} -> "
                  f"{lps.result.error_after['rms_track']:.4g} track; accepted: "
                  + (", ".join(lps.result.accepted) or "none"))

    # the sweep runs in the process pool beside the bench (one core each on an idle 2-core machine)
    from concurrent.futures import ThreadPoolExecutor
    pool, side = make_pool(cfg.workers), ThreadPoolExecutor(1, thread_name_prefix="demo-sweep")
    try:
        swept = side.submit(sweep, lps.design_plant, controller, cfg, out / "sweep", pool)
        with run.stage("design and bench against sine / windowed sine (sweep running beside it)") as rec:
            bench = design_and_bench(lps.design_plant, truth, controller, cfg, out / "figures")
            rec[3] = f"{len(cfg.lengths)} lengths, evaluated on the {bench.evaluated_on} plant"
        with run.stage("small TPI sweep (started with the bench; time after it)") as rec:
            sw = swept.result()
            rec[3] = (f"{sw.summary.total} cells, {len(sw.summary.failed_cells)} failed, "
                      f"{sw.summary.wall_s:.0f} s in all")
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        side.shutdown(wait=True)

    with run.stage("export firmware tables") as rec:
        ex = export(sw.folder, out / "export")
        rec[3] = f"{len(ex.tables.tables)} tables, {ex.tables.meta['ref_format']}"

    import resource
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)          # the sweep's workers, reaped above
    result = DemoResult(cfg, log, truth, controller, ids, lps, bench, sw, ex, run.done,
                        cpu_s=time.process_time() + kids.ru_utime + kids.ru_stime)
    with run.stage("write the report") as rec:
        result.report = demo_report(result, out)
        rec[3] = str(result.report)

    print(demo_summary(result).to_string(index=False))
    print(f"\nreport: {result.report.with_suffix('.html')}  (total {time.perf_counter() - run.t0:.0f} s wall, "
          f"{result.cpu_s:.0f} s CPU with the sweep's workers)")
    return result
