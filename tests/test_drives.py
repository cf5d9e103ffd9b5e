"""The independent test drive (tests/drives) against itself, against exact formulas, and against
seekopt's own synthetic drive (which steps the plant with identification/model/discrete.py).

The comparison with ``seekopt.evaluate.synth`` is what catches an error in the shared
discretisation: the two share no dynamics code (the drive integrates the continuous plant by
RK4 on a fine grid between the exact break points of the delayed, held commands and steps its
own copy of the controller), so an error in one of them (delay, sub-step hold, amplifier lag,
mode sign or gain, logged current) shows as a disagreement far above the integration error.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from seekopt.drive.controller import Controller
from seekopt.evaluate.synth import SynthConfig, synthesize
from tests.drives import (PlantStepper, Schedule, TruthPlant, closed_loop_poles, drive_50k, make_log, modal_plant,
                          nss_drive, nss_single_rate_controller, open_loop, rigid_reference, rk4_flow, run)

#: closed-loop positions agree to this [track] when both simulators are exact.  The drive's RK4 with
#: h |eig|max <= 0.002 has a local error ~ (0.002)^5 / 120 ~ 3e-16 relative per step (its period maps
#: match scipy's expm to ~1e-12, test below); positions reach 1e5 tracks (roundoff ~1e-11); measured
#: differences 1e-10 .. 2e-9 track.  1e-6 track is 1e-5 of the 0.1-track settle band: a 1 % error in
#: the delay alone moves the positions by ~0.1 track (test_agreement_test_is_sensitive).
POS_TOL = 1e-6
CUR_TOL = 1e-9      # [A]


def _replay(drive, cfg, plant=None, controller=None, **run_kw):
    """seekopt.synth's log and the independent drive run on the same feedforward and reference."""
    mp = plant or modal_plant(drive)
    log, _ = synthesize(cfg, plant=mp, controller=controller or Controller.from_json(drive.controller.to_json()))
    fs = log.sample_rate_hz
    k = int(round(cfg.preroll_s * fs)) - int(round(0.002 * fs))     # what synth trims off the start
    uff = np.r_[np.zeros(k), log.extra["u_ff_a"]]
    r = np.r_[np.full(k, log.extra["reference_track"][0]), log.extra["reference_track"]]
    tr = run(drive, uff, r, **run_kw)
    return log, tr, k


def _lag_delay(drive):
    return drive.with_plant(drive.plant.with_effects([{"effect": "amplifier_lag", "params": {"bandwidth_hz": 4000.0}},
                                                      {"effect": "input_delay", "params": {"delay_s": 3.3e-6}}]))


