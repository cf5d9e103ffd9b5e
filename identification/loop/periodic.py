"""Periodic-disturbance candidate of closing the loop: repeatable run-out at spindle harmonics.

The spindle frequency comes from the log's metadata when given
(:func:`identification.loop.analysis.spindle_from_metadata`: ``spindle_hz``, ``rpm``,
``sectors``), else from the three strongest harmonic-sum peaks of the residual, refined
(phase drift over the log).  Harmonics are chosen by forward selection on 2-fold
cross-validated SSE.  Units: tracks, s, Hz.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from identification.loop.analysis import detect_spindle, spindle_from_metadata
from identification.loop.fit_engine import Data, Engine, Fit, rebase, refit_base
from identification.loop.stats import lstsq
from identification.model.effects import PeriodicDisturbance

__all__ = ["fit_periodic_disturbance", "spindle_candidates"]


def _harmonic_cols(t, f0, hs):
    cols = []
    for h in hs:
        cols += [np.cos(2 * np.pi * h * f0 * t), np.sin(2 * np.pi * h * f0 * t)]
    return cols


def _harmonic_fit(eng, P0, data, f0, hs):
    X = np.column_stack([P0[:, 1:], eng.project(*_harmonic_cols(data.log.time_s, f0, hs))])
    th, sse = lstsq(P0[:, 0], X)
    return X, th, sse


def _cv_sse(y: np.ndarray, X: np.ndarray, data: Data) -> float:
    """2-fold cross-validated SSE over windows (fit on one half in time, test on the other)."""
    lens = np.array([b - a for a, b in data.windows.bounds])
    half = np.repeat(np.arange(len(lens)) < len(lens) // 2, lens)
    sse = 0.0
    for tr in (half, ~half):
        th = lstsq(y[tr], X[tr])[0]
        r = y[~tr] - X[~tr] @ th
        sse += float(r @ r)
    return sse


def _select_harmonics(eng, P0, data, f0, hmax, min_gain: float = 0.01):
    """Forward selection of harmonics 1..hmax by 2-fold cross-validated SSE (each added
    harmonic must lower it by ``min_gain``); returns ``(harmonics, cv_sse)``."""
    C = eng.project(*_harmonic_cols(data.log.time_s, f0, range(1, hmax + 1)))
    y, base = P0[:, 0], P0[:, 1:]
    keep, best = [], _cv_sse(y, base, data)
    while True:
        trial = {h: _cv_sse(y, np.column_stack([base] + [C[:, 2 * j - 2:2 * j] for j in keep + [h]]), data)
                 for h in range(1, hmax + 1) if h not in keep}
        if not trial:
            break
        h = min(trial, key=trial.get)
        if trial[h] > (1 - min_gain) * best:
            break
        keep.append(h)
        best = trial[h]
    return sorted(keep), best


def spindle_candidates(eng, data, spindle_hz=None) -> tuple:
    """``(frequencies [Hz], known)``: given, from metadata, else the three strongest
    harmonic-sum peaks of the residual (strongest first; ``known`` False)."""
    if spindle_hz:
        return [float(spindle_hz)], True
    f0, _ = spindle_from_metadata(data.log.metadata, data.log.sample_rate_hz)
    if f0:
        return [f0], True
    e = np.zeros(data.log.n)
    e[data.windows.index()] = eng.residual()
    out = [f for f, _ in detect_spindle(e, data.windows, data.log.sample_rate_hz, top=3)]
    return [f for f in dict.fromkeys(round(x, 3) for x in out) if 20.0 <= f <= 400.0], False


def fit_periodic_disturbance(plant, data, settings, spindle_hz=None):
    eng = Engine(plant, data)
    fs = data.log.sample_rate_hz
    P0 = eng.project(eng.target(), *eng.base_cols())
    freqs, known = spindle_candidates(eng, data, spindle_hz)
    best = None
    for f0 in freqs:
        hs, sse = _select_harmonics(eng, P0, data, f0, int(min(8, 0.45 * fs / f0)))
        # the strongest detected peak first; an alternative must do clearly better
        if hs and (best is None or sse < 0.98 * best[0]):
            best = (sse, f0, hs)
    if best is None:
        return None
    _, f0, hs = best
    if not known:   # a detected frequency may be a sub-harmonic: keep the gcd of the harmonics
        g = math.gcd(*hs)
        f0, hs = f0 * g, [h // g for h in hs]
        T = data.log.time_s[-1] - data.log.time_s[0]   # refine (phase drift over the log)
        f0 = float(minimize_scalar(lambda f: _harmonic_fit(eng, P0, data, f, hs)[2],
                                   bounds=(f0 - 1.0 / T, f0 + 1.0 / T), method="bounded",
                                   options={"xatol": 2e-3}).x)
    _, th, _ = _harmonic_fit(eng, P0, data, f0, hs)
    nb = P0.shape[1] - 1
    eff = PeriodicDisturbance(float(f0), [int(h) for h in hs], [float(x) for x in th[nb::2]],
                              [float(x) for x in th[nb + 1::2]])
    p = refit_base(rebase(plant, th[:nb], eng.setters, effects=plant.effects + [eff]), data)
    return Fit("periodic_disturbance", p, 2 * len(hs) + (0 if known else 1), eff.params)
