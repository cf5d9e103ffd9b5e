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
