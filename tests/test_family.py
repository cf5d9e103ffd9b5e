"""Tests for families of plants and drift in physical terms (seekopt.design.family) and their use by
the designer, the seek problem and the command line."""
import json
import math

import numpy as np
import pytest

from identification.model.plant import ModalPlant, Mode
from seekopt.app.cli import main
from seekopt.design.designer import SeekDesigner
from seekopt.design.family import (Drift, DriftError, calibrated, drift_set, drifted, family_spread,
                                   feedforward_scale, match_modes, played_on, set_label)
from seekopt.design.metrics import evaluate_profile
from seekopt.design.problem import SeekProblem
from seekopt.drive.controller import Controller

FS = 26400.0


def plant(**kw):
    modes = [Mode(420.0, 0.06, 0.0015, {"freq_hz": 0.2, "zeta": 0.0006, "gain": 1.1e-5}),
             Mode(1738.0, 0.03, 0.02, {"freq_hz": 0.25, "zeta": 0.0002, "gain": 1.4e-4}),
             Mode(4100.0, 0.03, -1.0, {"freq_hz": 0.2, "zeta": 8e-5, "gain": 0.006}),
             Mode(12300.0, 0.005, 1.0, {"freq_hz": 5.0, "zeta": 5e-4, "gain": 0.08})]
    args = dict(k0=3.9e9, modes=modes, delay_s=1e-5, sample_rate_hz=FS, track_pitch_nm=254.0,
                std={"k0": 6.5e4, "delay_s": 1.2e-8})
    args.update(kw)
    return ModalPlant(**args)


# ------------------------------------------------------------------ the text form
def test_drift_string_physical_terms():
    d = Drift.from_string("temp=±4%,zeta=±20%,gain=+-5%,delay=±1us,f1738=±5%,f1738.zeta=±30%,sigma=2")
    assert (d.temp_pct, d.zeta_pct, d.gain_pct, d.delay_s, d.n_sigma) == (4.0, 20.0, 5.0, pytest.approx(1e-6), 2.0)
    assert d.modes[1738.0].freq_pct == 5.0 and d.modes[1738.0].zeta_pct == 30.0 and d.modes[1738.0].gain_pct is None
    assert Drift.from_string("delay=0.5 us").delay_s == pytest.approx(5e-7)
    assert Drift.from_string("delay=2e-6").delay_s == pytest.approx(2e-6)
    again = Drift.from_string(d.to_string())
    assert again.to_dict() == d.to_dict()
    assert Drift.from_dict(json.loads(json.dumps(d.to_dict()))).to_dict() == d.to_dict()
    assert Drift.merged(["temp=±4%", "gain=±5%", "temp=±3%"]).temp_pct == 3.0
    defaults = Drift.from_string("default")
    assert defaults.temp_pct is None and defaults.seek_pct == 5.0


@pytest.mark.parametrize("bad", ["temp", "tmp=4%", "temp=four", "delay=1 parsec", "f1738.q=3%", "n=x"])
def test_drift_string_errors(bad):
    with pytest.raises(DriftError):
        Drift.from_string(bad)


def test_per_mode_range_must_name_a_mode():
    Drift.from_string("f1738=±5%").check_modes(plant())
    with pytest.raises(DriftError, match="no identified mode within 10 % of 2500"):
        Drift.from_string("f2500=±5%").check_modes(plant())


# ------------------------------------------------------------------ ranges from the data
def test_ranges_from_reported_std_and_seek_modes():
    p = plant()
    r = Drift().ranges(p)
    assert r.temp == 0 and r.zeta == 0 and r.gain == 0          # a single log shows no temperature drift
    assert r.df[0] == pytest.approx(0.05) and r.df[1] == pytest.approx(0.05)      # seek-induced: +-5 %
    assert r.df[2] == pytest.approx(3 * 0.2 / 4100)                               # others: 3 std
    assert r.dg[2] == pytest.approx(3 * 0.006)
    assert r.df[3] == 0 and r.dg[3] == 0                                          # near Nyquist: no own range
    assert r.ffgain == pytest.approx(3 * 6.5e4 / 3.9e9) and r.delay == pytest.approx(3 * 1.2e-8)
    stated = Drift.from_string("temp=±4%,f4100=±2%,f4100.gain=±10%,seek=±3%").ranges(p)
    assert stated.temp == pytest.approx(0.04) and stated.df[2] == pytest.approx(0.02) and stated.dg[2] == 0.1
    assert stated.df[1] == pytest.approx(0.03) and stated.source["temp"] == "stated"


