"""Each effect is written once: its numpy and CasADi evaluations agree (exact mode to 1e-12, the
smoothed mode converges to it), and so does the stepping engine's transition."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from identification.model.effects import (EFFECTS, AmplifierLag, CurrentSaturation, ExtraMode, Friction, InputDelay,
                                          PeriodicDisturbance, PivotSpringDamper, PositionBias,
                                          TorqueConstantVariation)
from identification.model.ops import NUMPY, SmoothingSettings, casadi_ops, numpy_ops
from identification.model.plant import ModalPlant, Mode

#: one instance of every library effect (the test fails when an effect is added without one)
EXAMPLES = {
    "input_delay": InputDelay(7e-6),
    "amplifier_lag": AmplifierLag(3000.0),
    "pivot_spring_damper": PivotSpringDamper(30.0, 0.1, 120.0),
    "extra_mode": ExtraMode(900.0, 0.05, 0.01),
    "current_saturation": CurrentSaturation(0.3),
    "torque_constant_variation": TorqueConstantVariation([0.08, -0.05, 0.02], 500.0, 2000.0),
    "position_bias": PositionBias([-1000.0, 0.0, 800.0, 3000.0], [0.004, -0.002, 0.001, 0.006]),
    "friction": Friction(0.002, 3e-8),
    "periodic_disturbance": PeriodicDisturbance(120.0, [1, 2, 5], [0.3, -0.1, 0.02], [0.05, 0.2, -0.01]),
}


def test_every_effect_has_an_example():
    assert set(EXAMPLES) == set(EFFECTS)
    assert all(type(EXAMPLES[k]) is EFFECTS[k] for k in EFFECTS)


def _points(n=400, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.uniform(-0.8, 0.8, n)                       # A, beyond the saturation limit too
    p = rng.uniform(-3000.0, 6000.0, n)                 # track, beyond the tables' ends too
    v = rng.normal(0.0, 2e5, n)                         # track/s
    v[::7] = 0.0                                        # sign(0) exactly
    p[::11] = 800.0                                     # on a knot
    t = rng.uniform(0.0, 0.05, n)                       # s
    return u, p, v, t


def _hooks(effect, ops):
    """The three hooks as functions of scalar symbols/numbers."""
    return (lambda u, p: effect.input_map(u, p, ops), lambda p, v: effect.force(p, v, ops),
            lambda t: effect.output(t, ops))


def _casadi_eval(effect, sym, smooth=None):
    """CasADi Functions of the three hooks, built from ``sym`` (SX or MX) symbols."""
    ops = casadi_ops(smooth)
    u, p, v, t = (sym.sym(k) for k in "upvt")
    fi, ff, fo = _hooks(effect, ops)
    F = ca.Function("hooks", [u, p, v, t], [fi(u, p), ff(p, v), fo(t)])
    return lambda uu, pp, vv, tt: [np.asarray(a).ravel() for a in F(uu, pp, vv, tt)]


def _numpy_eval(effect, ops=NUMPY, vectorised=True):
    fi, ff, fo = _hooks(effect, ops)
    if vectorised:
        return lambda u, p, v, t: [np.broadcast_to(fi(u, p), u.shape), np.broadcast_to(ff(p, v), u.shape),
                                   np.broadcast_to(fo(t), u.shape)]
    return lambda u, p, v, t: [np.array([fi(float(a), float(b)) for a, b in zip(u, p)]),
                               np.array([ff(float(a), float(b)) for a, b in zip(p, v)]),
                               np.array([fo(float(a)) for a in t])]


@pytest.mark.parametrize("name", sorted(EXAMPLES))
@pytest.mark.parametrize("sym", [ca.SX, ca.MX], ids=["SX", "MX"])
def test_casadi_equals_numpy_exact(name, sym):
    e = EXAMPLES[name]
    u, p, v, t = _points()
    ref = _numpy_eval(e)(u, p, v, t)
    scalar = _numpy_eval(e, vectorised=False)(u, p, v, t)     # scalar calls == array calls
    got = _casadi_eval(e, sym)(u, p, v, t)
    for a, b, c in zip(ref, scalar, got):
        scale = max(1.0, np.max(np.abs(a)))
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(c, a, rtol=0, atol=1e-12 * scale)


def test_hooks_match_their_definitions():
    """The hooks compute the documented formulas (independent restatement, numbers only)."""
    u, p, v, t = _points(50)
    sat, kt, pb, fr, pd = (EXAMPLES[k] for k in ("current_saturation", "torque_constant_variation",
                                                 "position_bias", "friction", "periodic_disturbance"))
    assert np.array_equal(sat.input_map(u, p), np.clip(u, -0.3, 0.3))
    x = (p - 500.0) / 2000.0
    np.testing.assert_allclose(kt.input_map(u, p), u * (1 + 0.08 * x - 0.05 * x ** 2 + 0.02 * x ** 3), rtol=1e-14)
    assert np.array_equal(pb.force(p, v), np.interp(p, pb.knots_track, pb.bias_a))
    np.testing.assert_allclose(fr.force(p, v), -0.002 * np.sign(v) - 3e-8 * v, rtol=1e-14)
    w = 2 * np.pi * 120.0
    ref = sum(a * np.cos(h * w * t) + b * np.sin(h * w * t) for h, a, b in zip([1, 2, 5], pd.cos_track, pd.sin_track))
    np.testing.assert_allclose(pd.output(t), ref, rtol=0, atol=1e-14)
    assert EXAMPLES["pivot_spring_damper"].rest_force_a(4e9) == pytest.approx((2 * np.pi * 30) ** 2 * 120 / 4e9)


@pytest.mark.parametrize("name", ["current_saturation", "position_bias", "friction"])
def test_smoothed_mode_converges(name):
    """Smoothed maps approach the exact ones as the stated width shrinks; numpy and CasADi smooth alike."""
    e = EXAMPLES[name]
    u, p, v, t = _points(300, seed=1)
    keep = np.abs(v) > 1e3                         # friction: away from v = 0 the tanh converges
    exact = _numpy_eval(e)(u, p, v, t)
    errs = []
    for s in (1.0, 0.1, 0.01, 0.001):
        sm = SmoothingSettings(friction_velocity_tps=1e3 * s, saturation_width_a=0.05 * s, table_width_track=100.0 * s)
        a = _numpy_eval(e, numpy_ops(sm))(u, p, v, t)
        c = _casadi_eval(e, ca.SX, sm)(u, p, v, t)
        for x, y in zip(a, c):
            np.testing.assert_allclose(y, x, rtol=0, atol=1e-12 * max(1.0, np.max(np.abs(x))))
        errs.append(max(np.max(np.abs((x - y)[keep])) for x, y in zip(a, exact)))
    assert errs[0] > 0
    assert all(b < a or b == 0.0 for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] <= 1e-3 * errs[0], errs
    # the smooth saturation's stated error bound: w / 2 at a corner
    sm = SmoothingSettings(saturation_width_a=0.02)
    x = np.linspace(-1, 1, 2001)
    assert np.max(np.abs(numpy_ops(sm).clip(x, -0.3, 0.3) - np.clip(x, -0.3, 0.3))) <= 0.01 + 1e-15


def test_smoothing_settings_are_data():
    sm = SmoothingSettings(friction_velocity_tps=50.0, saturation_width_a=0.01)
    assert SmoothingSettings.from_dict(sm.to_dict()) == sm and not sm.exact and SmoothingSettings().exact
    with pytest.raises(ValueError, match="saturation_width_a"):
        SmoothingSettings(saturation_width_a=-1.0)


def test_smoothed_maps_are_differentiable_for_ipopt():
    """Smoothed: CasADi's derivative equals a central difference everywhere, corners included."""
    sm = SmoothingSettings(friction_velocity_tps=50.0, saturation_width_a=0.01, table_width_track=20.0)
    ops = casadi_ops(sm)
    x = ca.SX.sym("x")
    cases = [(EXAMPLES["current_saturation"].input_map(x, 0.0, ops), [-0.3, 0.0, 0.3, 0.31]),
             (EXAMPLES["position_bias"].force(x, 0.0, ops), [-1000.0, 0.0, 800.0, 3000.0, 1234.5]),
             (EXAMPLES["friction"].force(0.0, x, ops), [0.0, 10.0, -40.0])]
    for expr, at in cases:
        f = ca.Function("f", [x], [expr])
        df = ca.Function("df", [x], [ca.jacobian(expr, x)])
        for a in at:
            h = 1e-6 * max(1.0, abs(a))
            fd = (float(f(a + h)) - float(f(a - h))) / (2 * h)
            assert float(df(a)) == pytest.approx(fd, rel=1e-5, abs=1e-9)


