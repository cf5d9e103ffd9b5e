"""End-to-end tests of identification.estimate.identify on synthetic seek logs, figures and the CLI.

The logs come from the independent drive of ``tests/drives`` (continuous plant integrated on a fine
grid, its own controller stepping), never from ``seekopt.synth``: an error in the package's
discretisation cannot cancel between the data and the estimator.

Which truth modes must be recovered
-----------------------------------
A truth mode is *required* when it lies between 200 Hz and 0.45 fs and its settle-window response
is at least 3x the noise floor, computed from the truth plant and the log (:func:`required_modes`):

* the mode's settle-window response is ``a_r = k0 g_r h_r * u`` (truth mode driven by the logged
  current) on every settle window ``[N, M]`` of at least 16 samples;
* the noise is what the truth plant does not explain there: measured position minus the truth's
  prediction (:func:`identification.estimate.identify.predict_segments`), i.e. sensor noise, flutter,
  run-out, force noise and the multirate model error;
* both have the per-window initial position and velocity removed (what the fit cannot use) and the
  noise floor is the noise's averaged periodogram ``S(f)`` over the windows (power per sample);
* the mode's response relative to that floor is its whitened energy pooled over the windows,
  ``SNR_r = sqrt(sum_w sum_f |A_r,w(f)|^2 / (NFFT S(f)))`` (the matched-filter SNR; for white
  noise of variance s^2 it is ``||a_r|| / s``), and the mode is required if ``SNR_r >= 3``.

The per-window ratio (no pooling) is below 3 for every mode at the benchmark noise, so a literal
per-window reading would require nothing; pooling over the windows is what any estimator that
uses all settle windows can exploit.
"""
import json

import numpy as np
import pytest

from identification.estimate.identify import identify, predict_segments
from identification.logs import LogError, SeekLog, segment_seeks, write_log
from identification.model.plant import ModalPlant
from identification.estimate.rigid import SegmentProjector
from identification.estimate.gains import mode_response
from tests.drives import (Schedule, drive_50k, make_log, modal_plant, nss_drive, nss_single_rate_controller,
                          other_nss_truth)

NFFT = 256