def test_family_spread_finds_the_common_scales():
    p = plant()
    cold, hot = drifted(p, 0.04, -0.2, 0.05), drifted(p, -0.04, 0.2, -0.05)
    # one mode moves on its own in the cold member
    cold.modes[1] = Mode(cold.modes[1].freq_hz * 1.02, cold.modes[1].zeta, cold.modes[1].gain)
    sp = family_spread(p, [cold, hot])
    assert sp["temp"] == pytest.approx(0.04, rel=1e-6) and sp["zeta"] == pytest.approx(0.2, rel=1e-6)
    assert sp["gain"] == pytest.approx(0.05, rel=1e-6)
    assert sp["modes"][1][0] == pytest.approx(0.02, rel=1e-6) and sp["modes"][2][0] == pytest.approx(0.0, abs=1e-12)
    r = Drift().ranges(p, [cold, hot])
    # the members carry the common drift themselves: no box around them
    assert r.temp == 0 and r.source["temp"].startswith("family members (spread ±4%") and r.df[1] >= 0.05
    assert match_modes(p, hot) == [(0, 0), (1, 1), (2, 2), (3, 3)]


def test_drift_set_correlated_vertices_are_few():
    p = plant()
    d = Drift.from_string("temp=±4%,zeta=±20%,gain=±5%,n=3")
    ps = drift_set(p, [], d)
    labels = [set_label(x) for x in ps]
    assert labels[0] == "nominal" and ps[0].hash() == p.hash()
    common = [x for x in ps if set_label(x).startswith(("temp", "gain"))]
    corners = [x for x in common if "(" in set_label(x) and "gain" in set_label(x)]
    assert len(corners) == 4                        # temperature (with its damping) x gain: two parameters
    # and the axial points (one parameter at +-1, the other nominal): a face-centred design
    assert {set_label(x) for x in common} - {set_label(x) for x in corners} == {
        "temp+4% (zeta-20%)", "temp-4% (zeta+20%)", "gain+5%", "gain-5%"}
    cold = next(x for x in corners if set_label(x).startswith("temp+4% (zeta-20%) gain+5%"))
    assert [m.freq_hz / m0.freq_hz for m, m0 in zip(cold.modes, p.modes)] == pytest.approx([1.04] * 4)
    assert [m.zeta / m0.zeta for m, m0 in zip(cold.modes, p.modes)] == pytest.approx([0.8] * 4)
    # the gain drift is compensated by the drive's feedforward calibration: same rigid-body travel
    assert cold.k0 == pytest.approx(1.05 * p.k0) and feedforward_scale(cold) == pytest.approx(1 / 1.05)
    assert sum(lab.startswith("oa") for lab in labels) == 3
    assert {"modes freq +", "modes freq -", "modes gain +", "modes gain -"} <= set(labels)
    for x in ps:                                    # nothing unphysical
        assert all(m.zeta > 0 and m.freq_hz > 0 for m in x.modes)


def test_family_members_in_the_set_with_their_calibration():
    p = plant()
    cold = drifted(p, 0.04, -0.2, 0.05)
    cold.meta["family_name"] = "cold"
    ps = SeekProblem(p, Controller.nss(), 0.3, robust=None, family=[cold]).plants()
    assert [set_label(x) for x in ps] == ["nominal", "member 1: cold"]
    assert feedforward_scale(ps[1]) == pytest.approx(1 / 1.05)
    prof_played = played_on(SeekDesigner(SeekProblem(p, Controller.nss(), 0.3, hf_guard=None,
                                                     guard_notch_depth_db=None)).design(10.0).profile, ps[1])
    assert prof_played.meta["ff_scale"] == pytest.approx(1 / 1.05, rel=1e-5)
    assert calibrated(cold, p.k0).meta["ff_scale"] == pytest.approx(1 / 1.05)


