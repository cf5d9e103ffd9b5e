"""ModalPlant: JSON, eq. (1) conversion, the one discretisation, effects."""
import json
import math

import numpy as np
import pytest

from identification.model.effects import (AmplifierLag, CurrentSaturation, ExtraMode, Friction, InputDelay,
                                    PeriodicDisturbance, PivotSpringDamper, PositionBias,
                                    TorqueConstantVariation, effect_from_dict)
from identification.model.plant import ModalPlant, Mode, PlantError

K0 = 3.937e9
DT = 1 / 52800


def plant(**kw):
    base = dict(k0=K0, modes=[Mode(420, 0.06, 0.0015), Mode(1738, 0.03, 0.02), Mode(4100, 0.03, -1.0)],
                delay_s=1e-5, sample_rate_hz=26400.0, track_pitch_nm=254.0)
    base.update(kw)
    return ModalPlant(**base)


def test_json_keys_and_round_trip(tmp_path):
    p = plant(bias_a=0.003, effects=[Friction(0.001, 1e-7)])
    p.modes[0].std = {"freq_hz": 1.0, "zeta": 0.01, "gain": 1e-4}
    d = json.loads(p.to_json(tmp_path / "p.json"))
    for key in ("schema", "sample_rate_hz", "track_pitch_nm", "k0", "bias_a", "delay_s", "modes", "effects"):
        assert key in d
    assert set(d["modes"][0]) >= {"freq_hz", "zeta", "gain", "std"}
    assert d["effects"] == [{"effect": "friction", "params": {"coulomb_a": 0.001, "viscous_a_per_tps": 1e-7}}]
    q = ModalPlant.load(tmp_path / "p.json")
    assert q.to_dict() == p.to_dict()
    assert q.hash() == p.hash()


@pytest.mark.parametrize("text, word", [("{", "JSON"), ("[1]", "object"), ('{"k0": -1}', "k0"),
                                        ('{"modes": []}', "k0"), ('{"k0": 1, "delay_s": -1}', "delay")])
def test_bad_plant_files(tmp_path, text, word):
    f = tmp_path / "bad.json"
    f.write_text(text)
    with pytest.raises(PlantError) as e:
        ModalPlant.load(f)
    assert "bad.json" in str(e.value) and word in str(e.value) and "\n" not in str(e.value)


def test_eq1_round_trip_and_form():
    p = plant()
    k0, eq1 = p.to_eq1()
    for m, r in zip(p.modes, eq1):
        # a w_d / (s^2 + 2 zeta' w_d s + (1 + zeta'^2) w_d^2) == k0 g / (s^2 + 2 zeta w s + w^2)
        assert r["a"] * r["omega"] == pytest.approx(K0 * m.gain)
        assert (1 + r["zeta"] ** 2) * r["omega"] ** 2 == pytest.approx(m.omega ** 2)
        assert 2 * r["zeta"] * r["omega"] == pytest.approx(2 * m.zeta * m.omega)
    q = ModalPlant.from_eq1(k0, eq1)
    for a, b in zip(p.modes, q.modes):
        assert (a.freq_hz, a.zeta, a.gain) == pytest.approx((b.freq_hz, b.zeta, b.gain))


@pytest.mark.parametrize("delay", [0.0, 0.52 * DT, 1.52 * DT, 2 * DT])
def test_discretisation_exact_against_fine_grid(delay):
    """ZOH with fractional delay equals a 50x finer simulation with an integer delay."""
    fine = 50
    delay = round(delay / (DT / fine)) * DT / fine
    p = plant(delay_s=delay)
    u = np.zeros(160); u[5:20] = 0.1; u[20:35] = -0.1; u[60:64] = 0.05
    y = p.simulate_open_loop(u, DT)
    shift = int(round(delay / (DT / fine)))
    uf = np.concatenate([np.zeros(shift), np.repeat(u, fine)])[:len(u) * fine]
    yf = p.copy(delay_s=0.0).simulate_open_loop(uf, DT / fine)[::fine]
    assert np.max(np.abs(y - yf)) < 1e-9 * np.max(np.abs(y))


def test_python_control_systems_agree():
    import control
    p = plant()
    u = np.sin(np.arange(300) / 7.0) * 0.01
    _, yc = control.forced_response(p.to_control_discrete(DT), U=u)
    assert np.allclose(yc, p.simulate_open_loop(u, DT, history_a=0.0), rtol=1e-9, atol=1e-9)
    f = np.array([100.0, 1000.0, 3000.0])
    sys = p.copy(delay_s=0.0).to_control()
    assert np.allclose(p.copy(delay_s=0.0).frf(f), np.squeeze(sys(2j * np.pi * f)))
    # rigid-body asymptote and mode gains: P = k0 (1/s^2 + sum g/(s^2+...))
    s = 2j * np.pi * f
    ref = K0 * (1 / s ** 2 + sum(m.gain / (s ** 2 + 2 * m.zeta * m.omega * s + m.omega ** 2) for m in p.modes))
    assert np.allclose(p.frf(f), ref * np.exp(-s * 1e-5))


