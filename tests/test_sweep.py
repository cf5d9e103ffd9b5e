"""Tests for seekopt.evaluate.sweep: grid parsing, engines (serial, process pool, Dask LocalCluster),
determinism, failing cells, kill-and-resume, CLI errors.

The machinery is tested with the ``baseline`` designer (shortest bang-bang within Imax) so
the tests do not depend on the optimiser's speed; the optimiser-backed sweep is under
``@pytest.mark.slow``.
"""
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pandas as pd
import pytest

from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from seekopt.evaluate.sweep import (ALL_KINDS, KINDS, TIMING_COLUMNS, TUNE_FACTORS, SweepConfig, SweepError, CellRunner, cell_key, compute_cell,
                           load_cells, parse_tpi, parse_tracks, run_sweep)

ROOT = Path(__file__).resolve().parents[1]
TPIS, TRACKS = [100e3, 200e3], [1, 10, 100]


def config(**kw):
    args = dict(plant=default_truth_plant(), controller=Controller.nss(), tpis=TPIS, tracks=TRACKS,
                imax=0.3, designer="baseline")
    args.update(kw)
    return SweepConfig(**args)


def numbers(outdir):
    """The sweep table without the timing columns (which depend on the machine)."""
    df = pd.read_csv(Path(outdir) / "results.csv")
    return df.drop(columns=list(TIMING_COLUMNS))


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    out = tmp_path_factory.mktemp("serial")
    s = run_sweep(config(), out, engine="serial", progress=False, figures=False)
    return out, s


class FailingDesigner:
    """Test designer: the baseline designer, but 10-track seeks fail."""

    def __init__(self, plant, controller, imax, settle=0.1):
        from seekopt.evaluate.sweep import BaselineDesigner
        self.inner = BaselineDesigner(plant, controller, imax, settle)

    def design(self, tracks):
        if tracks == 10:
            raise RuntimeError("solver exploded\nsecond line")
        return self.inner.design(tracks)


BUILT = []


class CountingDesigner(FailingDesigner):
    """Counts its builds: in this process (``BUILT``) and, in any process, as one file per build in the
    folder ``$SEEKOPT_TEST_BUILDS`` (``<pid>-<k0>-<uuid>``)."""

    def __init__(self, *a, **k):
        BUILT.append(a[0].k0)
        folder = os.environ.get("SEEKOPT_TEST_BUILDS")
        if folder:
            import uuid
            (Path(folder) / f"{os.getpid()}-{a[0].k0!r}-{uuid.uuid4().hex}").touch()
        super().__init__(*a, **k)

    def design(self, tracks):
        return self.inner.design(tracks)


# ------------------------------------------------------------------ parsing / config
def test_parse_grid():
    assert parse_tpi("200k:1000k:9") == [200e3 + 1e5 * i for i in range(9)]
    assert parse_tpi("500k") == [500e3] and parse_tpi("1m,200k") == [200e3, 1e6]
    assert parse_tracks("10,1,2,5,1") == [1, 2, 5, 10]
    for bad in ("200k:1000k", "a:b:3", "200k:1000k:0", "-5"):
        with pytest.raises(SweepError):
            parse_tpi(bad)
    with pytest.raises(SweepError):
        parse_tracks("1,x")
    with pytest.raises(SweepError):
        config(plant=default_truth_plant().copy(track_pitch_nm=None))


def test_cell_rows_and_tpi_scaling():
    """k0 scales with TPI (physical gain kept), the controller with it; one row per kind."""
    cfg = config()
    a = compute_cell({"config": cfg.to_dict(), "tpi": 100e3, "tracks": 10})
    b = compute_cell({"config": cfg.to_dict(), "tpi": 200e3, "tracks": 10})
    assert [r["kind"] for r in a["rows"]] == list(KINDS)
    ra, rb = a["rows"][1], b["rows"][1]
    assert rb["k0_track"] / ra["k0_track"] == pytest.approx(2.0, rel=1e-12)
    phys = [r["k0_track"] * r["track_pitch_nm"] * 1e-9 for r in (ra, rb)]
    assert phys[0] == pytest.approx(default_truth_plant().physical_gain, rel=1e-12) == phys[1]
    assert rb["controller_gain"] / ra["controller_gain"] == pytest.approx(0.5, rel=1e-12)
    assert all(r["status"] == "ok" for r in a["rows"] + b["rows"])
    assert a["optimal_profile"]["tracks"] == 10.0