def test_problem_json_round_trip_with_family_and_drift():
    p = plant()
    prob = SeekProblem(p, Controller.nss(), 0.3, robust=Drift.from_string("temp=±4%,f1738=±5%"),
                       family=[drifted(p, 0.04, -0.2, 0.05)])
    again = SeekProblem.from_json(prob.to_json())
    assert again == prob and isinstance(again.robust, Drift) and len(again.family) == 1
    assert [x.hash() for x in again.plants()] == [x.hash() for x in prob.plants()]


# ------------------------------------------------------------------ designs over a family
def simple(k0=3.9e9, f=1738.0, z=0.03):
    return ModalPlant(k0=k0, modes=[Mode(f, z, 0.02)], delay_s=1e-5, sample_rate_hz=FS, track_pitch_nm=254.0)


def test_family_design_holds_every_member_and_says_which_binds():
    ctrl = Controller.nss()
    nom = simple()
    members = [drifted(simple(), 0.06, -0.2, 0.03), drifted(simple(), -0.06, 0.2, -0.03)]
    kw = dict(hf_guard=None, guard_notch_depth_db=None)
    alone = SeekDesigner(SeekProblem(nom, ctrl, 0.3, **kw)).design(50.0)
    fam = SeekDesigner(SeekProblem(nom, ctrl, 0.3, robust=None, family=members, **kw)).design(50.0)
    pred = fam.prediction
    assert pred.labels == ["nominal", "member 1", "member 2"]
    N = fam.set_settle_samples      # every plant of the set holds the band from here (the nominal from settle_samples)
    assert fam.settle_samples <= N and fam.profile.seek_samples == N + round(3e-4 * FS)   # inputs go on 0.3 ms
    assert pred.nominal.settle_time_s * FS <= fam.settle_samples + 1 + 1e-9
    for lab, m in pred.members():
        assert m.settle_time_s * FS <= N + 1 + 1e-9, lab
    assert pred.labels[pred.binding] in pred.labels and 0 <= pred.worst < 3
    meta = fam.profile.meta
    assert float(meta["predicted_settle_worst_ms"]) == pytest.approx(pred.worst_metrics.settle_time_s * 1e3, abs=1e-3)
    assert meta["predicted_settle_members_ms"].count(";") == 2
    # the nominal design rings on the drifted members; the family design does not
    worst_alone = max(evaluate_profile(calibrated(m, nom.k0), ctrl, played_on(alone.profile, calibrated(m, nom.k0)))
                      .settle_time_s for m in members)
    assert worst_alone > pred.worst_metrics.settle_time_s