def _full_plant():
    return ModalPlant(k0=4e9, modes=[Mode(420.0, 0.06, 0.0015), Mode(1738.0, 0.03, 0.02)], bias_a=0.003,
                      delay_s=1.9e-5, effects=list(EXAMPLES.values()))


@pytest.mark.parametrize("sym", ["SX", "MX"])
def test_engine_transition_casadi_equals_numpy(sym):
    """One step of the stepping engine (every effect) on CasADi symbols == on numbers."""
    dp = _full_plant().discretize(1.0 / 52800)
    F, Y = dp.casadi_functions(sym=sym)
    rng = np.random.default_rng(2)
    x0, h0 = dp.rest_state(700.0)
    for _ in range(20):
        x = x0 + rng.normal(size=dp.n) * np.r_[2000.0, 2e5, np.full(dp.n - 2, 1e-3)]
        h = h0 + 0.2 * rng.normal(size=dp.m + 1)
        u, t = rng.uniform(-0.6, 0.6), rng.uniform(0, 0.05)
        xn, hn = dp.transition(x, h, u, t)
        xc, hc = F(x, h, u, t)
        np.testing.assert_allclose(xc.full().ravel(), xn, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(hc.full().ravel(), hn, rtol=0, atol=1e-15)
        assert float(Y(x, t)) == pytest.approx(dp.measure(x, t), rel=1e-14)