def test_tuned_baselines_never_slower_than_shortest():
    cfg = config(kinds=ALL_KINDS, tpis=[200e3])
    rows = {r["kind"]: r for r in compute_cell({"config": cfg.to_dict(), "tpi": 200e3, "tracks": 100})["rows"]}
    for k in ("sine", "windowed_sine"):
        assert rows[f"{k}_tuned"]["settle_time_s"] <= rows[k]["settle_time_s"]
        assert rows[f"{k}_tuned"]["objective"] == f"best of {len(TUNE_FACTORS)} durations"


def test_designer_built_once_per_tpi():
    """A runner (what each worker holds) builds one designer per TPI and reuses it across that TPI's
    cells; there is no module-level cache: a fresh runner, or compute_cell, builds its own."""
    BUILT.clear()
    cfg = config(designer="test_sweep:CountingDesigner", tpis=[300e3, 400e3])
    runner = CellRunner()
    for tpi in (300e3, 400e3):
        for k in (1, 10, 100):
            runner({"config": cfg.to_dict(), "tpi": tpi, "tracks": k})
    assert len(BUILT) == 2 and runner.designers_built == 2
    compute_cell({"config": cfg.to_dict(), "tpi": 300e3, "tracks": 1})
    compute_cell({"config": cfg.to_dict(), "tpi": 300e3, "tracks": 10})
    assert len(BUILT) == 4


def test_sweep_config_default_designer_is_the_cli_default():
    from seekopt.app.cli import build_parser
    args = build_parser().parse_args(["sweep", "--plant", "p.json", "--tpi", "200k", "--tracks", "1",
                                      "--imax", "0.3", "-o", "o"])
    cfg = SweepConfig(default_truth_plant(), Controller.nss(), [200e3], [1], 0.3)
    assert cfg.designer == args.designer == "ocp-robust"


# ------------------------------------------------------------------ results, determinism, engines
def test_serial_sweep_writes_table_cells_profiles(serial):
    out, s = serial
    assert s.total == 6 and s.computed == 6 and s.skipped == 0 and not s.engine_errors
    df = pd.read_csv(out / "results.csv")
    assert len(df) == 6 * len(KINDS)
    assert set(df["kind"]) == set(KINDS) and (df["status"] == "ok").all()
    assert {"seek_time_s", "settle_time_s", "peak_pes_after_track", "ratio_tbb", "settled",
            "design_status", "error"} <= set(df.columns)
    assert sorted(load_cells(out)) == sorted(cell_key(t, k) for t in TPIS for k in TRACKS)
    assert len(list((out / "profiles").glob("optimal_*.csv"))) == 6
    journal = (out / "journal.log").read_text().splitlines()
    assert sum(line.startswith("computed ") for line in journal) == 6


def test_rerun_is_deterministic_and_resumes(serial, tmp_path):
    out, _ = serial
    s = run_sweep(config(), out, engine="serial", progress=False, figures=False)
    assert s.computed == 0 and s.skipped == 6
    run_sweep(config(tracks=list(reversed(TRACKS))), tmp_path, engine="serial", progress=False,
              figures=False)
    pd.testing.assert_frame_equal(numbers(out), numbers(tmp_path), check_exact=True)


def test_process_pool_equals_serial(serial, tmp_path):
    out, _ = serial
    s = run_sweep(config(), tmp_path, engine="process", workers=2, progress=False, figures=True)
    assert s.engine == "process" and s.computed == 6
    pd.testing.assert_frame_equal(numbers(out), numbers(tmp_path), check_exact=True)
    assert {p.name for p in s.figures} >= {"seek_settle_vs_length.png", "heatmap_saving.png",
                                           "gain_over_baselines.png"}


def lanes_used(outdir, builds):
    """Per worker pid: (designers it built, counted by files; TPIs of its cells; lengths per TPI in
    the order it computed them)."""
    per = {}
    for c in sorted(load_cells(outdir).values(), key=lambda c: c["computation_id"]):
        per.setdefault(c["pid"], {}).setdefault(c["tpi"], []).append(c["tracks"])
    built = {}
    for f in Path(builds).iterdir():
        built[int(f.name.split("-")[0])] = built.get(int(f.name.split("-")[0]), 0) + 1
    return {pid: (built.get(pid, 0), sorted(t), t) for pid, t in per.items()}


