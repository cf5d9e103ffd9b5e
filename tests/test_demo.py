"""Tests for seekopt.app.demo: the bundled sample log, the quick pipeline end to end through the CLI
(self-contained report.html, per-stage progress, --quiet), a failing stage reported as one line
(exit 2), and the full demo (slow)."""
import json
import re
import time

import pandas as pd
import pytest

from identification.logs import read_log
from seekopt.app import demo
from seekopt.app.cli import main
from seekopt.evaluate.sweep import ALL_KINDS


def test_bundled_sample_log():
    p = demo.sample_log_path()
    assert p.exists() and p.stat().st_size < 3e6
    log = read_log(p)
    assert log.sample_rate_hz == 26400.0 and log.track_pitch_nm == pytest.approx(254.0)
    assert log.metadata["n_seeks"] == "120" and log.metadata["generator"] == "seekopt.synth"
    assert demo.sample_truth().hash() == log.metadata["truth_plant_hash"]


def test_demo_module_has_no_private_imports():
    src = (demo.__file__ and open(demo.__file__).read())
    assert "__import__" not in src
    assert not re.search(r"from \S+ import .*\b_[a-z]", src)
    assert "load_cells" not in src and "read_csv(s.table)" in src   # the bench is not read back from disk


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    pytest.importorskip("identification.estimate.identify", reason="identify not available")
    out = tmp_path_factory.mktemp("demo") / "out"
    import contextlib
    import io
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        status = main(["demo", "--quick", "-o", str(out)])
    return status, out, so.getvalue(), se.getvalue()


def test_demo_quick_writes_report_and_tables(quick_run):
    status, out, stdout, stderr = quick_run
    assert status == 0
    for i in range(1, 8):
        assert f"[{i}/7]" in stderr
    assert re.search(r"\[7/7\] write the report: ok in [\d.]+ s, CPU [\d.]+ s \(elapsed \d+ s\)", stderr)
    assert "seek-settle, truth [ms]" in stdout and "sine (best T)" in stdout and "report:" in stdout
    for n in ("seekopt_tables.h", "seekopt_tables.c", "seekopt_tables.csv", "seekopt_tables.json"):
        assert (out / "export" / n).exists()
    df = pd.read_csv(out / "sweep" / "results.csv")
    assert set(df["kind"]) == set(ALL_KINDS) and len(df) == len(ALL_KINDS) * 2 * 2
    assert json.loads((out / "plant.json").read_text())["k0"] > 0


def test_demo_report_is_self_contained(quick_run):
    _, out, _, _ = quick_run
    page = (out / "report.html").read_text()
    srcs = re.findall(r'<img src="([^"]*)"', page)
    assert len(srcs) >= 6 and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "overflow-x:auto" in page
    md = (out / "report.md").read_text()
    for what in ("fig5_tf.png", "plant_frf.png", "bench_k", "MATLAB's `compare`", "Accepted effects",
                 "Why the optimal current looks as it does"):
        assert what in md, what
    n_modes = int(re.search(r"(\d+) modes \(method", md).group(1))
    table = md.split("(method robust):")[1].split("\n\n")[1]
    assert len([ln for ln in table.splitlines() if ln.startswith("| ") and ln[2].isdigit()]) == n_modes
    assert "BIC drop nan" not in md


def test_demo_quiet_prints_no_progress(tmp_path, capsys, monkeypatch):
    """--quiet reaches the demo: no stage lines (the stages are replaced by a failing read)."""
    bad = tmp_path / "log.csv"
    bad.write_text("time_s,current_a\n0,0\n")
    assert main(["demo", str(bad), "--quick", "--quiet", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "[1/7]" not in err and err.count("\n") == 1


def test_failing_stage_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    def boom(log):
        raise RuntimeError("no modes found\nin the settle windows")
    monkeypatch.setattr(demo, "identify_plant", boom)
    assert main(["demo", "--quick", "-q", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "stage 2 (identify the plant) failed: RuntimeError: no modes found in the settle windows" in err
    assert "Traceback" in (tmp_path / "demo-error.log").read_text()


def test_bad_log_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "log.csv"
    bad.write_text("time_s,current_a\n0,0\n")
    assert main(["demo", str(bad), "--quick", "-q", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "stage 1 (read the seek log)" in err and "log.csv" in err


@pytest.mark.slow
def test_full_demo(tmp_path, capsys):
    t0 = time.perf_counter()
    res = demo.run_demo(demo.DemoConfig(outdir=str(tmp_path / "out")))
    wall = time.perf_counter() - t0
    print(f"full demo: {wall:.0f} s")
    assert res.report.exists() and "data:image/png;base64," in res.report.with_suffix(".html").read_text()
    assert res.sweep.summary.ok and len(res.export.tables.tables) == 9
    md = res.report.read_text()
    firsts = [ln.split(" | ")[1] for ln in md.splitlines() if ln.endswith("| accepted |")]
    assert sorted(firsts) == sorted(set(firsts)) and set(res.loop.result.accepted) <= set(firsts)
    for b in res.bench.results:
        opt = b.row("optimal")
        assert opt.settled and opt.settle_time_s <= min(r.settle_time_s for r in b.rows if r.kind == "tuned")
