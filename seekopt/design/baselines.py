"""The paper's baseline seek profiles, as complete :class:`~seekopt.design.profiles.Profile` objects
(one copy, used by the bench, the sweep and the studies).

* :func:`baseline_profile`: the shortest sine / windowed sine / bang-bang current within ``Imax``
  (:func:`seekopt.design.profiles.shortest_baseline`) with the paper's 2DOF reference from the rigid
  model (Fig. 7);
* :func:`tuned_baseline`: the same shape at the duration that settles soonest on a given plant
  (durations :data:`TUNE_FACTORS` times the shortest): the most a baseline can get.

The current shapes themselves (paper Section 4, ERRATA items 3 and 4) are in
:mod:`seekopt.design.profiles`.
"""
from __future__ import annotations

import numpy as np

from identification.model.plant import ModalPlant

from seekopt.design.metrics import evaluate_profile
from seekopt.design.profiles import (Profile, finish_profile, shortest_baseline, sine_profile,
                                     windowed_sine_profile)

__all__ = ["baseline_profile", "tuned_baseline", "TUNE_FACTORS", "BASELINE_SHAPES"]

#: Durations tried by :func:`tuned_baseline`, as multiples of the shortest within ``Imax``: 4 % steps
#: from 1 to 8 (rounded to whole samples, duplicates dropped).
TUNE_FACTORS = tuple(float(f) for f in np.unique(np.round(1.04 ** np.arange(54), 4)))
#: Baseline shapes with a duration argument (``f(tracks, seek_time_s, k0, fs) -> u_ff``).
BASELINE_SHAPES = {"sine": sine_profile, "windowed_sine": windowed_sine_profile}


def _rigid(plant: ModalPlant) -> ModalPlant:
    """The paper's reference model: the rigid body with the plant's delay."""
    return ModalPlant(k0=plant.k0, delay_s=plant.total_delay_s)


def baseline_profile(plant: ModalPlant, fs: float, kind: str, tracks: float, imax: float,
                     settle: float = 0.1) -> Profile:
    """Shortest ``kind`` baseline (``sine``, ``windowed_sine``, ``bang_bang``) within ``imax`` [A] with
    the rigid-model reference (paper, Fig. 7); ``fs`` the servo rate [Hz], ``settle`` the band [track]."""
    u = shortest_baseline(kind, tracks, plant.k0, fs, imax)
    return finish_profile(u, tracks, fs, imax, _rigid(plant), kind, settle_track=settle,
                          meta={"plant_hash": plant.hash()})


def tuned_baseline(plant: ModalPlant, controller, kind: str, tracks: float, imax: float, settle: float = 0.1, *,
                   tune_on: ModalPlant | None = None, factors=TUNE_FACTORS, horizon_s: float | None = None):
    """Best-length ``kind`` baseline: the :func:`baseline_profile` shape and rigid-model reference (from
    ``plant``) at the duration ``round(f * n0)`` samples, ``f`` in ``factors`` and ``n0`` the shortest
    within ``imax``, that has the least seek-settle time on ``tune_on`` (default ``plant``; ties: the
    shorter).  Returns ``(profile, metrics on tune_on)``."""
    shape = BASELINE_SHAPES[kind]
    fs = float(controller.sample_rate_hz)
    n0 = len(shortest_baseline(kind, tracks, plant.k0, fs, imax))
    rigid = _rigid(plant)
    best = None
    for n in sorted({max(2, int(round(f * n0))) for f in factors}):
        prof = finish_profile(shape(tracks, n / fs, plant.k0, fs), tracks, fs, imax, rigid, kind,
                              settle_track=settle, meta={"plant_hash": plant.hash(), "tuned_from_samples": n0})
        m = evaluate_profile(tune_on or plant, controller, prof, settle=settle, horizon_s=horizon_s,
                             k0_for_tbb=plant.k0)
        if best is None or m.settle_time_s < best[1].settle_time_s:
            best = (prof, m)
    return best
