"""Tests for identification.estimate.prony and .pencil: LS Prony (paper eqs. 4-7), pooled matrix pencil, CRB.

Signals are a mode's free response written independently in ``tests/drives``
(:func:`tests.drives.damped_free_response`, from the continuous pole), not the module's own
``damped_sinusoid`` helper; :func:`test_damped_sinusoid_helper_is_the_free_response` ties the two."""
from __future__ import annotations

import numpy as np
import pytest

from identification.estimate.pencil import matrix_pencil, stabilisation_diagram
from identification.estimate.prony import (PoleEstimate, crb_damped_sinusoid, crb_modes, damped_sinusoid, fit_amplitudes,
                                           ls_prony, modal_to_z, refine_poles, snr_db, z_to_modal)
from tests.drives import damped_free_response

FS = 26_400.0
FREQS = np.array([350.0, 1738.0, 4100.0])
ZETAS = np.array([0.03, 0.02, 0.03])


def _windows(rng, freqs=FREQS, zetas=ZETAS, n_windows=4, n=200, sigma=0.0, lengths=None):
    """Windows sharing the poles, each with its own amplitudes/phases (and lengths)."""
    lengths = lengths or [n + 23 * i for i in range(n_windows)]
    out = []
    for m in lengths:
        amps, phases = rng.uniform(0.5, 2.0, len(freqs)), rng.uniform(0, 2 * np.pi, len(freqs))
        x = sum(damped_free_response(m, FS, f, z, a, p) for f, z, a, p in zip(freqs, zetas, amps, phases))
        out.append(x + sigma * rng.standard_normal(m))
    return out


def _modal_upper(z):
    z = np.asarray(z)
    f, zeta = z_to_modal(z[z.imag > 0], FS)
    i = np.argsort(f)
    return f[i], zeta[i]


def _sigma_for(snr, amps=(1.0,), zetas=(0.02,), freqs=(1738.0,), n=200):
    return 10 ** ((snr_db(amps, zetas, freqs, n, FS, 1.0) - snr) / 20)


# ------------------------------------------------------------------------------------ conversions
def test_conversions_round_trip_and_errata_form():
    z = modal_to_z(FREQS, ZETAS, FS)
    f, zeta = z_to_modal(z, FS)
    np.testing.assert_allclose(f, FREQS, rtol=1e-12)
    np.testing.assert_allclose(zeta, ZETAS, rtol=1e-10)
    # paper eq. (1): poles -zeta_p w +- j w with w the DAMPED frequency (ERRATA item 2)
    w, zp = 2 * np.pi * 1738.0, 0.05
    f, zeta = z_to_modal(np.exp((-zp * w + 1j * w) / FS), FS)
    assert f == pytest.approx(w * np.sqrt(1 + zp ** 2) / (2 * np.pi), rel=1e-12)
    assert zeta == pytest.approx(zp / np.sqrt(1 + zp ** 2), rel=1e-10)


def test_damped_sinusoid_helper_is_the_free_response():
    """prony.damped_sinusoid (A e^{-zeta w t} cos(w_d t + phase), natural w) is the mode's free response."""
    for f, z, a, p in ((1738.0, 0.02, 1.3, 0.4), (350.0, 0.3, 0.7, -2.0)):
        np.testing.assert_allclose(damped_sinusoid(300, FS, f, z, a, p), damped_free_response(300, FS, f, z, a, p),
                                   rtol=1e-12, atol=1e-14)


# ------------------------------------------------------------------------------------ noise-free recovery
def test_ls_prony_noise_free_pooled_three_modes():
    ws = _windows(np.random.default_rng(1))
    z = ls_prony(ws, 3, FS)
    assert len(z) == 6
    f, zeta = _modal_upper(z)
    np.testing.assert_allclose(f, FREQS, rtol=1e-6)
    np.testing.assert_allclose(zeta, ZETAS, rtol=1e-6)


def test_ls_prony_two_modes_single_window():
    ws = _windows(np.random.default_rng(2), FREQS[:2], ZETAS[:2], n_windows=1)
    f, zeta = _modal_upper(ls_prony(ws[0], 2, FS))
    np.testing.assert_allclose(f, FREQS[:2], rtol=1e-6)
    np.testing.assert_allclose(zeta, ZETAS[:2], rtol=1e-6)


@pytest.mark.parametrize("k", [2, 3])
def test_matrix_pencil_noise_free_pooled(k):
    rng = np.random.default_rng(10 + k)
    ws = _windows(rng, FREQS[:k], ZETAS[:k], n_windows=5)
    poles, diag = matrix_pencil(ws, FS)
    assert diag.order == 2 * k and diag.n_windows == 5
    assert all(isinstance(p, PoleEstimate) for p in poles)
    np.testing.assert_allclose([p.freq_hz for p in poles], FREQS[:k], rtol=1e-6)
    np.testing.assert_allclose([p.zeta for p in poles], ZETAS[:k], rtol=1e-6)
    for p in poles:
        assert p.z.imag > 0 and abs(p.z) < 1 and 0.5 <= p.amplitude <= 2.0 and p.energy > 0


