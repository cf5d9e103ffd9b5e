"""Tests for seekopt.drive.controller: JSON forms, validation, multirate runtime, lifting, loop analysis."""
import json
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from seekopt.drive.controller import (Controller, ControllerError, loop_analysis, plot_loop_analysis,
                                print_loop_analysis)

BENCH = Path(__file__).resolve().parents[1] / "seekopt" / "data" / "nss_hdd_benchmark.json"
B = json.loads(BENCH.read_text())
PID = B["controller_v1"]["pid"]
NOTCHES = B["controller_v1"]["notches"]["sections"]
FS = 1.0 / PID["sample_period_s"]


def v2_seek_plant(f_hz):
    """NSS v2 plant, mode 1 replaced by the double integrator: k0 [1/s^2 + sum g/(...)] e^{-s Td}."""
    modes, common = B["plant_v2"]["modes"], B["common"]
    k0 = B["plant_v2"]["force_constant_N_per_A"] / common["equivalent_mass_kg"] / common["track_pitch_m"]
    s = 2j * np.pi * np.asarray(f_hz, dtype=float)
    p = 1.0 / s**2
    for fr, z, g in list(zip(modes["freq_hz"], modes["zeta"], modes["gain"]))[1:]:
        w = 2 * np.pi * fr
        p = p + g / (s**2 + 2 * z * w * s + w**2)
    return k0 * p * np.exp(-s * common["input_delay_s"])


def issue_form_dict():
    return {"name": "NSS HDD benchmark controller_v1 (PID + 4 notches at 2x rate)",
            "sample_period_s": PID["sample_period_s"],
            "cascade": [{"num": PID["num_z"], "den": PID["den_z"], "label": "PID (NSS controller_v1)"}],
            "multirate": {"rate_multiple": 2,
                          "sections": [dict(n, label=f"notch {n['center_hz']} Hz") for n in NOTCHES]}}


def run(ctrl, e, lifted=True):
    rt = ctrl.runtime(lifted=lifted)
    return np.array([rt.step(x) for x in e])


# ------------------------------------------------------------------ data / JSON
def test_nss_preset_matches_benchmark():
    c = Controller.nss()
    assert c.sample_rate_hz == pytest.approx(26400.0, rel=1e-12)
    assert c.fast_multiple == 2 and len(c.sections) == 5
    assert c.sections[0]["num"] == PID["num_z"] and c.sections[0]["den"] == [1.0, -1.0, 0.0]
    for sec, n in zip(c.sections[1:], NOTCHES):
        assert sec["rate_multiple"] == 2
        assert sec["A"] == n["a"] and sec["B"] == n["b"] and sec["C"] == n["c"] and sec["D"] == n["d"]


def test_json_round_trip(tmp_path):
    c = Controller.nss()
    p = tmp_path / "ctrl.json"
    text = c.to_json(p)
    assert json.loads(text) == c.to_dict() and p.read_text() == text
    c2 = Controller.from_json(p)
    assert c2 == c and c2.hash() == c.hash() and len(c.hash()) == 12
    assert Controller.from_json(c.to_dict()) == c
    c3 = Controller.from_json(dict(c.to_dict(), name="other"))
    assert c3.hash() != c.hash()


