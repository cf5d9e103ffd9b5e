"""Seek-settle metrics: settle time on the sample grid, evaluation through the one simulator."""
import math

import numpy as np
import pytest

from seekopt.design.baselines import baseline_profile
from seekopt.drive.controller import Controller
from seekopt.design.metrics import SeekMetrics, evaluate_profile, settle_index, settle_time, worst_case
from seekopt.drive.presets import default_truth_plant
from seekopt.design.profiles import t_bang_bang

FS = 26400.0


def test_settle_time_on_the_sample_grid():
    pes = np.array([-5.0, -1.0, 0.2, -0.05, 0.11, 0.09, 0.0, -0.1, 0.05])
    assert settle_index(pes, 0.1) == 5          # last outside sample is index 4 (0.11)
    assert settle_time(pes, FS, 0.1) == pytest.approx(5 / FS)
    assert settle_time(pes, FS, 0.2) == pytest.approx(2 / FS)   # |0.2| <= 0.2 is inside
    assert settle_time(np.zeros(4), FS) == 0.0


def test_settle_time_never_and_nan():
    assert settle_time(np.array([0.0, 0.0, 0.5]), FS) == math.inf
    assert settle_index(np.array([0.0, 0.0, 0.5])) is None
    # NaN is outside the band: a NaN tail never settles, an early NaN delays settling
    assert settle_time(np.array([0.0, np.nan]), FS) == math.inf
    assert settle_index(np.array([np.nan, 0.0, 0.0])) == 1


@pytest.fixture(scope="module")
def truth_and_ctrl():
    return default_truth_plant(), Controller.nss()


def test_evaluate_baseline(truth_and_ctrl):
    truth, ctrl = truth_and_ctrl
    prof = baseline_profile(truth, FS, "sine", 50.0, 0.3)
    m = evaluate_profile(truth, ctrl, prof, settle=0.1)
    assert isinstance(m, SeekMetrics)
    assert m.seek_time_s == pytest.approx(prof.seek_samples / FS)
    assert m.settled and m.seek_time_s < m.settle_time_s < 0.02
    assert m.ratio_tbb == pytest.approx(m.settle_time_s / t_bang_bang(50.0, truth.k0, 0.3))
    assert m.peak_current_a > 0.25 and m.peak_pes_after_track > 0.1 and m.rms_pes_after_track > 0
    d = m.to_dict()
    assert set(d) == {"seek_time_s", "settle_time_s", "peak_pes_after_track", "rms_pes_after_track",
                      "peak_current_a", "ratio_tbb", "settled"}
    assert isinstance(d["settled"], bool)


def test_evaluate_starts_at_equilibrium(truth_and_ctrl):
    """With no seek at all (zero profile) the biased drive stays put: the hold current is applied."""
    truth, ctrl = truth_and_ctrl
    prof = baseline_profile(truth, FS, "sine", 50.0, 0.3)
    prof.current_a = np.zeros_like(prof.current_a)
    prof.reference_track = np.zeros_like(prof.reference_track)
    prof.tracks = 0.0
    m = evaluate_profile(truth, ctrl, prof, settle=1e-9, horizon_s=0.01)
    assert m.settle_time_s == 0.0 and m.peak_pes_after_track < 1e-9


def test_worst_case():
    a = SeekMetrics(1e-3, 2e-3, 0.05, 0.01, 0.29, 2.0, True)
    b = SeekMetrics(1e-3, 3e-3, 0.02, 0.02, 0.30, 3.0, False)
    w = worst_case([a, b])
    assert (w.settle_time_s, w.peak_pes_after_track, w.peak_current_a, w.settled) == (3e-3, 0.05, 0.30, False)
