"""One dynamics engine: every propagation of a plant equals ``identification.model.discrete`` stepping.

One plant with vibration modes, an input delay of a fractional number of samples (at the servo
rate and at the sub-step), a multirate sub-step hold (L = 2) and every library effect; each path
(the pure transition on numbers and on CasADi symbols, the vectorised linear response, the open-loop
simulation, the 2DOF simulator, the identification regressors, the loop's linear engine and residual
simulation, the design's Toeplitz maps and the rigid closed form) is compared with stepping
``DiscretePlant`` sample by sample.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from identification.estimate.gains import mode_regressors
from identification.estimate.rigid import zoh_rigid_response
from identification.logs.seeklog import SeekLog
from identification.loop.residual import LinearModel, Windows, simulate
from identification.model.discrete import substep_hold
from identification.model.effects import (AmplifierLag, CurrentSaturation, ExtraMode, Friction, InputDelay,
                                          PeriodicDisturbance, PivotSpringDamper, PositionBias,
                                          TorqueConstantVariation)
from identification.model.plant import ModalPlant, Mode
from seekopt.design.profiles import rigid_endpoint_matrix
from seekopt.design.qp import LoopMaps
from seekopt.drive.controller import Controller
from seekopt.drive.simulator import simulate_2dof

FS = 26400.0                       # servo rate [Hz]
L = 2                              # current sub-steps per servo sample
TS, DT = 1.0 / FS, 1.0 / (FS * L)
K0 = 3.937e9
MODES = [Mode(420.0, 0.06, 0.0015), Mode(1738.0, 0.03, 0.02), Mode(4100.0, 0.03, -0.05)]
DELAY_S = 2.3 * DT                 # + InputDelay below: 2.37 sub-steps, 1.185 servo samples
LINEAR_EFFECTS = [InputDelay(0.07 * DT), AmplifierLag(6000.0), PivotSpringDamper(25.0, 0.1, 150.0),
                  ExtraMode(2900.0, 0.04, 0.004)]
NONLINEAR_EFFECTS = [CurrentSaturation(0.25), TorqueConstantVariation([0.06, -0.03], 300.0, 2000.0),
                     PositionBias([-500.0, 0.0, 400.0, 1500.0], [0.003, -0.002, 0.001, 0.004]), Friction(0.002, 2e-8)]
OUTPUT_EFFECTS = [PeriodicDisturbance(120.0, [1, 3], [0.2, -0.05], [0.1, 0.03])]


def full_plant(**kw) -> ModalPlant:
    return ModalPlant(k0=K0, modes=list(MODES), bias_a=0.003, delay_s=DELAY_S,
                      effects=LINEAR_EFFECTS + NONLINEAR_EFFECTS + OUTPUT_EFFECTS, **kw)


def linear_plant(**kw) -> ModalPlant:
    """Structural and output effects only (no state-dependent maps)."""
    return full_plant().copy(effects=LINEAR_EFFECTS + OUTPUT_EFFECTS, **kw)


def seek_current(n: int, seed: int = 0) -> np.ndarray:
    """A seek-like current [A]: a sine pulse, a reverse pulse, noise."""
    rng = np.random.default_rng(seed)
    u = 2e-3 * rng.standard_normal(n)
    a = n // 8
    u[a:a + 60] += 0.3 * np.sin(2 * np.pi * np.arange(60) / 60)
    u[4 * a:4 * a + 30] -= 0.2 * np.sin(2 * np.pi * np.arange(30) / 30)
    return u


def step_loop(dp, u, position0=200.0, current=None, t0=0.0, record=False):
    """Reference: ``DiscretePlant`` stepped one sample at a time (output before each step)."""
    dp.reset(position0, 0.0, current=current, t0=t0)
    y, X, cmd, frc = np.empty(len(u)), [], [], []
    for k, uk in enumerate(u):
        y[k] = dp.output()
        if record:
            X.append(dp.x.copy())
            cmd.append(float(dp.command(uk, dp.x[0])))
            frc.append(float(dp.net_force(dp.x[0], dp.x[1])))
        dp.step(uk)
    return (y, np.array(X), np.array(cmd), np.array(frc)) if record else y


def close(a, b, rel=1e-10):
    """``max|a - b| <= rel * max|b|`` (``rel`` absolute when ``b`` is 0): rounding of a recursion run two ways."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    err, scale = np.max(np.abs(a - b)), np.max(np.abs(b))
    assert err <= rel * (scale if scale > 0 else 1.0), f"max diff {err:.3g} vs scale {scale:.3g}"


