"""What the identification could not see: the frequency bands where a mode would have escaped detection.

A mode ``k0 g / (s^2 + 2 zeta w s + w^2)`` at ``f`` adds ``g x_f`` to the measured position, ``x_f``
the response of a unit-gain mode to the logged current (eq. (9), :func:`identification.estimate.gains.mode_regressors`,
the identification's own regressor, multirate hold included).  In the prediction-error fit its gain
would be estimated against the noise the model leaves (the residual, coloured: AR-whitened as the
robust method does), with a t-statistic of about::

    t(f) = |g| * || A * x_f || / sigma_w          (A the AR prediction-error filter of the residual,
                                                   sigma_w the whitened residual's standard deviation)

and a mode is kept only when ``t >= t_min``.  So ``g_min(f) = t_min sigma_w / ||A * x_f||`` is the
smallest gain the log could have revealed at ``f``: large where the log carries little current at
``f`` -- inside the controller's notches and multirate-filter zeros (the feedback current is notched
there), where the seek profiles have spectral nulls, and where the noise is high -- and unbounded
outside the identification's search range (above ``freq_range[1]``, i.e. near and above Nyquist,
where modes alias).

:func:`detectable_gain` computes ``g_min`` on a frequency grid; :func:`blind_bands` turns it into the
bands where a mode of gain ``gain`` would have escaped detection, for the plant JSON
(``plant.meta["blind_bands"]``, read by the seek designer's unmodelled-mode guard).  The estimate
ignores the collinearity with the modes already in the model (a second mode at the frequency of an
identified one is not separable from it) and the parameter-estimation loss of the frequency and
damping (a few percent of ``t``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from identification.estimate.gains import mode_regressors
from identification.estimate.linalg import sandwich_cov
from identification.estimate.varpro import ar_whitener
from identification.logs.seeklog import SeekLog, segment_seeks
from identification.model.plant import ModalPlant

__all__ = ["Detectability", "detectable_gain", "blind_bands", "blind_meta", "BLIND_KEYS"]

#: the ``plant.meta`` entries :func:`blind_meta` writes: they describe what the log could not show *about
#: that plant* (a band next to one of its modes is narrow, a mode it lacks widens it), so they travel
#: with the identification that computed them, never onto a plant identified again
BLIND_KEYS = ("blind_bands", "blind_detect", "detectable_gain_curve")


@dataclass
class Detectability:
    """Smallest detectable mode gain per frequency.

    Attributes
    ----------
    freqs_hz : ndarray
    min_gain : ndarray
        ``g_min(f)`` relative to the rigid body (``inf``: nothing excites the log there).
    calibration : float
        Factor applied to the raw estimate (see :func:`detectable_gain`).
    """

    freqs_hz: np.ndarray
    min_gain: np.ndarray
    calibration: float = 1.0


def _segments(log: SeekLog, min_len: int):
    seeks = [s for s in segment_seeks(log) if s.end - s.start >= min_len]
    return [(s.start, s.end) for s in seeks]


def detectable_gain(log: SeekLog, plant: ModalPlant, freqs_hz=None, *, zeta: float = 0.01, t_min: float = 5.0,
                    ar_order: int = 32, nw_lags: int = 32, chunk: int = 16, runout=None, calibrate: bool = True,
                    max_rows: int = 200_000):
    """Smallest mode gain ``g_min(f)`` (relative to the rigid body) the log reveals at ``t_min``.

    Parameters
    ----------
    log : SeekLog
        The log the plant was identified from (only the columns a drive logs are used).
    plant : ModalPlant
        The identified plant: its prediction (:func:`identification.estimate.identify.predict_segments`,
        initial position and velocity fitted per seek) leaves the residual that sets the noise.
    freqs_hz : array_like, optional
        Frequencies [Hz] (default: 1/24-octave grid from 100 Hz to 0.47 ``fs``).
    zeta : float
        Damping of the hypothetical mode (lightly damped: 0.01).
    t_min : float
        Detection threshold ``|g| / std(g)`` (the robust identification's ``t_min``).
    ar_order : int
        Order of the AR noise model.
    chunk : int
        Frequencies per batch (memory: about 8 ``chunk`` regressors of ``max_rows`` samples).
    max_rows : int
        Longest stretch of seeks used (the first seeks; the std is scaled by ``sqrt(used / all)``).
    runout : dict, optional
        The identified repeatable run-out (``Identification.diagnostics["runout"]``), removed from the
        residual.
    calibrate : bool
        Scale ``g_min`` by the largest ratio, over the identified modes below 0.45 ``fs``, of the gain
        std the identification reported to the one this estimate gives them (at their frequency and
        damping).  The identification's fit frees more than this estimate does (the other modes, the
        delay, the run-out, every seek's initial state); on the NSS-like drive the ratio is 1.2-4.5.

    Returns
    -------
    Detectability
        ``g_min`` is ``inf`` where the log has no excitation at all.
    """
    from identification.estimate.heldout import predict_segments     # the identification's own predictor
    fs, dt = log.sample_rate_hz, log.dt
    f = (np.geomspace(100.0, 0.47 * fs, int(math.ceil(24 * math.log2(0.47 * fs / 100.0))) + 1)
         if freqs_hz is None else np.atleast_1d(np.asarray(freqs_hz, dtype=float)))
    segs = _segments(log, ar_order + 16)
    if not segs:
        return Detectability(f, np.full(f.shape, np.inf), 1.0)
    # a long log: the first seeks holding about ``max_rows`` samples, the std scaled by sqrt(used / all)
    # (a gain's std falls as 1 / sqrt(samples); the calibration below absorbs any difference)
    total = sum(b - a for a, b in segs)
    used, n_used = [], 0
    for a, b in segs:
        if n_used >= max_rows:
            break
        used.append((a, b))
        n_used += b - a
    segs, row_scale = used, math.sqrt(n_used / total)
    pred = predict_segments(log, plant, segs, runout=runout)
    resid = [log.position_track[a:b] - p for (a, b), p in zip(segs, pred)]
    A = ar_whitener(resid, ar_order) if ar_order else np.ones(1)
    if A is None:
        A = np.ones(1)
    p = len(A) - 1
    w = np.concatenate([signal.lfilter(A, 1.0, e)[p:] for e in resid])
    bounds = np.r_[0, np.cumsum([b - a - p for a, b in segs])]
    sigma = float(np.std(w))
    u = log.input_current()[:segs[-1][1]]          # causal filters: the samples after the last seek used add nothing

    def gain_std(fc, zc):
        """Std of a unit-gain mode's gain at ``fc`` with damping ``zc`` (frequency, damping free)."""
        # the gain's regressor and the directions of the mode's own frequency and damping (unknown too:
        # for a lightly damped mode gain and damping trade off), by central differences
        cols = [mode_regressors(u, fc, zc, dt, plant.delay_s)]
        for df, dz in ((1e-4, 0.0), (-1e-4, 0.0), (0.0, 0.05), (0.0, -0.05)):
            cols.append(mode_regressors(u, fc * (1 + df), zc * (1 + dz), dt, plant.delay_s))
        X = plant.k0 * np.stack([cols[0], cols[1] - cols[2], cols[3] - cols[4]], axis=2)     # (n, nf, 3)
        Xw = np.concatenate([signal.lfilter(A, 1.0, X[a:b], axis=0)[p:] for a, b in segs])     # (rows, nf, 3)
        out = np.full(fc.size, np.inf)
        for j in range(fc.size):
            J = Xw[:, j, :]
            if not np.any(J[:, 0]):
                continue
            # Newey-West sandwich for the colour the AR model leaves (as the identification)
            cov = sandwich_cov(J, w, bounds, lags=nw_lags)[0] if nw_lags else sigma ** 2 * np.linalg.pinv(J.T @ J)
            out[j] = math.sqrt(cov[0, 0]) if cov[0, 0] > 0 else np.inf
        return out

    g = np.empty(f.shape)
    for i0 in range(0, f.size, chunk):
        fc = f[i0:i0 + chunk]
        g[i0:i0 + chunk] = t_min * gain_std(fc, np.full(fc.size, zeta)) * row_scale
    # calibration on the identified modes: the std this estimate gives them against the std the
    # identification reported (its fit also frees the other modes, the delay, the run-out...)
    fmax = 0.45 * fs
    ref = [m for m in plant.modes if m.freq_hz < fmax and (m.std or {}).get("gain", 0) > 0]
    factor = 1.0
    if calibrate and ref:
        est = gain_std(np.array([m.freq_hz for m in ref]), np.array([m.zeta for m in ref])) * row_scale
        ratios = [m.std["gain"] / e for m, e in zip(ref, est) if np.isfinite(e) and e > 0]
        factor = max([1.0] + ratios)
    return Detectability(f, g * factor, factor)


def blind_bands(log: SeekLog, plant: ModalPlant, gain: float = 0.05, *, t_min: float = 5.0,
                freq_range=None, zeta: float = 0.01, runout=None, detect=None) -> list:
    """Frequency bands where a mode of gain ``gain`` (relative to the rigid body) would have escaped
    detection.

    Returns a list of dicts ``{"lo_hz", "hi_hz", "reason", "min_detectable_gain"}``:

    * ``reason="low excitation"``: contiguous runs of :func:`detectable_gain` above ``gain`` inside the
      identification's search range ``freq_range`` (default ``(100 Hz, 0.47 fs)``);
      ``min_detectable_gain`` the largest ``g_min`` in the run (``None`` if unbounded);
    * ``reason="above the identification range"``: from ``freq_range[1]`` to ``L fs / 2`` (``L`` the
      logged sub-steps, at least 2: near and above Nyquist, where modes alias), ``None`` (no gain
      is excluded there).

    ``detect`` reuses a :func:`detectable_gain` result.
    """
    fs = log.sample_rate_hz
    lo, hi = freq_range or (100.0, 0.47 * fs)
    det = detect if detect is not None else detectable_gain(log, plant, zeta=zeta, t_min=t_min, runout=runout)
    f, g = det.freqs_hz, det.min_gain
    sel = (f >= lo) & (f <= hi)
    f, g = f[sel], g[sel]
    out = []
    blind = g > gain
    i = 0
    while i < f.size:
        if not blind[i]:
            i += 1
            continue
        j = i
        while j + 1 < f.size and blind[j + 1]:
            j += 1
        a = 0.5 * (f[i - 1] + f[i]) if i > 0 else f[i]
        b = 0.5 * (f[j] + f[j + 1]) if j + 1 < f.size else f[j]
        gm = float(np.max(g[i:j + 1]))
        out.append({"lo_hz": float(a), "hi_hz": float(b), "reason": "low excitation",
                    "min_detectable_gain": gm if math.isfinite(gm) else None})
        i = j + 1
    u = log.input_current()
    L = u.shape[1] if np.ndim(u) == 2 else 1
    out.append({"lo_hz": float(hi), "hi_hz": float(0.5 * max(L, 2) * fs), "reason": "above the identification range",
                "min_detectable_gain": None})
    return out


def blind_meta(log: SeekLog, plant: ModalPlant, gain: float = 0.05, *, t_min: float = 5.0, freq_range=None,
               zeta: float = 0.01, runout=None, curve_points_per_octave: int = 6) -> dict:
    """The plant-JSON entries (``plant.meta``): ``blind_bands`` (:func:`blind_bands`), ``blind_detect``
    (the settings: ``gain``, ``t_min``, ``zeta``) and ``detectable_gain_curve`` (``[[f_hz, g_min], ...]``
    every 1/``curve_points_per_octave`` octave; ``g_min`` None where unbounded)."""
    det = detectable_gain(log, plant, zeta=zeta, t_min=t_min, runout=runout)
    bands = blind_bands(log, plant, gain, t_min=t_min, freq_range=freq_range, zeta=zeta, detect=det)
    f, g = det.freqs_hz, det.min_gain
    step = max(int(round(24 / curve_points_per_octave)), 1)
    # every step-th point and the last one: the curve reaches the end of the search range (without it the
    # guard took the last 1/6 octave below 0.47 fs as unbounded: unit gain in a notch there)
    idx = np.unique(np.r_[np.arange(0, f.size, step), f.size - 1]) if f.size else np.arange(0)
    curve = [[round(float(f[i]), 1), (float(f"{g[i]:.4g}") if math.isfinite(g[i]) else None)] for i in idx]
    return {"blind_bands": bands, "blind_detect": {"gain": float(gain), "t_min": float(t_min), "zeta": float(zeta),
                                                   "calibration": round(float(det.calibration), 3)},
            "detectable_gain_curve": curve}