def test_matrix_pencil_overfitted_order_rejects_extras_noise_free():
    ws = _windows(np.random.default_rng(3))
    poles, diag = matrix_pencil(ws, FS, order=12)
    np.testing.assert_allclose([p.freq_hz for p in poles], FREQS, rtol=1e-6)
    assert len(diag.rejected) >= 3


def test_fit_amplitudes_recovers_amplitude_and_phase():
    amps, phases = np.array([1.3, 0.4, 0.9]), np.array([0.3, -2.0, 1.1])
    x = sum(damped_free_response(150, FS, f, z, a, p) for f, z, a, p in zip(FREQS, ZETAS, amps, phases))
    c = fit_amplitudes(x, modal_to_z(FREQS, ZETAS, FS), FS)   # upper poles only: conjugates added
    np.testing.assert_allclose(2 * np.abs(c), amps, rtol=1e-9)
    np.testing.assert_allclose(np.angle(c), phases, atol=1e-9)
    zs = modal_to_z(FREQS, ZETAS, FS)
    poles = [PoleEstimate(f, z, zz, 1.0, 1.0) for f, z, zz in zip(FREQS, ZETAS, zs)]
    np.testing.assert_allclose(fit_amplitudes(x, poles, FS), c, rtol=1e-12)


def test_short_windows_skipped_and_none_usable():
    rng = np.random.default_rng(4)
    ws = _windows(rng, FREQS[:2], ZETAS[:2], n_windows=2) + [np.ones(10)]
    poles, diag = matrix_pencil(ws, FS, min_len=32)
    assert diag.n_windows == 2 and len(poles) == 2
    with pytest.raises(ValueError):
        matrix_pencil([np.ones(10)], FS)


def test_stabilisation_diagram_stable_from_true_order():
    ws = _windows(np.random.default_rng(5), FREQS[:2], ZETAS[:2], n_windows=3)
    diag = stabilisation_diagram(ws, FS, [2, 4, 6, 8])
    assert len(diag) == 4 and diag[0].shape[1] == 2
    for fz in diag[1:]:
        for f, z in zip(FREQS[:2], ZETAS[:2]):
            i = np.argmin(np.abs(fz[:, 0] - f))
            assert fz[i, 0] == pytest.approx(f, rel=1e-6) and fz[i, 1] == pytest.approx(z, rel=1e-5)


def test_refine_poles_converges_from_perturbed_start():
    ws = _windows(np.random.default_rng(6), FREQS, ZETAS, n_windows=3)
    start = modal_to_z(FREQS * 1.003, ZETAS * 1.2, FS)
    f, zeta = _modal_upper(refine_poles(ws, FS, start))
    np.testing.assert_allclose(f, FREQS, rtol=1e-8)
    np.testing.assert_allclose(zeta, ZETAS, rtol=1e-6)


# ------------------------------------------------------------------------------------ spurious poles
def test_rejection_rules():
    rng = np.random.default_rng(7)
    n = 200
    good = damped_free_response(n, FS, 1738.0, 0.02)
    growing = np.exp(0.004 * np.arange(n)) * np.cos(2 * np.pi * 3000.0 / FS * np.arange(n))
    heavy = damped_free_response(n, FS, 2500.0, 0.7, 3.0)
    x = good + growing + heavy + 0.5 + 1e-4 * rng.standard_normal(n)
    poles, diag = matrix_pencil(x, FS, order=7)
    assert [round(p.freq_hz) for p in poles] == [1738]
    reasons = " ".join(r for _, r in diag.rejected)
    assert "unstable" in reasons and "zeta" in reasons and "real" in reasons
    both, _ = matrix_pencil(x, FS, order=7, keep_real=True, keep_unstable=True, max_zeta=0.9)
    assert len(both) == 4 and min(abs(p.z.imag) for p in both) == 0.0   # DC pole reported on request


def test_pure_noise_gives_no_poles():
    """Definition: on white-noise windows the automatic order is 0, and even with a forced (wrong) order
    every pencil pole fails the amplitude-significance test (T < amp_sigmas**2 = 16; null T is ~1-15)."""
    rng = np.random.default_rng(8)
    for trial in range(30):
        ws = [rng.standard_normal(200) for _ in range(1 + trial % 3)]
        poles, diag = matrix_pencil(ws, FS)
        assert poles == [] and diag.order == 0
        forced, diag = matrix_pencil(ws, FS, order=6)
        assert forced == [], [(p.freq_hz, t) for p, (_, t) in zip(forced, diag.significance)]


@pytest.mark.parametrize("n_windows", [1, 4])
def test_order_selection_at_25db(n_windows):
    rng = np.random.default_rng(9 + n_windows)
    sigma = _sigma_for(25.0, np.ones(3), ZETAS, FREQS)
    for _ in range(15):
        ws = []
        for _w in range(n_windows):
            ph = rng.uniform(0, 2 * np.pi, 3)
            ws.append(sum(damped_free_response(200, FS, f, z, 1.0, p) for f, z, p in zip(FREQS, ZETAS, ph))
                      + sigma * rng.standard_normal(200))
        poles, diag = matrix_pencil(ws, FS)
        assert diag.order == 6 and len(poles) == 3
        np.testing.assert_allclose([p.freq_hz for p in poles], FREQS, rtol=0.01)


