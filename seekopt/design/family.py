"""Families of plants and drift in physical terms: the robust set of a seek design.

A drive is not one plant.  Its resonances move together with temperature (a benchmark drive family
specifies every VCM resonance x1.04 at low and x0.96 at high temperature, damping x0.8 / x1.2), its
gain (torque constant over mass) moves a few percent, its delay by a fraction of a sample, and the
seek-induced modes (flex cable, coil) move on their own with head position.  Logs of one drive taken
at several temperatures, heads or zones identify to a **family** of plants.

Gain and the drive's feedforward calibration.  A profile is a current; played uncorrected on a plant
with 5 % more gain it moves the head 5 % too far (10 tracks at K = 200, measured 9 T_bb for the
optimal profile and for the sine alike; 2 % already 6 T_bb).  Drives therefore scale their seek
feedforward by their own gain estimate (seek-gain / torque-constant calibration), and so does this
model: a plant of the set whose gain differs from the design plant's plays the profile's current
scaled by ``plant.meta["ff_scale"]`` = design gain / its gain (:func:`feedforward_scale`,
:func:`played_on`; the closed-loop maps of the design are scaled the same way,
:func:`scale_feedforward_maps`).  What the gain drift still changes is the loop gain.  The
calibration's own error is the uncompensated ``ffgain`` range (default: ``n_sigma`` standard
deviations of the identified ``k0``).

:class:`Drift` states the drift in those physical terms (``temp=+-4%,zeta=+-20%,gain=+-5%,delay=+-1us``,
per-mode ranges ``f1738=+-5%``, ``f1738.zeta=+-30%``); what it does not state comes from the data
(:meth:`Drift.ranges`): every parameter's range is at least ``n_sigma`` of the standard deviation
the identification reports, and with a family the spread of the members about the nominal one -- the
common frequency and damping scale and the gain that best map the nominal plant onto each member, and
what each mode does beyond that.

:func:`drift_set` samples the drift with few plants: the nominal plant, every family member, the
corners and axial points of the correlated (common) drifts -- a common frequency scale is one parameter,
not one per mode, so temperature, damping scale, gain and delay give at most 16 corners and 8 axial points
(the residual is not monotone along a frequency scale: corners alone leave the faces' middles out) --,
every mode at +- its range about the nominal plant and about each member (its own reported std) and a few rows of a
strength-2 orthogonal array over the independent per-mode ranges (each mode's frequency, damping and
gain at +- its range; the residual vibration is linear in the gains and its worst case over a box
sits on vertices).  Each plant carries a label (``plant.meta["set_label"]``) so a design can say which plant of
the set binds; :mod:`seekopt.design.predict` plays a profile on every plant of the set.

The pieces, one module each, all importable from here: :mod:`seekopt.design.drift` (:class:`Drift`,
:class:`DriftRanges`), :mod:`seekopt.design.driftset` (:func:`drift_set`, :func:`drifted`),
:mod:`seekopt.design.members` (:func:`family_spread`, :func:`match_modes`, :func:`label_set`) and
:mod:`seekopt.design.predict` (the feedforward calibration and the predictions on a set).
"""
from __future__ import annotations

from seekopt.design.drift import Drift, DriftError, DriftRanges, ModeRange
from seekopt.design.driftset import drift_set, drifted
from seekopt.design.members import family_spread, label_set, match_modes
from seekopt.design.predict import (SetPrediction, calibrated, feedforward_scale, played_on, predict_on_set,
                                    scale_feedforward_maps, set_label)

__all__ = ["DriftError", "Drift", "DriftRanges", "ModeRange", "family_spread", "drift_set", "drifted", "match_modes",
           "label_set", "set_label", "SetPrediction", "predict_on_set", "feedforward_scale", "calibrated", "played_on",
           "scale_feedforward_maps"]