@pytest.mark.parametrize("engine", ["process", "local"])
def test_two_workers_same_cells_one_designer_per_worker_and_tpi(engine, tmp_path, monkeypatch):
    """2 workers (process pool, Dask LocalCluster) compute the same cells as one process, each worker
    builds one designer per TPI it computes (never one per cell), and both workers compute."""
    builds = tmp_path / "builds"
    builds.mkdir()
    monkeypatch.setenv("SEEKOPT_TEST_BUILDS", str(builds))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).parent), str(ROOT),
                                                      os.environ.get("PYTHONPATH", "")]))
    cfg = config(designer="test_sweep:CountingDesigner", tpis=[100e3, 200e3, 300e3], tracks=[1, 3, 10, 30])
    run_sweep(cfg, tmp_path / "one", engine="serial", progress=False, figures=False)
    assert len(list(builds.iterdir())) == 3             # serial: one designer per TPI
    for f in builds.iterdir():
        f.unlink()
    s = run_sweep(cfg, tmp_path / "two", engine=engine, workers=2, progress=False, figures=False)
    assert s.computed == 12 and not s.engine_errors and s.cell_cpu_s > 0
    pd.testing.assert_frame_equal(numbers(tmp_path / "one"), numbers(tmp_path / "two"), check_exact=True)
    used = lanes_used(tmp_path / "two", builds)
    assert len(used) == 2 and os.getpid() not in used
    for pid, (n_built, tpis, _) in used.items():
        assert n_built == len(tpis), (pid, n_built, tpis)        # one build per (worker, TPI)
    assert sum(n for n, _, _ in used.values()) <= 3 + 1          # 3 TPIs, at most one TPI shared
    assert sorted(s.designers_built.values()) == sorted(n for n, _, _ in used.values())
    assert set(s.blas_threads.values()) == {1}                   # one BLAS thread in every worker


def test_worker_pool_sends_work_to_the_chosen_worker_and_joins_on_shutdown():
    from seekopt.evaluate.engines import make_pool
    pool = make_pool(2)
    try:
        pids = [pool.submit_to(lane, os.getpid).result(timeout=120) for lane in (0, 1, 0, 1)]
        any_pid = pool.submit(os.getpid).result(timeout=120)
        procs = pool.processes()
    finally:
        pool.shutdown(wait=True)
    assert pids[0] == pids[2] != pids[1] == pids[3] and any_pid in pids and os.getpid() not in pids
    assert len(procs) == 2 and all(p.exitcode is not None for p in procs)     # joined, not left running


def test_lane_plan_keeps_tpis_on_workers_and_shares_the_last():
    from seekopt.evaluate.sweep_lanes import LanePlan
    cells = [(t, k) for t in (1e5, 2e5, 3e5) for k in (1, 3, 10, 30)]
    plan, got = LanePlan(cells, 2), {0: [], 1: []}
    for lane in (0, 1, 0, 1, 0, 1, 0, 1, 0, 1):         # two workers in step
        got[lane].append(plan.next(lane))
    assert [k for _, k in got[0][:4]] == [30, 10, 3, 1] and {t for t, _ in got[0][:4]} == {1e5}
    assert {t for t, _ in got[1][:4]} == {2e5}
    # the last TPI: longest first; the other worker takes the shorter half of what is left, then the rest
    assert got[0][4] == (3e5, 30) and got[1][4] == (3e5, 1)
    assert plan.next(0) == (3e5, 10) and plan.next(1) == (3e5, 3) and plan.next(0) is None
    assert not plan and plan.splits == 1
    plan.give_back(2e5, 3)
    assert plan and plan.next(1) == (2e5, 3) and plan.next(1) is None
    for lanes in (1, 2, 3, 5):                           # every cell exactly once
        plan, out = LanePlan(cells, lanes), []
        while plan:
            for lane in range(lanes):
                c = plan.next(lane)
                if c is not None:
                    out.append(c)
        assert sorted(out) == sorted(cells)


def test_dask_local_cluster_equals_serial(serial, tmp_path):
    from dask.distributed import Client, LocalCluster
    out, _ = serial
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        s = run_sweep(config(), tmp_path, client=client, progress=False, figures=False)
        pids = {c["pid"] for c in load_cells(tmp_path).values()}
    assert s.computed == 6 and not s.engine_errors
    assert os.getpid() not in pids
    pd.testing.assert_frame_equal(numbers(out), numbers(tmp_path), check_exact=True)


# ------------------------------------------------------------------ failures
def test_failing_cell_recorded_and_sweep_goes_on(tmp_path):
    cfg = config(designer="test_sweep:FailingDesigner", tpis=[100e3])
    s = run_sweep(cfg, tmp_path, engine="serial", progress=False, figures=True)
    assert s.failed_cells == [cell_key(100e3, 10)] and s.computed == 3
    df = pd.read_csv(tmp_path / "results.csv", keep_default_na=False)
    bad = df[(df["tracks"] == 10) & (df["kind"] == "optimal")].iloc[0]
    assert bad["status"] == "error" and bad["error"] == "RuntimeError: solver exploded second line"
    assert (df[df["kind"] != "optimal"]["status"] == "ok").all()
    assert (df[(df["tracks"] != 10)]["status"] == "ok").all()
    again = run_sweep(cfg, tmp_path, engine="serial", progress=False, figures=False)
    assert again.computed == 0  # a recorded failure is a result, not redone


