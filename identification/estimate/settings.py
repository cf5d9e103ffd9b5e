"""Settings of the two identification methods, as data: :class:`PaperSettings`, :class:`RobustSettings`.

Each is a dataclass with named, unit-bearing fields and a JSON round trip (``to_json`` /
``from_json``); :meth:`IdentifySettings.replace` maps ``identify(log, method, **options)`` keyword
options onto the fields (one-line :class:`ValueError` on an unknown option or a bad value).
Units: frequencies [Hz], damping ratios [-], lengths in log samples [samples], ``*_rel`` relative
frequency differences ``|f_a / f_b - 1|`` [-].
"""
from __future__ import annotations

import dataclasses
import json
import numbers
from dataclasses import dataclass, fields

__all__ = ["IdentifySettings", "PaperSettings", "RobustSettings", "DEFAULT_FREQ_LOW_HZ",
           "DEFAULT_FREQ_HIGH_FRACTION"]

DEFAULT_FREQ_LOW_HZ = 100.0         #: lowest mode frequency looked for by default [Hz]
DEFAULT_FREQ_HIGH_FRACTION = 0.47   #: highest mode frequency looked for by default [fraction of fs]


@dataclass(frozen=True)
class IdentifySettings:
    """What both methods share.

    Attributes
    ----------
    holdout_every : int
        Every ``holdout_every``-th seek is held out of the fit for the held-out fit % [seeks];
        0 or 1, or fewer than ``2 holdout_every`` seeks in the log: none is held out.
    freq_range : (float, float) or None
        Band where modes are looked for [Hz]; None: ``(DEFAULT_FREQ_LOW_HZ, DEFAULT_FREQ_HIGH_FRACTION fs)``.
    """
    holdout_every: int = 5
    freq_range: tuple | None = None

    method = ""                                  # (class attribute: "paper" or "robust")

    def __post_init__(self):
        if not isinstance(self.holdout_every, numbers.Integral) or self.holdout_every < 0:
            raise ValueError(f"holdout_every must be a non-negative integer, got {self.holdout_every!r}")
        object.__setattr__(self, "holdout_every", int(self.holdout_every))
        if self.freq_range is not None:
            lo, hi = (float(v) for v in self.freq_range)
            if not 0 < lo < hi:
                raise ValueError(f"freq_range must be (lo, hi) with 0 < lo < hi [Hz], got {self.freq_range!r}")
            object.__setattr__(self, "freq_range", (lo, hi))

    def band(self, sample_rate_hz: float) -> tuple[float, float]:
        """``freq_range`` [Hz] resolved for a log sampled at ``sample_rate_hz``."""
        if self.freq_range is not None:
            return self.freq_range
        return DEFAULT_FREQ_LOW_HZ, DEFAULT_FREQ_HIGH_FRACTION * float(sample_rate_hz)

    def replace(self, **options) -> "IdentifySettings":
        """A copy with ``options`` (field names) changed; ValueError names an unknown option."""
        known = [f.name for f in fields(self)]
        unknown = sorted(set(options) - set(known))
        if unknown:
            raise ValueError(f"identify: unknown option(s) {unknown} for method {self.method!r} "
                             f"(known: {', '.join(known)})")
        return dataclasses.replace(self, **options)

    def to_dict(self) -> dict:
        return {"method": self.method, **{f.name: getattr(self, f.name) for f in fields(self)}}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @staticmethod
    def from_dict(d: dict) -> "IdentifySettings":
        """Settings from :meth:`to_dict` (the ``method`` key picks the class)."""
        d = dict(d)
        cls = {"paper": PaperSettings, "robust": RobustSettings}.get(d.pop("method", "robust"))
        if cls is None:
            raise ValueError("settings: method must be 'paper' or 'robust'")
        return cls().replace(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})

    @staticmethod
    def from_json(text: str) -> "IdentifySettings":
        return IdentifySettings.from_dict(json.loads(text))


@dataclass(frozen=True)
class PaperSettings(IdentifySettings):
    """The paper's method (Sections 2-3): eq. (8), LS Prony (eqs. (4)-(7)), eqs. (9)-(11).

    Attributes
    ----------
    prony_order : int
        Largest number of mode pairs ``n`` of LS Prony (the roots of the order-``2n`` polynomial).
    max_zeta : float
        Prony roots with a damping ratio at or above this are not modes [-].
    """
    prony_order: int = 8
    max_zeta: float = 0.5

    method = "paper"


