"""Residual simulation and analysis (identification.loop.residual): the fast linear engine equals
DiscretePlant stepping, windows, and the statistical tests behave as stated on known signals."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from identification.model.effects import AmplifierLag, ExtraMode, InputDelay, PivotSpringDamper
from identification.logs.seeklog import SeekLog
from identification.loop.analysis import (correlations, detect_spindle, nonlinear_tests, spectra,
                                          synchronous_average)
from identification.loop.linear import LinearModel
from identification.loop.residual import fit_percent, simulate
from identification.loop.windows import Windows, seek_windows
from tests.drives import Schedule, make_log, modal_plant, nss_drive


@pytest.fixture(scope="module")
def small_log():
    """10 seeks of the NSS-like independent drive (tests/drives) with the benchmark's noise."""
    drive = nss_drive(seed=3)
    return make_log(drive, Schedule(n_seeks=10, seed=3)), modal_plant(drive)


def _project(windows, basis, x):
    out = []
    for a, b in windows.bounds:
        Q, _ = np.linalg.qr(basis(b - a))
        out.append(x[a:b] - Q @ (Q.T @ x[a:b]))
    return np.concatenate(out)


@pytest.mark.parametrize("effects", [[], [AmplifierLag(3000.0)], [InputDelay(2.3e-5)],
                                     [PivotSpringDamper(8.0, 0.2, 30000.0)],
                                     [ExtraMode(700.0, 0.05, 0.003), AmplifierLag(5000.0)]],
                         ids=["plain", "lag", "delay", "pivot", "mode+lag"])
def test_linear_engine_equals_discrete_plant(small_log, effects):
    log, truth = small_log
    plant = truth.copy(effects=effects)
    w = seek_windows(log)
    ref = simulate(plant, log, w, continuous=False, engine="step")   # DiscretePlant stepped, each seek from rest
    u = log.input_current()                                  # (n, L): the drive's sub-step currents
    lm = LinearModel(plant, log.dt, u.shape[1])
    force = np.full(log.n, plant.bias_a)
    if effects and isinstance(effects[0], PivotSpringDamper):
        force += (2 * np.pi * effects[0].freq_hz) ** 2 * effects[0].rest_track / plant.k0
    e = _project(w, lm.free_basis, log.position_track - lm.response(u, force, w))
    assert np.max(np.abs(e - ref.e)) < 1e-6 * max(1.0, np.max(np.abs(ref.e)))


@pytest.mark.parametrize("continuous", [False, True])
def test_reference_simulation_engines_agree(small_log, continuous):
    """``simulate``'s linear-engine path equals stepping ``DiscretePlant`` for every effect that
    does not depend on the state (saturation, run-out, lag, delay, extra mode), with records."""
    from identification.model.effects import CurrentSaturation, PeriodicDisturbance
    log, truth = small_log
    plant = truth.copy(effects=[CurrentSaturation(0.2), AmplifierLag(4000.0), InputDelay(7e-6),
                                ExtraMode(900.0, 0.04, 0.002), PeriodicDisturbance(120.0, [1, 3], [0.1, 0.02], [0.05, 0.0])])
    w = seek_windows(log)
    a = simulate(plant, log, w, continuous=continuous, engine="step", record=True)
    b = simulate(plant, log, w, continuous=continuous, engine="filter", record=True)
    assert np.max(np.abs(a.e - b.e)) < 1e-6 * max(1.0, np.max(np.abs(a.e)))
    k = w.index()
    assert np.allclose(a.cmd[k], b.cmd[k]) and np.allclose(a.force[k], b.force[k])


def test_exact_model_leaves_small_residual_without_noise():
    drive = nss_drive(noise=False)
    log, truth = make_log(drive, Schedule(n_seeks=8, seed=4), noise_seed=None), modal_plant(drive)
    res = simulate(truth, log, seek_windows(log), continuous=False)
    # only the servo-rate ZOH of the mean sub-step current differs from the drive
    assert res.rms < 0.05
    assert res.fit_percent > 99.99


def test_seek_windows_split_and_groups(small_log):
    log, _ = small_log
    w = seek_windows(log, max_len_s=0.004)
    L = int(round(0.004 * log.sample_rate_hz))
    assert all(b - a <= L + 32 for a, b in w.bounds)
    assert all(b1 <= a2 for (_, b1), (a2, _) in zip(w.bounds, w.bounds[1:]))
    fit, val = w.split(2)
    assert not set(fit.groups) & set(val.groups)          # a seek is either fit or validation
    assert fit.n_samples + val.n_samples == w.n_samples


def test_fit_percent_definition(small_log):
    log, _ = small_log
    w = Windows([(100, 400)])
    y = log.position_track[100:400]
    assert fit_percent(log, w, np.zeros(300)) == pytest.approx(100.0)
    assert fit_percent(log, w, y - y.mean()) == pytest.approx(0.0)


def _fake_log(n, fs=10000.0):
    t = np.arange(n) / fs
    z = np.zeros(n)
    return SeekLog(t, z, z.copy(), z.copy(), fs)


def test_ljung_band_is_valid_for_coloured_independent_signals():
    rng = np.random.default_rng(0)
    n = 40000
    w = Windows([(a, a + 2000) for a in range(0, n, 2000)])
    viol_ljung, viol_white = [], []
    for _ in range(6):
        e = lfilter([1.0], [1.0, -0.9], rng.standard_normal(n))     # coloured, independent
        u = lfilter([1.0], [1.0, -0.8], rng.standard_normal(n))
        c = correlations(e, u, w, max_lag=30)
        viol_ljung.append(np.mean(np.abs(c.cross) > c.cross_band))
        viol_white.append(np.mean(np.abs(c.cross) > 1.96 / np.sqrt(n)))
    assert np.mean(viol_ljung) < 0.12                            # ~5 % nominal
    assert np.mean(viol_white) > 2 * max(np.mean(viol_ljung), 0.05)   # the white band is wrong here


