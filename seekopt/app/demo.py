"""The whole pipeline on one seek log (``seekopt demo``).

Stages, each timed and reported; a failing stage stops the demo with a one-line
:class:`DemoError` (the traceback goes to ``<out>/demo-error.log``):

1. **log** -- read the log (default: the bundled synthetic ``seekopt/data/sample_log.npz``,
   120 seeks of ``seekopt synth`` with its defaults; its truth plant is bundled beside it);
2. **identify** -- :func:`identification.estimate.identify.identify` (robust method);
3. **close the loop** -- :mod:`identification.loop.closing` (residual analysis, model augmentation);
   skipped, and said so, where that module is not available;
4. **design & bench** -- optimal profiles for a set of seek lengths at the log's track
   density, benchmarked against sine and windowed sine (:mod:`seekopt.evaluate.sweep`, one TPI), and,
   when the truth plant is known, the same profiles run on the truth;
5. **sweep** -- a small TPI x length sweep (local process pool) that extends the bench folder;
6. **export** -- C, CSV and JSON firmware tables (:mod:`seekopt.export.tables`);
7. **report** -- ``report.md`` (+ ``report.html``) with figures, and a summary table printed.

Everything is written under the output folder (default ``./seekopt-out``); a sweep folder left
there by an earlier demo with another plant or settings is moved aside (``sweep-<hash>``), one with
the same settings is resumed.  The drive's controller is taken to be the NSS benchmark controller
(the one the bundled log was recorded with).
"""
from __future__ import annotations

import json
import time
import traceback
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

__all__ = ["DemoError", "DemoConfig", "run_demo", "identify_plant", "close_loop", "sample_log_path"]


class DemoError(ValueError):
    """A demo stage failed (one-line message naming the stage)."""


@dataclass
class DemoConfig:
    """What the demo does.  ``quick`` (for tests) uses the first 60 seeks of the log and shrinks
    the design set and the sweep."""

    log: str | None = None
    outdir: str = "seekopt-out"
    quick: bool = False
    imax: float = 0.3
    settle: float = 0.1
    lengths: tuple = (1, 10, 100, 1000, 3000)
    sweep_tpi_factors: tuple = (1.0, 2.0, 5.0)
    sweep_lengths: tuple = (10, 100, 1000, 3000)
    workers: int = 2
    html: bool = True
    designer: str = "ocp-robust"
    max_seeks: int | None = None

    def __post_init__(self):
        if self.quick:
            self.lengths, self.sweep_lengths, self.sweep_tpi_factors = (10, 1000), (10, 1000), (1.0, 3.0)
            self.max_seeks = self.max_seeks or 60


