"""Fast checks of the pieces behind the loop's quality on independent drives (issue 10, item 6).

The long acceptance (independent drives, every library effect, CLI) is in ``tests/test_closing.py``
(slow) and ``studies/loop_quality.py``.  Here: the penalised table fit on a toy regression whose
answer is known, and the split of the validation error by the fitted positions.
"""
from __future__ import annotations

import numpy as np

from identification.loop.fit_engine import hats
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


def test_validation_seeks_outside_the_settled_positions_are_left_out():
    """``split_data`` with held-out seeks: the fit (even) seeks settle on 0 ... 1000 track; the
    validation seek to 5000 track leaves that range and is left out (returned apart), the other
    three validate.  With a validation log every seek of the fit log sets the range."""
    from identification.logs.seeklog import SeekLog
    from identification.loop.closing import inside_groups, settled_range, split_data
    fs = 10000.0
    targets = [0.0, 1000.0, 500.0, 0.0, 5000.0, 1000.0, 0.0, 500.0, 1000.0]
    tgt = np.repeat(targets, 200)
    t = np.arange(len(tgt)) / fs
    log = SeekLog(t, np.zeros_like(t), tgt.copy(), tgt, fs)
    val = SeekLog(t, np.zeros_like(t), tgt.copy(), tgt, fs)
    fit, v, same, out = split_data(log, val, outside=True)
    lo, hi = settled_range(log, fit.windows)
    assert (lo, hi) == (0.0, 5000.0)                 # every seek of the fit log
    fit, v, same, out = split_data(log, outside=True)
    lo, hi = settled_range(log, fit.windows)         # the even seeks: 1000, 0, 1000, 500
    assert (lo, hi) == (0.0, 1000.0)
    assert out is not None and out.windows.n_groups == 1 and v.windows.n_groups == 3
    assert all(log.target_track[a] <= 1000.0 for a, _ in v.windows.bounds)
    assert len(inside_groups(log, out.windows, lo, hi)) == 0
