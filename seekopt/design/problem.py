"""The seek-design problem as data (:class:`SeekProblem`), its JSON form, and the quantities derived from
it that need no optimiser (the default band margin, :func:`band_tail_samples`).  How its QPs are solved,
:class:`SolverSettings`, is in :mod:`seekopt.design.solver_settings`, the checks of its settings and
:func:`check_closed_loop` in :mod:`seekopt.design.problem_checks` (both re-exported here).

The acados template pattern: the problem is a serialisable description; a
:class:`seekopt.design.designer.SeekDesigner` is built once from it and then called for many seek
lengths.  Nothing here builds a QP.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from identification.model.plant import ModalPlant, atomic_write_text

from seekopt.design.problem_checks import (ProblemError, check_closed_loop, fraction, nonnegative_s, positive,
                                           samples_within)
from seekopt.design.robust import RobustSpec
from seekopt.design.solver_settings import SIZE_CLASSES, SolverSettings  # noqa: F401
from seekopt.design.solvers import DAQP_PKG
from seekopt.drive.loopcheck import closed_loop_poles

__all__ = ["ProblemError", "SolverSettings", "SeekProblem", "check_closed_loop", "band_tail_samples", "SIZE_CLASSES",
           "TAIL_MIN_SAMPLES", "TAIL_CYCLES", "LIGHT_DAMPING", "TAIL_MAX_S", "BAND_MARGIN", "DRIFT_BAND_MARGIN",
           "default_band_margin"]

#: Design band (fraction of the settle band) of a design on the nominal plant alone or over a
#: :class:`RobustSpec` box (corners and orthogonal-array rows: nothing inside the box is sampled, so the
#: margin also covers the box's interior -- a quadratic model of the PES along one drift direction through
#: the nominal plant and its two vertices peaks at b0 + bv^2 / (4 b0) = 1.0 for 0.8 / 0.8).
BAND_MARGIN = 0.8
#: Design band over a :class:`seekopt.design.family.Drift` set: the set samples the common drifts' faces
#: (corners and axial points, :func:`seekopt.design.driftset._common_points`; a face's dense grid then
#: settles no later than the set's worst) and carries the identification's +-n_sigma per-mode ranges, so
#: the margin covers only what no plant of the set carries (identification error beyond them, unmodelled
#: modes under the guard, nonlinear effects).  Measured (studies/operating_range.py, the room member's
#: truth played on a grid of its temperature x gain drift, K = 200): 0.9 settles within 1.06x the set's
#: predicted worst; 0.95 leaves the band for 66 samples at temperature +1 %, gain +5 % (set: 33).
DRIFT_BAND_MARGIN = 0.9


def default_band_margin(robust) -> float:
    """:data:`DRIFT_BAND_MARGIN` for a :class:`~seekopt.design.family.Drift` set, else :data:`BAND_MARGIN`."""
    return DRIFT_BAND_MARGIN if _is_drift(robust) else BAND_MARGIN


def _is_drift(robust) -> bool:
    return robust is not None and getattr(robust, "to_dict", lambda: {})().get("kind") == "drift"


#: The band rows after a seek (:func:`band_tail_samples`): at least this many samples, ...
TAIL_MIN_SAMPLES = 64
#: ... and this many periods of the slowest lightly damped closed-loop oscillation (damping ratio below
#: ``LIGHT_DAMPING``): a slow mode cancelled by faster ones at the end of the seek crests once they have
#: decayed (a 300 Hz flex mode of a loop-fitted Kt plant rose from 0.065 to 0.0999 band 0.8-1.6 ms after a
#: 3 ms row window), ...
TAIL_CYCLES = 2.0
LIGHT_DAMPING = 0.1
#: ... but never more than this [s] (a lightly damped loop pole below ~70 Hz is a loop problem, not a seek's)
TAIL_MAX_S = 0.03


@dataclass(eq=False)
class SeekProblem:
    """One seek-design problem: the drive, the limits and what "settled" means.

    Parameters
    ----------
    plant : ModalPlant
        Identified (design) plant; its linear part is designed for, the full plant checked.
    controller : Controller
        The drive's feedback controller (servo rate ``controller.sample_rate_hz``).
    imax_a : float
        Current limit [A] on the total current (feedforward + feedback + hold, every sub-step).
    settle_band_track : float
        Settle band [track] (``|PES| <= band`` from the settle time on).
    band_margin : float or None
        ``beta``: design band as a fraction of the settle band, kept for what the plant set does not
        cover.  None: :func:`default_band_margin` (0.8 on the nominal plant or a :class:`RobustSpec` box,
        0.9 over a :class:`~seekopt.design.family.Drift` set, whose plants sample the interior of the
        common drifts; at K = 200 on the identified plant with ``RobustSpec()`` 0.7 -> 2.12 T_bb,
        0.8 -> 1.93, 0.9 -> 1.80).
    current_margin : float
        ``gamma``: design current limit as a fraction of ``imax_a``.
    robust : RobustSpec, Drift or None
        Plant uncertainty (None: nominal plant only): a :class:`seekopt.design.family.Drift` (drift in
        physical terms, ranges from the data) or a :class:`RobustSpec` (per-mode box).
    family : list of ModalPlant
        Further plants of the drive's family (other temperatures, heads, zones) the design must hold
        (worst case); ``plant`` is the nominal member.
    slew_a_per_s : float or None
        Feedforward slew-rate limit [A/s].
    reference : {"free", "model", "rigid"}
        Reference designed jointly (ERRATA item 6), or the response of the plant model (modes
        included) or of the rigid body to the feedforward (the paper).
    tail_s : float
        Time after the seek over which the band is enforced in the QP [s] (lengthened for a slow
        lightly damped loop mode: :meth:`band_tail_samples`; the simulator check runs longer).
    hf_guard : (float, float) or None
        Band of unmodelled modes as fractions of the servo rate (identification does not see modes
        near and above Nyquist); ``hf_gain`` their gain relative to the rigid body, ``hf_tol`` the
        allowed residual per mode as a fraction of the settle band.
    guard_notch_depth_db : float or None
        The guard also covers the controller's notches and filter zeros at least this deep
        (:func:`seekopt.design.guard_bands.controller_notches`; None: not).
    guard_bands_hz : tuple
        Further guard bands ``(lo_hz, hi_hz)`` or ``(lo_hz, hi_hz, gain)``.
    blind_pes_points : int
        Minimum seek-settle designs: the PES a mode of the Nyquist guard band (gain ``hf_gain``, either
        sign) adds after the settle sample, forced and free, on this many frequencies across the band, is
        added to every band plant's PES and the sum bounded (:mod:`seekopt.design.blind_pes`; 0: not).
    blind_pes_tol : float or None
        That bound as a fraction of the settle band; None: ``(1 + band_margin) / 2`` (the margin above the
        design band split between the blind-band mode and what no plant carries -- identification error:
        with 1, K = 1 on the operating-range family's cold / hot member left the band by 0.01-0.04 band, the
        identified member's error, and settled 1.5 x later than predicted).  Rows off when not positive.
    check_robust : bool
        Also simulate each design on every plant of the robust set.
    input_tail_s : float
        Minimum seek-settle designs: the feedforward and the reference may go on for this long after the
        settle sample [s] (rounded to samples; the seek-settle time counts ``|PES|`` only, so the inputs
        may keep shaping the loop while the head is inside the band; the profile's ``seek_samples`` is
        the length of its inputs).  0: the inputs end at the settle sample.
    nominal_first : bool
        Minimum seek-settle design over a plant set, lexicographic: the worst seek-settle time over the
        set first, then, holding it, the nominal plant's (the nominal plant may settle before the set's
        worst; :meth:`seekopt.design.designer.SeekDesigner._nominal_first`).  False: every plant's band
        from the same sample (the worst case alone).
    worst_case_slack_s : float
        The servo engineer's trade-off between the set's worst case and the nominal plant [s] (rounded down
        to whole servo samples, :meth:`worst_case_slack_samples`): the lexicographic design may let the
        set's worst seek-settle time be up to this much later than its minimum ``N`` (the set's band rows
        from ``N + slack`` at most, the seek that long) so that the nominal plant settles earlier; of the
        lengths within the slack the shortest that keeps the nominal plant's earliest settle is taken.
        0 (default): the set's minimum exactly.  Needs ``nominal_first``.  Stated in s, not samples,
        like every time of the problem (a slack means the same at any servo rate; the family of
        ``studies/operating_range.py`` needs one sample, 38 us at 26.4 kHz, for the room plant's 32 samples).
    solver : SolverSettings
    """

    plant: ModalPlant
    controller: object
    imax_a: float
    settle_band_track: float = 0.1
    band_margin: float | None = None
    current_margin: float = 0.97
    robust: RobustSpec | None = None
    family: list = field(default_factory=list)
    slew_a_per_s: float | None = None
    reference: str = "free"
    tail_s: float = 0.008
    hf_guard: tuple | None = (0.45, 0.65)
    hf_gain: float = 1.0
    hf_tol: float = 0.1
    guard_notch_depth_db: float | None = 6.0
    guard_bands_hz: tuple = ()
    blind_pes_points: int = 5
    blind_pes_tol: float | None = None
    check_robust: bool = False
    input_tail_s: float = 3e-4
    nominal_first: bool = True
    worst_case_slack_s: float = 0.0
    solver: SolverSettings = field(default_factory=SolverSettings)

    def __post_init__(self):
        self.imax_a = positive("imax", self.imax_a)
        self.settle_band_track = positive("settle band", self.settle_band_track)
        if isinstance(self.robust, str):
            self.robust = None if self.robust.lower() == "none" else RobustSpec.from_string(self.robust)
        if self.band_margin is None:
            self.band_margin = default_band_margin(self.robust)
        self.band_margin = fraction("band_margin", self.band_margin)
        self.current_margin = fraction("current_margin", self.current_margin)
        if self.reference not in ("free", "model", "rigid"):
            raise ProblemError(f"reference must be 'free', 'model' or 'rigid', not {self.reference!r}")
        self.family = list(self.family or [])
        if self.slew_a_per_s is not None:
            self.slew_a_per_s = positive("slew", self.slew_a_per_s)
        if self.hf_guard is not None:
            self.hf_guard = tuple(float(f) for f in self.hf_guard)
        self.guard_bands_hz = tuple(tuple(float(v) for v in b) for b in (self.guard_bands_hz or ()))
        self.blind_pes_points = int(self.blind_pes_points)
        if self.blind_pes_tol is not None:
            self.blind_pes_tol = float(self.blind_pes_tol)
        self.tail_s = positive("tail_s", self.tail_s)
        self.input_tail_s = float(self.input_tail_s)
        if not (math.isfinite(self.input_tail_s) and 0 <= self.input_tail_s < self.tail_s):
            raise ProblemError(f"input_tail_s must be in [0, tail_s) (got {self.input_tail_s!r})")
        self.worst_case_slack_s = nonnegative_s("worst_case_slack_s", self.worst_case_slack_s)
        if self.worst_case_slack_s > 0 and not self.nominal_first:
            raise ProblemError("worst_case_slack_s needs nominal_first (the slack lets the nominal plant settle "
                               "before the set's worst)")
        if isinstance(self.solver, dict):
            self.solver = SolverSettings.from_dict(self.solver)

    # ------------------------------------------------------------------ derived
    @property
    def sample_rate_hz(self) -> float:
        return float(self.controller.sample_rate_hz)

    def worst_case_slack_samples(self) -> int:
        """:attr:`worst_case_slack_s` in whole servo samples (rounded down: the set's worst case is never
        later than stated)."""
        return samples_within(self.worst_case_slack_s, self.sample_rate_hz)

    def blind_pes_bound(self) -> float | None:
        """Bound of the blind-band mode's PES rows [fraction of the band] (:mod:`seekopt.design.blind_pes`),
        None when the rows are off (no Nyquist band, no points, or a bound that is not positive)."""
        tol = 0.5 * (1.0 + self.band_margin) if self.blind_pes_tol is None else self.blind_pes_tol
        if not self.hf_guard or self.blind_pes_points <= 0 or not tol > 0:
            return None
        return float(tol)

    def band_tail_samples(self) -> int:
        """Samples after the seek carrying settle-band rows: :func:`band_tail_samples` of the nominal plant
        (the one rule of the linear designer, the long-seek designer and the effect-aware NLP)."""
        return band_tail_samples(self.plant, self.controller, self.tail_s)

    def plants(self) -> list:
        """The design's plant set: nominal first, then the family members and the robust set's vertices
        (a :class:`~seekopt.design.family.Drift` places the members itself)."""
        from seekopt.design.family import label_set
        if self.robust is None:
            return label_set([self.plant], self.family)
        if _is_drift(self.robust):
            return self.robust.plants(self.plant, self.family)
        return label_set(self.robust.plants(self.plant), self.family)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict:
        """Plain data: ``plant`` and ``controller`` as their own JSON dicts."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["plant"], d["controller"] = self.plant.to_dict(), self.controller.to_dict()
        d["robust"] = self.robust.to_dict() if self.robust else None
        d["family"] = [p.to_dict() for p in self.family]
        d["hf_guard"] = list(self.hf_guard) if self.hf_guard is not None else None
        d["guard_bands_hz"] = [list(b) for b in self.guard_bands_hz]
        d["solver"] = self.solver.to_dict()
        return {"schema": 1, **d}

    @classmethod
    def from_dict(cls, d: dict, source: str = "problem") -> "SeekProblem":
        from seekopt.drive.controller import Controller
        d = dict(d)
        if d.pop("schema", 1) != 1:
            raise ProblemError(f"{source}: unsupported seek-problem schema")
        try:
            d["plant"] = ModalPlant.from_dict(d["plant"], source=f"{source}: plant")
            d["controller"] = Controller.from_json(d["controller"])
            d["robust"] = _robust_from_dict(d["robust"]) if d.get("robust") else None
            d["family"] = [ModalPlant.from_dict(p, source=f"{source}: family member {i}")
                           for i, p in enumerate(d.get("family") or [], 1)]
            d["solver"] = SolverSettings.from_dict(d.get("solver") or {})
            return cls(**d)
        except (KeyError, TypeError) as exc:
            raise ProblemError(f"{source}: not a valid seek problem ({type(exc).__name__}: {exc})") from None

    def to_json(self, path: str | Path | None = None) -> str:
        text = json.dumps(self.to_dict(), indent=1)
        if path is not None:
            atomic_write_text(path, text)
        return text

    @classmethod
    def from_json(cls, text_or_path) -> "SeekProblem":
        """From a JSON string or a file path."""
        src = "problem"
        if isinstance(text_or_path, Path) or not str(text_or_path).lstrip().startswith("{"):
            src = str(text_or_path)
            text_or_path = Path(text_or_path).read_text()
        try:
            d = json.loads(text_or_path)
        except json.JSONDecodeError as exc:
            raise ProblemError(f"{src}: not valid JSON (line {exc.lineno})") from None
        return cls.from_dict(d, source=src)

    def __eq__(self, other) -> bool:
        return isinstance(other, SeekProblem) and self.to_dict() == other.to_dict()

    # ------------------------------------------------------------------ legacy keywords
    @classmethod
    def from_options(cls, plant, controller, imax, settle=0.1, robust=None, *, solver=DAQP_PKG, solver_options=None,
                     max_samples=512, fallbacks=None, **kw) -> "SeekProblem":
        """The former ``SeekDesigner(plant, controller, imax, settle, robust, **options)`` keywords."""
        ss = {"qp_solver": solver, "options": {solver: solver_options} if solver_options else {},
              "max_samples": max_samples}
        if fallbacks is not None:
            ss["fallbacks"] = tuple(fallbacks)
        return cls(plant, controller, imax, settle, robust=robust, solver=SolverSettings(**ss), **kw)


def _robust_from_dict(d: dict):
    """A :class:`RobustSpec` or (``"kind": "drift"``) a :class:`seekopt.design.family.Drift`."""
    if d.get("kind") == "drift":
        from seekopt.design.family import Drift
        return Drift.from_dict(d)
    return RobustSpec.from_dict(d)


def band_tail_samples(plant: ModalPlant, controller, tail_s: float) -> int:
    """Samples after a seek over which a design must hold its band margin (its band rows, and the
    effect-aware design's full-plant acceptance): ``tail_s`` [s], at least :data:`TAIL_MIN_SAMPLES`, and
    at least :data:`TAIL_CYCLES` periods of the slowest lightly damped (damping ratio below
    :data:`LIGHT_DAMPING`) pole of the closed loop of ``plant``'s linear part
    (:func:`seekopt.drive.loopcheck.closed_loop_poles`), at most :data:`TAIL_MAX_S`."""
    fs = float(controller.sample_rate_hz)
    n = max(int(round(float(tail_s) * fs)), TAIL_MIN_SAMPLES)
    poles = closed_loop_poles(plant, controller)
    poles = poles[(np.abs(poles) > 1e-12) & (np.abs(np.imag(poles)) > 1e-12)]
    if poles.size:
        s = np.log(poles) * fs                               # continuous-time equivalents [1/s]
        zeta = -np.real(s) / np.abs(s)
        w = np.abs(np.imag(s))[zeta < LIGHT_DAMPING]
        if w.size:
            period = 2 * math.pi / float(np.min(w))          # [s]
            n = max(n, int(math.ceil(min(TAIL_CYCLES * period, TAIL_MAX_S) * fs)))
    return n