def test_delay_is_fractional_at_both_rates():
    p = full_plant()
    assert p.discretize(DT).m == 2 and p.discretize(DT).frac == pytest.approx(0.37)
    assert p.discretize(TS).m == 1 and p.discretize(TS).frac == pytest.approx(0.185)


# ------------------------------------------------------------------ the engine itself
def test_pure_transition_and_casadi_rollout_equal_step():
    """``step`` == ``transition``/``measure`` on numbers == the CasADi ``mapaccum`` rollout (every effect)."""
    dp = full_plant().discretize(DT)
    u = np.repeat(seek_current(400), L)
    y_ref = step_loop(dp, u, t0=0.01)
    x, h = dp.rest_state(200.0)
    y = np.empty(len(u))
    for k, uk in enumerate(u):
        t = 0.01 + k * DT
        y[k] = dp.measure(x, t)
        x, h = dp.transition(x, h, uk, t)
    assert np.array_equal(y, y_ref)
    F, Y = dp.casadi_functions()
    roll = F.mapaccum("roll", len(u), 2)              # x and hist accumulated, u and t per step
    x0, h0 = dp.rest_state(200.0)
    t = 0.01 + DT * np.arange(len(u))
    X, _ = roll(x0, h0, u[None, :], t[None, :])
    Xs = np.column_stack([x0, X.full()[:, :-1]])
    y_ca = Y.map(len(u))(Xs, t[None, :]).full().ravel()
    close(y_ca, y_ref, 1e-12)


def test_linear_response_equals_step_single_and_multirate():
    p = linear_plant()
    u = seek_current(500)
    for dt, uu in ((TS, u), (DT, np.repeat(u, L))):
        dp = p.discretize(dt)
        y_ref = step_loop(dp, uu, t0=0.002)
        x0, h0 = dp.rest_state(200.0)
        close(dp.linear_response(uu, x0=x0, hist0=h0, t0=0.002), y_ref, 1e-12)
    # the sub-step hold: (n, L) currents on the Ts/L plant, output at the servo instants
    dp = p.discretize(DT)
    U = np.column_stack([u, -0.5 * u])
    y_ref = step_loop(dp, substep_hold(U)[0], t0=0.0)[::L]
    x0, h0 = dp.rest_state(200.0)
    close(dp.linear_response(U, x0=x0, hist0=h0), y_ref, 1e-12)


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_linear_response_short_sequences_from_any_state(n):
    dp = linear_plant().discretize(DT)
    rng = np.random.default_rng(n)
    x0, h0 = rng.standard_normal(dp.n), rng.standard_normal(dp.m + 1)
    u = rng.standard_normal(n)
    dp.x, dp.hist, dp.k, dp.t0 = x0.copy(), h0.copy(), 0, 0.0
    y_ref = []
    for uk in u:
        y_ref.append(dp.output())
        dp.step(uk)
    close(dp.linear_response(u, x0=x0, hist0=h0), y_ref, 1e-12)


def test_linear_response_replays_nonlinear_stepping():
    """With the commands and forces the nonlinear stepping applied, the fast path reproduces it."""
    dp = full_plant().discretize(DT)
    u = np.repeat(seek_current(400), L)
    y_ref, X, cmd, frc = step_loop(dp, u, record=True)
    x0, h0 = dp.rest_state(200.0)
    close(dp.linear_response(cmd, force=frc - dp.force0, x0=x0, hist0=h0), y_ref, 1e-12)


def test_simulate_open_loop_equals_step():
    p = full_plant()
    u = seek_current(600)
    close(p.simulate_open_loop(u, TS, position0=200.0, t0=0.003), step_loop(p.discretize(TS), u, t0=0.003,
                                                                            current=u[0]), 0)