def loop_is_stable(plant, controller, n: int = 3000) -> bool:
    """Does the linear 2DOF loop of ``plant`` and ``controller`` decay?  (Impulse response from the
    reference over ``n`` servo samples, by the one simulator; a stable loop decays by many decades.)"""
    from seekopt.drive.simulator import closed_loop_responses
    y = closed_loop_responses(plant, controller, n)["y_r"]
    peak = float(np.max(np.abs(y))) if np.all(np.isfinite(y)) else float("inf")
    return bool(np.isfinite(peak) and np.max(np.abs(y[-n // 10:])) < 1e-3 * peak)


def first_seeks(log, n: int):
    """The log up to the start of its ``n+1``-th seek (target change)."""
    starts = np.nonzero(np.diff(log.target_track) != 0)[0] + 1
    return log if len(starts) <= n else log.slice(0, int(starts[n]))


def sample_log_path() -> Path:
    """The bundled sample log."""
    return Path(str(resources.files("seekopt").joinpath("data/sample_log.npz")))


def _sample_truth():
    from identification.model.plant import ModalPlant
    return ModalPlant.load(str(resources.files("seekopt").joinpath("data/sample_log.truth.json")))


# ------------------------------------------------------------------ stage adapters
def identify_plant(log):
    """``identify(log).plant`` with the log's track pitch and sample rate filled in.

    Returns ``(plant, notes)``; ``notes`` is a dict of what identification reported.
    """
    from identification.estimate.identify import identify
    res = identify(log)
    plant = res.plant
    if plant.track_pitch_nm is None and log.track_pitch_nm is not None:
        plant = plant.copy(track_pitch_nm=log.track_pitch_nm)
    if plant.sample_rate_hz is None:
        plant = plant.copy(sample_rate_hz=log.sample_rate_hz)
    notes = {k: getattr(res, k) for k in ("method", "fit_percent", "fit_percent_rigid", "residual_rms")
             if hasattr(res, k)}
    return plant, notes


def close_loop(log, plant):
    """:func:`identification.loop.closing.close_loop` on ``(log, plant)`` (held-out seeks validate).

    Returns ``(plant, summary)``: the (possibly augmented) plant and a short Markdown summary,
    or ``(plant, None)`` when the module is not available (the stage is then reported skipped).
    """
    try:
        from identification.loop.closing import close_loop as _close
    except ImportError:
        return plant, None
    res = _close(log, plant)
    eb, ea = res.error_before, res.error_after
    lines = [f"Validation RMS error {eb['rms_track']:.4g} -> {ea['rms_track']:.4g} track "
             f"(fit {eb['fit_percent']:.1f} % -> {ea['fit_percent']:.1f} %); accepted effects: "
             + (", ".join(res.accepted) or "none") + "."]
    tried = [f"- {s.effect}: validation RMS {s.rms_before:.4g} -> {s.rms_after:.4g} track, "
             f"BIC drop {s.bic_drop:.1f}, {'accepted' if s.accepted else 'rejected'}" for s in res.steps]
    if tried:
        lines += ["", "Candidates tried:", ""] + tried
    if res.unexplained:
        lines += ["", "Still in the residual:", ""] + [f"- {u}" for u in res.unexplained]
    return res.plant, "\n".join(lines)


# ------------------------------------------------------------------ stages
@dataclass
class _Run:
    out: Path
    stages: list = field(default_factory=list)   # (name, status, seconds, note)
    n: int = 7

    @contextmanager
    def stage(self, name: str):
        i = len(self.stages) + 1
        print(f"[{i}/{self.n}] {name} ...", flush=True)
        t0 = time.perf_counter()
        rec = [name, "ok", 0.0, ""]
        self.stages.append(rec)
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
        rec[2] = time.perf_counter() - t0
        print(f"[{i}/{self.n}] {name}: {rec[1]} in {rec[2]:.1f} s" + (f" - {rec[3]}" if rec[3] else ""),
              flush=True)


def _bench_on(plant, controller, profiles, settle, k0):
    """Evaluate each ``(tracks, kind, profile)`` on ``plant``; rows as dicts."""
    from seekopt.evaluate.sweep import evaluate
    rows = []
    for tracks, kind, prof in profiles:
        rows.append(dict(tracks=tracks, kind=kind, **evaluate(plant, controller, prof, settle, None, k0)))
    return rows


def _set_aside_other_sweep(sweep_dir: Path, config_hash: str) -> None:
    """A sweep folder of an earlier demo with another plant or settings is renamed, not reused."""
    meta = sweep_dir / "sweep.json"
    if not meta.exists():
        return
    try:
        old = json.loads(meta.read_text()).get("config_hash", "unknown")
    except ValueError:
        old = "unreadable"
    if old != config_hash:
        dest = sweep_dir.with_name(f"sweep-{old}")
        if dest.exists():
            dest = sweep_dir.with_name(f"sweep-{old}-{int(time.time())}")
        sweep_dir.rename(dest)
        print(f"      (an earlier sweep with other settings moved to {dest})", flush=True)


def _design_and_sweep(cfg, run, pool, plant, truth, controller, native, sweep_dir):
    """Stages 4 and 5: bench at the log's TPI, then the small sweep (reusing the bench cells)."""
    import pandas as pd
    from seekopt.design.profiles import Profile
    from seekopt.evaluate.sweep import ALL_KINDS, SweepConfig, baseline_profile, cell_key, load_cells, run_sweep
    with run.stage("design and bench against sine / windowed sine") as rec:
        bcfg = SweepConfig(plant, controller, [native], list(cfg.lengths), cfg.imax, cfg.settle,
                           designer=cfg.designer, kinds=ALL_KINDS)
        _set_aside_other_sweep(sweep_dir, bcfg.hash())
        bs = run_sweep(bcfg, sweep_dir, executor=pool, figures=False)
        cells = load_cells(sweep_dir)
        bench = pd.read_csv(bs.table)
        bench = bench[bench["tpi"] == bcfg.tpis[0]]
        truth_rows = []
        if truth is not None:
            profs = []
            for L in bcfg.tracks:
                c = cells[cell_key(bcfg.tpis[0], L)]
                if c.get("optimal_profile"):
                    profs.append((L, "optimal", Profile.from_dict(c["optimal_profile"])))
                for kind in ("sine", "windowed_sine"):
                    profs.append((L, kind, baseline_profile(plant, controller.sample_rate_hz, kind, L,
                                                            cfg.imax, cfg.settle)))
                for kind, d in sorted(c.get("tuned_profiles", {}).items()):
                    profs.append((L, kind, Profile.from_dict(d)))
            truth_rows = _bench_on(truth, controller, profs, cfg.settle, plant.k0)
        rec[3] = f"{len(bcfg.tracks)} lengths, {len(bs.failed_cells)} failed cells"

    with run.stage("small TPI sweep") as rec:
        tpis = [round(native * f) for f in cfg.sweep_tpi_factors]
        scfg = SweepConfig(plant, controller, tpis, sorted(set(cfg.sweep_lengths) | set(cfg.lengths)),
                           cfg.imax, cfg.settle, designer=cfg.designer, kinds=ALL_KINDS)
        ss = run_sweep(scfg, sweep_dir, executor=pool, figures=True,
                       progress=True)
        sweep_df = pd.read_csv(ss.table)
        rec[3] = (f"{ss.total} cells ({ss.skipped} reused from the bench), {ss.computed} computed "
                  f"at {ss.cells_per_s:.2f} cells/s")

    return bench, truth_rows, sweep_df, ss


def run_demo(cfg: DemoConfig) -> dict:
    """Run the pipeline; returns a dict with the report path, tables and stage timings."""
    import pandas as pd
    from identification.logs import read_log
    from identification.model.plant import TRACK_PITCH_PER_TPI_NM
    from seekopt.app import report
    from seekopt.drive.controller import Controller
    from seekopt.export.tables import load_tables, write_tables
    from seekopt.design.profiles import Profile
    from seekopt.evaluate.sweep import make_pool
    out = Path(cfg.outdir)
    out.mkdir(parents=True, exist_ok=True)
    figs = out / "figures"
    run = _Run(out)
    t_start = time.perf_counter()
    controller = Controller.nss()
    truth = None

    with run.stage("read the seek log") as rec:
        path = Path(cfg.log) if cfg.log else sample_log_path()
        log = read_log(path)
        if cfg.max_seeks:
            log = first_seeks(log, cfg.max_seeks)
        if cfg.log is None:
            truth = _sample_truth()
        rec[3] = f"{path.name}: {log.n} samples at {log.sample_rate_hz:g} Hz" + \
            (f" (first {cfg.max_seeks} seeks)" if cfg.max_seeks else "")
        if log.track_pitch_nm is None:
            raise DemoError(f"{path}: the log has no track_pitch_nm; the sweep needs the physical gain")

    with run.stage("identify the plant") as rec:
        plant, id_notes = identify_plant(log)
        plant.to_json(out / "plant.json")
        rec[3] = f"k0 = {plant.k0:.4g} track/(A s^2), {len(plant.modes)} modes"
        if not loop_is_stable(plant, controller):
            id_notes["warning"] = (f"the closed loop of the identified plant with `{controller.name}` does not "
                                   "decay (unstable model loop): designs and benches on it are not trustworthy")
            rec[1], rec[3] = "warning", rec[3] + "; UNSTABLE model loop with the drive's controller"

    with run.stage("close the loop") as rec:
        plant2, loop_summary = close_loop(log, plant)
        if loop_summary is None:
            rec[1], rec[3] = "skipped", "identification.loop.closing not available"
        else:
            plant2.to_json(out / "plant.json")
            rec[3] = loop_summary.splitlines()[0][:100]
            # disturbances found in the residual (output effects, e.g. run-out) stay in plant.json but
            # not in the design plant: settle metrics are disturbance-free, as on the truth plant
            plant = plant2.copy(effects=[e for e in plant2.effects if e.kind != "output"])
            dropped = [e.to_dict()["effect"] for e in plant2.effects if e.kind == "output"]
            if dropped:
                loop_summary += ("\n\nOutput effects (" + ", ".join(dropped) + ") are kept in `plant.json` "
                                 "but left out of the design and bench plant: settle metrics are "
                                 "disturbance-free, as on the truth plant.")

    native = TRACK_PITCH_PER_TPI_NM / plant.track_pitch_nm
    sweep_dir = out / "sweep"
    pool = make_pool(cfg.workers)  # one pool for both sweeps: workers keep their designers
    try:
        bench, truth_rows, sweep_df, ss = _design_and_sweep(cfg, run, pool, plant, truth, controller,
                                                            native, sweep_dir)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)

    with run.stage("export firmware tables") as rec:
        ts = load_tables(sweep_dir)
        paths = []
        for fmt in ("c", "csv", "json"):
            paths += write_tables(ts, fmt, out / "export")
        rec[3] = f"{len(ts.tables)} tables, {ts.meta['ref_format']}"

    with run.stage("write the report") as rec:
        report_path = _write_report(cfg, out, figs, log, plant, truth, id_notes, loop_summary, bench,
                                    truth_rows, sweep_df, ss, ts, paths, run, controller)
        rec[3] = str(report_path)

    summary = _summary_table(bench, truth_rows)
    print()
    print(summary.to_string(index=False))
    print(f"\nreport: {report_path}  (total {time.perf_counter() - t_start:.0f} s)")
    return {"report": report_path, "bench": bench, "truth": truth_rows, "sweep": sweep_df,
            "stages": run.stages, "summary": summary}


# ------------------------------------------------------------------ report
def _summary_table(bench, truth_rows):
    """One row per (seek length, profile): seek time and seek-settle time [ms] on the identified
    plant and, when known, on the truth plant."""
    import pandas as pd
    from seekopt.app.report import KIND_LABELS, seek_settle_s
    from seekopt.evaluate.sweep import ALL_KINDS
    b = bench.copy()
    b["settle_ms"] = 1e3 * seek_settle_s(b)
    out = pd.DataFrame({"tracks": b["tracks"], "kind": b["kind"], "seek [ms]": 1e3 * b["seek_time_s"],
                        "seek-settle, model [ms]": b["settle_ms"]})
    if truth_rows:
        tr = pd.DataFrame(truth_rows).assign(status="ok")
        tr["truth"] = 1e3 * seek_settle_s(tr)
        out = out.merge(tr[["tracks", "kind", "truth"]], on=["tracks", "kind"], how="left")
        out = out.rename(columns={"truth": "seek-settle, truth [ms]"})
    out["order"] = [ALL_KINDS.index(k) for k in out["kind"]]
    out = out.sort_values(["tracks", "order"]).drop(columns="order")
    out["kind"] = [KIND_LABELS.get(k, k) for k in out["kind"]]
    return out.rename(columns={"kind": "profile"}).reset_index(drop=True).round(3)


def _plot_frf(plant, truth, path):
    plt = __import__("seekopt.app.report", fromlist=["_plt"])._plt()
    f = np.logspace(1.5, np.log10(13000), 600)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.loglog(f, np.abs(plant.frf(f)), "C3", label="identified")
    if truth is not None:
        ax.loglog(f, np.abs(truth.frf(f)), "k--", lw=0.9, label="truth (synthetic drive)")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("|P(j2πf)| [track/A]")
    ax.set_title("Plant frequency response")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return __import__("seekopt.app.report", fromlist=["_save"])._save(fig, path)


def _plot_traces(plant, truth, controller, cells, tpi, tracks, imax, settle, folder):
    """Fig. 9/10-style traces (:func:`seekopt.evaluate.bench.plot_bench`) of the three profiles of one seek,
    played on the truth plant when known, else on the identified plant."""
    from seekopt.evaluate.bench import BenchResult, BenchRow, plot_bench
    from seekopt.design.metrics import evaluate_profile
    from seekopt.design.profiles import Profile
    from seekopt.evaluate.sweep import baseline_profile, cell_key
    evalp = truth or plant
    c = cells.get(cell_key(tpi, tracks))
    profs = [(k, baseline_profile(plant, controller.sample_rate_hz, k, tracks, imax, settle))
             for k in ("sine", "windowed_sine")]
    if c and c.get("optimal_profile"):
        profs.append(("optimal", Profile.from_dict(c["optimal_profile"])))
    rows = []
    for kind, p in profs:
        m = evaluate_profile(evalp, controller, p, settle=settle, k0_for_tbb=plant.k0)
        rows.append(BenchRow(kind, kind, m, profile=p))
    from seekopt.design.profiles import t_bang_bang
    res = BenchResult(float(tracks), imax, settle, t_bang_bang(tracks, plant.k0, imax), rows)
    return plot_bench(res, evalp, controller, Path(folder))


def _write_report(cfg, out, figs, log, plant, truth, id_notes, loop_summary, bench, truth_rows,
                  sweep_df, ss, ts, export_paths, run, controller):
    from seekopt import __version__
    from seekopt.app import report
    from seekopt.evaluate.sweep import load_cells
    sections = []
    rows = [{"stage": s[0], "status": s[1], "time_s": s[2], "note": s[3]} for s in run.stages]
    rows[-1]["time_s"], rows[-1]["note"] = float("nan"), "(this report)"
    import pandas as pd
    sections.append(("Pipeline", f"seekopt {__version__}; log `{cfg.log or 'bundled sample_log.npz'}`, "
                     f"{log.n} samples at {log.sample_rate_hz:g} Hz; controller `{controller.name}`; "
                     f"Imax {cfg.imax:g} A; settle band ±{cfg.settle:g} track.\n\n"
                     + report.markdown_table(pd.DataFrame(rows), fmt=".1f"), []))
    mt = pd.DataFrame([{"freq_hz": m.freq_hz, "zeta": m.zeta, "gain": m.gain} for m in plant.modes])
    text = (f"k0 = {plant.k0:.5g} track/(A s²) (physical gain {plant.physical_gain:.4g} m/(A s²)), "
            f"bias {plant.bias_a:.3g} A, delay {1e6 * plant.delay_s:.2f} µs. "
            + ", ".join(f"{k}: {v:.4g}" if isinstance(v, float) else f"{k}: {v}" for k, v in id_notes.items())
            + "\n\n" + (report.markdown_table(mt, fmt=".4g") if len(mt) else "(no modes)\n"))
    if truth is not None:
        tt = pd.DataFrame([{"freq_hz": m.freq_hz, "zeta": m.zeta, "gain": m.gain} for m in truth.modes])
        text += f"\nTruth of the synthetic drive: k0 = {truth.k0:.5g}, bias {truth.bias_a:.3g} A.\n\n" + \
            report.markdown_table(tt, fmt=".4g")
    sections.append(("Identified plant", text, [_plot_frf(plant, truth, figs / "plant_frf.png")]))
    sections.append(("Closing the loop", loop_summary or "Skipped: `identification.loop.closing` is not "
                     "available in this installation.", []))
    summary = _summary_table(bench, truth_rows)
    cells = load_cells(out / "sweep")
    L = 1000 if 1000 in cfg.lengths else sorted(cfg.lengths)[len(cfg.lengths) // 2]
    trace = _plot_traces(plant, truth, controller, cells, float(bench["tpi"].iloc[0]), L,
                         cfg.imax, cfg.settle, figs)
    sections.append(("Bench: optimal vs sine and windowed sine",
                     "Seek-settle time [ms] (seek start until the error stays within the band) on the "
                     "identified plant" + (" and on the truth plant of the synthetic drive" if truth_rows else "")
                     + "; – : not settled or failed.\n\n" + report.markdown_table(summary, fmt=".3g")
                     + f"\nTraces of the {L:g}-track seek on the "
                     + ("truth" if truth is not None else "identified") + " plant:\n", [trace]))
    sv = report.savings_table(sweep_df)
    sections.append(("TPI sweep", "The identified plant re-expressed per TPI (physical gain kept, "
                     "controller gain scaled with the track pitch, settle band in tracks). "
                     f"{ss.total} cells; results in `sweep/results.csv`.\n\n"
                     + report.markdown_table(sv, fmt=".3g"), ss.figures))
    sections.append(("Firmware export", f"{len(ts.tables)} tables; feedforward {ts.meta['ff_format']}; "
                     f"reference {ts.meta['ref_format']}. Files: "
                     + ", ".join(f"`{Path(p).relative_to(out)}`" for p in export_paths), []))
    return report.write_report(out, "seekopt demo report", sections, html_too=cfg.html)