def test_whiteness_and_cross_correlation_detect_dependence():
    rng = np.random.default_rng(1)
    n = 20000
    w = Windows([(a, a + 1000) for a in range(0, n, 1000)])
    u = rng.standard_normal(n)
    e = np.r_[0.0, 0.0, 0.8 * u[:-2]] + 0.3 * rng.standard_normal(n)   # depends on u(t - 2)
    c = correlations(e, u, w, max_lag=10)
    assert 2 in c.past_input_violations
    white = correlations(rng.standard_normal(n), u, w, max_lag=50)
    assert white.whiteness_fraction < 0.15


def test_coherence_peak_for_unmodelled_resonance():
    rng = np.random.default_rng(2)
    fs, n = 10000.0, 60000
    w = Windows([(a, a + 3000) for a in range(0, n, 3000)])
    u = rng.standard_normal(n)
    from scipy.signal import butter
    b, a = butter(2, [700 / (fs / 2), 900 / (fs / 2)], btype="band")
    e = lfilter(b, a, u) + 0.05 * rng.standard_normal(n)
    e += 0.3 * rng.standard_normal(n) * np.std(e) / 0.3                # as much noise as signal
    sp = spectra(e, u, w, fs, nperseg=256)
    f, coh = sp.coherent_peaks(max_peaks=1)[0]
    assert 650 < f < 950 and coh > 0.5
    far = (sp.f > 2500) & (sp.f < 4500)
    assert np.median(sp.coh[far]) < 2 * sp.coh_band


def test_spindle_detection_and_synchronous_average():
    rng = np.random.default_rng(3)
    fs, n, f0 = 20000.0, 60000, 87.3
    t = np.arange(n) / fs
    w = Windows([(a, a + 400) for a in range(0, n, 500)])
    walk = np.cumsum(np.cumsum(rng.standard_normal(n))) * 5e-4        # ~0.2 rms after the anchors
    e = walk + 0.2 * np.sin(2 * np.pi * f0 * t) + 0.05 * np.sin(4 * np.pi * f0 * t + 1) + 0.1 * rng.standard_normal(n)
    for a, b in w.bounds:                                               # per-window anchors removed
        B = np.c_[np.ones(b - a), np.arange(b - a)]
        e[a:b] -= B @ np.linalg.lstsq(B, e[a:b], rcond=None)[0]
    (f, score), = detect_spindle(e, w, fs, top=1)
    assert abs(f - f0) < 0.5 and score > 3
    ph, mean, se, frac = synchronous_average(e, t, w, f0, nbins=64)
    assert frac > 0.15                       # the sines are ~30 % of the variance
    ref = 0.2 * np.sin(2 * np.pi * ph) + 0.05 * np.sin(4 * np.pi * ph + 1)
    assert np.corrcoef(mean, ref)[0, 1] > 0.9


def test_nonlinear_tests_flag_quadratic_dependence():
    """Calibrated tests (clusters = windows here): a residual quadratic in the current fires, an
    independent one does not."""
    rng = np.random.default_rng(4)
    n = 20000
    w = Windows([(a, a + 200) for a in range(0, n, 200)])
    u = rng.standard_normal(n)
    y = np.cumsum(u) * 0.01
    lin = nonlinear_tests(0.1 * rng.standard_normal(n), u, y, w)
    quad = nonlinear_tests(0.5 * (u ** 2 - 1) + 0.1 * rng.standard_normal(n), u, y, w)
    m, band = quad["BV_u2_e"]
    assert m > 2 * band
    assert all(v < b for v, b in lin.values()), lin


def test_hybrid_reference_equals_discrete_plant(small_log):
    """The reference simulation of a plant with state-dependent effects (rigid body stepped for
    all seeks at once, modes filtered) equals stepping ``DiscretePlant`` seek by seek, with the
    sub-step currents and several effect evaluations per sub-step."""
    from identification.loop.grid import Grid
    from identification.model.effects import Friction, PositionBias, TorqueConstantVariation
    log, truth = small_log
    lo, hi = np.min(log.position_track), np.max(log.position_track)
    plant = truth.copy(effects=[TorqueConstantVariation([0.05, -0.02], 0.5 * (lo + hi), 0.5 * (hi - lo)),
                                PositionBias([lo, 0.5 * (lo + hi), hi], [0.002, -0.001, 0.003]),
                                Friction(0.002, 1e-9), AmplifierLag(4000.0), InputDelay(7e-6),
                                ExtraMode(900.0, 0.04, 0.002)])
    w = seek_windows(log)
    grid = Grid(log, effect_step_s=6e-6)
    assert grid.M > 1
    a = simulate(plant, log, w, continuous=False, engine="step", record=True, grid=grid)
    b = simulate(plant, log, w, continuous=False, engine="hybrid", record=True, grid=grid)
    assert np.max(np.abs(a.e - b.e)) < 1e-6 * max(1.0, np.max(np.abs(a.e)))
    k = w.index()
    assert np.allclose(a.cmd[k], b.cmd[k]) and np.allclose(a.force[k], b.force[k])
    assert np.allclose(a.state[k], b.state[k])