def test_other_configuration_refused_grid_change_reuses(serial, tmp_path):
    out, _ = serial
    with pytest.raises(SweepError, match="another plant/controller"):
        run_sweep(config(imax=0.2), out, engine="serial", progress=False, figures=False)
    s = run_sweep(config(tracks=TRACKS + [1000]), out, engine="serial", progress=False, figures=False)
    assert s.skipped == 6 and s.computed == 2 and s.total == 8


def test_cli_errors_are_one_line_exit_2(tmp_path, capsys):
    from seekopt.app.cli import main
    plant = tmp_path / "p.json"
    default_truth_plant().to_json(plant)
    args = ["sweep", "--plant", str(plant), "--tracks", "1,10", "--imax", "0.3", "-o", str(tmp_path / "o")]
    assert main(args + ["--tpi", "200k:1000k"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "start:stop:count" in err
    assert main(["sweep", "--plant", str(tmp_path / "missing.json"), "--tpi", "200k", "--tracks", "1",
                 "--imax", "0.3", "-o", str(tmp_path / "o")]) == 2
    assert "missing.json" in capsys.readouterr().err


# ------------------------------------------------------------------ kill and resume
KILL_SCRIPT = textwrap.dedent("""
    import sys
    from seekopt.drive.controller import Controller
    from seekopt.drive.presets import default_truth_plant
    from seekopt.evaluate.sweep import SweepConfig, run_sweep
    cfg = SweepConfig(default_truth_plant(), Controller.nss(), [100e3, 150e3, 200e3, 300e3],
                      [1, 3, 10, 30, 100], 0.3, designer="baseline")
    run_sweep(cfg, sys.argv[1], engine="process", workers=2, progress=False, figures=False)
""")


def test_killed_sweep_resumes_without_loss_or_recompute(tmp_path):
    out = tmp_path / "res"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-c", KILL_SCRIPT, str(out)], env=env,
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and len(list((out / "cells").glob("*.json"))) < 4:
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its pool workers, mid-way
        proc.wait()
    before = {k: c["computation_id"] for k, c in load_cells(out).items()}
    assert 4 <= len(before) < 20, "the kill did not land mid-way"
    cfg = SweepConfig(default_truth_plant(), Controller.nss(), [100e3, 150e3, 200e3, 300e3],
                      [1, 3, 10, 30, 100], 0.3, designer="baseline")
    s = run_sweep(cfg, out, engine="serial", progress=False, figures=False)
    after = load_cells(out)
    assert s.total == 20 and s.skipped == len(before) and s.computed == 20 - len(before)
    assert len(after) == 20                                              # no cell lost
    assert all(after[k]["computation_id"] == i for k, i in before.items())  # none recomputed
    computed = [line.split()[1] for line in (out / "journal.log").read_text().splitlines()
                if line.startswith("computed ")]
    assert len(computed) == len(set(computed))                        # each computation once
    assert set(computed) >= set(after) - set(before)
    assert len(pd.read_csv(out / "results.csv")) == 20 * len(KINDS)


# ------------------------------------------------------------------ with the optimiser
@pytest.mark.slow
def test_optimal_sweep_deterministic_across_engines(tmp_path):
    pytest.importorskip("seekopt.design.ocp")
    cfg = config(designer="ocp", tpis=[200e3, 600e3], tracks=[10, 200])
    run_sweep(cfg, tmp_path / "a", engine="serial", progress=False, figures=False)
    run_sweep(cfg, tmp_path / "b", engine="process", workers=2, progress=False, figures=False)
    run_sweep(cfg, tmp_path / "c", engine="local", workers=2, progress=False, figures=False)
    a = numbers(tmp_path / "a")
    for other in ("b", "c"):
        pd.testing.assert_frame_equal(a, numbers(tmp_path / other), check_exact=True)
    assert (a[a["kind"] == "optimal"]["status"] == "ok").all()


def test_code_hash_covers_every_design_module():
    """A resumed sweep warns when its saved cells came from other code: the provenance hash covers every
    module of the design chain, the simulator and the plant -- also modules split out later (qp_rows,
    guard_bands ...), which a hand-kept list had missed."""
    import seekopt.design as design
    from seekopt.evaluate.sweep_config import code_files, code_hash
    covered = {str(f) for _, f in code_files()}
    for pkg in (design,):
        for f in Path(pkg.__file__).parent.glob("*.py"):
            assert str(f) in covered, f
    assert any(n == "seekopt.drive.simulator" for n, _ in code_files())
    assert len(code_hash()) == 12
