"""Baseline profiles (ERRATA items 3-4) and the Profile file format."""
import math

import numpy as np
import pytest
from scipy import integrate

from identification.model.plant import ModalPlant
from seekopt.design.profiles import (Profile, ProfileError, finish_profile, normalise_rest_to_rest,
                              rigid_endpoint_matrix, shortest_baseline, sine_profile, t_bang_bang,
                              windowed_sine_profile)

K0, FS = 3.937e9, 26400.0


def test_printed_windowed_sine_amplitude_reaches_k_over_pi():
    """ERRATA 3: 9 pi K/(8 T^2) reaches K/pi; 9 pi^2 K/(8 T^2) reaches K."""
    K, T = 200.0, 1.2e-3
    f = lambda t: math.sin(math.pi * t / T) * math.sin(2 * math.pi * t / T)
    # double integral over [0, T] = int_0^T (T - t) f(t) dt
    dd = integrate.quad(lambda t: (T - t) * f(t), 0, T)[0]
    assert 9 * math.pi * K / (8 * T ** 2) * dd == pytest.approx(K / math.pi, rel=1e-9)
    assert 9 * math.pi ** 2 * K / (8 * T ** 2) * dd == pytest.approx(K, rel=1e-9)


@pytest.mark.parametrize("make", [sine_profile, windowed_sine_profile])
@pytest.mark.parametrize("K, T", [(1.0, 1e-4), (200.0, 1.2e-3), (200.0, 2e-3), (-5000.0, 5e-3)])
def test_baselines_rest_to_rest(make, K, T):
    u = make(K, T, K0, FS)
    pos, vel = rigid_endpoint_matrix(len(u), K0, 1 / FS) @ u
    assert abs(pos - K) < 1e-6 and abs(vel) < 1e-9
    y = ModalPlant(k0=K0).simulate_open_loop(np.r_[u, np.zeros(20)], 1 / FS, history_a=0.0)
    assert np.allclose(y[len(u) + 1:], K, atol=1e-6)


def test_unnormalised_sine_misses_k():
    """ERRATA 4: sampled at 50 kHz the 1.2 ms sine brings a discrete double integrator to ~199.8."""
    T, fs, K = 1.2e-3, 50e3, 200.0
    n = int(round(T * fs))
    t = np.arange(n) / fs
    u = 2 * math.pi * K / T ** 2 * np.sin(2 * math.pi * t / T) / K0
    pos = rigid_endpoint_matrix(n, K0, 1 / fs)[0] @ u
    assert 199.0 < pos < 200.0 and abs(pos - K) > 0.1


def test_shortest_baseline_within_imax_and_tbb():
    for K in (1.0, 10.0, 200.0, 1000.0):
        for kind in ("sine", "windowed_sine", "bang_bang"):
            u = shortest_baseline(kind, K, K0, FS, 0.3)
            assert np.max(np.abs(u)) <= 0.3 * (1 + 1e-12)
            assert len(u) / FS >= t_bang_bang(K, K0, 0.3) - 1 / FS
    assert t_bang_bang(200.0, K0, 0.3) == pytest.approx(2 * math.sqrt(200 / (K0 * 0.3)))


def test_profile_csv_round_trip(tmp_path):
    model = ModalPlant(k0=K0, delay_s=1e-5)
    u = sine_profile(200.0, 1.2e-3, K0, FS)
    prof = finish_profile(u, 200.0, FS, 0.3, model, "sine", meta={"plant_hash": "abc"})
    assert abs(prof.reference_track[-1] - 200.0) < 1e-6
    prof.to_csv(tmp_path / "p.csv")
    q = Profile.from_csv(tmp_path / "p.csv")
    assert np.array_equal(q.current_a, prof.current_a) and np.array_equal(q.reference_track, prof.reference_track)
    assert (q.tracks, q.imax_a, q.kind, q.seek_samples, q.meta["plant_hash"]) == (200.0, 0.3, "sine", len(u), "abc")
    (tmp_path / "bad.csv").write_text("nonsense\n1,2\n")
    with pytest.raises(ProfileError, match="bad.csv"):
        Profile.from_csv(tmp_path / "bad.csv")


def test_normalise_corrects_nonzero_sum():
    u = normalise_rest_to_rest(np.ones(10), 10.0, K0, 1 / FS)
    assert rigid_endpoint_matrix(10, K0, 1 / FS) @ u == pytest.approx([10.0, 0.0], abs=1e-9)