CASES = {
    "nss-multirate": (lambda: nss_drive(noise=False), SynthConfig(n_seeks=12, seed=3, noise=False)),
    "nss-single-rate": (lambda: nss_drive(noise=False, controller=nss_single_rate_controller()),
                        SynthConfig(n_seeks=10, seed=4, noise=False)),
    "50k-lag-delay-compdelay": (lambda: _lag_delay(drive_50k(noise=False)),
                                SynthConfig(n_seeks=12, seed=4, noise=False, stroke_track=(0.0, 100000.0), imax_a=0.25)),
    "nss-saturation": (lambda: nss_drive(noise=False).with_plant(
        nss_drive().plant.with_effects([{"effect": "current_saturation", "params": {"limit_a": 0.2}}])),
        SynthConfig(n_seeks=10, seed=5, noise=False)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_agrees_with_seekopt_synth(case):
    """Same plant, same controller, no noise: the logs agree to the integration error."""
    make, cfg = CASES[case]
    drive = make()
    log, tr, k = _replay(drive, cfg)
    dy = np.abs(tr.position_track[k:] - log.position_track).max()
    du = np.abs(tr.current_a[k:] - log.current_a).max()
    print(f"\n{case}: max |position difference| {dy:.3g} track, max |current difference| {du:.3g} A "
          f"over {log.n} samples, seeks up to {np.ptp(log.target_track):.0f} tracks")
    assert dy < POS_TOL and du < CUR_TOL
    if drive.controller.L > 1:
        for j in range(drive.controller.L):
            assert np.abs(tr.current_sub_a[k:, j] - log.extra[f"current_sub{j + 1}_a"]).max() < CUR_TOL


def test_agreement_test_is_sensitive():
    """A 1 % error in the delay (0.17 us) or a missing amplifier lag on one side: far above POS_TOL."""
    make, cfg = CASES["50k-lag-delay-compdelay"]
    drive = make()
    mp = modal_plant(drive)
    for wrong in (mp.copy(delay_s=1.01 * mp.delay_s), mp.copy(effects=[e for e in mp.effects if e.name != "amplifier_lag"])):
        log, tr, k = _replay(drive, cfg, plant=wrong)
        assert np.abs(tr.position_track[k:] - log.position_track).max() > 1e4 * POS_TOL


BIAS = {"effect": "position_bias", "params": {"knots_track": [0.0, 20000.0, 40000.0, 60000.0],
                                               "bias_a": [0.001, -0.0005, 0.0012, -0.001]}}
KT = {"effect": "torque_constant_variation", "params": {"coeffs": [0.05, -0.01], "center_track": 30000.0,
                                                         "scale_track": 20000.0}}
FRICTION = {"effect": "friction", "params": {"coulomb_a": 0.002, "viscous_a_per_tps": 1e-9}}


@pytest.mark.parametrize("effect", [
    BIAS, KT,
    pytest.param(FRICTION, marks=pytest.mark.xfail(strict=True, reason=(
        "measured: synth (force held over each 19 us sub-step) differs from the drive by 0.42 track, 22 % "
        "of the friction's 1.9-track effect (0.46 track from the drive at 64 force nodes per sample; the "
        "drive at 16 vs 64 nodes differs by 0.055 track): Coulomb friction is discontinuous in the "
        "velocity and a sub-step hold of it is a coarse integration")))],
    ids=["position_bias", "torque_constant", "friction"])
def test_state_dependent_effects_agree_with_synth_within_the_hold_error(effect):
    """With a state-dependent force the two differ by how often the force is evaluated: synth holds it
    over a sub-step (Ts/L; Kt(p) is also applied before the delay, at the commanding instant), the
    drive re-evaluates it 16 times per sample.  Tolerance: 1 % of the effect's own size (max change of
    the positions when the effect is switched on).  Measured: the drive at 2 vs 64 nodes differs by
    0.2 % (bias) and 0.1 % (Kt) of the effect, synth by 0.37 % and 0.43 %; a wrong sign, table or unit
    changes the result by the whole effect."""
    drive = nss_drive(noise=False)
    cfg = SynthConfig(n_seeks=12, seed=5, noise=False)
    with_effect = drive.with_plant(drive.plant.with_effects([effect]))
    log, tr, k = _replay(with_effect, cfg)
    _, base, _ = _replay(drive, cfg)
    size = np.abs(tr.position_track - base.position_track)[k:].max()
    diff = np.abs(tr.position_track[k:] - log.position_track).max()
    print(f"\n{effect['effect']}: effect {size:.3g} track, synth vs drive {diff:.3g} track ({100 * diff / size:.2f} %)")
    assert size > 0.1
    assert diff < 0.01 * size


# ------------------------------------------------------------------------------------ the drive itself
def test_rk4_flow_matches_matrix_exponential():
    p = drive_50k(noise=False).plant.with_effects([{"effect": "amplifier_lag", "params": {"bandwidth_hz": 3000.0}}])
    A, bc, bf, _, _ = p.continuous()
    M = np.zeros((A.shape[0] + 2,) * 2)
    M[:-2, :-2], M[:-2, -2], M[:-2, -1] = A, bc, bf
    h = 1 / 50400.0
    E, ref = rk4_flow(M, h), expm(M * h)
    assert np.abs(E - ref).max() < 1e-9 * np.abs(ref).max()


def test_open_loop_rigid_body_is_the_exact_double_integral():
    """Rigid body with a fractional delay: the fine-grid stepping equals the closed-form response
    ``k0 sum_j u_j [R(t - j Ts - tau) - R(t - (j+1) Ts - tau)]`` (also written in tests/drives)."""
    fs, k0, tau = 26400.0, 3.9e9, 2.37 / 26400.0
    u = np.r_[0.0, np.random.default_rng(0).normal(size=300) * 0.1]
    y = open_loop(TruthPlant(k0=k0, delay_s=tau), u, fs, history_a=0.0)
    ref = rigid_reference(u, k0, fs, tau, len(u))
    assert np.abs(y - ref).max() < 1e-9 * np.abs(ref).max()


def test_node_stepping_equals_the_period_matrix_on_a_linear_plant():
    drive = _lag_delay(drive_50k(noise=False))
    fast = drive.stepper()
    slow = PlantStepper(drive.plant, drive.sample_rate_hz, 2, drive.computation_delay_s, nodes=7)
    slow.nonlinear = True                                  # force the interval-by-interval path
    u = np.random.default_rng(1).normal(size=(400, 2)) * 0.05
    for st in (fast, slow):
        st.reset(1000.0, 0.01)
    for k in range(len(u)):
        fast.step(u[k], 1e-4)
        slow.step(u[k], 1e-4)
    assert np.abs(fast.x - slow.x).max() < 1e-8 * np.abs(fast.x).max()


def test_torque_constant_behind_an_amplifier_lag_converges_in_the_force_nodes():
    """Kt(p) on a lagged current: the current moves between the force nodes, so a force held at the
    interval's start is first order in the node spacing (16 vs 256 nodes: 0.0068 track after a 0.1 A,
    4-sample pulse from track 9000, Kt 0.86 there; seekopt's model 0.0005 from 256 nodes); the drive
    averages the force at the interval's two ends (measured 9e-5 track)."""
    from dataclasses import replace
    t = nss_drive(noise=False).plant.with_effects([
        {"effect": "torque_constant_variation", "params": {"coeffs": [0.2], "center_track": 30000.0,
                                                          "scale_track": 30000.0}},
        {"effect": "amplifier_lag", "params": {"bandwidth_hz": 3000.0}}])
    u = np.zeros(100)
    u[2:6] = 0.1
    hold, T0 = t.holding_current(9000.0), 9000.0
    y = {}
    for nodes in (16, 256):
        d = replace(nss_drive(t, noise=False), nodes=nodes)
        y[nodes] = run(d, u + hold, np.full(len(u), T0), position0=T0, current0=hold).true_position_track - T0
    assert np.abs(y[16]).max() > 5.0                        # the pulse moves the head by tracks
    assert np.abs(y[16] - y[256]).max() < 5e-4


def test_drives_are_stable_and_logs_settle():
    for drive in (nss_drive(noise=False), drive_50k(noise=False)):
        assert np.max(np.abs(closed_loop_poles(drive))) < 0.9995
    log = make_log(drive_50k(), Schedule(n_seeks=6, seed=2, stroke_track=(0.0, 100000.0)))
    assert log.sample_rate_hz == 50400.0 and log.input_current().shape[1] == 2
    assert log.metadata["generator"] == "tests.drives" and log.metadata["sectors"] == "420"
    a = make_log(drive_50k(), Schedule(n_seeks=6, seed=2, stroke_track=(0.0, 100000.0)))
    np.testing.assert_array_equal(a.position_track, log.position_track)       # deterministic for a seed
