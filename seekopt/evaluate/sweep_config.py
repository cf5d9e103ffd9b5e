"""The grid of a sweep: its configuration (plant, controller, TPI x seek-length cells, current limit,
settle band, designer), the table's columns, the cell keys and the TPI re-expression of the controller.

One *cell* is a pair ``(tpi, tracks)``; :meth:`SweepConfig.cells` lists them in submission order
and :func:`cell_key` names each one's file in a results folder (:mod:`seekopt.evaluate.sweep_store`).
:meth:`SweepConfig.hash` is what saved cells must agree on to be reused, :func:`code_hash` the
provenance of the code that computed them.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from identification.model.plant import TRACK_PITCH_PER_TPI_NM, ModalPlant

from seekopt.drive.controller import Controller

__all__ = ["SweepError", "SweepConfig", "parse_tpi", "parse_tracks", "cell_key", "code_hash", "controller_factor",
           "controller_at_tpi", "KINDS", "ALL_KINDS", "TUNE_FACTORS", "TIMING_COLUMNS", "METRICS", "COLUMNS"]

#: Default profile kinds of a sweep, in table order.
KINDS = ("optimal", "sine", "windowed_sine")
#: All kinds: ``*_tuned`` are the baselines at the duration (from :data:`TUNE_FACTORS` times the
#: shortest within Imax) that minimises their seek-settle time on the design plant.
ALL_KINDS = KINDS + ("sine_tuned", "windowed_sine_tuned")
TUNE_FACTORS = (1.0, 1.25, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)
#: Columns whose values depend on the machine and load (excluded from determinism checks).
TIMING_COLUMNS = ("solve_time_s", "eval_time_s")
METRICS = ("seek_time_s", "settle_time_s", "peak_pes_after_track", "rms_pes_after_track",
            "peak_current_a", "ratio_tbb", "settled")
#: Columns of ``results.csv``.
COLUMNS = ("tpi", "track_pitch_nm", "k0_track", "controller_gain", "tracks", "kind", "status", "error",
           "designer", "design_status", "solver", "objective", "t_bb_s", "n_samples") + METRICS + TIMING_COLUMNS


class SweepError(ValueError):
    """Bad sweep input or results folder (one-line message)."""


# ------------------------------------------------------------------ grid parsing
def _num(text: str, what: str) -> float:
    t = text.strip().lower()
    mult = {"k": 1e3, "m": 1e6}.get(t[-1:], 1.0)
    try:
        v = float(t[:-1] if mult != 1.0 else t) * mult
    except ValueError:
        raise SweepError(f"{what}: {text!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise SweepError(f"{what}: {text!r} must be positive")
    return v


def parse_tpi(spec: str) -> list[float]:
    """``"200k:1000k:9"`` (start:stop:count, linear) or ``"200k,500k"`` -> TPI values."""
    if ":" in spec:
        parts = spec.split(":")
        if len(parts) != 3:
            raise SweepError(f"--tpi {spec!r}: expected start:stop:count, e.g. 200k:1000k:9")
        a, b = _num(parts[0], "--tpi"), _num(parts[1], "--tpi")
        try:
            n = int(parts[2])
        except ValueError:
            raise SweepError(f"--tpi {spec!r}: count {parts[2]!r} is not an integer") from None
        if n < 1:
            raise SweepError(f"--tpi {spec!r}: count must be >= 1")
        vals = [a] if n == 1 else [float(v) for v in np.linspace(a, b, n)]
    else:
        vals = [_num(p, "--tpi") for p in spec.split(",") if p.strip()]
    if not vals:
        raise SweepError(f"--tpi {spec!r}: no values")
    return sorted(set(round(v, 6) for v in vals))


def parse_tracks(spec) -> list[float]:
    """``"1,2,5,10"`` (or a sequence) -> sorted unique seek lengths [track]."""
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    vals = [_num(str(p), "--tracks") for p in items if str(p).strip()]
    if not vals:
        raise SweepError(f"--tracks {spec!r}: no values")
    return sorted(set(vals))


def _fmt(x: float) -> str:
    return format(float(x), ".10g").replace(".", "p").replace("+", "")


def cell_key(tpi: float, tracks: float) -> str:
    """File-name-safe key of a cell, e.g. ``tpi200000_k10``."""
    return f"tpi{_fmt(tpi)}_k{_fmt(tracks)}"


#: What a cell's numbers come from: every module of these packages, and these modules (the design
#: chain, the one simulator and the plant; a module split out of another is covered without a list).
_CODE_PACKAGES = ("seekopt.design", "seekopt.drive", "identification.model")
_CODE_MODULES = ("seekopt.evaluate.bench", "seekopt.evaluate.sweep_cell")


def code_files() -> list:
    """``[(module name, path)]`` of the sources :func:`code_hash` covers: every ``.py`` file of
    :data:`_CODE_PACKAGES`, in name order, and :data:`_CODE_MODULES`."""
    import importlib.util
    files = []
    for name in _CODE_PACKAGES:
        spec = importlib.util.find_spec(name)
        for d in (spec.submodule_search_locations or []) if spec else []:
            files += [(f"{name}.{f.stem}", f) for f in sorted(Path(d).glob("*.py"))]
    for name in _CODE_MODULES:
        spec = importlib.util.find_spec(name)
        if spec and spec.origin and os.path.exists(spec.origin):
            files.append((name, Path(spec.origin)))
    return files


def code_hash() -> str:
    """Hash of the sources that produce a cell's numbers (provenance; a resumed sweep warns when
    its saved cells came from other code), over :func:`code_files`."""
    import hashlib
    h = hashlib.sha256()
    for name, f in code_files():
        h.update(name.encode() + f.read_bytes())
    return h.hexdigest()[:12]


# ------------------------------------------------------------------ configuration
@dataclass
class SweepConfig:
    """What a sweep computes.

    Parameters
    ----------
    plant : ModalPlant
        Design (and evaluation) plant; needs ``track_pitch_nm`` (re-expressed per TPI).
    controller : Controller
    tpis : list of float
        Track densities [track/inch].
    tracks : list of float
        Seek lengths [track].
    imax : float
        Current limit [A].
    settle : float
        Settle band [track] (the same in tracks at every TPI).
    designer : str
        ``"ocp-robust"`` (default: :class:`seekopt.design.ocp.SeekDesigner` with the default
        :class:`seekopt.design.family.Drift`, what ``seekopt design`` and ``seekopt sweep`` do),
        ``"ocp"`` (the same, nominal), ``"baseline"``
        (:class:`BaselineDesigner`, for testing the machinery) or ``"module:attr"``,
        a factory ``f(plant, controller, imax, settle) -> obj`` with ``obj.design(tracks)``.
    kinds : tuple of str
        Subset of :data:`ALL_KINDS` (default :data:`KINDS`).
    family : list of ModalPlant
        Further members of the drive's plant family (``plant`` is the nominal one): the optimal
        designs (``ocp``, ``ocp-robust``) hold every member; the table evaluates on ``plant``.
    drift : str or None
        Drift of the ``ocp-robust`` designer in physical terms (:meth:`seekopt.design.family.Drift.from_string`;
        None: from the data).
    worst_case_slack_s : float
        The ``ocp`` designers' :attr:`seekopt.design.problem.SeekProblem.worst_case_slack_s` [s] (0: the set's
        minimum; ``seekopt sweep --worst-case-slack``).
    """

    plant: ModalPlant
    controller: Controller
    tpis: list
    tracks: list
    imax: float
    settle: float = 0.1
    designer: str = "ocp-robust"
    kinds: tuple = KINDS
    horizon_s: float | None = None
    scale_controller: bool = True
    family: list = field(default_factory=list)
    drift: str | None = None
    worst_case_slack_s: float = 0.0

    def __post_init__(self):
        if self.plant.track_pitch_nm is None:
            raise SweepError("plant has no track_pitch_nm; a TPI sweep needs the physical gain")
        if not (self.imax > 0 and self.settle > 0):
            raise SweepError("--imax and --settle must be positive")
        bad = [k for k in self.kinds if k not in ALL_KINDS]
        if bad:
            raise SweepError(f"unknown profile kind {bad[0]!r} (known: {', '.join(ALL_KINDS)})")
        self.tpis, self.tracks = parse_tpi(",".join(map(repr, self.tpis))), parse_tracks(self.tracks)
        self.family = list(self.family or [])
        if any(p.track_pitch_nm is None for p in self.family):
            raise SweepError("a family member has no track_pitch_nm; a TPI sweep needs the physical gain")
        self.worst_case_slack_s = float(self.worst_case_slack_s or 0.0)
        if not (math.isfinite(self.worst_case_slack_s) and self.worst_case_slack_s >= 0):
            raise SweepError(f"worst-case slack must be a time >= 0 s (got {self.worst_case_slack_s!r})")
        if self.drift:
            from seekopt.design.family import Drift, DriftError
            try:
                Drift.from_string(self.drift).check_modes(self.plant)
            except DriftError as exc:
                raise SweepError(f"--drift: {exc}") from None

    def identity(self) -> dict:
        """Everything but the grid: what saved cells must agree on to be reused."""
        d = {"plant": self.plant.to_dict(), "controller": self.controller.to_dict(),
             "imax": float(self.imax), "settle": float(self.settle), "designer": self.designer,
             "kinds": list(self.kinds), "horizon_s": self.horizon_s,
             "scale_controller": bool(self.scale_controller)}
        if self.family:              # only when used: sweeps of one plant keep their hash
            d["family"] = [p.to_dict() for p in self.family]
        if self.drift:
            d["drift"] = self.drift
        if self.worst_case_slack_s:  # only when used: sweeps without it keep their hash
            d["worst_case_slack_s"] = self.worst_case_slack_s
        return d

    def hash(self) -> str:
        import hashlib
        text = json.dumps(self.identity(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    def to_dict(self) -> dict:
        from seekopt import __version__
        d = self.identity()
        d.update(tpis=list(self.tpis), tracks=list(self.tracks), config_hash=self.hash(),
                 plant_hash=self.plant.hash(), controller_hash=self.controller.hash(),
                 **({"family_hashes": [p.hash() for p in self.family]} if self.family else {}),
                 tool_version=__version__, code_hash=code_hash(), schema=1)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SweepConfig":
        return cls(ModalPlant.from_dict(d["plant"]), Controller.from_json(d["controller"]),
                   d["tpis"], d["tracks"], d["imax"], d["settle"], d["designer"],
                   tuple(d["kinds"]), d.get("horizon_s"), d.get("scale_controller", True),
                   [ModalPlant.from_dict(p) for p in d.get("family", [])], d.get("drift"),
                   d.get("worst_case_slack_s", 0.0))

    def cells(self) -> list[tuple[float, float]]:
        """Cells in submission order: by TPI (designer reuse), longest seeks first (balance)."""
        return [(tpi, k) for tpi in self.tpis for k in sorted(self.tracks, reverse=True)]


def controller_factor(plant0: ModalPlant, tpi: float) -> float:
    """``pitch_tpi / pitch_0``: the controller gain factor that keeps the physical loop at ``tpi``."""
    return (TRACK_PITCH_PER_TPI_NM / tpi) / plant0.track_pitch_nm


def controller_at_tpi(controller: Controller, plant0: ModalPlant, tpi: float) -> Controller:
    """The controller re-expressed at ``tpi``: the same physical loop.

    ``C`` maps a PES in tracks to A; at ``tpi`` a track is ``pitch_tpi / pitch_0`` of the
    plant's native track, so ``C_tpi = C * pitch_tpi / pitch_0`` keeps ``C(z) P(z)`` (crossover,
    margins) unchanged, as a drive's loop-gain calibration does.  Without it the NSS loop is
    unstable beyond about twice its native 100k TPI.
    """
    factor = controller_factor(plant0, tpi)
    secs = [dict(s) for s in controller.sections]
    first = secs[0]
    if first["kind"] == "tf":
        first["num"] = [factor * v for v in first["num"]]
    else:
        first["C"] = [factor * v for v in first["C"]]
        first["D"] = factor * first["D"]
    return Controller(f"{controller.name} (x{factor:.6g} for {tpi:.6g} TPI)", controller.sample_rate_hz, secs)