def test_input_forms_normalise_to_same_controller():
    ref = Controller.nss()
    issue = Controller.from_json(issue_form_dict())
    assert issue.to_dict() == ref.to_dict() and issue.hash() == ref.hash()
    # explicit sections with rate in each section and upper-case keys
    d = issue_form_dict()
    secs = [{"kind": "tf", "num": PID["num_z"], "den": PID["den_z"], "rate_multiple": 1,
             "label": "PID (NSS controller_v1)"}]
    secs += [{"A": n["a"], "B": n["b"], "C": n["c"], "D": n["d"], "rate_multiple": 2,
              "label": f"notch {n['center_hz']} Hz"} for n in NOTCHES]
    expl = Controller.from_json({"schema": 1, "name": d["name"], "sample_rate_hz": FS, "sections": secs})
    assert expl == ref and expl.hash() == ref.hash()
    # state_space form of the PID (same dynamics, different realisation)
    A, Bm, C, D = signal.tf2ss(PID["num_z"], PID["den_z"])
    d2 = issue_form_dict()
    del d2["cascade"]
    d2["state_space"] = {"A": A.tolist(), "B": Bm.ravel().tolist(), "C": C.ravel().tolist(), "D": float(D[0, 0])}
    ss = Controller.from_json(d2)
    e = np.random.default_rng(1).standard_normal(300)
    np.testing.assert_allclose(run(ss, e), run(ref, e), rtol=1e-10, atol=1e-12)
    f = np.logspace(1, 4, 50)
    np.testing.assert_allclose(ss.freqresp(f), ref.freqresp(f), rtol=1e-10)


