"""Bench (sine / windowed sine / optimal) and the ``design`` / ``bench`` commands."""
import numpy as np
import pytest

from identification.model.plant import ModalPlant, Mode
from seekopt.evaluate.bench import format_table, mode_response, perturbed_plant, run_bench, tuned_baseline
from seekopt.design.metrics import SeekMetrics, evaluate_profile
from seekopt.app.cli import main
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant
from seekopt.design.profiles import Profile, rigid_endpoint_matrix

FS = 26400.0


@pytest.fixture(scope="module")
def plants(tmp_path_factory):
    d = tmp_path_factory.mktemp("plants")
    truth = default_truth_plant()
    design = perturbed_plant(truth, FS)
    truth.to_json(d / "truth.json")
    design.to_json(d / "design.json")
    return truth, design, d


def test_perturbed_plant(plants):
    truth, design, _ = plants
    assert max(m.freq_hz for m in design.modes) < 0.45 * FS
    assert len(design.modes) == sum(m.freq_hz < 0.45 * FS for m in truth.modes)
    r = [d.freq_hz / t.freq_hz for d, t in zip(design.modes, truth.modes)]
    assert np.allclose(np.abs(np.array(r) - 1), 0.02)
    assert design.delay_s == pytest.approx(truth.delay_s + 3e-6)


def test_mode_response_matches_closed_form():
    """Undamped mode, one held current sample from rest: x(t) = k0 g u (1 - cos w t)/w^2 during the hold."""
    k0, f = 4e9, 1738.0
    mode = Mode(f, 0.0, 0.02)
    p = ModalPlant(k0=k0)
    u = np.r_[0.1, np.zeros(30)]
    x = mode_response(p, mode, u, FS)
    w = 2 * np.pi * f
    t1 = 1 / FS
    amp = k0 * 0.02 * 0.1 / w ** 2
    # after the pulse: x(t) = amp [cos(w (t - t1)) - cos(w t)]
    k = np.arange(2, 31)
    assert np.allclose(x[k], amp * (np.cos(w * (k / FS - t1)) - np.cos(w * k / FS)), rtol=1e-9, atol=1e-12)


def test_run_bench_table_and_figure(plants, tmp_path):
    truth, design, _ = plants
    res = run_bench(design, Controller.nss(), 10.0, 0.3, truth=truth, robust=None, figures=tmp_path)
    labels = [r.label for r in res.rows]
    assert labels == ["sine", "windowed_sine", "sine tuned", "windowed_sine tuned", "optimal"]
    best = min(res.row("sine").settle_time_s, res.row("windowed_sine").settle_time_s)
    opt = res.row("optimal")
    assert opt.ratio_best_baseline == pytest.approx(opt.settle_time_s / best)
    tuned = min(res.row("sine tuned").settle_time_s, res.row("windowed_sine tuned").settle_time_s)
    assert tuned <= best and opt.ratio_tuned_baseline == pytest.approx(opt.settle_time_s / tuned)
    assert isinstance(opt.metrics, SeekMetrics) and opt.settle_time_s == opt.metrics.settle_time_s
    with pytest.raises(AttributeError):
        opt.no_such_field
    text = format_table(res)
    assert "windowed_sine" in text and "T_bb" in text and "/tuned" in text
    assert res.figures and res.figures[0].exists()


def test_tuned_baseline_is_best_length(plants):
    """The tuned baseline settles no later than the shortest one and than any other tried length."""
    truth, design, _ = plants
    ctrl = Controller.nss()
    prof, m = tuned_baseline(design, ctrl, "sine", 20.0, 0.3, factors=(1.0, 1.5, 2.0))
    n0 = prof.meta["tuned_from_samples"]
    assert prof.seek_samples in {n0, round(1.5 * n0), 2 * n0}
    for f in (1.0, 1.5, 2.0):
        p2, m2 = tuned_baseline(design, ctrl, "sine", 20.0, 0.3, factors=(f,))
        assert m.settle_time_s <= m2.settle_time_s
    assert m.settle_time_s == evaluate_profile(design, ctrl, prof).settle_time_s


def test_cli_design_writes_profile(plants, tmp_path, capsys):
    truth, design, d = plants
    out = tmp_path / "p.csv"
    assert main(["design", "--plant", str(d / "design.json"), "--tracks", "50", "--imax", "0.3",
                 "-o", str(out)]) == 0
    prof = Profile.from_csv(out)
    head = out.read_text()
    for key in ("sample_rate_hz", "tracks", "imax_a", "settle_track", "plant_hash", "controller_hash",
                "tool_version", "seek_samples"):
        assert f"# {key}:" in head
    assert prof.meta["plant_hash"] == design.hash()
    pos, vel = rigid_endpoint_matrix(prof.n, design.k0, 1 / FS) @ prof.current_a
    assert abs(pos - 50) <= 1e-6 and abs(vel) <= 1e-6 and np.max(np.abs(prof.current_a)) <= 0.3
    assert "seek-settle" in capsys.readouterr().out


