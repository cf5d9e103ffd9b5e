"""Identify the modal plant from a seek log: ``identify(log, method="robust" | "paper", settings=..., **options)``.

Only the columns a real drive logs are used: ``time_s``, ``current_a``, ``position_track``,
``target_track`` (never the synthetic drive's feedforward or reference columns); a multirate drive's
sub-step currents ``current_sub1_a`` .. ``current_subL_a``, when logged, replace ``current_a`` in the
robust method (exact hold, :meth:`identification.logs.seeklog.SeekLog.input_current`).

``method="paper"``
    The seed paper's method, eqs. (8), (4)-(7) and (9)-(11) in order
    (:class:`identification.estimate.paper.PaperIdentifier`, :class:`PaperSettings`).
``method="robust"`` (default)
    Output-error fit of position to current over whole seeks by variable projection, AR noise
    model, scan for modes the settle windows miss, run-out, sandwich standard deviations
    (:class:`identification.estimate.robust.RobustIdentifier`, :class:`RobustSettings`).

Known model error (tolerated, not modelled).  The synthetic drive steps the plant at 2x the PES rate
with multirate notches and logs the mean current per PES sample; the intersample current then acts
as an unlogged feedback around the high-frequency modes.  Measured on the default drive: 4.1 kHz
frequency +0.5 %, 7 kHz damping about -33 %; on a drive with single-rate notches these vanish
(``tests/test_identify.py``, ``docs/results_identification.md``).  Logging the sub-step currents
removes it.

Held-out seeks (both methods): seeks ``i`` with ``i % holdout_every == holdout_every - 1`` are not
fitted; the fit % on them is :func:`identification.estimate.heldout.heldout_fit`
(``Identification.fit_percent``; ``diagnostics["fit_percent_window_init"]`` fits the initial position
and velocity on the settle window instead).
"""
from __future__ import annotations

import math
import time

from identification.estimate.heldout import heldout_fit, predict_segments, runout_signal
from identification.estimate.paper import PaperIdentifier
from identification.estimate.result import Identification
from identification.estimate.robust import RobustIdentifier
from identification.estimate.settings import IdentifySettings, PaperSettings, RobustSettings
from identification.logs.seeklog import LogError, SeekLog, segment_seeks

__all__ = ["Identification", "identify", "make_settings", "PaperSettings", "RobustSettings", "heldout_fit",
           "predict_segments", "runout_signal"]

_METHODS = {"paper": (PaperSettings, PaperIdentifier), "robust": (RobustSettings, RobustIdentifier)}


def make_settings(method: str | None = None, settings: IdentifySettings | None = None, **options) -> IdentifySettings:
    """The settings ``identify`` runs with: ``settings`` (default: the method's defaults) with
    ``options`` applied.  ValueError (one line) for an unknown method or option, or a method that
    contradicts ``settings``."""
    if method is not None and method not in _METHODS:
        raise ValueError(f"method must be 'robust' or 'paper', got {method!r}")
    if settings is None:
        settings = _METHODS[method or "robust"][0]()
    elif not isinstance(settings, IdentifySettings):
        raise ValueError(f"settings must be PaperSettings or RobustSettings, got {type(settings).__name__}")
    elif method is not None and settings.method != method:
        raise ValueError(f"method {method!r} contradicts {type(settings).__name__}")
    return settings.replace(**options) if options else settings


def _split(log: SeekLog, holdout_every: int):
    seeks = segment_seeks(log)
    name = log.source or "<log>"
    if len(seeks) < 2:
        raise LogError(name, f"need at least 2 seeks to identify a plant, found {len(seeks)}")
    if holdout_every and holdout_every > 1 and len(seeks) >= 2 * holdout_every:
        held = [s for i, s in enumerate(seeks) if i % holdout_every == holdout_every - 1]
        fit = [s for i, s in enumerate(seeks) if i % holdout_every != holdout_every - 1]
    else:
        held, fit = [], seeks
    if not any(s.settled for s in fit):
        raise LogError(name, "no seek settles within the 0.1-track band: no settle window to identify modes from")
    return seeks, fit, held


def identify(log: SeekLog, method: str | None = None, settings: IdentifySettings | None = None,
             **options) -> Identification:
    """Identify the modal plant (rigid body, modes, bias, delay) from a seek log.

    Parameters
    ----------
    log : SeekLog
        Seek log; only ``current_a`` (or the sub-step currents), ``position_track``,
        ``target_track`` and the rate are used.
    method : {"robust", "paper"}, optional
        See the module notes; default ``settings.method``, else ``"robust"``.
    settings : PaperSettings or RobustSettings, optional
        Every setting of the method (:mod:`identification.estimate.settings`); default its defaults.
    **options
        Fields of the settings to change, e.g. ``holdout_every`` (5), ``freq_range`` ((lo, hi) [Hz],
        default ``(100, 0.47 fs)``), ``prony_order`` (paper), ``max_modes``, ``ar_order``, ``t_min``,
        ``periodic``, ``cov``, ``nw_lags`` (robust).

    Returns
    -------
    Identification

    Raises
    ------
    ValueError
        Unknown method or option, or a bad setting (before any computation).
    LogError
        Too few seeks, no settled seek, or no usable data.
    """
    settings = make_settings(method, settings, **options)
    t0 = time.perf_counter()
    seeks, fit_seeks, held = _split(log, settings.holdout_every)
    timing = {"segment": time.perf_counter() - t0}
    ident = _METHODS[settings.method][1](settings).run(log, fit_seeks, timing)
    t1 = time.perf_counter()
    if held:
        ro, rigid = ident.diagnostics.get("runout"), ident.plant.copy(modes=[])
        ident.fit_percent = heldout_fit(log, ident.plant, held, runout=ro)
        ident.fit_percent_rigid = heldout_fit(log, rigid, held, runout=ro)
        ident.diagnostics["fit_percent_window_init"] = heldout_fit(log, ident.plant, held, "window", ro)
        ident.diagnostics["fit_percent_rigid_window_init"] = heldout_fit(log, rigid, held, "window", ro)
    timing["heldout"] = time.perf_counter() - t1
    timing["total"] = time.perf_counter() - t0
    ident.timing = timing
    ident.diagnostics.update(n_samples=log.n, n_seeks=len(seeks), n_fit_seeks=len(fit_seeks),
                             n_heldout_seeks=len(held), holdout_every=settings.holdout_every if held else 0,
                             samples_per_s=log.n / timing["total"] if timing["total"] > 0 else float("inf"))
    fit = None if math.isnan(ident.fit_percent) else round(ident.fit_percent, 3)
    ident.plant.meta.update(method=settings.method, log=log.source or "<arrays>", heldout_fit_percent=fit)
    if getattr(settings, "blind", False):      # what the log could not show (identification.estimate.blind)
        from identification.estimate.blind import blind_meta
        t2 = time.perf_counter()
        ident.plant.meta.update(blind_meta(log, ident.plant, t_min=settings.t_min,
                                           freq_range=settings.band(log.sample_rate_hz),
                                           runout=ident.diagnostics.get("runout")))
        timing["blind"] = time.perf_counter() - t2
    return ident
