"""A new user's commands, replayed through the CLI entry (issue 13, items 2-5 and 8).

Each test runs what the user typed -- ``seekopt.app.cli.main([...])`` in process, or the
``seekopt`` entry point in a subprocess where signals or processes matter -- and checks the
exit status and the one line printed: bad input is ONE line on stderr naming the user's path,
exit status 2, before anything is computed or written; an internal error keeps its traceback
(exit 1); a sweep with failed cells exits non-zero with a one-line summary; workers die with the
sweep; two sweeps into one folder share the cells.
"""
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from identification.logs import SeekLog, read_log, write_log
from identification.model.plant import ModalPlant, PlantError
from seekopt.app import cli
from seekopt.app.cli import main
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from seekopt.evaluate.claims import Claims, pid_alive, process_start_time
from seekopt.evaluate.sweep import BaselineDesigner, SweepConfig, load_cells, run_sweep

ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(TESTS), os.environ.get("PYTHONPATH", "")]),
           OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


def run(argv, capsys):
    """``main(argv)`` -> (exit status, stdout, stderr lines)."""
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, [line for line in err.splitlines() if line.strip()]


def one_error(err_lines, command):
    """The stderr of a refused command: exactly one line, ``seekopt <command>: error: ...``."""
    assert len(err_lines) == 1, err_lines
    assert err_lines[0].startswith(f"seekopt {command}: error: "), err_lines
    assert ".tmp" not in err_lines[0]
    return err_lines[0]