def test_cli_design_errors(plants, tmp_path, capsys):
    truth, design, d = plants
    out = tmp_path / "p.csv"
    assert main(["design", "--plant", str(d / "design.json"), "--tracks", "50", "--imax", "0.3",
                 "--robust", "speed=3", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--robust" in err
    assert main(["design", "--plant", str(d / "nope.json"), "--tracks", "50", "--imax", "0.3", "-o", str(out)]) == 2
    assert not out.exists()


def test_cli_bench_prints_table(plants, tmp_path, capsys):
    truth, design, d = plants
    assert main(["bench", "--plant", str(d / "design.json"), "--truth", str(d / "truth.json"),
                 "--tracks", "5", "--imax", "0.3", "--figures", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "optimal robust" in out and "sine" in out and "bench_k5.png" in out


# ----------------------------------------------------------------------------- one calibration path
def _other_gain(design):
    """A truth of another gain (another member of the family): k0 10 % above the design plant's."""
    return default_truth_plant().copy(k0=design.k0 * 1.1)


def test_bench_figure_plays_what_the_table_played(plants, tmp_path, monkeypatch):
    """The figure's seeks are the table's: on a truth of another gain both go through the drive's gain
    calibration (seekopt.design.predict.played_plant), so every trace, cut to the table's horizon, gives the
    row's metrics exactly (the simulator is causal)."""
    import seekopt.evaluate.bench as bench
    from seekopt.design.metrics import DEFAULT_TAIL_S, seek_metrics
    _, design, _ = plants
    truth, ctrl = _other_gain(design), Controller.nss()
    res = run_bench(design, ctrl, 10.0, 0.3, truth=truth, robust=None, tuned=False)
    played, real = [], bench.simulate_profile

    def recording(plant, controller, profile, **kw):
        sim = real(plant, controller, profile, **kw)
        played.append((profile, sim))
        return sim
    monkeypatch.setattr(bench, "simulate_profile", recording)
    bench.plot_bench(res, truth, ctrl, tmp_path, tail_s=DEFAULT_TAIL_S)
    rows = [r for r in res.rows if r.profile is not None]
    assert len(played) == len(rows) == 3
    for r, (prof, sim) in zip(rows, played):
        n = r.profile.n + int(round(DEFAULT_TAIL_S * FS))          # the table's horizon (evaluate_profile)
        m = seek_metrics(sim.true_position_track[:n] - r.profile.tracks, 0.0, prof, FS, 0.1, design.k0)
        assert (m.settle_time_s, m.peak_pes_after_track, m.rms_pes_after_track) == \
            (r.settle_time_s, r.peak_pes_after_track, r.rms_pes_after_track), r.label
        assert np.array_equal(prof.current_a, r.profile.current_a * (design.k0 / truth.k0))   # x 1/1.1


def test_effect_bench_plays_what_the_bench_table_played(plants):
    """The effect bench on a truth of another gain plays the same seeks as the bench table: the paper's
    profiles and the linear design, through the same calibration (there from the start track on the full
    plant, here from rest at 0 on the same linear plant: equal to the hold current's 1e-14 A solve)."""
    from seekopt.design.nlp import EffectAwareDesigner, NLPSettings
    from seekopt.evaluate.effect_bench import run_effect_bench
    _, design, _ = plants
    truth, ctrl = _other_gain(design), Controller.nss()
    des = EffectAwareDesigner(design, ctrl, 0.3, 0.1, None, NLPSettings(tail_s=0.002))
    eb = run_effect_bench(design, ctrl, 10.0, 0.3, truth=truth, designer=des)
    table = run_bench(design, ctrl, 10.0, 0.3, truth=truth, robust=None, tuned=False,
                      designers={"optimal (linear)": des.linear})
    for label in ("sine", "windowed_sine", "optimal (linear)"):
        e, t = eb.row(label), table.row(label)
        # the same designer designs the linear seek twice: the second QP is warm-started from the first's
        # active set, so the two answers agree to the solver's tolerance, not bit for bit
        np.testing.assert_allclose(e.profile.current_a, t.profile.current_a, rtol=0, atol=1e-9)
        assert e.settle_time_s == t.settle_time_s, label
        assert e.peak_current_a == pytest.approx(t.peak_current_a, abs=1e-9)
        assert e.peak_pes_after_track == pytest.approx(t.peak_pes_after_track, abs=1e-9)
