"""Calibration of the robust identification's standard deviations (``studies/std_calibration.py``).

Fast: the study's statistics on known numbers; the noise model of the final fit whitens the
prediction-error estimate's own error (a drive of the independent simulator, ``tests/drives``).
Slow (``-m slow``): a Monte-Carlo over noise seeds on the 36 kHz drive."""
import os
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "studies"))


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def _rec(z_k0, z_modes):
    """A study record with truth 1, std 1 and the given normalised errors."""
    return {"drive": "t", "seed": 0, "seconds": 1.0, "k0": [1.0 + z_k0, 1.0, 1.0], "bias_a": [0.0, 1.0, 0.0],
            "modes": [{"truth_hz": 100.0 * (i + 1), **{k: [1.0 + z, 1.0, 1.0] for k in ("freq_hz", "zeta", "gain")}}
                      for i, z in enumerate(z_modes)], "missed": []}


def test_summary_statistics():
    """RMS, mean and their per-log standard errors of :func:`std_calibration.summary`."""
    from std_calibration import summary, table
    recs = [_rec(1.0, [1.0, -1.0]), _rec(-3.0, [2.0, 2.0]), _rec(1.0, [0.0, 0.0])]
    s = summary(recs)
    assert s["k0"]["n"] == 3 and s["freq_hz"]["n"] == 6
    assert s["k0"]["rms"] == pytest.approx(np.sqrt(11 / 3))
    assert s["k0"]["mean"] == pytest.approx(-1 / 3)
    assert s["k0"]["mean_se"] == pytest.approx(np.std([1.0, -3.0, 1.0], ddof=1) / np.sqrt(3))
    # per-log mean of z^2: 1, 4, 0 -> RMS sqrt(10/6); s.e. of the RMS by the delta method
    assert s["freq_hz"]["rms"] == pytest.approx(np.sqrt(10 / 6))
    assert s["freq_hz"]["rms_se"] == pytest.approx(np.std([1.0, 4.0, 0.0], ddof=1) / np.sqrt(3) / (2 * np.sqrt(10 / 6)))
    assert s["bias_a"]["rms"] == 0.0
    assert "| t | k0 | 3 |" in table({"t": recs})


def _acf(r, lags=(1, 2, 3)):
    return np.array([np.sum(r[:-k] * r[k:]) / np.sum(r * r) for k in lags])


def test_final_noise_model_whitens_the_prediction_error():
    """On a closed-loop log of the 36 kHz drive (independent simulator, sensor and force noise),
    the AR noise model fitted to the residual of the unwhitened LS fit leaves the whitened residual
    correlated at lags 1-3 (measured -0.07: in closed loop the LS coefficients are biased and the AR
    model whitens their misfit too); fitted to the output error of the whitened estimate (what the
    final stage does, ``noise_model_passes``) the correlation halves (measured -0.035).  The colour
    left is the sandwich covariance's business."""
    from std_calibration import drive_36k
    from tests.drives import Noise, Schedule, make_log, modal_plant
    from identification.estimate.identify import _split
    from identification.estimate.robust import _Run
    from identification.estimate.settings import RobustSettings
    d = drive_36k(2)
    d.noise = Noise(d.noise.sensor_noise_track, d.noise.force_noise_a)
    log = make_log(d, Schedule(n_seeks=60, seed=2), noise_seed=2)
    truth = modal_plant(d)
    s = RobustSettings()
    run = _Run(s, log, _split(log, s.holdout_every)[1], {})
    x = np.r_[np.log([m.freq_hz for m in truth.modes]), np.log([m.zeta for m in truth.modes]), truth.delay_s / log.dt]
    data = (0, None, run.segs)
    vp_ls, _ = run.problem(data, x)
    vp_pe, _ = run.problem(data, x, noise_from=vp_ls)
    a_ls, a_pe = _acf(vp_ls.solve(x)[2]), _acf(vp_pe.solve(x)[2])
    assert np.abs(a_ls).min() > 0.05, a_ls
    assert np.abs(a_pe).max() < 0.6 * np.abs(a_ls).min(), (a_ls, a_pe)
    # the output error of a noise-free fit at the truth is each segment's initial-condition line
    clean = make_log(d, Schedule(n_seeks=10, seed=2), noise_seed=None)
    run = _Run(s, clean, _split(clean, 0)[1], {})
    vp, _ = run.problem((0, None, run.segs), x, white=False)
    v = vp.output_error(x)
    assert np.abs(vp.proj.project(vp.proj.take(v))).max() < 1e-6 * np.abs(v).max() + 1e-9


@pytest.mark.slow
def test_std_calibration_monte_carlo():
    """12 noise seeds on the 36 kHz drive: the RMS of the normalised errors of frequency and bias is
    not significantly above 1.2 (RMS minus two standard errors; 12 logs leave the RMS uncertain by
    about 0.1: the 40-seed study measures 1.08 and 0.67); every RMS and mean is printed (README
    "Operating range" has the 40-seed table and what misses 1.2: damping, gain, k0)."""
    from std_calibration import calibration, summary, table
    recs = calibration("36k", range(12), 60, verbose=False)
    print("\n" + table({"36k": recs}, "std calibration, 12 seeds x 60 seeks, 36 kHz drive"))
    s = summary(recs)
    assert s["k0"]["n"] == 12 and s["freq_hz"]["n"] >= 12 * 4
    for k in ("bias_a", "freq_hz"):
        assert s[k]["rms"] - 2 * s[k]["rms_se"] <= 1.2, (k, s[k])
