"""Fast checks of the pieces behind the loop's quality on independent drives (issue 10, item 6).

The long acceptance (independent drives, every library effect, CLI) is in ``tests/test_closing.py``
(slow) and ``studies/loop_quality.py``.  Here: the penalised table fit on a toy regression whose
answer is known, and the split of the validation error by the fitted positions.
"""
from __future__ import annotations

import numpy as np

from identification.loop.fit_engine import hats
from identification.loop.result import range_errors
from identification.loop.stats import smooth_lstsq
from identification.loop.windows import Windows


def _table_problem(seed=0, outlier=True):
    """A position table observed through windows of 40 samples over 0..1 (noise 0.05) and,
    optionally, one window far beyond them.  The truth is piecewise linear with one kink at 0.5."""
    rng = np.random.default_rng(seed)
    centres = list(np.linspace(0.02, 0.98, 30)) + ([1.6] if outlier else [])
    c = np.concatenate([x + 0.01 * rng.standard_normal(40) for x in centres])
    truth = np.where(c < 0.5, 2.0 * c, 1.0 - 1.0 * (c - 0.5))
    knots = np.linspace(0.0, 1.7, 35)
    X = np.column_stack(hats(c, knots))
    y = truth + 0.05 * rng.standard_normal(len(c))
    bounds = [(40 * i, 40 * i + 40) for i in range(len(centres))]
    return y, X, Windows(bounds), c, knots


def test_kink_count_penalty_does_not_shrink_a_kink():
    """At a penalty strong enough to leave 3 effective parameters (a straight line each side of
    one kink), trend filtering (L1) shrinks the kink -- a flex-cable bias table then sits tens
    of micro-amperes off on both sides, a track over a 10 ms window -- and the kink-count-like
    penalty (L0) does not."""
    y, X, w, c, knots = _table_problem(outlier=False, seed=3)
    k = int(np.argmin(np.abs(knots - 0.5)))
    err = {}
    for pen in ("L1", "L0"):
        th, edf, _, _ = smooth_lstsq(y, X, 0, w, penalties=((pen, 2),), lams=[1e4])
        assert edf < 4, (pen, edf)
        err[pen] = abs(th[k] - 1.0)
    assert err["L0"] < 0.005 < 0.03 < err["L1"], err


def test_chosen_penalty_reproduces_a_kinked_table():
    """With the penalty and its weight chosen by cross-validation the kink is kept within the noise."""
    y, X, w, c, knots = _table_problem(outlier=False, seed=3)
    th, edf, name, lam = smooth_lstsq(y, X, 0, w)
    k = int(np.argmin(np.abs(knots - 0.5)))
    assert abs(th[k] - 1.0) < 0.02, (th[k], name, lam, edf)


def test_range_errors_split_the_validation_windows():
    class R:   # the fields range_errors reads
        pass
    r = R()
    pos = np.r_[np.full(10, 100.0), np.linspace(100, 900, 10), np.full(10, 900.0)]
    r.log = type("L", (), {"position_track": pos})()
    r.windows = Windows([(0, 10), (10, 20), (20, 30)])
    r.e = np.r_[np.full(10, 1.0), np.full(10, 2.0), np.full(10, 3.0)]
    out = range_errors(r, 50.0, 500.0)
    assert out["windows_in_range"] == 1 and out["windows_outside_range"] == 2
    assert out["rms_in_range_track"] == 1.0
    assert np.isclose(out["rms_outside_range_track"], np.sqrt((4 + 9) / 2))
    assert out["position_range_track"] == [50.0, 500.0]