def required_modes(log: SeekLog, truth: ModalPlant, lo=200.0, hi_frac=0.45, min_snr=3.0):
    """``[(mode, snr)]`` of the truth modes that must be recovered (see the module notes)."""
    seeks = [s for s in segment_seeks(log) if s.settled and s.end - s.settle >= 16]
    pred = predict_segments(log, truth, [(s.start, s.end) for s in seeks])
    proj = SegmentProjector([(s.settle, s.end) for s in seeks])
    noise = proj.project(np.concatenate([log.position_track[s.settle:s.end] - p[s.settle - s.start:]
                                         for p, s in zip(pred, seeks)]))
    B = proj.bounds

    def spec(x):
        return np.array([np.abs(np.fft.rfft(x[B[i]:B[i + 1]], NFFT)) ** 2 for i in range(len(B) - 1)])
    S = spec(noise).sum(axis=0) / proj.n_rows
    w = np.full(NFFT // 2 + 1, 2.0)
    w[0] = w[-1] = 1.0
    out = []
    for m in truth.modes:
        if not lo <= m.freq_hz <= hi_frac * log.sample_rate_hz:
            continue
        a = truth.k0 * m.gain * mode_response(log.input_current(), m.freq_hz, m.zeta, log.dt, truth.delay_s)
        snr = float(np.sqrt(np.sum(w * spec(proj.project(proj.take(a))).sum(axis=0) / S) / NFFT))
        if snr >= min_snr:
            out.append((m, snr))
    return out


def match(plant, mode):
    """The identified mode nearest in frequency to a truth mode, or None."""
    return min(plant.modes, key=lambda m: abs(np.log(m.freq_hz / mode.freq_hz)), default=None)


def errors(plant, mode):
    m = match(plant, mode)
    if m is None:
        return np.inf, np.inf, np.inf
    return m.freq_hz / mode.freq_hz - 1, m.zeta / mode.zeta - 1, m.gain / mode.gain - 1


def table(truth, required, ids):
    lines = [f"{'truth mode':>22} {'SNR':>6} " + " ".join(f"{k + ' df,dzeta,dgain [%]':>32}" for k in ids)]
    for m, snr in required:
        cells = []
        for res in ids.values():
            e = errors(res.plant, m)
            cells.append(f"{100 * e[0]:+8.3f} {100 * e[1]:+8.1f} {100 * e[2]:+8.1f}      ")
        lines.append(f"{m.freq_hz:7.0f} Hz z={m.zeta:<6.3f} {snr:6.1f} " + " ".join(f"{c:>32}" for c in cells))
    lines.append("k0 error [%]: " + ", ".join(f"{k} {100 * (r.plant.k0 / truth.k0 - 1):+.4f}" for k, r in ids.items()))
    lines.append("held-out fit [%]: " + ", ".join(f"{k} {r.fit_percent:.1f} (rigid only {r.fit_percent_rigid:.1f})"
                                                 for k, r in ids.items()))
    return "\n".join(lines)


def drive_log(drive, schedule, noise_seed=0):
    """``(log, truth)`` from an independent drive (tests/drives: no dynamics code shared with the package)."""
    return make_log(drive, schedule, noise_seed=noise_seed), modal_plant(drive)


# ------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="session")
def default_log():
    """NSS-like truth (benchmark plant + flex and coil modes + bias), benchmark noise (sensor, force,
    flutter, RRO), 120 seeks, from the independent drive."""
    return drive_log(nss_drive(seed=0), Schedule(n_seeks=120, seed=0))


@pytest.fixture(scope="session")
def default_ids(default_log):
    log, _ = default_log
    return {"robust": identify(log), "paper": identify(log, method="paper")}


@pytest.fixture(scope="session")
def clean_log():
    """Default truth without any noise or disturbance, 40 seeks."""
    return drive_log(nss_drive(noise=False), Schedule(n_seeks=40, seed=1), noise_seed=None)


@pytest.fixture(scope="session")
def alt_logs():
    """Another truth (flex mode at 300 Hz, coil at 2.2 kHz, other damping, gains and bias), seed and
    current limit: on the default (multirate) drive and on a single-rate drive."""
    truth = other_nss_truth()
    multi = drive_log(nss_drive(truth, seed=7), Schedule(n_seeks=100, seed=7, imax_a=0.5))
    single = drive_log(nss_drive(truth, nss_single_rate_controller(), seed=11), Schedule(n_seeks=100, seed=11, imax_a=0.4))
    return {"multirate": (multi, identify(multi[0])), "single-rate": (single, identify(single[0]))}


# ------------------------------------------------------------------------------------ end to end
def test_default_truth_robust_freq_gain_k0(default_log, default_ids):
    log, truth = default_log
    req = required_modes(log, truth)
    print("\n" + table(truth, req, default_ids))
    assert len(req) >= 4, "the criterion should require most of the seek-induced and benchmark modes"
    robust = default_ids["robust"].plant
    for m, snr in req:
        df, dz, dg = errors(robust, m)
        assert abs(df) < 0.01, f"{m.freq_hz} Hz: frequency error {100 * df:+.3f} %"
        assert abs(dg) < 0.25, f"{m.freq_hz} Hz: gain error {100 * dg:+.1f} %"
    assert abs(robust.k0 / truth.k0 - 1) < 0.02
    assert abs(default_ids["paper"].plant.k0 / truth.k0 - 1) < 0.02
    assert robust.bias_a == pytest.approx(truth.bias_a, rel=0.02)
    assert robust.delay_s == pytest.approx(truth.delay_s, rel=0.1)


def test_default_truth_robust_zeta(default_log, default_ids):
    log, truth = default_log
    for m, snr in required_modes(log, truth):
        dz = errors(default_ids["robust"].plant, m)[1]
        assert abs(dz) < 0.25, f"{m.freq_hz} Hz: damping error {100 * dz:+.1f} %"


def test_default_truth_mean_current_only(default_log, default_ids):
    """The same log without its sub-step current columns (a multirate drive that logs only the mean
    current per sample): the intersample current is then unlogged feedback.  Frequencies and k0 stay
    within the targets; the damping errors are printed (measured on the independent drive's log: the 7 kHz
    mode's is -36 %, the others within 7 %)."""
    log, truth = default_log
    mean_only = log.slice()
    mean_only.extra = {k: v for k, v in log.extra.items() if not k.startswith("current_sub")}
    assert mean_only.input_current().ndim == 1
    res = identify(mean_only)
    req = required_modes(log, truth)
    print("\nmean current only:\n" + table(truth, req, {"robust (mean current)": res, **default_ids}))
    for m, snr in req:
        assert abs(errors(res.plant, m)[0]) < 0.01, f"{m.freq_hz} Hz"
    assert abs(res.plant.k0 / truth.k0 - 1) < 0.02


def test_robust_uncertainties_and_diagnostics(default_ids):
    res = default_ids["robust"]
    p = res.plant
    assert set(p.std) == {"k0", "bias_a", "delay_s"} and all(v > 0 for v in p.std.values())
    for m in p.modes:
        assert set(m.std) == {"freq_hz", "zeta", "gain"} and all(np.isfinite(list(m.std.values())))
    back = ModalPlant.from_dict(json.loads(p.to_json()))
    assert back.modes[0].std == p.modes[0].std
    d = res.diagnostics
    assert d["periodic_period_samples"] == 220          # the RRO period (26400 Hz / 120 Hz) was found
    assert 0.5 < d["std_inflation_median"] < 3.0
    assert res.timing["total"] > 0 and d["samples_per_s"] > 0
    assert "pencil" in res.poles_per_order and "final" in res.poles_per_order


def test_clean_log_fit_percent(clean_log):
    """noise=False (no sensor/force noise, flutter or RRO): held-out fit >= 60 %, far above rigid only."""
    log, truth = clean_log
    res = identify(log)
    print(f"\nclean log: held-out fit {res.fit_percent:.1f} %, rigid only {res.fit_percent_rigid:.1f} %")
    assert res.fit_percent >= 60.0
    assert res.fit_percent - res.fit_percent_rigid >= 50.0
    assert abs(res.plant.k0 / truth.k0 - 1) < 0.002


@pytest.mark.parametrize("drive", ["multirate", "single-rate"])
def test_other_truth(alt_logs, drive):
    """A different truth (300 Hz flex, 2.2 kHz coil, other damping/gains/bias, seed, imax): the same
    method, no option changed.  On the single-rate drive every tolerance holds; on the multirate
    drive frequency, gain and k0 (damping: see test_default_truth_robust_zeta)."""
    (log, truth), res = alt_logs[drive]
    req = required_modes(log, truth)
    print(f"\n{drive} drive, other truth\n" + table(truth, req, {"robust": res}))
    assert any(m.freq_hz == 300.0 for m, _ in req) and len(req) >= 3
    for m, snr in req:
        df, dz, dg = errors(res.plant, m)
        assert abs(df) < 0.01 and abs(dg) < 0.25, f"{m.freq_hz} Hz: {100 * df:+.3f} % / {100 * dg:+.1f} %"
        if drive == "single-rate":
            assert abs(dz) < 0.25, f"{m.freq_hz} Hz: damping error {100 * dz:+.1f} %"
    assert abs(res.plant.k0 / truth.k0 - 1) < 0.02


# ------------------------------------------------------------------------------------ a drive unlike the bundled one
#: 50.4 kHz drive of tests/drives: k0 6e9, modes 260 Hz / 2.6 kHz (seek-induced), 5.3 / 7.8 / 10.6 / 14.8 /
#: 19.5 kHz, PID with lead + notches at 5.3 / 10.6 / 14.8 kHz run at 100.8 kHz, 6 us plant delay + 8 us
#: computation delay, its own noise (0.01 track sensor, 0.1 mA force, flutter 640 Hz .. 4.2 kHz, run-out)
SCHEDULE_50K = dict(imax_a=0.25, stroke_track=(0.0, 100000.0))


def test_50k_drive_noise_free_is_identified_exactly():
    """No noise at all: the log is the continuous plant integrated to ~1e-10 (RK4 on a fine grid, exact
    delay and 2x sub-step hold), so every mode, k0, bias and the total delay (plant + computation) must be
    recovered to the estimator's convergence, not to a noise level.  Measured (20 seeks): mode frequencies
    within 5e-7, damping within 8e-6, gains within 4e-6 (relative), k0 2e-10, delay 1e-8, bias 2e-9 with an
    AR-only noise model; with the noise model's two poles at z = 1 (the default) the whitener is fitted to
    the twice-differenced numerical residual and weights its high-frequency part: modes within 2e-5, k0
    1.8e-8 (also with 40 refinement steps: a weighting of the ~1e-10 integration error, not a convergence
    limit).  A
    discretisation error in the estimator's regressors (half a sample of delay, a wrong sub-step hold) shows
    orders of magnitude above these tolerances."""
    drive = drive_50k(noise=False)
    log, truth = drive_log(drive, Schedule(n_seeks=20, seed=3, **SCHEDULE_50K), noise_seed=None)
    res = identify(log)
    p = res.plant
    assert len(p.modes) == len(truth.modes)
    for m in truth.modes:
        df, dz, dg = errors(p, m)
        assert abs(df) < 1e-5 and abs(dz) < 1e-4 and abs(dg) < 1e-4, (m, df, dz, dg)
    assert abs(p.k0 / truth.k0 - 1) < 1e-7
    assert abs(p.delay_s / truth.delay_s - 1) < 1e-6
    assert abs(p.bias_a / truth.bias_a - 1) < 1e-6


@pytest.fixture(scope="session")
def log_50k():
    drive = drive_50k(seed=3)
    log, truth = drive_log(drive, Schedule(n_seeks=60, seed=3, **SCHEDULE_50K))
    return log, truth, identify(log)


@pytest.mark.slow
def test_50k_drive_with_noise(log_50k):
    """60 seeks with the drive's noise (8-30 s with the identification, depending on load): the modes required by the noise criterion of this module
    (settle-window SNR >= 3 against the log's own noise floor) within the same targets as the bundled
    drive (frequency 1 %, damping and gain 25 %, k0 2 %, delay 10 %, bias 2 %), and every error within
    5 reported standard deviations (the reported std is the noise-level yardstick; issue 11 found them
    optimistic by up to 2.2x).  Measured: frequencies within 0.04 %, damping within 3.8 %, gains within
    3.9 %, k0 5e-5, |error / std| at most 1.7; the 14.8 kHz mode, in a notch of the controller (SNR < 3),
    is found at 14792 Hz with damping -20 % and gain -19 %; the 19.5 kHz mode is not found."""
    log, truth, res = log_50k
    req = required_modes(log, truth)
    print("\n50.4 kHz drive\n" + table(truth, req, {"robust": res}))
    assert {round(m.freq_hz) for m, _ in req} >= {260, 2600, 5300}
    for m, snr in req:
        df, dz, dg = errors(res.plant, m)
        assert abs(df) < 0.01 and abs(dz) < 0.25 and abs(dg) < 0.25, (m.freq_hz, df, dz, dg)
        e = match(res.plant, m)
        z = [(e.freq_hz - m.freq_hz) / e.std["freq_hz"], (e.zeta - m.zeta) / e.std["zeta"], (e.gain - m.gain) / e.std["gain"]]
        print(f"{m.freq_hz:7.0f} Hz: error / reported std (freq, zeta, gain) = {z[0]:+.2f} {z[1]:+.2f} {z[2]:+.2f}")
        assert max(abs(v) for v in z) < 5.0, (m.freq_hz, z)
    p = res.plant
    assert abs(p.k0 / truth.k0 - 1) < 0.02 and abs(p.k0 - truth.k0) < 5 * p.std["k0"]
    assert p.delay_s == pytest.approx(truth.delay_s, rel=0.1)
    assert p.bias_a == pytest.approx(truth.bias_a, rel=0.02)


@pytest.mark.slow
def test_50k_drive_mean_current_only(log_50k):
    """The same log without its sub-step current columns (the multirate drive logs only the mean current).
    Targets as for the bundled drive's mean-current test plus damping and gain 25 %.  Measured: frequencies
    within 0.08 %, damping within 4.7 %, gains within 5.1 %, k0 5e-5."""
    log, truth, _ = log_50k
    mean_only = log.slice()
    mean_only.extra = {k: v for k, v in log.extra.items() if not k.startswith("current_sub")}
    res = identify(mean_only)
    req = required_modes(log, truth)
    print("\n50.4 kHz drive, mean current only\n" + table(truth, req, {"robust (mean current)": res}))
    for m, snr in req:
        df, dz, dg = errors(res.plant, m)
        assert abs(df) < 0.01 and abs(dz) < 0.25 and abs(dg) < 0.25, (m.freq_hz, df, dz, dg)
    assert abs(res.plant.k0 / truth.k0 - 1) < 0.02


def test_settings_recorded_and_options_map(default_log, default_ids):
    """identify(log, method, **options) runs the method's settings with the options applied, the
    same as passing the settings; the result records them."""
    from identification.estimate.settings import PaperSettings, RobustSettings
    log, _ = default_log
    assert default_ids["robust"].settings == RobustSettings() and default_ids["paper"].settings == PaperSettings()
    a = identify(log, method="paper", prony_order=6)
    b = identify(log, settings=PaperSettings(prony_order=6))
    assert a.settings == b.settings == PaperSettings(prony_order=6)
    assert a.plant.to_dict() == b.plant.to_dict()
    assert max(int(k.split("=")[1]) for k in a.poles_per_order) == 6
    with pytest.raises(ValueError, match="unknown option"):
        identify(log, method="paper", max_modes=3)


# ------------------------------------------------------------------------------------ errors, CLI, figures
def test_unusable_logs_raise_logerror():
    n = 400
    one_seek = SeekLog.from_arrays(None, np.zeros(n), np.r_[np.zeros(200), np.full(200, 5.0)],
                                   np.r_[np.zeros(200), np.full(200, 5.0)], 26400.0, source="one.csv")
    with pytest.raises(LogError, match="one.csv: need at least 2 seeks"):
        identify(one_seek)
    target = np.repeat([0.0, 5.0, 10.0], [100, 150, 150])
    never = SeekLog.from_arrays(None, np.zeros(n), target + 3.0, target, 26400.0, source="never.csv")
    with pytest.raises(LogError, match="never settles|no seek settles"):
        identify(never)
    with pytest.raises(ValueError):
        identify(never, method="magic")


def test_cli_identify(default_log, default_ids, tmp_path, monkeypatch, capsys):
    from seekopt.app import cli
    import identification.estimate.identify as ident_mod
    log, _ = default_log
    path = tmp_path / "log.npz"
    write_log(log, path)
    # robust: reuse the session's result (the CLI maps arguments; the estimator is tested above)
    monkeypatch.setattr(ident_mod, "identify", lambda lg, method="robust": default_ids[method])
    out = tmp_path / "plant.json"
    assert cli.main(["identify", str(path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "k0" in text and "±" in text and "held-out fit" in text and "delay" in text
    assert len([ln for ln in text.splitlines() if "Hz" in ln or ln.strip()[:1].isdigit()]) >= 4
    plant = ModalPlant.load(out)
    assert plant.modes and plant.modes[0].std is not None
    figs = tmp_path / "figs"
    assert cli.main(["identify", str(path), "--method", "paper", "--figures", str(figs)]) == 0
    assert sorted(p.name for p in figs.glob("*.png")) == ["fig3_modes.png", "fig4_spectra.png", "fig5_tf.png",
                                                          "fig6_settle_pes.png", "fig6_settle_pes_window_init.png"]
    capsys.readouterr()                 # (the figures' stage log, if they took over 2 s)
    bad = tmp_path / "bad.csv"
    bad.write_text("# sample_rate_hz: 26400\ntime_s,current_a,position_track\n0,0,0\n")
    assert cli.main(["identify", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.csv" in err[0]
