"""Issue 10, item 6: the loop's own quality on an independent drive (slow, ~3-5 min per case).

The logs come from :mod:`tests.drives` (its own RK4 plant between the exact break points of the
delayed, held commands, its own controller stepping and noise: no dynamics code shared with the
package), here the 50.4 kHz drive; the loop runs as ``seekopt loop FIT --validate VAL`` does
(:func:`studies.loop_quality.run_case`: identify, then close the loop with the validation log).
Figures of the study are in ``docs/results_loop.md``.
"""
from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "studies"))
import loop_quality as lq  # noqa: E402

pytestmark = pytest.mark.slow

SEEKS = 60


@lru_cache(maxsize=None)
def _row(case: str) -> dict:
    return lq.run_case("50k", case, SEEKS)


#: cases measured to miss the target (strict xfail with the figure); none since h-loopq (kt_bias_friction:
#: 75.59 -> 0.1901 track against the clean drive's 0.1411, 1.35x, with the joint output-error refit by simulation)
_MISSED: dict = {}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=_MISSED[c]))
                                  if c in _MISSED else c for c in lq.CASES if c != "clean"])
def test_validation_rms_reaches_the_clean_floor(case):
    """On the validation seeks inside the positions the fit log settled on (where the plant is
    defined and a design may start and end), the validation RMS after the loop is within 1.5x the
    clean drive's (same schedules and noise seeds)."""
    r, c = _row(case), _row("clean")
    assert r["rms_after"] <= lq.RATIO_TARGET * c["rms_after"], (r["rms_after"], c["rms_after"], r["accepted"])


def test_amplifier_lag_is_named_with_its_bandwidth():
    """Named at 3086 Hz, total delay 15.4 us (truth 3000 Hz, 14 us).  It was 4408 Hz on session 6's
    merged main: the identification's residual-compliance term paired with a 25.1 kHz mode of gain
    129 to build the lag's phase and the plant, which does not hold the term, missed the fit log by
    2.35 track (validation RMS 2.33 before the loop); the term is now kept only while it is small
    (``RobustSettings.residual_max_share``)."""
    r = _row("lag")
    assert "amplifier_lag" in r["accepted"], r["accepted"]
    assert abs(r["lag_bandwidth_hz"] / 3000.0 - 1) < 0.15, r["lag_bandwidth_hz"]
    assert abs(r["delay_after_us"] - r["delay_truth_us"]) < 3.0, (r["delay_after_us"], r["delay_truth_us"])


def test_an_extra_delay_stays_a_delay():
    r = _row("delay")
    assert "amplifier_lag" not in r["accepted"], r["accepted"]
    assert abs(r["delay_after_us"] - r["delay_truth_us"]) < 2.0, (r["delay_after_us"], r["delay_truth_us"])


def test_linear_drive_raises_no_nonlinearity_flag_and_takes_the_spindle_from_metadata():
    """The clean 50.4 kHz drive (rpm 7200, 420 sectors in the log's metadata, run-out at 120 Hz):
    no nonlinear-correlation test fires, no nonlinear effect is accepted, the spindle is 120 Hz."""
    r = _row("clean")
    assert not [u for u in r["unexplained"] if u.startswith("nonlinear")], r["unexplained"]
    assert not set(r["accepted"]) & {"friction", "current_saturation", "torque_constant_variation", "position_bias"}
    assert r["spindle_analysis_hz"] == pytest.approx(120.0, abs=0.05), r["spindle_source"]
    if r["spindle_hz"] is not None:
        assert r["spindle_hz"] == pytest.approx(120.0, abs=0.05)
