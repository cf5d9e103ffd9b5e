"""Prediction of seeks from the measured current, and the held-out fit % of an identified plant.

Fit % on held-out seeks (both methods of :func:`identification.estimate.identify.identify`).  For each
held-out seek the model is simulated from the measured current (modes over the whole log, rigid body
and bias from the seek start, plus the identified run-out), the seek's initial position and velocity
are fitted by LS over the whole seek (two numbers per seek), and on the settle windows ``[N, M]``
of those seeks ``fit = 100 (1 - ||y - y_hat|| / ||y - y_bar||)`` with ``y`` the PES, ``y_hat`` the
predicted PES and ``y_bar`` the mean of ``y`` over those windows (:func:`heldout_fit`).  With force
noise the open-loop simulation accumulates a position random walk over a seek that no model
predicts, so the fit is only meaningful on logs without it.
"""
from __future__ import annotations

import numpy as np

from identification.estimate.gains import mode_regressors
from identification.estimate.linalg import SegmentProjector
from identification.estimate.rigid import bias_response, zoh_rigid_response
from identification.estimate.varpro import periodic_columns
from identification.logs.seeklog import SeekLog
from identification.model.plant import ModalPlant

__all__ = ["runout_signal", "predict_segments", "initial_velocities", "heldout_fit"]


def runout_signal(n: int, runout: dict | None) -> np.ndarray:
    """The identified repeatable run-out [track] at log samples ``0..n-1`` (zeros if None):
    ``sum_h a_h cos(2 pi h k / P) + b_h sin(2 pi h k / P)``."""
    if not runout:
        return np.zeros(n)
    Z = periodic_columns(n, runout["period_samples"], len(runout["cos_track"]))
    return Z @ np.ravel(np.column_stack([runout["cos_track"], runout["sin_track"]]))


def _response(log: SeekLog, plant: ModalPlant, starts, steady: bool = True, runout=None) -> np.ndarray:
    """The plant's response [track] to the measured current: modes over the whole log, rigid body and
    bias restarted (position and velocity 0) at each start, plus the run-out if given."""
    dt, u = log.dt, log.input_current()
    d = plant.delay_s
    y = plant.k0 * (zoh_rigid_response(u, dt, d, starts) + plant.bias_a * bias_response(len(u), dt, starts))
    if plant.modes:
        M = mode_regressors(u, [m.freq_hz for m in plant.modes], [m.zeta for m in plant.modes], dt, d, steady)
        y = y + M @ (plant.k0 * np.array([m.gain for m in plant.modes]))
    if runout:
        y = y + runout_signal(len(u), runout)
    return y


def _initial_conditions(log: SeekLog, plant: ModalPlant, segments, init, t_local, runout, steady: bool = True):
    """The per-segment LS fit of ``p0 + v0 t`` (over ``init[j]``, default the segment) to what the
    model leaves unexplained, evaluated at ``t_local[j]`` [samples from the segment start]; and the
    model's response."""
    y = _response(log, plant, [a for a, _ in segments], steady, runout)
    fit_on = list(segments) if init is None else list(init)
    proj = SegmentProjector(fit_on, offsets=[ia - a for (a, _), (ia, _) in zip(segments, fit_on)])
    if len(proj.segments) != len(fit_on):
        raise ValueError("predict_segments: an empty initial-condition range")
    return proj.polynomial(proj.take(log.position_track - y), t_local), y


def predict_segments(log: SeekLog, plant: ModalPlant, segments, init=None, steady: bool = True, runout=None):
    """Predicted position [track] on each segment ``[i0, i1)`` (list of arrays).

    The plant's response to the measured current -- modes run over the whole log (their state at
    ``i0`` comes from the current history), rigid body and bias restarted at ``i0`` -- plus an
    initial position and velocity fitted by LS over ``init[j] = (a, b)`` (log indices inside the
    segment; default the whole segment; :class:`identification.estimate.linalg.SegmentProjector`),
    plus the identified run-out (:func:`runout_signal`) if given.
    """
    ic, y = _initial_conditions(log, plant, segments, init, [np.arange(b - a) for a, b in segments], runout, steady)
    return [y[a:b] + p for (a, b), p in zip(segments, ic)]


def initial_velocities(log: SeekLog, plant: ModalPlant, segments, runout=None) -> np.ndarray:
    """The rigid body's velocity [track/s] at the start of each segment: the ``v0`` of the initial
    position and velocity fitted over the whole segment (as :func:`predict_segments`)."""
    ic, _ = _initial_conditions(log, plant, segments, None, [np.array([0.0, 1.0])] * len(segments), runout)
    return np.array([(p[1] - p[0]) / log.dt for p in ic])


def heldout_fit(log: SeekLog, plant: ModalPlant, seeks, init: str = "seek", runout=None) -> float:
    """Fit % ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` of the settle-window PES of ``seeks``.

    ``y`` is the PES on the settle windows ``[N, M]`` of the (settled) seeks, concatenated;
    ``y_hat`` the PES predicted by :func:`predict_segments` over each seek, its initial position and
    velocity fitted over the whole seek (``init="seek"``: a simulation from the seek start, the
    definition used for ``Identification.fit_percent``) or over the settle window only
    (``init="window"``: insensitive to the double-integrated force noise accumulated during
    the seek).  ``runout`` (``Identification.diagnostics["runout"]``) adds the identified repeatable
    run-out to the prediction.
    """
    seeks = [s for s in seeks if s.settled and s.settle - s.start >= 2 and s.end - s.settle >= 4]
    if not seeks:
        return float("nan")
    segs = [(s.start, s.end) for s in seeks]
    pred = predict_segments(log, plant, segs, None if init == "seek" else [(s.settle, s.end) for s in seeks],
                            runout=runout)
    pes = log.pes                                   # (a property: compute once)
    y = np.concatenate([pes[s.settle:s.end] for s in seeks])
    yh = np.concatenate([p[s.settle - s.start:] - log.target_track[s.settle:s.end] for p, s in zip(pred, seeks)])
    return float(100.0 * (1.0 - np.linalg.norm(y - yh) / np.linalg.norm(y - y.mean())))