def test_cli_design_family_and_drift(tmp_path, capsys):
    nom, cold = simple(), drifted(simple(), 0.04, -0.2, 0.05)
    a, b = tmp_path / "room.json", tmp_path / "cold.json"
    nom.to_json(a)
    cold.to_json(b)
    out = tmp_path / "k20.csv"
    rc = main(["design", "--plant", str(a), "--plant", str(b), "--tracks", "20", "--imax", "0.3", "-o", str(out),
               "--drift", "delay=±0.5us"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "predicted on room.json" in text and "predicted on cold.json" in text and "binding plant" in text
    assert "unmodelled-mode guard: worst residual" in text
    csv = out.read_text()
    assert "# predicted_settle_worst_ms:" in csv and "# family_hashes:" in csv and "# guard_worst_residual_band:" in csv
    # bad drift: one line, exit 2, nothing written
    bad = tmp_path / "bad.csv"
    assert main(["design", "--plant", str(a), "--tracks", "20", "--imax", "0.3", "-o", str(bad),
                 "--drift", "f2500=±5%"]) == 2
    assert "no identified mode within 10 %" in capsys.readouterr().err and not bad.exists()
    assert main(["design", "--plant", str(a), "--tracks", "20", "--imax", "0.3", "-o", str(bad),
                 "--drift", "temp=±4%", "--robust", "freq=5"]) == 2
    assert not bad.exists()


def test_sweep_and_export_take_a_family(tmp_path):
    from seekopt.evaluate.sweep import SweepConfig, run_sweep
    from seekopt.export.tables import load_tables, write_tables
    nom, cold = simple(), drifted(simple(), 0.04, -0.2, 0.05)
    cfg = SweepConfig(nom, Controller.nss(), [100e3], [20], 0.3, designer="ocp", family=[cold])
    plain = SweepConfig(nom, Controller.nss(), [100e3], [20], 0.3, designer="ocp")
    assert "family" not in plain.identity() and cfg.hash() != plain.hash()
    again = SweepConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again.hash() == cfg.hash() and len(again.family) == 1
    s = run_sweep(cfg, tmp_path / "sw", engine="serial", progress=False, figures=False)
    assert s.computed == 1 and not s.failed_cells
    cell = json.loads(next((tmp_path / "sw" / "cells").glob("*.json")).read_text())
    meta = cell["optimal_profile"]          # the profile's header: metadata keys at the top level
    assert meta["predicted_settle_members_ms"].startswith("nominal=") and "member 1" in meta["predicted_settle_members_ms"]
    ts = load_tables(tmp_path / "sw")
    assert ts.meta["family_hashes"] == cold.at_tpi(100e3).hash() or ts.meta["family_hashes"] == cold.hash()
    paths = write_tables(ts, "c", tmp_path / "fw")
    assert "holds the plant family" in paths[0].read_text()


def test_cli_identify_several_logs_gives_a_family(tmp_path, capsys):
    from identification.logs.formats import write_log
    from seekopt.evaluate.synth import SynthConfig, synthesize
    logs = []
    for name, t, seed in (("room", 0.0, 0), ("cold", 0.04, 1)):
        truth = drifted(simple(), t, -5 * t, 0.0)
        log, _ = synthesize(SynthConfig(n_seeks=16, seed=seed, max_tracks=2000.0, rro=False), plant=truth)
        path = tmp_path / f"{name}.npz"
        write_log(log, path)
        logs.append(str(path))
    assert main(["identify", *logs, "-o", str(tmp_path / "plants.json")]) == 2     # one file for two logs
    assert "several logs need a folder" in capsys.readouterr().err
    assert main(["identify", *logs, "-o", str(tmp_path / "plants"), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "family of 2 plants, relative to room.npz" in text and "cold.npz: frequencies x1.04" in text
    assert "blind (a mode of gain 0.05 would escape detection)" in text
    p = ModalPlant.load(tmp_path / "plants" / "cold.json")
    assert p.meta["blind_bands"][-1]["reason"] == "above the identification range"


def test_temperature_family_design_beats_the_paper_on_every_member():
    """The default truth at three temperatures (x1.04 / x0.8 / gain x1.05, room, x0.96 / x1.2 /
    x0.95), the exact plants as the family, K = 200: on every member (its drive calibrating its gain) at
    most 0.7 x the better of the shortest sine and windowed sine played on that member."""
    from seekopt.design.baselines import baseline_profile
    from seekopt.drive.presets import default_truth_plant
    ctrl, K = Controller.nss(), 200.0
    room = default_truth_plant()
    cold, hot = drifted(room, 0.04, -0.2, 0.05), drifted(room, -0.04, 0.2, -0.05)
    res = SeekDesigner(SeekProblem(room, ctrl, 0.3, robust=Drift(), family=[cold, hot])).design(K)
    for m in (room, cold, hot):
        mc = calibrated(m, room.k0)
        t = evaluate_profile(mc, ctrl, played_on(res.profile, mc)).settle_time_s
        base = min(evaluate_profile(mc, ctrl, played_on(baseline_profile(room, FS, k, K, 0.3), mc)).settle_time_s
                   for k in ("sine", "windowed_sine"))
        assert t <= 0.7 * base
        assert t <= res.prediction.worst_metrics.settle_time_s * 1.2


def test_plants_differing_only_in_calibration_stay_in_the_set():
    """The corners of a feedforward-gain error are the same plant played with different calibrations:
    distinct drives of the set (before, the plant hash, which leaves out meta, collapsed them into one)."""
    from seekopt.design.family import Drift
    p = plant()
    s = drift_set(p, [], Drift.from_string("ffgain=±2%"))
    scales = sorted(round(feedforward_scale(q), 9) for q in s)
    assert {0.98, 1.0, 1.02} <= set(scales)
    assert {"ffgain+2%", "ffgain-2%"} <= {set_label(q) for q in s}
    # temperature x feedforward gain error: all four corners, and the four axial points
    s = drift_set(p, [], Drift.from_string("temp=±4%,ffgain=±1%"))
    assert len([q for q in s if set_label(q).startswith("temp") and "ffgain" in set_label(q)]) == 4
    assert len([q for q in s if set_label(q).startswith(("temp", "ffgain"))]) == 8
    from seekopt.design.predict import set_identity
    assert len({set_identity(q) for q in s}) == len(s)
    # identity: the plant and its calibration; the label is not part of it
    a = p.copy(meta={"set_label": "a", "ff_scale": 1.01})
    assert set_identity(a) == set_identity(p.copy(meta={"set_label": "b", "ff_scale": 1.01}))
    assert set_identity(a) != set_identity(p.copy(meta={"set_label": "a", "ff_scale": 0.99}))
    assert set_identity(p) == set_identity(p.copy(meta={"ff_scale": 1.0}))


def test_inputs_after_the_settle_sample_hold_every_plant_and_settle_no_later():
    """``input_tail_s``: the feedforward and reference go on after the settle sample (the seek-settle time
    counts |PES| only).  Every plant of the set still holds the band from the design's settle sample when
    the simulator plays it; the profile's ``seek_samples`` counts its inputs; the set settles no later than
    with inputs that end at the settle sample (K = 200 on the NSS-like plant: earlier)."""
    ctrl, K = Controller.nss(), 200.0
    p = plant()
    old = SeekDesigner(SeekProblem(p, ctrl, 0.3, robust=Drift(), input_tail_s=0.0, nominal_first=False)).design(K)
    new = SeekDesigner(SeekProblem(p, ctrl, 0.3, robust=Drift())).design(K)
    tail = round(3e-4 * FS)
    assert old.profile.seek_samples == old.settle_samples == old.set_settle_samples
    assert new.profile.seek_samples == new.set_settle_samples + tail
    assert new.settle_samples <= new.set_settle_samples < old.settle_samples
    assert new.prediction.nominal.settle_time_s * FS <= new.settle_samples + 1 + 1e-9
    for lab, m in zip(new.prediction.labels, new.prediction.metrics):
        assert m.settle_time_s * FS <= new.set_settle_samples + 1 + 1e-9, lab
    assert new.profile.meta["design_settle_samples"] == new.settle_samples


def test_nominal_first_keeps_the_worst_case_and_settles_the_nominal_plant_sooner():
    """Lexicographic design over a set (``nominal_first``): the set's worst settle sample of the worst-case
    design is kept, the nominal plant settles no later (here: sooner, inputs ending at the settle sample).
    Without the blind-band PES rows (the case measured; with them both take 36: the nominal plant holds the
    blind mode's PES too from its own settle sample)."""
    ctrl, K = Controller.nss(), 200.0
    p = plant()
    kw = dict(robust=Drift(), input_tail_s=0.0, band_margin=0.8,    # the case measured (at 0.9 both take 33)
              blind_pes_points=0)
    worst = SeekDesigner(SeekProblem(p, ctrl, 0.3, nominal_first=False, **kw)).design(K)
    lex = SeekDesigner(SeekProblem(p, ctrl, 0.3, **kw)).design(K)
    assert lex.set_settle_samples == worst.settle_samples == lex.profile.seek_samples
    assert lex.settle_samples < worst.settle_samples
    assert lex.profile.meta["design_set_settle_samples"] == lex.set_settle_samples
    assert lex.prediction.nominal.settle_time_s * FS <= lex.settle_samples + 1 + 1e-9
    for lab, m in zip(lex.prediction.labels, lex.prediction.metrics):
        assert m.settle_time_s * FS <= lex.set_settle_samples + 1 + 1e-9, lab


# ------------------------------------------------------------------ session 6: faces, members' ranges, margin
def test_members_carry_their_own_per_mode_ranges_with_their_calibration():
    """Each family member is an identified plant: the set holds its own per-mode corners (its reported std,
    the seek-induced modes' range), played with the member's feedforward calibration."""
    p = plant()
    cold = drifted(p, 0.04, -0.2, 0.05)
    cold.meta["family_name"] = "cold"
    d = Drift()
    ps = drift_set(p, [cold], d)
    mem = {set_label(q): q for q in ps if set_label(q).startswith("member 1: cold modes")}
    assert set(mem) == {f"member 1: cold modes {w} {s}" for w in ("freq", "gain") for s in "+-"}
    r = d.ranges(cold)
    up = mem["member 1: cold modes freq +"]
    assert [m.freq_hz / m0.freq_hz - 1 for m, m0 in zip(up.modes, cold.modes)] == pytest.approx(list(r.df))
    assert r.df[0] == pytest.approx(0.05)            # 420 Hz: a seek-induced mode, +-5 %
    lo = mem["member 1: cold modes gain -"]
    assert [m.gain / m0.gain - 1 for m, m0 in zip(lo.modes, cold.modes)] == pytest.approx(list(-r.dg))
    for q in mem.values():
        assert q.k0 == cold.k0 and feedforward_scale(q) == pytest.approx(p.k0 / cold.k0)


def test_default_band_margin_follows_the_set():
    """0.8 on the nominal plant or a RobustSpec box, 0.9 over a Drift set (whose plants sample the common
    drifts' faces and carry every identified plant's ranges); a stated margin is kept, JSON keeps it."""
    from seekopt.design.problem import BAND_MARGIN, DRIFT_BAND_MARGIN
    from seekopt.design.robust import RobustSpec
    p, ctrl = plant(), Controller.nss()
    assert SeekProblem(p, ctrl, 0.3).band_margin == BAND_MARGIN == 0.8
    assert SeekProblem(p, ctrl, 0.3, robust=RobustSpec()).band_margin == BAND_MARGIN
    assert SeekProblem(p, ctrl, 0.3, robust="default").band_margin == BAND_MARGIN
    prob = SeekProblem(p, ctrl, 0.3, robust=Drift())
    assert prob.band_margin == DRIFT_BAND_MARGIN == 0.9
    assert SeekProblem.from_json(prob.to_json()).band_margin == DRIFT_BAND_MARGIN
    assert SeekProblem(p, ctrl, 0.3, robust=Drift(), band_margin=0.75).band_margin == 0.75


def test_drift_design_holds_the_faces_of_the_common_drifts():
    """The seek's residual is not monotone along a common frequency scale: a design held on the corners of
    temperature x gain alone left the middle of a face (measured: 38 samples at temperature +4 %, nominal
    gain, against the set's worst 34).  With the axial points, the design played on a 9 x 3 grid of the
    stated drift (temperature with its damping, compensated gain) settles no later than the worst the
    design predicts over its set (K = 200, NSS-like plant, the set's default margin)."""
    from seekopt.drive.presets import default_truth_plant
    ctrl, K = Controller.nss(), 200.0
    p = default_truth_plant().linear_part()
    res = SeekDesigner(SeekProblem(p, ctrl, 0.3, robust=Drift.from_string("temp=±4%,zeta=±20%,gain=±5%"))).design(K)
    worst = res.prediction.worst_metrics.settle_time_s * FS
    for t in np.linspace(-0.04, 0.04, 9):
        for g in (-0.05, 0.0, 0.05):
            q = calibrated(drifted(p, t, -5.0 * t, g), p.k0)
            got = evaluate_profile(q, ctrl, played_on(res.profile, q)).settle_time_s * FS
            assert got <= worst + 1e-9, (t, g, got, worst)
