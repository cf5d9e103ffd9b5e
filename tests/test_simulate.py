"""The one closed-loop 2DOF simulator."""
import numpy as np
import pytest

from identification.model.plant import ModalPlant
from seekopt.drive.controller import Controller
from seekopt.drive.presets import default_truth_plant, nss_disturbances
from seekopt.design.profiles import reference_from_model, shortest_baseline
from seekopt.drive.simulator import closed_loop_responses, simulate_2dof

FS = 26400.0


@pytest.fixture(scope="module")
def ctrl():
    return Controller.nss()


def test_step_reference_converges(ctrl):
    p = default_truth_plant(bias_a=0.004)
    r = np.ones(3000)
    res = simulate_2dof(p, ctrl, np.zeros(3000), r, position0=0.0)
    assert abs(res.true_position_track[-1] - 1.0) < 1e-3   # integral action holds the bias


def test_model_following_needs_no_feedback(ctrl):
    """With the plant equal to the reference model, the 2DOF loop leaves the feedback idle."""
    rigid = ModalPlant(k0=3.937e9, delay_s=1e-5)
    u = shortest_baseline("sine", 200.0, rigid.k0, FS, 0.3)
    r = reference_from_model(rigid, u, FS, 400)
    res = simulate_2dof(rigid, ctrl, u, r, position0=0.0)
    assert np.max(np.abs(res.error_track)) < 1e-6
    assert np.max(np.abs(res.feedback_a)) < 1e-9


def test_closed_loop_responses_superpose(ctrl):
    p = default_truth_plant(bias_a=0.0)
    n = 300
    imp = closed_loop_responses(p, ctrl, n)
    rng = np.random.default_rng(1)
    u = rng.standard_normal(n) * 0.01
    r = np.cumsum(rng.standard_normal(n))
    res = simulate_2dof(p, ctrl, u, r, position0=0.0, current0=0.0)
    y = np.convolve(imp["y_uff"], u)[:n] + np.convolve(imp["y_r"], r)[:n]
    assert np.allclose(res.true_position_track, y, atol=1e-8 * np.max(np.abs(y)))
    sub = np.stack([np.convolve(imp["u_sub_uff"][:, j], u)[:n] + np.convolve(imp["u_sub_r"][:, j], r)[:n]
                    for j in range(ctrl.fast_multiple)], axis=1)
    res2 = simulate_2dof(p, ctrl, u, r, position0=0.0, current0=0.0, record_substeps=True)
    assert np.allclose(res2.current_sub_a, sub, atol=1e-10)
    assert res2.peak_current_a == pytest.approx(np.abs(sub).max())


def test_disturbances_deterministic_and_rro_periodic():
    d = nss_disturbances(seed=3)
    a = d.output_disturbance(2000, FS)
    b = nss_disturbances(seed=3).output_disturbance(2000, FS)
    assert np.array_equal(a, b)
    quiet = nss_disturbances(seed=3)
    quiet.sensor_noise_track = 0.0
    quiet.flutter = []
    rro = quiet.output_disturbance(880, FS)
    assert np.allclose(rro[:220], rro[220:440])           # one revolution = 220 samples at 26.4 kHz
    assert 0.05 < np.std(a) < 1.0
