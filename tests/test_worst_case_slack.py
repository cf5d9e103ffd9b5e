"""The servo engineer's trade-off between the set's worst case and the nominal plant
(:attr:`SeekProblem.worst_case_slack_s`, ``seekopt design --worst-case-slack``)."""
from __future__ import annotations

import numpy as np
import pytest

from seekopt.app.cli import main
from seekopt.design.designer import SeekDesigner
from seekopt.design.family import Drift
from seekopt.design.problem import ProblemError, SeekProblem
from seekopt.drive.controller import Controller
from test_family import FS, plant

#: the case measured: the NSS-like plant with a stated temperature x gain drift, K = 200 (slack 0: nominal
#: 35, set 37; one sample of slack: nominal 33, set 38)
DRIFT, K = "temp=±4%,zeta=±20%,gain=±5%", 200.0


@pytest.fixture(scope="module")
def designs():
    ctrl, p = Controller.nss(), plant()

    def design(**kw):
        return SeekDesigner(SeekProblem(p, ctrl, 0.3, robust=Drift.from_string(DRIFT), **kw)).design(K)
    return design(nominal_first=False), design(), design(worst_case_slack_s=0.9 / FS), design(worst_case_slack_s=1 / FS)


def test_zero_slack_is_the_set_minimum(designs):
    """Slack 0 (and any slack under one servo sample: rounded down) is the lexicographic design at the set's
    minimum: the set settles where the worst-case design does, and nothing of the slack is recorded."""
    worst, zero, under, _ = designs
    assert zero.set_settle_samples == zero.set_min_settle_samples == worst.settle_samples
    assert zero.settle_samples <= zero.set_settle_samples
    assert "worst_case_slack_s" not in zero.profile.meta
    assert np.array_equal(under.profile.current_a, zero.profile.current_a)
    assert np.array_equal(under.profile.reference_track, zero.profile.reference_track)
    assert under.settle_samples == zero.settle_samples
    assert under.set_settle_samples == zero.set_settle_samples


def test_slack_settles_the_nominal_plant_no_later_and_the_set_within_it(designs):
    """One sample of slack: the nominal plant settles no later than without (here earlier), the set's minimum
    is the same, and every plant of the set, played by the simulator, settles by the set's minimum + slack."""
    _, zero, _, one = designs
    assert one.set_min_settle_samples == zero.set_settle_samples
    assert one.settle_samples < zero.settle_samples
    assert one.set_settle_samples <= one.set_min_settle_samples + 1
    assert one.profile.seek_samples == one.set_settle_samples + round(3e-4 * FS)
    assert one.prediction.nominal.settle_time_s * FS <= one.settle_samples + 1 + 1e-9
    for lab, m in zip(one.prediction.labels, one.prediction.metrics):
        assert m.settle_time_s * FS <= one.set_settle_samples + 1 + 1e-9, lab
    meta = one.profile.meta
    assert meta["worst_case_slack_s"] == pytest.approx(1 / FS)
    assert meta["design_set_min_settle_samples"] == one.set_min_settle_samples
    assert meta["design_set_settle_samples"] == one.set_settle_samples
    assert meta["design_settle_samples"] == one.settle_samples
    assert "predicted_settle_nominal_ms" in meta and "predicted_settle_worst_ms" in meta


def test_slack_checks():
    ctrl, p = Controller.nss(), plant()
    assert SeekProblem(p, ctrl, 0.3, worst_case_slack_s=0.12e-3).worst_case_slack_samples() == 3  # 3.17 -> 3
    assert SeekProblem(p, ctrl, 0.3, worst_case_slack_s=2 / FS).worst_case_slack_samples() == 2
    for bad in (-1e-5, float("nan"), float("inf")):
        with pytest.raises(ProblemError, match="worst_case_slack_s"):
            SeekProblem(p, ctrl, 0.3, worst_case_slack_s=bad)
    with pytest.raises(ProblemError, match="nominal_first"):
        SeekProblem(p, ctrl, 0.3, worst_case_slack_s=1e-4, nominal_first=False)
    q = SeekProblem(p, ctrl, 0.3, worst_case_slack_s=4e-5)
    assert SeekProblem.from_json(q.to_json()) == q


@pytest.mark.parametrize("bad", ["5 parsecs", "-0.04ms", "ms", "nan"])
def test_cli_bad_slack_is_one_line_exit_2(tmp_path, capsys, bad):
    a = tmp_path / "p.json"
    plant().to_json(a)
    out = tmp_path / "k.csv"
    rc = main(["design", "--plant", str(a), "--tracks", "20", "--imax", "0.3", "-o", str(out),
               f"--worst-case-slack={bad}"])
    err = capsys.readouterr().err
    assert rc == 2 and "--worst-case-slack" in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


def test_sweep_and_export_carry_the_slack():
    """``seekopt sweep --worst-case-slack``: the sweep's configuration keeps it (its hash changes only when it
    is used) and its ``ocp`` designers' problems (the export's too) are built with it."""
    from seekopt.evaluate.sweep_cell import designer_problem
    from seekopt.evaluate.sweep_config import SweepConfig
    from seekopt.evaluate.sweep import SweepError
    ctrl, p = Controller.nss(), plant()
    tpi = 25.4e6 / p.track_pitch_nm
    base = SweepConfig(p, ctrl, [tpi], [10.0], 0.3)
    cfg = SweepConfig(p, ctrl, [tpi], [10.0], 0.3, worst_case_slack_s=4e-5)
    assert "worst_case_slack_s" not in base.identity() and cfg.hash() != base.hash()
    assert SweepConfig.from_dict(cfg.to_dict()).worst_case_slack_s == 4e-5
    assert designer_problem("ocp-robust", p, ctrl, 0.3, 0.1, worst_case_slack_s=4e-5).worst_case_slack_samples() == 1
    with pytest.raises(SweepError, match="slack"):
        SweepConfig(p, ctrl, [tpi], [10.0], 0.3, worst_case_slack_s=-1.0)