def seekopt(*args, **kw):
    """Popen of the ``seekopt`` entry point (as a user runs it)."""
    return subprocess.Popen([sys.executable, "-m", "seekopt.app.cli", *map(str, args)], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A small synthetic log (10 seeks), its truth plant, bad controllers and plants."""
    d = tmp_path_factory.mktemp("user")
    assert main(["--quiet", "synth", "--seeks", "10", "-o", str(d / "log.csv"), "--truth", str(d / "truth.json")]) == 0
    c = Controller.nss().to_dict()
    for name, factor in (("negated", -1.0), ("x50", 50.0)):
        dd = json.loads(json.dumps(c))
        dd["sections"][0]["num"] = [factor * v for v in dd["sections"][0]["num"]]
        (d / f"ctrl_{name}.json").write_text(json.dumps(dd))
    dd = json.loads(json.dumps(c))
    dd["sample_rate_hz"] = 50000.0
    (d / "ctrl_50k.json").write_text(json.dumps(dd))
    return d


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    cfg = SweepConfig(default_truth_plant(), Controller.nss(), [100e3], [1, 20], 0.3, designer="baseline")
    run_sweep(cfg, out, engine="serial", progress=False, figures=False)
    return out


class SlowDesigner:
    """The baseline designer, slowed down (``SEEKOPT_TEST_DESIGN_S`` seconds per design) so a sweep
    is still running when it is killed or joined."""

    def __init__(self, plant, controller, imax, settle=0.1):
        self.inner = BaselineDesigner(plant, controller, imax, settle)

    def design(self, tracks):
        time.sleep(float(os.environ.get("SEEKOPT_TEST_DESIGN_S", "0.5")))
        return self.inner.design(tracks)


# ------------------------------------------------------------------ item 2: one line, exit 2, not a traceback
def test_synth_imax_zero_is_one_line(work, capsys):
    out = work / "imax0.csv"
    code, _, err = run(["synth", "--imax", "0", "-o", str(out)], capsys)
    assert code == 2 and not out.exists()
    assert one_error(err, "synth") == "seekopt synth: error: --imax [A] must be a positive number (got 0.0)"


def test_export_onto_an_existing_file_is_one_line_and_keeps_the_file(results, tmp_path, capsys):
    existing = tmp_path / "existing_file"
    existing.write_text("keep me\n")
    code, _, err = run(["export", str(results), "-o", str(existing)], capsys)
    assert code == 2 and existing.read_text() == "keep me\n"
    assert one_error(err, "export") == f"seekopt export: error: -o {existing}: exists and is not a folder"


@pytest.mark.parametrize("ctrl, expect", [
    ("negated", "closed loop with the default truth plant is unstable (pole |z| = 1.199 at 0 Hz)"),
    ("x50", "closed loop with the default truth plant is unstable (pole |z| = 2.405 at 3616 Hz)"),
    ("50k", "controller runs at 50000 Hz but the default truth plant was identified at 26400 Hz")])
def test_synth_with_a_bad_controller_is_refused_before_simulating(work, capsys, ctrl, expect):
    out = work / f"bad_{ctrl}.csv"
    t0 = time.perf_counter()
    code, _, err = run(["synth", "--controller", str(work / f"ctrl_{ctrl}.json"), "-o", str(out)], capsys)
    assert code == 2 and not out.exists()
    assert expect in one_error(err, "synth") and f"ctrl_{ctrl}.json: " in err[0]
    assert time.perf_counter() - t0 < 5        # 120 seeks would take longer: refused before simulating


@pytest.mark.parametrize("command", ["sweep", "bench", "design"])
def test_unstable_or_wrong_rate_controller_in_other_commands(work, tmp_path, capsys, command):
    base = {"sweep": ["sweep", "--tpi", "100k", "--tracks", "1,10", "-o", str(tmp_path / "sw")],
            "bench": ["bench", "--tracks", "200"],
            "design": ["design", "--tracks", "200", "-o", str(tmp_path / "p.csv")]}[command]
    for ctrl, expect in (("negated", "is unstable"), ("50k", "controller runs at 50000 Hz")):
        code, _, err = run(base + ["--plant", str(work / "truth.json"), "--imax", "0.3",
                                   "--controller", str(work / f"ctrl_{ctrl}.json")], capsys)
        assert code == 2 and expect in one_error(err, command)
        assert f"plant {work / 'truth.json'}" in err[0]
    assert not (tmp_path / "sw").exists() and not (tmp_path / "p.csv").exists()


def test_an_internal_error_keeps_its_traceback(work, monkeypatch):
    """A bug is not dressed up as bad input: the exception propagates (traceback, exit 1)."""
    def boom(args):
        raise RuntimeError("a bug")
    monkeypatch.setattr(cli, "cmd_synth", boom)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["synth", "-o", str(work / "x.csv")])
    p = subprocess.run([sys.executable, "-c", "import sys, seekopt.app.cli as c\n"
                        "def boom(a): raise RuntimeError('a bug')\n"
                        "c.cmd_export = boom\nsys.exit(c.main(['export', 'x', '-o', 'y']))"],
                       env=ENV, capture_output=True, text=True, timeout=60)
    assert p.returncode == 1 and "Traceback" in p.stderr and "RuntimeError: a bug" in p.stderr


# ------------------------------------------------------------------ item 3: checked first, the user's path named
def test_output_in_a_missing_folder_is_refused_before_identifying(tmp_path, capsys):
    from seekopt.app.demo import sample_log_path
    out = tmp_path / "nowhere" / "o.json"
    t0 = time.perf_counter()
    code, _, err = run(["identify", str(sample_log_path()), "-o", str(out)], capsys)
    assert code == 2 and time.perf_counter() - t0 < 5     # identifying 120 seeks takes 15-70 s
    assert one_error(err, "identify") == f"seekopt identify: error: -o {out}: folder {out.parent} does not exist"


@pytest.mark.parametrize("argv, expect", [
    (["synth", "-o", "{d}/x.txt"], "-o {d}/x.txt: unknown extension '.txt' (expected .csv, .npz, .mat)"),
    (["synth", "-o", "{d}"], "-o {d}: is a folder, expected a file name"),
    (["synth", "--seeks", "0", "-o", "{d}/x.csv"], "--seeks must be at least 1 (got 0)"),
    (["synth", "--truth", "{d}/no/t.json", "-o", "{d}/x.csv"], "--truth {d}/no/t.json: folder {d}/no does not exist"),
    (["identify", "{d}/log.csv", "--figures", "{d}/log.csv/figs"], "--figures {d}/log.csv/figs: {d}/log.csv is not a folder"),
    (["design", "--plant", "{d}/truth.json", "--tracks", "200", "--imax", "0.3", "-o", "{d}/no/p.csv"],
     "-o {d}/no/p.csv: folder {d}/no does not exist"),
    (["design", "--plant", "{d}/truth.json", "--tracks", "0", "--imax", "0.3", "-o", "{d}/p.csv"],
     "--tracks must be a non-zero number of tracks (got 0.0)"),
    (["bench", "--plant", "{d}/truth.json", "--imax", "-1"], "--imax [A] must be a positive number (got -1.0)"),
    (["sweep", "--plant", "{d}/truth.json", "--tpi", "100k", "--tracks", "1", "--imax", "0.3", "-o", "{d}/log.csv"],
     "-o {d}/log.csv: exists and is not a folder"),
    (["sweep", "--plant", "{d}/truth.json", "--tpi", "100k", "--tracks", "1", "--imax", "0.3", "--workers", "0",
      "-o", "{d}/sw"], "--workers must be at least 1 (got 0)"),
])
def test_arguments_and_paths_checked_before_computing(work, capsys, argv, expect):
    code, _, err = run([a.format(d=work) for a in argv], capsys)
    assert code == 2
    assert one_error(err, argv[0]).endswith(expect.format(d=work)), err


@pytest.mark.skipif(IS_ROOT, reason="root writes into read-only folders")
def test_read_only_output_folder(work, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, _, err = run(["synth", "-o", str(ro / "x.csv")], capsys)
        assert code == 2 and one_error(err, "synth").endswith(f"-o {ro / 'x.csv'}: folder {ro} is not writable")
    finally:
        ro.chmod(0o755)


def test_atomic_writer_names_the_users_file_not_the_temporary_one(tmp_path):
    from identification.fileio import atomic_write_text
    target = tmp_path / "missing" / "o.csv"
    with pytest.raises(FileNotFoundError) as e:
        atomic_write_text(target, "x")
    assert e.value.filename == str(target) and ".tmp" not in str(e.value)
    (tmp_path / "adir").mkdir()
    with pytest.raises(OSError) as e:
        atomic_write_text(tmp_path / "adir", "x")
    assert e.value.filename == str(tmp_path / "adir")
    assert [p.name for p in tmp_path.iterdir()] == ["adir"] and not list((tmp_path / "adir").iterdir())


# ------------------------------------------------------------------ item 4: units and consistency
@pytest.fixture(scope="module")
def log_in_ma(work):
    log = read_log(work / "log.csv")
    extra = {k: (v * 1e3 if k.startswith("current_sub") else v) for k, v in log.extra.items()}
    ma = SeekLog.from_arrays(log.time_s, log.current_a * 1e3, log.position_track, log.target_track,
                             log.sample_rate_hz, track_pitch_nm=log.track_pitch_nm, extra=extra)
    write_log(ma, work / "log_mA.csv")
    return work / "log_mA.csv"


def test_log_in_ma_warns_and_current_unit_ma_fixes_it(log_in_ma, capsys):
    code, out, err = run(["--quiet", "identify", str(log_in_ma)], capsys)
    assert code == 0 and len(err) == 2, err
    assert err[0].startswith(f"seekopt identify: warning: {log_in_ma}: current_a peaks at 3")
    assert err[0].endswith("implausible in A for a disk-drive actuator (below 10 A): is the log's current in mA? "
                           "(then use --current-unit mA)")
    assert "k0 = 3.937e+06 track/(A s^2) is outside the range of disk drives (1e+08 to 1e+12): the current " \
           "looks 1000 times too large: is it logged in mA? (then use --current-unit mA)" in err[1]
    code, out, err = run(["identify", str(log_in_ma), "--current-unit", "mA", "--quiet"], capsys)
    assert code == 0 and err == []
    k0 = float(out.splitlines()[1].split("=")[1].split()[0])
    assert k0 == pytest.approx(3.9366e9, rel=1e-3)


def test_current_a_disagreeing_with_substeps_is_an_error(work, capsys):
    lines = (work / "log.csv").read_text().splitlines()
    h = next(i for i, line in enumerate(lines) if line.startswith("time_s"))
    col = lines[h].split(",").index("current_a")
    row = lines[h + 1208].split(",")
    row[col] = repr(float(row[col]) + 0.05)
    lines[h + 1208] = ",".join(row)
    bad = work / "log_badcur.csv"
    bad.write_text("\n".join(lines) + "\n")
    code, _, err = run(["identify", str(bad)], capsys)
    assert code == 2
    msg = one_error(err, "identify")
    assert msg.startswith(f"seekopt identify: error: {bad}: row 1208: current_a = ")
    assert "disagrees with the mean" in msg and "of current_sub1_a .. current_sub2_a (by 0.05 A" in msg


@pytest.mark.parametrize("change, expect", [
    ({"sample_rate_hz": 0}, "sample_rate_hz must be a positive number of Hz or null (got 0)"),
    ({"k0": "3.9e9"}, "k0 must be a number, got the string '3.9e9'"),
    ({"track_pitch_nm": -254}, "track_pitch_nm must be a positive number of nm or null (got -254)"),
    ({"modes": [{"freq_hz": "420", "zeta": 0.06, "gain": 0.0015}]}, "mode 1 freq_hz must be a number, got the string '420'"),
    ({"modes": [{"freq_hz": 15000.0, "zeta": 0.01, "gain": 0.1}], "meta": {"method": "robust"}},
     "mode 1 at 15000 Hz is at or above the Nyquist frequency 13200 Hz of sample_rate_hz 26400"),
])
def test_implausible_plant_json_is_one_line(work, capsys, change, expect):
    d = json.loads((work / "truth.json").read_text())
    d.update(change)
    path = work / "bad_plant.json"
    path.write_text(json.dumps(d))
    with pytest.raises(PlantError, match="^" + re.escape(str(path)) + ": "):
        ModalPlant.load(path)
    code, _, err = run(["design", "--plant", str(path), "--tracks", "200", "--imax", "0.3", "-o", str(work / "p.csv")],
                       capsys)
    assert code == 2 and expect in one_error(err, "design")


def test_truth_plants_may_keep_modes_above_nyquist():
    """A physical (truth) model's mode above Nyquist is real (the NSS benchmark has one at 16.4 kHz);
    only a plant identified from a log at that rate cannot have one."""
    truth = default_truth_plant()
    assert max(m.freq_hz for m in truth.modes) > truth.sample_rate_hz / 2
    assert ModalPlant.from_dict(truth.to_dict()).hash() == truth.hash()


# ------------------------------------------------------------------ item 5: sweep status, workers, claims
def test_sweep_with_failed_cells_exits_nonzero_with_one_line(tmp_path, capsys):
    plant = tmp_path / "p.json"
    default_truth_plant().to_json(plant)
    argv = ["--quiet", "sweep", "--plant", str(plant), "--tpi", "100k", "--tracks", "1,10,100", "--imax", "0.3",
            "--workers", "1", "--no-figures", "-o", str(tmp_path / "sw")]
    code, out, err = run(argv + ["--designer", "test_sweep:FailingDesigner"], capsys)
    assert code == 1 and len(err) == 1
    assert err[0] == (f"seekopt sweep: 1 of 3 cells failed (1 error; see the 'error' column of {tmp_path / 'sw'}"
                      "/results.csv); first: 10 tracks at 100000 TPI (optimal): RuntimeError: solver exploded second line")
    code, out, err = run(argv + ["--designer", "test_sweep:FailingDesigner"], capsys)   # resumed: still failed
    assert code == 1 and len(err) == 1 and "1 of 3 cells failed" in err[0]
    argv[-1] = str(tmp_path / "ok")
    code, out, err = run(argv + ["--designer", "baseline"], capsys)
    assert code == 0 and err == [] and out.startswith("sweep: 3 cells (0 saved before, 3 computed")


def test_sweep_api_refuses_an_unstable_controller_before_computing(tmp_path):
    from seekopt.evaluate.sweep import SweepError
    c = Controller.nss().to_dict()
    c["sections"][0]["num"] = [-v for v in c["sections"][0]["num"]]
    cfg = SweepConfig(default_truth_plant(), Controller.from_json(c), [100e3, 200e3], [1, 10], 0.3, designer="baseline")
    with pytest.raises(SweepError, match=r"closed loop with the plant is unstable .* \(at 100000 TPI\)$"):
        run_sweep(cfg, tmp_path / "o", engine="serial", progress=False, figures=False)
    assert not (tmp_path / "o").exists()


def descendants(pid):
    """pids of all live descendants of ``pid`` (from /proc)."""
    children = {}
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                ppid = int(p.joinpath("stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(p.name))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return [p for p in out if pid_alive(p)]


def start_sweep(tmp_path, out, tracks="1,2,3,5,10,20,30,50", workers=2, design_s="1.0"):
    plant = tmp_path / "p.json"
    if not plant.exists():
        default_truth_plant().to_json(plant)
    env = dict(ENV, SEEKOPT_TEST_DESIGN_S=design_s)
    return subprocess.Popen([sys.executable, "-m", "seekopt.app.cli", "sweep", "--plant", str(plant), "--tpi", "100k",
                             "--tracks", tracks, "--imax", "0.3", "--designer", "test_cli_user:SlowDesigner",
                             "--workers", str(workers), "--no-figures", "-o", str(out)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_interruptible)


def _interruptible():
    """In the child: SIGINT back to its default, as in a terminal.  A test run started in the
    background (``cmd &`` without job control) ignores SIGINT, the child inherits that and Python
    then installs no KeyboardInterrupt handler: Ctrl-C would not reach the sweep at all."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_sweep_workers_die_with_the_sweep(tmp_path, sig):
    """Kill only the sweep process (not its group): its pool workers and the resource tracker follow."""
    out = tmp_path / "res"
    proc = start_sweep(tmp_path, out, design_s="5.0")     # 8 cells x 5 s on 2 workers: still running under any load
    try:
        deadline = time.time() + 90
        while time.time() < deadline and len(descendants(proc.pid)) < 3:   # 2 workers + resource tracker
            assert proc.poll() is None, proc.stderr.read()[-2000:]
            time.sleep(0.1)
        time.sleep(1.5)                                   # the workers are inside their first cells
        kids = descendants(proc.pid)
        assert len(kids) >= 2, kids
        os.kill(proc.pid, sig)
        code = proc.wait(timeout=60)
        deadline = time.time() + 20
        while time.time() < deadline and any(pid_alive(k) for k in kids):
            time.sleep(0.1)
        assert not [k for k in kids if pid_alive(k)], "workers survived their sweep"
    finally:
        for k in descendants(proc.pid):
            os.kill(k, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
    if sig == signal.SIGINT:
        assert code == 130 and "seekopt sweep: interrupted" in proc.stderr.read()
        assert not list((out / "claims").glob("*.claim"))         # claims released
    # a rerun takes over what the killed sweep had claimed and finishes the grid
    cfg = SweepConfig(ModalPlant.load(tmp_path / "p.json"), Controller.nss(), [100e3], [1, 2, 3, 5, 10, 20, 30, 50],
                      0.3, designer="test_cli_user:SlowDesigner")
    os.environ["SEEKOPT_TEST_DESIGN_S"] = "0"
    try:
        s = run_sweep(cfg, out, engine="serial", progress=False, figures=False)
    finally:
        del os.environ["SEEKOPT_TEST_DESIGN_S"]
    assert s.ok and s.skipped + s.computed == 8 and len(load_cells(out)) == 8


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")
def test_two_sweeps_into_one_folder_share_the_cells(tmp_path):
    out = tmp_path / "shared"
    tracks = ",".join(str(k) for k in range(1, 13))
    a = start_sweep(tmp_path, out, tracks, workers=1, design_s="0.5")
    time.sleep(0.2)
    b = start_sweep(tmp_path, out, tracks, workers=1, design_s="0.5")
    outs = [p.communicate(timeout=240) for p in (a, b)]
    assert a.returncode == 0 and b.returncode == 0, [o[1][-1500:] for o in outs]
    computed = [line.split()[1] for line in (out / "journal.log").read_text().splitlines()
                if line.startswith("computed ")]
    assert len(computed) == 12 and len(set(computed)) == 12          # every cell computed once, by one of them
    by_a = int(outs[0][0].split(" saved before, ")[1].split()[0])
    by_b = int(outs[1][0].split(" saved before, ")[1].split()[0])
    assert by_a + by_b == 12 and by_a >= 2 and by_b >= 2, outs        # shared, not doubled
    assert "by another sweep" in outs[0][0] and "by another sweep" in outs[1][0]
    assert len(load_cells(out)) == 12 and not list((out / "claims").glob("*.claim"))


def test_stale_claim_of_a_dead_process_is_taken_over(tmp_path):
    claims = Claims(tmp_path)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    claims.path("k").write_text(f"{dead.pid} {socket.gethostname()} 1\n")
    assert claims.claim("k") is None and claims.path("k").read_text().strip() == claims.identity
    live = f"{os.getppid()} {socket.gethostname()} {process_start_time(os.getppid())}"
    claims.path("live").write_text(live + "\n")
    assert claims.claim("live") == live                                # a live claimant keeps its cell
    reused = f"{os.getppid()} {socket.gethostname()} 12345"           # that pid, but another process
    claims.path("reused").write_text(reused + "\n")
    assert claims.claim("reused") is None
    claims.release("k")
    assert not claims.path("k").exists()


def worker_blas(_):
    import numpy  # noqa: F401 - load BLAS
    from threadpoolctl import threadpool_info
    return os.environ.get("OPENBLAS_NUM_THREADS"), sorted({i["num_threads"] for i in threadpool_info()})


def test_pool_workers_use_one_blas_thread(monkeypatch):
    from seekopt.evaluate.engines import make_pool
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")     # what the worker would inherit
    pool = make_pool(1)
    try:
        env, threads = pool.submit(worker_blas, 0).result(timeout=120)
    finally:
        pool.shutdown()
    assert env == "1" and threads == [1]


# ------------------------------------------------------------------ progress, --quiet
def test_progress_stage_log_and_quiet(capsys):
    args = cli.build_parser().parse_args(["export", "r", "-o", "o"])
    with cli.progress(args, "doing a long thing", after_s=0.05):
        time.sleep(0.3)
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("seekopt export: doing a long thing ... (")
    assert err[-1].startswith("seekopt export: doing a long thing: done in 0.")
    with cli.progress(args, "a quick thing"):
        pass
    assert capsys.readouterr().err == ""                  # under 2 s: nothing
    for argv in (["--quiet", "export", "r", "-o", "o"], ["export", "r", "-o", "o", "--quiet"]):
        args = cli.build_parser().parse_args(argv)
        with cli.progress(args, "doing a long thing", after_s=0.0):
            time.sleep(0.1)
        assert capsys.readouterr().err == ""


def test_identify_shows_its_stage_unless_quiet(work, capsys, monkeypatch):
    monkeypatch.setattr(cli, "PROGRESS_AFTER_S", 0.0)
    code, _, err = run(["identify", str(work / "log.csv")], capsys)
    assert code == 0 and err[0] == "seekopt identify: identifying the plant from 10 seeks (robust) ... (0 s)"
    assert err[-1].startswith("seekopt identify: identifying the plant from 10 seeks (robust): done in ")
    code, _, err = run(["identify", str(work / "log.csv"), "--quiet"], capsys)
    assert code == 0 and err == []


# ------------------------------------------------------------------ item 8: help, defaults, v7.3 .mat
def subparsers():
    p = cli.build_parser()
    return p, next(a for a in p._actions if a.__class__.__name__ == "_SubParsersAction").choices


def test_every_option_has_help_with_units():
    import argparse
    p, subs = subparsers()
    for name, sp in subs.items():
        for a in sp._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            assert a.help and a.help.strip(), f"seekopt {name} {a.option_strings or a.dest}: no help"
    helps = {(n, o): a.help for n, sp in subs.items() for a in sp._actions for o in a.option_strings}
    for cmd in ("design", "bench", "sweep"):
        assert "[track]" in helps[(cmd, "--tracks")] and "[A]" in helps[(cmd, "--imax")]
        assert "[track]" in helps[(cmd, "--settle")]
    assert "[A]" in helps[("synth", "--imax")] and "seeks" in helps[("synth", "--seeks")]
    assert "seed" in helps[("synth", "--seed")] and "[track/inch]" in helps[("sweep", "--tpi")]
    assert "processes" in helps[("sweep", "--workers")] and "BLAS" in helps[("sweep", "--workers")]
    assert all(f in helps[("export", "--format")] for f in ("c:", "csv:", "json:", "Q15"))
    assert "mA" in helps[("identify", "--current-unit")]


def test_top_level_help_plain_text_names_the_default_controller(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "``" not in text and ":class:" not in text and ":func:" not in text
    assert "default controller" in text and "NSS benchmark's PID + 4 notches at 26400 Hz" in text
    _, subs = subparsers()
    assert "IEEJ NSS benchmark's PID + notch" in " ".join(subs["design"].format_help().split())


def test_sweep_config_default_designer_is_the_clis():
    p, subs = subparsers()
    cli_default = next(a.default for a in subs["sweep"]._actions if a.dest == "designer")
    cfg = SweepConfig(default_truth_plant(), Controller.nss(), [100e3], [1], 0.3)
    assert cfg.designer == cli_default == "ocp-robust"


def write_mat73(path, log, struct_metadata=False):
    """A MATLAB v7.3 file as MATLAB writes it: HDF5 behind a 512-byte MAT header, columns as (1, n)
    datasets with MATLAB_class attributes, metadata as a uint16 char array (or a struct group)."""
    h5py = pytest.importorskip("h5py")
    from identification.logs.formats import _columns, _header
    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in _columns(log).items():
            d = f.create_dataset(k, data=np.asarray(v, float).reshape(1, -1))
            d.attrs["MATLAB_class"] = np.bytes_("double")
        if struct_metadata:
            g = f.create_group("metadata")
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            d = g.create_dataset("sample_rate_hz", data=np.array([[log.sample_rate_hz]]))
            d.attrs["MATLAB_class"] = np.bytes_("double")
        else:
            meta = json.dumps(_header(log))
            d = f.create_dataset("metadata", data=np.array([ord(c) for c in meta], np.uint16).reshape(-1, 1))
            d.attrs["MATLAB_class"] = np.bytes_("char")
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(head.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02IM")


def test_matlab_v73_log_read_with_h5py(work, tmp_path, capsys):
    log = read_log(work / "log.csv")
    for struct in (False, True):
        path = tmp_path / f"log73_{struct}.mat"
        write_mat73(path, log, struct_metadata=struct)
        back = read_log(path)
        for c in ("time_s", "current_a", "position_track", "target_track"):
            np.testing.assert_array_equal(getattr(back, c), getattr(log, c))
        np.testing.assert_array_equal(back.input_current(), log.input_current())
        assert back.sample_rate_hz == log.sample_rate_hz
    code, out, err = run(["identify", str(path), "--quiet"], capsys)
    assert code == 0 and err == [] and out.startswith(f"{path}: 2978 samples at 26400 Hz, 10 seeks")


def test_matlab_v73_without_h5py_says_how_to_save_v7(work, tmp_path, capsys, monkeypatch):
    path = tmp_path / "log73.mat"
    write_mat73(path, read_log(work / "log.csv"))
    monkeypatch.setitem(sys.modules, "h5py", None)                  # as if not installed
    code, _, err = run(["identify", str(path)], capsys)
    assert code == 2
    assert one_error(err, "identify") == (
        f"seekopt identify: error: {path}: MATLAB v7.3 (HDF5) .mat file: reading it needs h5py "
        "(pip install 'seekopt[hdf5]'), or save the log as v7 in MATLAB: save('log.mat', ..., '-v7')")