# ------------------------------------------------------------------ the 2DOF simulator
def test_simulate_2dof_zero_controller_equals_open_loop_stepping():
    zero = Controller("zero", FS, [{"kind": "tf", "num": [0.0], "den": [1.0], "rate_multiple": L}])
    assert zero.fast_multiple == L
    p = full_plant()
    u = seek_current(700)
    r = np.full(len(u), 200.0)
    res = simulate_2dof(p, zero, u, r, t0=0.004, record_substeps=True)
    y_ref = step_loop(p.discretize(DT), np.repeat(u, L), t0=0.004)[::L]
    close(res.true_position_track, y_ref, 1e-13)
    close(res.current_sub_a, np.column_stack([u] * L), 0)


# ------------------------------------------------------------------ identification regressors
@pytest.mark.parametrize("multirate", [False, True], ids=["servo-rate", "substeps"])
def test_mode_regressors_equal_mode_blocks(multirate):
    """eq. (9)'s regressors == each mode block of the stepped plant (steady start), k0 g per unit."""
    p = ModalPlant(k0=K0, modes=list(MODES), delay_s=DELAY_S)
    u = seek_current(600)
    U = np.column_stack([u, 0.7 * u]) if multirate else u
    dt = DT if multirate else TS
    dp = p.discretize(dt)
    uf = substep_hold(U)[0]
    _, X, _, _ = step_loop(dp, uf, position0=0.0, current=uf[0], record=True)
    blocks = np.column_stack([X[:, s] @ dp.C[s] for s in dp.blocks])[::L if multirate else 1]
    Y = mode_regressors(U, [m.freq_hz for m in MODES], [m.zeta for m in MODES], TS, DELAY_S)
    close(Y * (K0 * np.array([m.gain for m in MODES])), blocks[:, 1:], 1e-11)
    x0, h0 = dp.rest_state(0.0, current=uf[0])
    close(dp.linear_response(U, x0=x0, hist0=h0, split=True), blocks, 1e-12)


@pytest.mark.parametrize("multirate", [False, True], ids=["servo-rate", "substeps"])
def test_zoh_rigid_response_equals_rigid_block(multirate):
    """The rigid fit's restarted double integrator == the rigid block stepped with p = v = 0 at each start."""
    u = seek_current(800, seed=3)
    U = np.column_stack([u, -0.3 * u + 0.01]) if multirate else u
    starts = [50, 300, 301, 620]
    got = zoh_rigid_response(U, TS, DELAY_S, starts)
    dp = ModalPlant(k0=1.0, delay_s=DELAY_S).discretize(DT if multirate else TS)
    uf, l = substep_hold(U)
    dp.reset(0.0, current=uf[0])
    ref = np.zeros(len(uf))
    fine_starts = {l * s for s in starts}
    for k, uk in enumerate(uf):
        if k in fine_starts:
            dp.x[:2] = 0.0
        ref[k] = dp.output() if k >= l * starts[0] else 0.0
        dp.step(uk)
    close(got, ref[::l], 1e-10)


# ------------------------------------------------------------------ the loop
def test_loop_linear_model_equals_linear_response():
    """``LinearModel`` (the loop's lfilter engine) == the engine's linear part.  Its rigid block starts
    at rest *with an empty delay line* (the fractional delay's old-part input ``Gamma_old c[-m-1]``
    before sample 0 is left to the window anchors): equal with zero history, equal up to a rigid free
    response from sample 1 on otherwise."""
    p = ModalPlant(k0=K0, modes=list(MODES), delay_s=DELAY_S * 2, effects=LINEAR_EFFECTS)
    dp = p.discretize(TS)
    u = seek_current(900)
    force = np.full(len(u), dp.force0) + 1e-3 * np.sin(np.arange(len(u)) / 30)
    lm = LinearModel(p, TS)
    for hc in (0.0, 0.05):
        rigid, flex = lm.response(u, force, hist_cmd=[hc], split=True)
        x0 = np.zeros(dp.n)
        for i, md in enumerate(p.all_modes()):
            x0[2 + 2 * i] = K0 * md.gain * (hc + force[0]) / md.omega ** 2
        x0[dp.lag] = hc
        Y = dp.linear_response(u, force=force - dp.force0, x0=x0, hist0=np.full(dp.m + 1, hc), split=True)
        close(flex, Y[:, 1:].sum(axis=1), 1e-10)
        e = rigid - Y[:, 0]
        assert e[0] == 0.0
        B = lm.free_basis(len(u) - 1)                  # free response from sample 1
        c = np.linalg.lstsq(B, e[1:], rcond=None)[0]
        close(e[1:] - B @ c, 0 * e[1:], 1e-10 * np.max(np.abs(Y[:, 0])))
        if hc == 0.0:
            close(rigid, Y[:, 0], 1e-10)


