"""Tests for identification.estimate.gains: the mode regressors (plant.py's discretisation), the paper's
eqs. (9)-(11), the variable-projection problem and its noise model / covariance helpers.

Data are made by the independent open-loop simulation of ``tests/drives`` (continuous plant, RK4 on a
fine grid, exact hold and delay), so an error in the package's discretisation cannot cancel; the
regressors are also compared with the package's own DiscretePlant (one discretisation, issue 9)."""
import numpy as np
import pytest

from identification.estimate.gains import modal_gains, mode_filters, mode_regressors, mode_response
from identification.estimate.linalg import sandwich_cov
from identification.estimate.varpro import VarPro, ar_whitener, detect_period, fir_filter, periodic_columns
from identification.model.plant import ModalPlant, Mode
from tests.drives import TruthPlant, open_loop

FS = 26400.0
DT = 1.0 / FS
K0 = 3.937e9
MODES = [Mode(420.0, 0.06, 0.0015), Mode(1738.0, 0.03, 0.02), Mode(4100.0, 0.03, -1.0)]


def truth(modes=(), bias_a=0.0, delay_s=0.0):
    """The independent drive's plant (tests/drives) with these numbers."""
    return TruthPlant(k0=K0, modes=tuple((m.freq_hz, m.zeta, m.gain) for m in modes), bias_a=bias_a, delay_s=delay_s)


def current(n=3000, seed=0):
    """Seek-like current: random bursts of sine with quiet gaps, plus a little noise."""
    rng = np.random.default_rng(seed)
    u = 1e-3 * rng.normal(size=n)
    for a in range(100, n - 100, 400):
        m = int(rng.integers(15, 60))
        u[a:a + m] += 0.2 * rng.uniform(0.5, 1) * np.sin(2 * np.pi * np.arange(m) / m)
    return u


@pytest.mark.parametrize("delay_samples", [0.0, 0.264, 1.0, 2.4])
def test_mode_response_is_plant_py_discretisation(delay_samples):
    """mode plant minus rigid plant simulated by DiscretePlant == k0 g * mode_response (exact)."""
    u = current(800)
    for m in MODES:
        full = ModalPlant(k0=K0, modes=[m], delay_s=delay_samples * DT).simulate_open_loop(u, DT)
        rigid = ModalPlant(k0=K0, delay_s=delay_samples * DT).simulate_open_loop(u, DT)
        y = K0 * m.gain * mode_response(u, m.freq_hz, m.zeta, DT, delay_samples * DT)
        np.testing.assert_allclose(y, full - rigid, rtol=0, atol=1e-9 * np.abs(full - rigid).max())
        ind = open_loop(truth([m], delay_s=delay_samples * DT), u, FS, modes_only=True)   # independent
        np.testing.assert_allclose(y, ind, rtol=0, atol=1e-9 * np.abs(ind).max())


def test_mode_filter_dc_gain_and_batch():
    fl = mode_filters([420.0, 5000.0], [0.06, 0.01], DT, 1e-5)
    for (b, a), f in zip(fl, (420.0, 5000.0)):
        assert b.sum() / a.sum() == pytest.approx(1.0 / (2 * np.pi * f) ** 2, rel=1e-9)
    u = current(500)
    M = mode_regressors(u, [420.0, 5000.0], [0.06, 0.01], DT, 1e-5)
    np.testing.assert_allclose(M[:, 1], mode_response(u, 5000.0, 0.01, DT, 1e-5), rtol=1e-12)
    # steady start: a constant current gives the static deflection from sample 0
    np.testing.assert_allclose(mode_response(np.full(50, 0.3), 420.0, 0.06, DT), 0.3 / (2 * np.pi * 420) ** 2,
                               rtol=1e-9)


def test_eq9_11_gains_exact_given_true_poles():
    """eqs. (9)-(11) on noise-free modal responses: the LS gains over the settle windows are exact."""
    u = current(4000, seed=1)
    y = open_loop(truth(MODES, delay_s=1e-5), u, FS, modes_only=True)
    Y = mode_regressors(u, [m.freq_hz for m in MODES], [m.zeta for m in MODES], DT, 1e-5)
    windows = [(a + 80, a + 380) for a in range(100, 3600, 400)]    # "after settling" of each burst
    fit = modal_gains(y, Y, windows)
    np.testing.assert_allclose(fit.coef / K0, [m.gain for m in MODES], rtol=1e-8)
    assert fit.residual_rms < 1e-9 * np.abs(y).max()
    assert fit.normal_matrix.shape == (3, 3) and fit.n_samples == 300 * len(windows)


def _synthetic_problem(noise=0.0, seed=2, ar=None):
    u = current(6000, seed=seed)
    plant = ModalPlant(k0=K0, modes=MODES, bias_a=0.003, delay_s=0.3 * DT)
    y = open_loop(truth(MODES, 0.003, 0.3 * DT), u, FS, position0=500.0)
    y = y + noise * np.random.default_rng(seed + 1).normal(size=len(y))
    segs = [(a, a + 400) for a in range(100, 5600, 400)]
    return u, y, segs, plant


