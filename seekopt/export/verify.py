"""Playing exported seek tables on the design plant: settle and peak current of many lengths at once.

The 2DOF loop around the design plant's linear part is linear and time-invariant at the servo rate, so
the played seek's position and sub-step currents are convolutions of the fixed-point ``u_ff`` and ``r``
(:meth:`seekopt.export.classes.SeekSet.play`, converted to A and track) with the loop's impulse responses
from the one simulator (:func:`seekopt.drive.simulator.closed_loop_responses`); the pre-seek hold current
``-bias_a`` cancels the bias exactly.  :func:`play_linear` does thousands of lengths in one batched FFT
convolution; :func:`play_simulated` runs :func:`seekopt.drive.simulator.simulate_2dof` (via
:func:`seekopt.design.metrics.evaluate_profile`) for a sample, and is the only path for a plant whose loop
does not superpose (:func:`seekopt.design.predict.superposes`: nonlinear effects, a pivot spring's rest
offset); :func:`play_rule` picks the path.  A negative seek plays the exact negation (the rule rounds
``|K|``), so on a superposing loop its position error is the negation and only its current differs: both
directions' peak currents are returned.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import fftconvolve

from seekopt.export.classes import SeekSet

__all__ = ["play_rule", "play_linear", "play_simulated", "played_profile", "DEFAULT_TAIL_SAMPLES"]

#: Samples simulated after the longest seek of a batch (15 ms at 26.4 kHz; the metrics' default tail).
DEFAULT_TAIL_SAMPLES = 396


def played_profile(s: SeekSet, tracks: int, imax: float, fs: float, settle: float = 0.1):
    """The fixed-point seek of ``tracks`` as a :class:`seekopt.design.profiles.Profile` (A, track)."""
    from seekopt.design.profiles import Profile
    u, r = s.play(tracks)
    n = len(u)
    uu = np.r_[u.astype(float) * imax / 32768.0, 0.0]
    rr = np.r_[r.astype(float) / 2.0 ** s.frac_bits, float(tracks)]
    seek = int(np.max(np.nonzero(u)[0]) + 1) if np.any(u) else 0
    return Profile(uu, rr, fs, float(tracks), imax, settle, "table_rule", seek, {"tpi": s.tpi, "samples": n})


def play_linear(s: SeekSet, plant, controller, lengths, imax: float, settle: float = 0.1,
                tail: int = DEFAULT_TAIL_SAMPLES, batch: int = 256) -> dict:
    """Settle and peak current of the rule's seeks of ``lengths`` (positive) on ``plant``'s linear loop
    (a plant whose loop superposes, :func:`seekopt.design.predict.superposes`; ValueError otherwise).

    Returns
    -------
    dict of arrays (one entry per length)
        ``tracks``, ``n`` (rule samples), ``settle_samples`` (-1: never settles within the horizon),
        ``peak_current_a`` (positive seek), ``peak_current_neg_a`` (negative seek).
    """
    from seekopt.design.metrics import settle_index
    from seekopt.design.predict import superposes
    from seekopt.drive.simulator import closed_loop_responses
    if not superposes(plant):
        raise ValueError("play_linear needs a plant whose loop superposes (no nonlinear effects, no pivot rest "
                         "offset); use play_simulated")
    lengths = np.asarray(lengths, dtype=np.int64)
    ns = np.array([s.n_samples(int(K)) for K in lengths])
    out = {"tracks": lengths, "n": ns, "settle_samples": np.zeros(len(lengths), int),
           "peak_current_a": np.zeros(len(lengths)), "peak_current_neg_a": np.zeros(len(lengths))}
    order = np.argsort(ns)
    R = None
    hold = -float(plant.bias_a)
    for b in range(0, len(order), batch):
        idx = order[b:b + batch]
        H = int(ns[idx].max()) + tail
        if R is None or len(R["y_uff"]) < H:
            R = closed_loop_responses(plant, controller, max(H, 2 * (0 if R is None else len(R["y_uff"]))))
        U, Rr = np.zeros((len(idx), H)), np.zeros((len(idx), H))
        for j, i in enumerate(idx):
            u, r = s.play(int(lengths[i]), H)
            U[j], Rr[j] = u * (imax / 32768.0), r / 2.0 ** s.frac_bits
        y = fftconvolve(U, R["y_uff"][None, :H], axes=1)[:, :H] + fftconvolve(Rr, R["y_r"][None, :H], axes=1)[:, :H]
        L = R["u_sub_uff"].shape[1]
        cur = np.stack([fftconvolve(U, R["u_sub_uff"][None, :H, l], axes=1)[:, :H]
                        + fftconvolve(Rr, R["u_sub_r"][None, :H, l], axes=1)[:, :H] for l in range(L)], axis=2)
        for j, i in enumerate(idx):
            k = settle_index(y[j] - lengths[i], settle)
            out["settle_samples"][i] = -1 if k is None else k
            out["peak_current_a"][i] = np.max(np.abs(cur[j] + hold))
            out["peak_current_neg_a"][i] = np.max(np.abs(-cur[j] + hold))
    return out


def play_simulated(s: SeekSet, plant, controller, lengths, imax: float, settle: float = 0.1,
                   negative: bool = False) -> dict:
    """As :func:`play_linear` with the full simulator on the full plant: positive seeks (``settle_samples``,
    ``peak_current_a``) and, with ``negative``, also ``n`` and the negative seeks' ``peak_current_neg_a``
    (each direction played on its own: a loop that does not superpose is not symmetric)."""
    from seekopt.design.metrics import evaluate_profile
    fs = float(controller.sample_rate_hz)
    st, pk, pk_neg = [], [], []
    for K in lengths:
        horizon = (s.n_samples(int(K)) + DEFAULT_TAIL_SAMPLES) / fs
        m = evaluate_profile(plant, controller, played_profile(s, int(K), imax, fs, settle), settle=settle,
                             horizon_s=horizon)
        st.append(int(round(m.settle_time_s * fs)) if m.settled else -1)
        pk.append(m.peak_current_a)
        if negative:
            pk_neg.append(evaluate_profile(plant, controller, played_profile(s, -int(K), imax, fs, settle),
                                           settle=settle, horizon_s=horizon).peak_current_a)
    out = {"tracks": np.asarray(lengths), "settle_samples": np.array(st), "peak_current_a": np.array(pk)}
    if negative:
        out.update(n=np.array([s.n_samples(int(K)) for K in lengths]), peak_current_neg_a=np.array(pk_neg))
    return out


def play_rule(s: SeekSet, plant, controller, lengths, imax: float, settle: float = 0.1) -> dict:
    """:func:`play_linear` when ``plant``'s loop superposes (:func:`seekopt.design.predict.superposes`), else
    :func:`play_simulated` in both directions: the same entries, each the one simulator's figure."""
    from seekopt.design.predict import superposes
    if superposes(plant):
        return play_linear(s, plant, controller, lengths, imax, settle)
    return play_simulated(s, plant, controller, lengths, imax, settle, negative=True)