@dataclass(frozen=True)
class RobustSettings(IdentifySettings):
    """The robust output-error method (:class:`identification.estimate.robust.RobustIdentifier`).

    Model and search
        ``max_modes`` (most modes fitted), ``t_min`` (least ``|gain| / std`` kept [-]),
        ``blind`` (write into ``plant.meta`` the bands where a mode would have escaped detection,
        :func:`identification.estimate.blind.blind_meta`), ``scan`` (look for modes the settle windows do not show), ``max_nfev`` / ``final_nfev``
        (residual evaluations per refinement in the search / final stage), ``stage_rows`` (samples
        of the search stage [samples]), ``stage_history`` (samples before its first seek, where
        the mode filters start [samples]).
    Parameter bounds and start
        ``freq_low_factor`` (lowest mode frequency, times the low end of ``freq_range`` [-]),
        ``freq_high_fraction`` (highest, times fs [-]; below Nyquist), ``zeta_bounds`` [-],
        ``delay_bounds_samples`` (input delay [samples]), ``zeta_start_min`` (floor on a pencil
        pole's damping used as a start [-]), ``rigid_delay_range_samples`` / ``rigid_delay_grid``
        (grid of the rigid fit's delay search [samples] / [points]), ``stabilisation_max_order``
        (largest pencil order of the stabilisation diagram, in poles).
    Noise model, covariance, bias
        ``ar_order`` (AR whitening order [samples], 0 disables), ``noise_model_passes`` (times the
        final stage re-fits the AR model to the whitened estimate's own output error and refines
        again [-]), ``noise_unit_poles`` (poles at z = 1 imposed on the noise model, the AR model
        fitted to the output error differenced that many times [-]; 2: the unlogged force noise
        through the rigid body's double integrator, a random walk of velocity within each seek, which
        an AR model of short detrended segments cannot place on the unit circle), ``cov`` (``"newey-west"`` or
        ``"cluster"``), ``nw_lags`` (Newey-West lags [samples]), ``cov_floor_white`` (every variance at
        least the Gauss-Newton one of the whitened problem, the sandwich's correlations kept:
        :func:`identification.estimate.linalg.floored_cov`), ``bias_from`` (``"whole-log"``:
        the rigid body's momentum balance from seek to seek over the whole log; ``"seeks"``: the
        per-seek output-error fit's), ``residual_fs_multiple`` (the output-error model's residual
        compliance of the modes it does not hold -- a missed mode near the detection threshold, modes
        near or above Nyquist -- is the response of an overdamped mode at this multiple of fs times
        its ``w^2`` [-]; 0: no such term, and a missed mode's quasi-static response is taken up by the
        highest fitted modes' gains and damping, biasing them by several std, see
        :class:`identification.estimate.varpro.VarPro`), ``residual_max_share`` (the plant does not
        hold that term: it is kept while its contribution's RMS on the fit rows is at most this
        multiple of the fitted model's output-error RMS [-] or at most ``residual_max_track`` [track]
        (half the settle band: a noise-free log has no output error to compare with); beyond both it is not a residual
        compliance but half of a pair with a fitted mode -- e.g. a broad mode at the frequency bound
        and a compliance of opposite sign that together build the phase of an amplifier lag -- and the
        plant without it would not be the model fitted, so the final stage is refined without it).
    Repeatable run-out
        ``periodic`` (``"auto"``: detected; None: none; or the period [samples]),
        ``periodic_harmonics`` (harmonics fitted), ``periodic_search_samples`` (periods tried by the
        detection, (shortest, longest) [samples]), ``periodic_min_F`` (least phase-bin F statistic
        of a detected period [-]), ``runout_zeta_max`` / ``runout_harmonic_tol`` (a fitted mode with
        damping below this [-] within this many harmonic numbers [-] of a run-out harmonic is a
        run-out line, not a mode).
    Mode pruning and the scan (relative frequency differences ``|f_a / f_b - 1|`` [-])
        ``duplicate_sep_rel`` (two modes closer than this: the weaker is dropped), ``scan_step_rel``
        (step of the log-spaced scan grid), ``scan_zetas`` / ``scan_fine_zetas`` (damping ratios
        of the coarse / fine scan [-]), ``scan_gate`` (least RSS reduction of one more mode, in
        residual variances, as a multiple of ``t_min^2`` [-]; 1: every mode the pruning would keep
        is proposed -- a left-out mode that passes ``t_min`` biases the others by more than their
        std, e.g. the 36 kHz calibration drive's 15.2 kHz mode, statistic 32, moved the other gains
        by 2-4 std), ``scan_max_new`` (peaks tried per
        round), ``scan_peak_sep_rel`` (least separation of the peaks tried in one round),
        ``scan_fine_span_rel`` / ``scan_fine_points`` (the fine grid around a peak: +-span in ln f, points),
        ``scan_step_zeta`` (the grid of the scan column of damping ``zeta`` is stepped by
        ``min(scan_step_rel, scan_step_zeta zeta)``: a lightly damped mode's statistic is a spike about
        its bandwidth wide), ``scan_ar_zeta_max`` (the scan also looks around each pole of the AR noise
        model damped less than this [-], at relative steps of ``scan_step_zeta`` times the pole's
        damping: a lightly damped mode the noise model absorbed leaves a spike that narrow; 0 disables),
        ``scan_proposal_sep_rel`` (least separation of refined proposals), ``tabu_sep_rel`` (no
        proposal this close to a frequency proposed or dropped before), ``existing_sep_rel`` (nor
        this close to a fitted mode), ``scan_idle_rounds`` (rounds without a new mode that stop
        the scan).
    """
    max_modes: int = 12
    t_min: float = 5.0
    blind: bool = True
    scan: bool = True
    max_nfev: int = 25
    final_nfev: int = 10
    stage_rows: int = 60_000
    stage_history: int = 4096
    freq_low_factor: float = 0.8
    freq_high_fraction: float = 0.499
    zeta_bounds: tuple = (1e-4, 0.7)
    delay_bounds_samples: tuple = (0.0, 4.0)
    zeta_start_min: float = 1e-3
    rigid_delay_range_samples: tuple = (0.0, 3.0)
    rigid_delay_grid: int = 13
    stabilisation_max_order: int = 24
    ar_order: int = 32
    cov: str = "newey-west"
    nw_lags: int = 32
    cov_floor_white: bool = True
    noise_model_passes: int = 1
    noise_unit_poles: int = 2
    bias_from: str = "whole-log"
    periodic: object = "auto"
    periodic_harmonics: int = 10
    periodic_search_samples: tuple = (20, 2000)
    periodic_min_F: float = 4.0
    runout_zeta_max: float = 1e-3
    runout_harmonic_tol: float = 0.02
    duplicate_sep_rel: float = 0.015
    scan_step_rel: float = 0.02
    scan_zetas: tuple = (0.01, 0.05)
    scan_fine_zetas: tuple = (0.003, 0.01, 0.03, 0.1)
    scan_gate: float = 1.0
    scan_max_new: int = 3
    scan_peak_sep_rel: float = 0.05
    scan_fine_span_rel: float = 0.02
    scan_fine_points: int = 17
    scan_step_zeta: float = 0.5
    scan_ar_zeta_max: float = 0.05
    scan_proposal_sep_rel: float = 0.03
    tabu_sep_rel: float = 0.01
    existing_sep_rel: float = 0.02
    scan_idle_rounds: int = 2
    residual_fs_multiple: float = 2.0
    residual_max_share: float = 1.0
    residual_max_track: float = 0.05

    method = "robust"

    def __post_init__(self):
        super().__post_init__()
        if self.cov not in ("newey-west", "cluster"):
            raise ValueError(f"cov must be 'newey-west' or 'cluster', got {self.cov!r}")
        if not isinstance(self.cov_floor_white, bool):
            raise ValueError(f"cov_floor_white must be True or False, got {self.cov_floor_white!r}")
        if self.bias_from not in ("whole-log", "seeks"):
            raise ValueError(f"bias_from must be 'whole-log' or 'seeks', got {self.bias_from!r}")
        if not (self.periodic in ("auto", None) or (isinstance(self.periodic, numbers.Integral)
                                                       and not isinstance(self.periodic, bool) and self.periodic >= 2)):
            raise ValueError(f"periodic must be 'auto', None or a period >= 2 [samples], got {self.periodic!r}")
        if not isinstance(self.noise_model_passes, numbers.Integral) or self.noise_model_passes < 0:
            raise ValueError(f"noise_model_passes must be a non-negative integer, got {self.noise_model_passes!r}")
        for name in ("max_modes", "max_nfev", "final_nfev", "stage_rows", "scan_fine_points"):
            if not isinstance(getattr(self, name), numbers.Integral) or getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if not isinstance(self.noise_unit_poles, numbers.Integral) or self.noise_unit_poles < 0:
            raise ValueError(f"noise_unit_poles must be a non-negative integer, got {self.noise_unit_poles!r}")
        if not isinstance(self.ar_order, numbers.Integral) or self.ar_order < 0:
            raise ValueError(f"ar_order must be a non-negative integer, got {self.ar_order!r}")
        if not (self.residual_fs_multiple == 0 or self.residual_fs_multiple > 0.5):
            raise ValueError(f"residual_fs_multiple must be 0 or above 0.5 (above Nyquist), got {self.residual_fs_multiple!r}")
        for name in ("residual_max_share", "residual_max_track"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        for name in ("scan_step_rel", "scan_step_zeta"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not 0 < self.freq_high_fraction < 0.5:
            raise ValueError(f"freq_high_fraction must lie in (0, 0.5) (below Nyquist), got {self.freq_high_fraction!r}")
