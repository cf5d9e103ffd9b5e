"""Tests for seekopt.app.demo: the bundled sample log, the quick pipeline end to end through the CLI,
and a failing stage reported as one line (exit 2)."""
import json

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
    assert demo._sample_truth().hash() == log.metadata["truth_plant_hash"]


def test_demo_quick_writes_report_with_figures(tmp_path, capsys):
    pytest.importorskip("identification.estimate.identify", reason="identify not available")
    out = tmp_path / "out"
    assert main(["demo", "--quick", "-o", str(out)]) == 0
    stdout = capsys.readouterr().out
    for i in range(1, 8):
        assert f"[{i}/7]" in stdout
    assert "seek-settle, truth [ms]" in stdout and "sine (best T)" in stdout and "report:" in stdout
    md = (out / "report.md").read_text()
    assert (out / "report.html").exists()
    figs = [line.split("](")[1].rstrip(")") for line in md.splitlines() if line.startswith("![")]
    assert len(figs) >= 5
    for f in figs:
        assert (out / f).stat().st_size > 5000, f
    for n in ("seekopt_tables.h", "seekopt_tables.c", "seekopt_tables.csv", "seekopt_tables.json"):
        assert (out / "export" / n).exists()
    df = pd.read_csv(out / "sweep" / "results.csv")
    assert set(df["kind"]) == set(ALL_KINDS) and len(df) == len(ALL_KINDS) * 2 * 2
    assert json.loads((out / "plant.json").read_text())["k0"] > 0


def test_failing_stage_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    def boom(log):
        raise RuntimeError("no modes found\nin the settle windows")
    monkeypatch.setattr(demo, "identify_plant", boom)
    assert main(["demo", "--quick", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "stage 2 (identify the plant) failed: RuntimeError: no modes found in the settle windows" in err
    assert "Traceback" in (tmp_path / "demo-error.log").read_text()


def test_bad_log_is_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "log.csv"
    bad.write_text("time_s,current_a\n0,0\n")
    assert main(["demo", str(bad), "--quick", "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "stage 1 (read the seek log)" in err and "log.csv" in err
