"""The inputs several ``seekopt`` commands read the same way: a seek log (``--current-unit``), the plant
and controller pair checked to close a stable loop, a family of plants (``--plant`` repeated) and the
design's uncertainty (``--drift`` / ``--robust``).  Every check runs before any long computation and
fails as a :class:`~seekopt.app.commands.common.UsageError` or the API's own input error.
"""
from __future__ import annotations

from pathlib import Path

from seekopt.app.commands.common import UsageError, warn

__all__ = ["read_log_cli", "load_plant", "load_controller", "load_pair", "plant_family", "robust_choice"]


def read_log_cli(path, current_unit: str = "A", args=None):
    """Read a seek log for a command: :func:`identification.logs.read_log`, currents converted
    from ``current_unit`` (``--current-unit``) to A, and a warning for currents implausible for a
    disk drive (:func:`identification.logs.checks.unit_warnings`).  A bad log raises LogError."""
    from identification.logs.checks import convert_current, unit_warnings
    from identification.logs import read_log
    log = convert_current(read_log(path), current_unit or "A")
    for w in unit_warnings(log):
        warn(args, w)
    return log


def load_plant(path):
    """The :class:`~identification.model.plant.ModalPlant` in the JSON file ``path`` (PlantError if bad)."""
    from identification.model.plant import ModalPlant
    return ModalPlant.load(path)


def load_controller(path):
    """The :class:`~seekopt.drive.controller.Controller` in the JSON file ``path``; None: the NSS preset."""
    from seekopt.drive.controller import Controller
    return Controller.nss() if path is None else Controller.from_json(path)


def load_pair(plant_path, controller_path, plant=None):
    """Plant and controller of a command, checked to make a working loop before anything is
    computed (:func:`seekopt.drive.loopcheck.check_loop`: same sample rate, stable closed loop)."""
    from seekopt.drive.loopcheck import check_loop
    plant = plant if plant is not None else load_plant(plant_path)
    controller = load_controller(controller_path)
    check_loop(plant, controller, plant_name=f"plant {plant_path}" if plant_path else "the default truth plant",
               controller_name=str(controller_path) if controller_path else "default controller (NSS, 26400 Hz)")
    return plant, controller


def plant_family(paths, controller_path):
    """``--plant`` once or once per member of a family: ``(nominal, [other members], controller, names)``,
    every member checked against the controller (:func:`load_pair`) before anything is computed."""
    paths = list(paths) if isinstance(paths, (list, tuple)) else [paths]
    plant, controller = load_pair(paths[0], controller_path)
    plants = [plant] + [load_pair(p, controller_path)[0] for p in paths[1:]]
    if len(plants) > 1:
        for p, path in zip(plants, paths):
            p.meta.setdefault("family_name", Path(path).stem)
    return plants[0], plants[1:], controller, [Path(p).name for p in paths]


def robust_choice(args, nominal=None):
    """The design's uncertainty from ``--drift`` (physical drift, repeatable) or ``--robust``: a
    :class:`~seekopt.design.family.Drift`, a :class:`~seekopt.design.robust.RobustSpec` or None."""
    from seekopt.design.family import Drift, DriftError
    from seekopt.design.robust import RobustSpec
    drift = getattr(args, "drift", None) or []
    robust = getattr(args, "robust", None)
    if drift and robust not in (None, "default"):
        raise UsageError("give --drift (drift in physical terms) or --robust (per-mode box), not both")
    try:
        if drift:
            d = Drift.merged(drift)
            if nominal is not None:
                d.check_modes(nominal)
            return d
        if robust in (None, "default"):
            return Drift()                          # ranges from the data (reported std, family spread)
        return None if str(robust).lower() == "none" else RobustSpec.from_string(robust)
    except DriftError as exc:
        raise UsageError(f"--drift: {exc}") from None
    except ValueError as exc:
        raise UsageError(f"--robust: {exc}") from None