# ------------------------------------------------------------------ runtime / lifting
def test_runtime_equals_lifted_ss_and_group_stepping():
    c = Controller.nss()
    e = np.random.default_rng(0).standard_normal(500)
    u_fast, u_ref = run(c, e), run(c, e, lifted=False)
    A, Bm, C, D = c.lifted_ss()
    assert A.shape == (10, 10) and Bm.shape == (10, 1) and C.shape == (2, 10) and D.shape == (2, 1)
    x, u_lift = np.zeros(10), []
    for ek in e:
        u_lift.append(C @ x + D[:, 0] * ek)
        x = A @ x + Bm[:, 0] * ek
    np.testing.assert_allclose(u_fast, np.array(u_lift), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(u_fast, u_ref, rtol=1e-9, atol=1e-12)
    rt = c.runtime()
    first = rt.step(1.0)
    rt.step(-3.0)
    rt.reset()
    np.testing.assert_array_equal(rt.step(1.0), first)


def test_multirate_matches_independent_per_section_simulation():
    """PID at fs via lfilter, held x2, then each notch stepped at 2 fs from its own x, a, b, c, d."""
    c = Controller.nss()
    e = np.random.default_rng(2).standard_normal(400)
    v = np.repeat(signal.lfilter(PID["num_z"], PID["den_z"], e), 2)
    for n in NOTCHES:
        a, b, cc, d = (np.asarray(n[k], float) for k in "abcd")
        x, out = np.zeros(2), np.empty_like(v)
        for i, vi in enumerate(v):
            out[i] = cc @ x + d * vi
            x = a @ x + b * vi
        v = out
    np.testing.assert_allclose(run(c, e).ravel(), v, rtol=1e-9, atol=1e-12)


def test_single_rate_matches_scipy():
    lowpass = signal.butter(2, 0.3)
    c = Controller.from_json({"name": "sr", "sample_rate_hz": FS,
                              "cascade": [{"num": PID["num_z"], "den": PID["den_z"]},
                                          {"num": list(lowpass[0]), "den": list(lowpass[1])}]})
    assert c.fast_multiple == 1
    e = np.random.default_rng(3).standard_normal(300)
    ref = signal.lfilter(lowpass[0], lowpass[1], signal.lfilter(PID["num_z"], PID["den_z"], e))
    u = run(c, e)
    assert u.shape == (300, 1)
    np.testing.assert_allclose(u[:, 0], ref, rtol=1e-9, atol=1e-12)
    num = np.polymul(PID["num_z"], lowpass[0])
    den = np.polymul(PID["den_z"], lowpass[1])
    _, y = signal.dlsim((num, den, 1.0 / FS), e)
    np.testing.assert_allclose(u[:, 0], y[:, 0], rtol=1e-7, atol=1e-10)


def test_multirate_hold_behaviour():
    # gain 2 at fs, then a one-fast-sample delay z^-1 at 2 fs
    c = Controller.from_json({"name": "hold", "sample_rate_hz": 1000.0, "sections": [
        {"kind": "tf", "num": [2.0], "den": [1.0]},
        {"kind": "tf", "num": [1.0], "den": [1.0, 0.0], "rate_multiple": 2}]})
    u = run(c, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(u, [[0, 2], [2, 4], [4, 6]])
    # error held over all three sub-steps when the first section is already fast
    c3 = Controller.from_json({"name": "hold3", "sample_rate_hz": 1000.0, "sections": [
        {"kind": "ss", "A": [[0.5]], "B": [1.0], "C": [1.0], "D": 0.0, "rate_multiple": 3}]})
    u3 = run(c3, [1.0, 0.0])
    np.testing.assert_allclose(u3, [[0, 1, 1.5], [1.75, 0.875, 0.4375]])


def test_pid_dc_integrator():
    slope = float(np.sum(PID["num_z"]))  # (72 - 141.95 + 70) / 1665 per PES sample per track
    assert slope == pytest.approx(0.05 / 1665, rel=1e-9)
    pid = Controller.from_json({"name": "pid", "sample_rate_hz": FS, "cascade": [
        {"num": PID["num_z"], "den": PID["den_z"]}]})
    u = run(pid, np.ones(200))[:, 0]
    np.testing.assert_allclose(np.diff(u)[5:], slope, rtol=1e-9)
    # the notches pass DC: the full preset ramps with slope * prod(notch DC gains)
    dc = np.prod([n["c"] @ np.linalg.solve(np.eye(2) - np.array(n["a"]), n["b"]) + n["d"] for n in NOTCHES])
    assert dc == pytest.approx(1.0, abs=1e-3)
    u = run(Controller.nss(), np.ones(4000))
    np.testing.assert_allclose(np.diff(u[:, 1])[-100:], slope * dc, rtol=1e-6)
    lo = Controller.nss().freqresp([0.1])[0]  # integrator: C ~ slope * fs / (j 2 pi f)
    assert abs(lo) == pytest.approx(slope * dc * FS / (2 * np.pi * 0.1), rel=1e-3)


# ------------------------------------------------------------------ validation
GOOD_TF = {"kind": "tf", "num": [1.0, -0.5], "den": [1.0, -0.9]}
GOOD_SS = {"kind": "ss", "A": [[0.5, 0.1], [0.0, 0.2]], "B": [1.0, 0.0], "C": [0.0, 1.0], "D": 0.0}


@pytest.mark.parametrize("doc, word", [
    ({"sections": [GOOD_TF]}, "sample_rate_hz"),
    ({"sample_rate_hz": 0, "sections": [GOOD_TF]}, "sample_rate_hz"),
    ({"sample_rate_hz": 1e3}, "missing"),
    ({"sample_rate_hz": 1e3, "sections": []}, "no sections"),
    ({"sample_rate_hz": 1e3, "sections": [{"kind": "tf", "num": [1.0]}]}, "missing"),
    ({"sample_rate_hz": 1e3, "sections": [{"kind": "ss", "A": [[0.5]], "B": [1], "C": [1]}]}, "missing"),
    ({"sample_rate_hz": 1e3, "sections": [{"foo": 1}]}, "missing"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_TF, kind="zpk")]}, "unknown kind"),
    ({"sample_rate_hz": 1e3, "sections": [{"kind": "tf", "num": [1, 0, 0], "den": [1, -0.5]}]}, "improper"),
    ({"sample_rate_hz": 1e3, "sections": [{"kind": "tf", "num": [1], "den": [1, -1.2]}]}, "unstable"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_SS, A=[[1.5, 0], [0, 0]])]}, "unstable"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_SS, A=[[0.5, 0, 0], [0, 0.5, 0]])]}, "shape"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_SS, B=[1.0, 0.0, 0.0])]}, "shape"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_SS, C=[[1.0], [0.0]])]}, "shape"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_TF, num=[[1.0, 2.0]])]}, "shape"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_TF, num=["a"])]}, "numeric"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_TF, rate_multiple=1.5)]}, "rate_multiple"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_TF, rate_multiple=0)]}, "rate_multiple"),
    ({"sample_rate_hz": 1e3, "sections": [dict(GOOD_TF, rate_multiple=2), GOOD_SS]}, "decreases"),
    ({"sample_rate_hz": 1e3, "cascade": [GOOD_TF], "state_space": GOOD_SS}, "only one"),
    ({"sample_rate_hz": 1e3, "cascade": [GOOD_TF], "multirate": {"rate_multiple": 2}}, "multirate"),
    ({"schema": 7, "sample_rate_hz": 1e3, "sections": [GOOD_TF]}, "schema"),
])
def test_validation_errors_name_the_file(tmp_path, doc, word):
    p = tmp_path / "bad_controller.json"
    p.write_text(json.dumps(doc))
    with pytest.raises(ControllerError) as exc:
        Controller.from_json(p)
    msg = str(exc.value)
    assert "bad_controller.json" in msg and word in msg and "\n" not in msg
    assert isinstance(exc.value, ValueError)