def test_loop_residual_simulate_equals_step():
    """The loop's reference simulation of a log made by stepping the same plant leaves no residual."""
    p = linear_plant(bias_a=0.002)
    dp = p.discretize(TS)
    u = seek_current(1200)
    y = step_loop(dp, u, position0=200.0, current=u[0], t0=0.0)
    t = np.arange(len(u)) * TS
    log = SeekLog(t, u, y, np.full(len(u), 200.0), FS)
    w = Windows([(0, 300), (300, 700), (700, 1200)], [0, 0, 0])
    res = simulate(p, log, w, continuous=True)
    assert np.max(np.abs(res.e)) < 1e-9 * np.max(np.abs(y))


# ------------------------------------------------------------------ the design maps
def test_loop_maps_equal_simulate_2dof():
    """The QP's Toeplitz maps (closed_loop_responses) == the 2DOF simulator on the linear part (the
    map current -> position: no bias, no pivot rest offset; the rest offset of 150 track is an affine
    force that once made the 'impulse responses' drift by 114 track in 400 samples)."""
    ctrl = Controller.nss()
    assert ctrl.fast_multiple == L
    p = ModalPlant(k0=K0, modes=list(MODES), delay_s=DELAY_S, effects=LINEAR_EFFECTS)
    n = 400
    maps = LoopMaps(p, ctrl, n)
    rng = np.random.default_rng(5)
    u = 0.05 * rng.standard_normal(n)
    r = np.cumsum(0.2 * rng.standard_normal(n))
    lin = p.linear_part()
    assert lin.discretize(DT).force0 == 0.0
    res = simulate_2dof(lin, ctrl, u, r, position0=0.0, current0=0.0, record_substeps=True)
    Tyu, Tyr, _ = maps.position_rows(np.arange(n), n)
    close(Tyu @ u + Tyr @ r, res.true_position_track, 1e-9)
    Tiu, Tir, _ = maps.current_rows(n, n)
    close(Tiu @ u + Tir @ r, res.current_sub_a.ravel(), 1e-9)


@pytest.mark.parametrize("delay_samples", [0.0, 1.185])
def test_rigid_endpoint_matrix_equals_rigid_stepping(delay_samples):
    """``rigid_endpoint_matrix`` (closed form of the ZOH double integrator) == stepping the rigid body."""
    n = 37
    u = np.random.default_rng(6).standard_normal(n)
    M = rigid_endpoint_matrix(n, K0, TS)
    dp = ModalPlant(k0=K0, delay_s=delay_samples * TS).discretize(TS)
    if delay_samples:                      # delay shifts the motion: compare rest-to-rest seeks
        u -= M[1] @ u / M[1].sum()         # zero end velocity
    dp.reset(0.0, current=0.0)
    for uk in np.r_[u, np.zeros(dp.m + (dp.frac > 0))]:    # the whole of u through the delay line
        dp.step(uk)
    end = np.array([dp.x[0], dp.x[1] * TS])
    close(end, M @ u, 1e-12)


def test_flutter_filter_is_the_one_zoh():
    """The simulator's flutter filter (through ``model.discrete.zoh``) samples the continuous
    ``a 2 zeta w^2 / (s^2 + 2 zeta w s + w^2)`` exactly under a held input (independent check:
    ``scipy.signal.lsim`` of the continuous system on a 20x finer grid, input held)."""
    from scipy import signal
    from seekopt.drive.simulator import flutter_filter
    term = {"freq_hz": 3100.0, "zeta": 0.02, "peak_gain_track": 0.004}
    b, a = flutter_filter(term, TS)
    e = np.random.default_rng(7).standard_normal(60)
    y = signal.lfilter(b, a, e)
    w, z = 2 * np.pi * 3100.0, 0.02
    sub = 20
    t = np.arange(60 * sub) * TS / sub
    _, yc, _ = signal.lsim((np.array([0.004 * 2 * z * w * w]), np.array([1.0, 2 * z * w, w * w])),
                           np.repeat(e, sub), t, interp=False)
    assert np.max(np.abs(y - yc[::sub])) < 1e-10 * np.max(np.abs(y))