def test_tpi_re_expression_keeps_physical_gain():
    p = plant()
    q = p.at_tpi(500e3)
    assert q.track_pitch_nm == pytest.approx(50.8)
    assert q.physical_gain == pytest.approx(p.physical_gain)
    assert q.k0 == pytest.approx(K0 * 254 / 50.8)


def test_rest_with_bias_stays_at_rest():
    p = plant(bias_a=0.004)
    dp = p.discretize(DT)
    dp.reset(1234.0)
    for _ in range(500):
        dp.step(-0.004)
    assert dp.output() == pytest.approx(1234.0, abs=1e-9)


def test_structural_effects_frf():
    f = np.array([50.0, 500.0, 5000.0])
    s = 2j * np.pi * f
    base = plant(delay_s=0.0, modes=[])
    lag = base.copy(effects=[AmplifierLag(3000.0)])
    assert np.allclose(lag.frf(f), base.frf(f) / (1 + s / (2 * np.pi * 3000)))
    piv = base.copy(effects=[PivotSpringDamper(30.0, 0.1)])
    wp = 2 * np.pi * 30
    assert np.allclose(piv.frf(f), K0 / (s ** 2 + 2 * 0.1 * wp * s + wp ** 2))
    extra = base.copy(effects=[ExtraMode(900.0, 0.05, 0.01)])
    assert len(extra.all_modes()) == 1
    dly = base.copy(delay_s=1e-5, effects=[InputDelay(5e-6)])
    assert dly.total_delay_s == pytest.approx(1.5e-5)
    assert np.allclose(dly.frf(f), base.frf(f) * np.exp(-s * 1.5e-5))


def test_nonlinear_effects_step():
    base = plant(delay_s=0.0, modes=[])
    # saturation: a 1 A command delivers 0.2 A
    sat = base.copy(effects=[CurrentSaturation(0.2)])
    u = np.r_[np.ones(10), np.zeros(10)]
    assert np.allclose(sat.simulate_open_loop(u, DT, history_a=0.0),
                       base.simulate_open_loop(0.2 * u, DT, history_a=0.0))
    # torque constant 10 % higher at +1 scale from centre
    kt = base.copy(effects=[TorqueConstantVariation([0.1], center_track=0.0, scale_track=100.0)])
    y = kt.simulate_open_loop(u * 1e-3, DT, position0=100.0, history_a=0.0)
    y0 = base.simulate_open_loop(u * 1e-3, DT, position0=100.0, history_a=0.0)
    assert (y[-1] - 100) / (y0[-1] - 100) == pytest.approx(1.1, rel=1e-3)
    # friction decelerates a coasting head
    fr = base.copy(effects=[Friction(0.01)])
    dp = fr.discretize(DT); dp.reset(0.0, velocity=1e5, current=0.0)
    v0 = dp.x[1]
    for _ in range(5):
        dp.step(0.0)
    assert dp.x[1] == pytest.approx(v0 - 5 * DT * K0 * 0.01)
    # position bias table is a force added to the bias
    pb = PositionBias([0.0, 1000.0], [0.0, 0.01])
    assert pb.force(500.0, 0.0) == pytest.approx(0.005)
    # periodic disturbance on the output
    pd = PeriodicDisturbance(120.0, [1, 2], [0.1, 0.0], [0.0, 0.05])
    assert pd.output(0.0) == pytest.approx(0.1)
    per = base.copy(effects=[pd])
    yp = per.simulate_open_loop(np.zeros(10), DT, history_a=0.0)
    assert np.allclose(yp, pd.output(np.arange(10) * DT))


def test_effect_registry_round_trip():
    for e in (InputDelay(1e-6), AmplifierLag(2000.0), PivotSpringDamper(20.0, 0.2, 5.0), ExtraMode(800, 0.02, 0.01),
              CurrentSaturation(0.5), TorqueConstantVariation([0.02, -0.01]), PositionBias([0, 1], [0, 1e-3]),
              Friction(1e-3, 1e-8), PeriodicDisturbance(120.0, [1], [0.1], [0.2])):
        assert effect_from_dict(json.loads(json.dumps(e.to_dict()))) == e
    with pytest.raises(ValueError):
        effect_from_dict({"effect": "warp_drive", "params": {}})
