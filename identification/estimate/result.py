"""The result of an identification: :class:`Identification`."""
from __future__ import annotations

from dataclasses import dataclass, field

from identification.estimate.settings import IdentifySettings
from identification.model.plant import ModalPlant

__all__ = ["Identification"]


@dataclass
class Identification:
    """What :func:`identify` found.

    Attributes
    ----------
    plant : ModalPlant
        The identified plant; ``plant.std`` holds ``k0``, ``bias_a``, ``delay_s`` standard
        deviations and each mode's ``std`` its ``freq_hz``, ``zeta``, ``gain`` ones.
    method : str
        ``"robust"`` or ``"paper"``.
    poles_per_order : dict
        Pole sets seen on the way: ``{label: [(freq_hz, zeta), ...]}`` (pencil, Prony order,
        after each refinement stage).
    fit_percent : float
        Held-out fit % on settle windows (see the module notes); nan without held-out seeks.
    fit_percent_rigid : float
        The same for the identified rigid body alone (modes removed).
    residual_rms : float
        RMS of the fit residual [track] (robust: output error on the fit segments, before
        whitening; paper: eq. (10) residual on the settle windows).
    timing : dict
        Seconds per stage.
    diagnostics : dict
        Anything else, e.g. ``fit_percent_window_init`` (held-out fit with the initial conditions
        fitted on the settle window), ``runout`` (period and harmonic amplitudes [track] of the
        identified repeatable run-out), ``t_stat`` (|gain| / std per mode), ``std_inflation_median``
        (sandwich / plain std), ``scan_added``, ``pencil_rejected``, ``samples_per_s``.
    settings : PaperSettings or RobustSettings
        The settings the method ran with (:mod:`identification.estimate.settings`).
    """
    plant: ModalPlant
    method: str
    poles_per_order: dict = field(default_factory=dict)
    fit_percent: float = float("nan")
    fit_percent_rigid: float = float("nan")
    residual_rms: float = float("nan")
    timing: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    settings: IdentifySettings | None = None