def test_unreadable_file_errors(tmp_path):
    p = tmp_path / "broken.json"
    p.write_text("{not json")
    with pytest.raises(ControllerError, match="broken.json"):
        Controller.from_json(p)
    with pytest.raises(ControllerError, match="absent.json"):
        Controller.from_json(tmp_path / "absent.json")


# ------------------------------------------------------------------ loop analysis
def test_loop_analysis_nss_v2(tmp_path):
    import control

    c = Controller.nss()
    f = np.logspace(1, np.log10(13200.0), 3000)
    res = loop_analysis(c, v2_seek_plant, f)
    text = print_loop_analysis(res)
    print(f"\nNSS + v2 (seek form): crossover {res.crossover_hz:.1f} Hz, PM {res.phase_margin_deg:.2f} deg, "
          f"GM {res.gain_margin_db:.2f} dB at {res.phase_crossover_hz:.0f} Hz, |S|max "
          f"{res.sensitivity_peak_db:.2f} dB at {res.sensitivity_peak_hz:.0f} Hz")
    assert "phase margin" in text and c.hash() in text
    assert 700 < res.crossover_hz < 1400
    assert res.phase_margin_deg > 20 and res.gain_margin_db > 3
    assert 1.0 < res.sensitivity_peak < 4.0
    np.testing.assert_allclose(res.S + res.T, 1.0, atol=1e-12)
    # cross-check against python-control on the same frequency response
    gm, pm, *_ = control.stability_margins(control.frd(res.L, 2 * np.pi * f))
    assert pm == pytest.approx(res.phase_margin_deg, abs=0.2)
    assert 20 * np.log10(gm) == pytest.approx(res.gain_margin_db, abs=0.05)
    no_hold = loop_analysis(c, v2_seek_plant, f, zoh=False)
    fc = no_hold.crossover_hz  # refined exactly, not a grid point: |P C| = 1 there
    assert abs(v2_seek_plant(fc) * c.freqresp(fc)[0]) == pytest.approx(1.0, abs=1e-8)
    assert no_hold.phase_margin_deg > res.phase_margin_deg  # the DAC hold costs phase
    out = plot_loop_analysis(res, tmp_path / "loop.png")
    assert out.exists() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_loop_analysis_scalar_plant_callable():
    c = Controller.nss()
    f = np.logspace(2, 4, 400)
    a = loop_analysis(c, lambda x: complex(v2_seek_plant(x)), f)
    b = loop_analysis(c, v2_seek_plant, f)
    assert a.crossover_hz == pytest.approx(b.crossover_hz, rel=1e-9)
    np.testing.assert_allclose(a.L, b.L, rtol=1e-12)
