"""The synthetic drive."""
import numpy as np

from identification.logs import read_log, segment_seeks, write_log
from seekopt.app.cli import main
from seekopt.evaluate.synth import SynthConfig, synthesize


def test_deterministic_for_a_seed():
    a, _ = synthesize(SynthConfig(n_seeks=6, seed=5))
    b, _ = synthesize(SynthConfig(n_seeks=6, seed=5))
    c, _ = synthesize(SynthConfig(n_seeks=6, seed=6))
    assert np.array_equal(a.position_track, b.position_track)
    assert not np.array_equal(a.position_track[:200], c.position_track[:200]) or a.n != c.n


def test_log_has_seeks_and_undeclared_effects_in_truth(tmp_path):
    cfg = SynthConfig(n_seeks=8, seed=2, effects=[{"effect": "friction", "params": {"coulomb_a": 0.002}}])
    log, truth = synthesize(cfg)
    assert [e.name for e in truth.effects] == ["friction"]
    seeks = segment_seeks(log)
    assert len(seeks) == 8
    write_log(log, tmp_path / "s.npz")
    assert np.array_equal(read_log(tmp_path / "s.npz").current_a, log.current_a)


def test_cli_synth(tmp_path, capsys):
    out = tmp_path / "log.csv"
    assert main(["synth", "-o", str(out), "--seeks", "3", "--truth", str(tmp_path / "truth.json")]) == 0
    assert read_log(out).n > 100 and (tmp_path / "truth.json").exists()
    assert main(["synth", "-o", str(out), "--seeks", "3", "--effect", "nope:x=1"]) == 2
    assert "nope" in capsys.readouterr().err