def test_varpro_exact_at_truth_and_converges():
    u, y, segs, truth = _synthetic_problem()
    vp = VarPro(u, y, DT, segs)
    xt = np.r_[np.log([m.freq_hz for m in MODES]), np.log([m.zeta for m in MODES]), 0.3]
    X, c, r, Q = vp.solve(xt)
    assert np.sqrt(np.mean(r ** 2)) < 1e-6
    np.testing.assert_allclose(c[2:] / c[0], [m.gain for m in MODES], rtol=1e-6)
    assert c[0] == pytest.approx(K0, rel=1e-9) and c[1] / c[0] == pytest.approx(0.003, rel=1e-6)
    x0 = xt + np.r_[0.01, -0.01, 0.005, 0.2, -0.2, 0.1, 0.2]
    lb = np.r_[np.full(3, np.log(100)), np.full(3, np.log(1e-4)), 0.0]
    ub = np.r_[np.full(3, np.log(13000)), np.full(3, np.log(0.7)), 4.0]
    x = vp.fit(x0, lb, ub, max_nfev=60)
    np.testing.assert_allclose(x, xt, atol=1e-6)
    # near the solution Kaufman's Jacobian is close to a finite-difference one (it drops a term
    # proportional to the residual)
    x1 = xt + 1e-3
    J = vp.jacobian(x1)
    Jfd = np.column_stack([(vp.residual(x1 + h) - vp.residual(x1 - h)) / 2e-6 for h in np.eye(7) * 1e-6])
    assert np.linalg.norm(J - Jfd) / np.linalg.norm(Jfd) < 0.05


def test_varpro_with_whitening_and_nuisance_still_exact():
    u, y, segs, truth = _synthetic_problem()
    ro = periodic_columns(len(u), 220, 2) @ np.array([0.15, -0.05, 0.03, 0.01])
    ar = np.r_[1.0, -0.9]
    vp = VarPro(u, y + ro, DT, segs, ar=ar, nuisance=periodic_columns(len(u), 220, 2))
    xt = np.r_[np.log([m.freq_hz for m in MODES]), np.log([m.zeta for m in MODES]), 0.3]
    X, c, r, _ = vp.solve(xt)
    assert np.sqrt(np.mean(r ** 2)) < 1e-6
    assert len(c) == 5                           # nuisance projected out (Frisch-Waugh-Lovell)
    np.testing.assert_allclose(vp.nuisance_coef(xt), [0.15, -0.05, 0.03, 0.01], atol=1e-6)
    np.testing.assert_allclose(c[2:5] / c[0], [m.gain for m in MODES], rtol=1e-6)
    stat, _ = vp.scan(np.r_[xt[:2], xt[3:5], xt[6]], np.array([3000.0, 4100.0, 6000.0]))
    assert np.argmax(stat.max(axis=1)) == 1      # the missing 4100 Hz mode is found by the scan


def test_fir_filter_and_ar_whitener():
    rng = np.random.default_rng(5)
    e = rng.normal(size=20000)
    x = np.zeros_like(e)
    for k in range(2, len(e)):                    # AR(2): x = 1.5 x[-1] - 0.7 x[-2] + e
        x[k] = 1.5 * x[k - 1] - 0.7 * x[k - 2] + e[k]
    a = ar_whitener([x[:10000], x[10000:]], 2)
    np.testing.assert_allclose(a, [1.0, -1.5, 0.7], atol=0.02)
    w = fir_filter(a, x)
    assert np.std(w[10:]) == pytest.approx(1.0, rel=0.03)
    np.testing.assert_allclose(fir_filter([1.0, -1.0], np.full(5, 2.0), steady=True), 0.0)


def test_detect_period_and_sandwich():
    rng = np.random.default_rng(6)
    rows = np.arange(30000)
    r = 0.3 * np.sin(2 * np.pi * rows / 220) + rng.normal(size=len(rows))
    P, F = detect_period(rows, r, periods=range(100, 400))
    assert P == 220 and F > 4
    assert detect_period(rows, rng.normal(size=len(rows)), periods=range(100, 400))[0] is None
    J = rng.normal(size=(5000, 3))
    res = rng.normal(size=5000)
    cov, cov_w = sandwich_cov(J, res, np.array([0, 2500, 5000]), lags=10)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), np.sqrt(np.diag(cov_w)), rtol=0.15)
    # an MA(1)-coloured residual with a smooth regressor: the sandwich inflates the std
    e = rng.normal(size=5001)
    res2 = e[1:] + 0.9 * e[:-1]
    Js = np.column_stack([np.ones(5000), np.sin(np.arange(5000) / 500)])
    cov2, cov2_w = sandwich_cov(Js, res2, np.array([0, 5000]), lags=10)
    assert np.sqrt(cov2[0, 0] / cov2_w[0, 0]) > 1.2


@pytest.mark.parametrize("delay_samples", [0.0, 0.37, 1.5])
def test_mode_regressors_multirate_hold_is_fine_rate_plant(delay_samples):
    """(n, L) sub-step currents: the mode response equals plant.py's discretisation stepped at dt/L on
    the held sub-step values, sampled at the log's instants -- and differs from holding their mean."""
    L = 2
    u = np.column_stack([current(600, 1), current(600, 2)])
    for m in MODES:
        fine = (ModalPlant(k0=K0, modes=[m], delay_s=delay_samples * DT).simulate_open_loop(u.reshape(-1), DT / L)
                - ModalPlant(k0=K0, delay_s=delay_samples * DT).simulate_open_loop(u.reshape(-1), DT / L))[::L]
        y = K0 * m.gain * mode_regressors(u, [m.freq_hz], [m.zeta], DT, delay_samples * DT)[:, 0]
        np.testing.assert_allclose(y, fine, rtol=0, atol=1e-9 * np.abs(fine).max())
        ind = open_loop(truth([m], delay_s=delay_samples * DT), u, FS, modes_only=True)   # exact (n, L) hold
        np.testing.assert_allclose(y, ind, rtol=0, atol=1e-9 * np.abs(ind).max())
        mean = K0 * m.gain * mode_response(u.mean(axis=1), m.freq_hz, m.zeta, DT, delay_samples * DT)
        assert np.abs(mean - fine).max() > 1e-3 * np.abs(fine).max()
