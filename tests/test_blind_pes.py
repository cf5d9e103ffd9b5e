"""The blind-band mode's PES rows go on the set's operating plants (seekopt.design.blind_pes.blind_pes_plants),
not on the plants that stand for the identification's own error."""
import numpy as np

from identification.model.plant import ModalPlant, Mode
from seekopt.design.blind_pes import ID_ERROR_ROLE, blind_pes_plants
from seekopt.design.designer import SeekDesigner
from seekopt.design.family import Drift, drift_set, drifted, set_label
from seekopt.design.problem import SeekProblem
from seekopt.drive.controller import Controller

FS = 26400.0


def plant():
    modes = [Mode(420.0, 0.06, 0.0015, {"freq_hz": 0.2, "zeta": 0.0006, "gain": 1.1e-5}),
             Mode(1738.0, 0.03, 0.02, {"freq_hz": 0.25, "zeta": 0.0002, "gain": 1.4e-4}),
             Mode(4100.0, 0.03, -1.0, {"freq_hz": 0.2, "zeta": 8e-5, "gain": 0.006})]
    return ModalPlant(k0=3.9e9, modes=modes, delay_s=1e-5, sample_rate_hz=FS, track_pitch_nm=254.0,
                      std={"k0": 6.5e4, "delay_s": 1.2e-8})


def test_operating_plants_are_the_conditions_not_the_identification_error():
    p = plant()
    cold = drifted(p, 0.04, -0.2, 0.05)
    cold.meta["family_name"] = "cold"
    ps = drift_set(p, [cold], Drift.from_string("temp=±4%,zeta=±20%,gain=±5%,n=3"))
    labels = [set_label(q) for q in ps]
    op = {labels[i] for i in blind_pes_plants(ps)}
    # the drive in another condition: nominal, member, common drifts (the nominal plant at the member's
    # drift is the member itself here: kept once)
    assert {"nominal", "member 1: cold", "temp+4% (zeta-20%) gain-5%",
            "temp-4% (zeta+20%)", "gain+5%"} <= op
    # the identification's error: per-mode corners about the nominal plant and about the member, OA rows
    err = {lab for lab in labels if " modes " in f" {lab} " or lab.startswith("oa ")}
    assert {"modes freq +", "modes gain -", "member 1: cold modes freq -", "oa 1"} <= err
    assert not op & err and op | err == set(labels)
    assert all((q.meta.get("set_role") == ID_ERROR_ROLE) == (set_label(q) in err) for q in ps)
    # a drifted truth is a plant, not a set vertex: no role; the nominal plant is always operating
    assert "set_role" not in drifted(ps[-1], 0.01).meta
    assert blind_pes_plants([ps[-1]]) == [0]


def test_the_qp_has_blind_rows_on_the_operating_plants_only():
    p = plant()
    des = SeekDesigner(SeekProblem(p, Controller.nss(), 0.3, 0.1, robust=Drift.from_string("temp=±4%")))
    qp = des._structure(des._classes(24)[0], False)
    with_rows = set(np.unique(qp.plant_idx[qp.kind == "bpes"]).tolist())
    assert with_rows == set(blind_pes_plants(des.plants)) and len(with_rows) < len(des.plants)
    assert {set_label(des.plants[i]) for i in with_rows} == {"nominal", "temp+4%", "temp-4%"}
    # every plant keeps its own band rows
    assert set(np.unique(qp.plant_idx[qp.kind == "pes"]).tolist()) == set(range(len(des.plants)))


def test_blind_pes_maps_equal_the_simulated_loops_with_the_mode():
    """The blind-band mode's PES maps by superposition on the design plant's loop equal the difference of
    closed loops simulated with the mode (+g and -g) added to the plant (the one simulator)."""
    from identification.model.plant import Mode
    from seekopt.design.blind_pes import blind_pes_maps
    from seekopt.drive.controller import Controller
    from seekopt.drive.presets import default_truth_plant
    from seekopt.drive.simulator import closed_loop_responses
    plant, ctrl, H = default_truth_plant(), Controller.nss(), 300
    freqs, gains = [11880.0, 15000.0], [1.0, 0.5]
    maps = blind_pes_maps(plant, ctrl, H, freqs, gains)
    lin = plant.linear_part().copy(meta={})
    base = closed_loop_responses(lin, ctrl, H)
    assert len(maps) == 2
    for (du, dr), f, g in zip(maps, freqs, gains):
        sim = {}
        for s in (1.0, -1.0):
            p = lin.copy(modes=sorted(list(lin.modes) + [Mode(f, 0.02, s * g)], key=lambda m: m.freq_hz))
            r = closed_loop_responses(p, ctrl, H)
            sim[s] = (r["y_uff"] - base["y_uff"], r["y_r"] - base["y_r"])
        su, sr = (0.5 * (a - b) for a, b in zip(sim[1.0], sim[-1.0]))
        assert np.max(np.abs(su)) > 1e-3 * np.max(np.abs(base["y_uff"][:50]))     # the mode matters
        assert np.allclose(du, su, rtol=0, atol=1e-9 * np.max(np.abs(su)))
        assert np.allclose(dr, sr, rtol=0, atol=1e-9 * np.max(np.abs(sr)))
    # the designer's shortcut (SeekDesigner._blind_pes): its set's first loop map, longer than H and of the
    # full plant, as the base -- the same maps as the design plant's linear loop simulated afresh
    from seekopt.design.blind_pes import blind_pes_freqs
    des = SeekDesigner(SeekProblem(plant, ctrl, 0.3))
    des._loop_maps(2 * H)
    assert des._maps[0].horizon > H
    f, g = blind_pes_freqs(des.guard_bands, des.problem.blind_pes_points)
    assert len(f) > 0
    ref = blind_pes_maps(plant, ctrl, H, f, g)
    got = des._blind_pes(H)
    assert len(got) == len(ref)
    assert all(np.allclose(a, b, rtol=0, atol=1e-12 * np.max(np.abs(b))) for p, q in zip(got, ref) for a, b in zip(p, q))