# ------------------------------------------------------------------------------------ noise: CRB efficiency
def test_monte_carlo_20db_matrix_pencil_near_crb_and_prony_worse():
    rng = np.random.default_rng(20)
    f0, z0, n, snr = 1738.0, 0.02, 200, 20.0
    sigma = _sigma_for(snr)
    err = {"prony": [], "pencil": [], "pencil+vp": []}
    crb_var = []
    for _ in range(200):
        ph = rng.uniform(0, 2 * np.pi)
        x = damped_free_response(n, FS, f0, z0, 1.0, ph) + sigma * rng.standard_normal(n)
        crb_var.append(np.square(crb_damped_sinusoid(n, FS, f0, z0, 1.0, sigma, ph)))
        zp = ls_prony(x, 1, FS)
        zp = zp[np.argmax(zp.imag)]
        err["prony"].append(np.subtract(z_to_modal(zp, FS), (f0, z0)))
        poles, _ = matrix_pencil(x, FS, order=2)
        assert len(poles) == 1
        err["pencil"].append([poles[0].freq_hz - f0, poles[0].zeta - z0])
        zr = refine_poles(x, FS, [poles[0].z])   # what matrix_pencil(..., refine=True) does
        err["pencil+vp"].append(np.subtract(z_to_modal(zr[0], FS), (f0, z0)))
    crb = np.sqrt(np.mean(crb_var, axis=0))
    ratios = {k: np.sqrt(np.mean(np.square(v), axis=0)) / crb for k, v in err.items()}
    print("\n20 dB, 200 runs, RMSE/CRB (freq, zeta): "
          + ", ".join(f"{k} {r[0]:.3f} {r[1]:.3f}" for k, r in ratios.items()))
    assert np.all(ratios["pencil"] <= 1.5) and np.all(ratios["pencil+vp"] <= 1.5)
    assert np.all(ratios["prony"] > ratios["pencil"])


# ------------------------------------------------------------------------------------ CRB and SNR
def _numerical_fisher_std(n, fs, freqs, zetas, amps, phases, sigma, h=1e-6):
    """Brute force: central-difference Jacobian of the model in (f_n, zeta, A, phi) per mode."""
    theta0 = np.ravel(np.column_stack([freqs, zetas, amps, phases]))

    def model(theta):
        return sum(damped_free_response(n, fs, *theta[4 * r:4 * r + 4]) for r in range(len(freqs)))

    J = np.empty((n, len(theta0)))
    for i in range(len(theta0)):
        d = h * max(abs(theta0[i]), 1e-3)
        tp, tm = theta0.copy(), theta0.copy()
        tp[i] += d
        tm[i] -= d
        J[:, i] = (model(tp) - model(tm)) / (2 * d)
    C = np.linalg.inv(J.T @ J / sigma ** 2)
    std = np.sqrt(np.diag(C))
    return std[0::4], std[1::4]


def test_crb_single_mode_matches_numerical_fisher():
    cases = [(1738.0, 0.02, 1.0, 0.0, 0.05), (350.0, 0.03, 2.0, 1.2, 0.3), (4100.0, 0.1, 0.5, -2.0, 0.01)]
    for f, z, A, ph, sig in cases:
        sf, sz = crb_damped_sinusoid(200, FS, f, z, A, sig, phase=ph)
        nf, nz = _numerical_fisher_std(200, FS, [f], [z], [A], [ph], sig)
        assert sf == pytest.approx(nf[0], rel=1e-5) and sz == pytest.approx(nz[0], rel=1e-5)
    s1 = crb_damped_sinusoid(200, FS, 1738.0, 0.02, 1.0, 0.1)
    s2 = crb_damped_sinusoid(200, FS, 1738.0, 0.02, 1.0, 0.2)
    np.testing.assert_allclose(np.array(s2) / np.array(s1), 2.0)   # scales with sigma


def test_crb_two_modes_matches_numerical_fisher():
    args = (200, FS, FREQS[:2], ZETAS[:2], [1.0, 0.7], [0.4, 2.0], 0.05)
    sf, sz = crb_modes(*args)
    nf, nz = _numerical_fisher_std(*args)
    np.testing.assert_allclose(sf, nf, rtol=1e-5)
    np.testing.assert_allclose(sz, nz, rtol=1e-5)


def test_snr_definition_is_phase_averaged_energy():
    n, sigma = 200, 0.1
    phases = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    energy = np.mean([np.sum(damped_free_response(n, FS, 1738.0, 0.02, 1.5, p) ** 2) for p in phases])
    expected = 10 * np.log10(energy / (n * sigma ** 2))
    assert snr_db(1.5, 0.02, 1738.0, n, FS, sigma) == pytest.approx(expected, abs=1e-3)
