"""The seekopt command line: a thin layer over the Python API.

Every command checks its arguments and paths before it computes anything (output folders exist
and are writable, numbers are in range, the controller closes a stable loop with the plant at
the plant's sample rate), reports bad input as one line on stderr naming the user's file and
the problem, and exits with status 2.  An unexpected internal error is a bug: it keeps its
traceback (exit status 1).  Outputs are written atomically.  Steps that take more than a moment
print a one-line stage log with the elapsed time on stderr (``--quiet`` silences it; warnings
and errors are always printed).

Each ``cmd_*`` function below maps parsed arguments onto the API of one module; the logic lives
in those modules.  Helpers other commands reuse: :func:`read_log_cli` (a log read with
``--current-unit`` and unit-plausibility warnings), :func:`progress` (the stage log),
:func:`warn`, :func:`check_output_file`, :func:`check_output_dir`, :func:`load_pair`.
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import threading
import time
from pathlib import Path

__all__ = ["main", "build_parser", "UsageError", "read_log_cli", "progress", "warn", "check_output_file",
           "check_output_dir", "check_positive", "load_pair", "DEFAULT_CONTROLLER"]

#: What runs when no ``--controller`` is given (named in the help).
DEFAULT_CONTROLLER = ("the IEEJ NSS benchmark's PID + 4 notches at 26400 Hz (notches at twice the PES rate; "
                      "seekopt/data/nss_controller.json)")
LOG_SUFFIXES = (".csv", ".npz", ".mat")
_HEARTBEAT_S = 30.0
#: a stage is logged once it has run this long [s]
PROGRESS_AFTER_S = 2.0


class UsageError(ValueError):
    """Bad command-line input (reported as one line, exit status 2)."""


def _input_errors() -> tuple:
    """Exception types that are the user's input, not a bug: one line, exit status 2."""
    from identification.logs.seeklog import LogError
    from identification.model.plant import PlantError
    from seekopt.drive.controller import ControllerError
    from seekopt.drive.loopcheck import LoopError
    from seekopt.design.profiles import ProfileError
    from seekopt.evaluate.synth import SynthError
    errs = [UsageError, LogError, PlantError, ControllerError, ProfileError, LoopError, SynthError,
            FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError]
    for mod, name in (("seekopt.design.problem", "ProblemError"), ("seekopt.evaluate.sweep", "SweepError"),
                      ("seekopt.export.tables", "ExportError"), ("seekopt.app.demo", "DemoError")):
        try:
            errs.append(getattr(__import__(mod, fromlist=[name]), name))
        except (ImportError, AttributeError):
            pass
    return tuple(errs)


def _message(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.filename:
        return f"{exc.filename}: {exc.strerror or type(exc).__name__}"
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


# ------------------------------------------------------------------ stage log, warnings
def warn(args, text: str) -> None:
    """``seekopt <command>: warning: <text>`` on stderr (also with --quiet)."""
    print(f"seekopt {getattr(args, 'command', '')}: warning: {text}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def progress(args, what: str, after_s: float | None = None):
    """One stage of a command, logged on stderr with its elapsed time once it has run ``after_s``
    (2 s; quicker stages print nothing); silent with ``--quiet``.

    On a terminal one line counts the seconds while the stage runs; otherwise (a log file) a line
    after 2 s, one every 30 s while it runs, and one when it ends::

        seekopt identify: identifying the plant from 120 seeks (robust) ... (2 s)
        seekopt identify: identifying the plant from 120 seeks (robust): done in 61.2 s

    Usage: ``with progress(args, "closing the loop"): result = close_loop(...)``.
    """
    if getattr(args, "quiet", False):
        yield
        return
    after_s = PROGRESS_AFTER_S if after_s is None else after_s
    head = f"seekopt {getattr(args, 'command', '')}: {what}"
    tty = sys.stderr.isatty()
    t0 = time.perf_counter()
    stop = threading.Event()
    lock = threading.Lock()
    shown = []

    def tick():
        wait = after_s
        while not stop.wait(wait):
            with lock:
                if stop.is_set():
                    return
                el = time.perf_counter() - t0
                if tty:
                    sys.stderr.write(f"\r{head} ... {el:.0f} s")
                elif not shown:
                    sys.stderr.write(f"{head} ... ({el:.0f} s)\n")
                else:
                    sys.stderr.write(f"{head} ... still running ({el:.0f} s)\n")
                sys.stderr.flush()
                shown.append(el)
            wait = 1.0 if tty else _HEARTBEAT_S
    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    ok = False
    try:
        yield
        ok = True
    finally:
        with lock:
            stop.set()
        thread.join()
        if shown:
            dt = time.perf_counter() - t0
            end = f"done in {dt:.1f} s" if ok else f"stopped after {dt:.1f} s"
            sys.stderr.write(f"\r{head}: {end}\033[K\n" if tty else f"{head}: {end}\n")
            sys.stderr.flush()


# ------------------------------------------------------------------ argument and path checks
def check_positive(value: float, option: str) -> float:
    """``value`` if finite and > 0, else a :class:`UsageError` naming ``option`` (e.g. ``"--imax [A]"``)."""
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise UsageError(f"{option} must be a positive number (got {value})")
    return value


def check_output_file(path, option: str, suffixes: tuple | None = None) -> None:
    """Before computing: ``path`` can be written -- its folder exists and is writable, it is not a
    folder, not read-only, and has one of ``suffixes``.  :class:`UsageError` naming the user's path."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{option} {path}: is a folder, expected a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise UsageError(f"{option} {path}: unknown extension {p.suffix!r} (expected {', '.join(suffixes)})")
    folder = p.parent
    if not folder.exists():
        raise UsageError(f"{option} {path}: folder {folder} does not exist")
    if not folder.is_dir():
        raise UsageError(f"{option} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: folder {folder} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise UsageError(f"{option} {path}: exists and is read-only")


def check_output_dir(path, option: str) -> None:
    """Before computing: ``path`` is a folder or can be created as one (its nearest existing
    ancestor is a writable folder).  :class:`UsageError` naming the user's path."""
    if path is None:
        return
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise UsageError(f"{option} {path}: exists and is not a folder")
    q = p
    while not q.exists() and q != q.parent:
        q = q.parent
    if not q.is_dir():
        raise UsageError(f"{option} {path}: {q} is not a folder")
    if not os.access(q, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: {q} is not writable")


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


def _load_plant(path):
    from identification.model.plant import ModalPlant
    return ModalPlant.load(path)


def _load_controller(path):
    from seekopt.drive.controller import Controller
    return Controller.nss() if path is None else Controller.from_json(path)


def load_pair(plant_path, controller_path, plant=None):
    """Plant and controller of a command, checked to make a working loop before anything is
    computed (:func:`seekopt.drive.loopcheck.check_loop`: same sample rate, stable closed loop)."""
    from seekopt.drive.loopcheck import check_loop
    plant = plant if plant is not None else _load_plant(plant_path)
    controller = _load_controller(controller_path)
    check_loop(plant, controller, plant_name=f"plant {plant_path}" if plant_path else "the default truth plant",
               controller_name=str(controller_path) if controller_path else "default controller (NSS, 26400 Hz)")
    return plant, controller


def _plant_family(paths, controller_path):
    """``--plant`` once or once per member of a family: ``(nominal, [other members], controller, names)``,
    every member checked against the controller (:func:`load_pair`) before anything is computed."""
    paths = list(paths) if isinstance(paths, (list, tuple)) else [paths]
    plant, controller = load_pair(paths[0], controller_path)
    plants = [plant] + [load_pair(p, controller_path)[0] for p in paths[1:]]
    if len(plants) > 1:
        for p, path in zip(plants, paths):
            p.meta.setdefault("family_name", Path(path).stem)
    return plants[0], plants[1:], controller, [Path(p).name for p in paths]


def _first(paths) -> str:
    """The first ``--plant`` path as the user gave it (for one-line errors)."""
    return str(paths[0] if isinstance(paths, (list, tuple)) else paths)


def _robust_choice(args, nominal=None):
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


def _print_predictions(res, names) -> None:
    """Predicted seek-settle times (nominal, each family member, worst over the set) and the guard."""
    pred, g = res.prediction, res.guard
    if pred is not None:
        ms = lambda m: f"{m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb)"     # noqa: E731
        for lab, m in pred.members():
            i = 0 if lab == "nominal" else int(lab.split()[1].rstrip(":"))
            print(f"  predicted on {names[i] if i < len(names) else lab}: {ms(m)}")
        print(f"  predicted worst over the {len(pred.labels)}-plant set: {ms(pred.worst_metrics)} on "
              f"'{pred.labels[pred.worst]}'; binding plant: '{pred.labels[pred.binding]}'")
    if g is not None:
        print(f"  unmodelled-mode guard: worst residual {g.worst_band:.3f} band at {g.worst_hz:.0f} Hz "
              f"({g.worst_reason}); bands " + ", ".join(str(b) for b, _ in g.per_band))


def _identify_outputs(logs, output):
    """Output path per log: ``-o`` as given for one log; for several logs ``-o`` is a folder (``<stem>.json``
    in it) or a pattern with ``{stem}``."""
    if not output:
        return [None] * len(logs)
    if len(logs) == 1:
        return [output]
    if "{stem}" in output:
        outs = [output.format(stem=Path(x).stem) for x in logs]
    else:
        if Path(output).suffix.lower() == ".json":
            raise UsageError(f"-o {output}: several logs need a folder or a pattern with {{stem}}, not one file")
        outs = [str(Path(output) / f"{Path(x).stem}.json") for x in logs]
    if len(set(outs)) != len(outs):
        raise UsageError(f"-o {output}: two logs would write the same plant file (same file stem)")
    return outs


def _parse_effect(text: str) -> dict:
    """``name:key=value,key=value`` (lists as ``a;b;c``) -> effect dict."""
    name, _, rest = text.partition(":")
    params = {}
    for item in filter(None, rest.split(",")):
        k, eq, v = item.partition("=")
        if not eq:
            raise UsageError(f"--effect {text!r}: expected key=value, got {item!r}")
        try:
            params[k.strip()] = [float(x) for x in v.split(";")] if ";" in v else float(v)
        except ValueError:
            raise UsageError(f"--effect {text!r}: {k} is not a number") from None
    from dataclasses import fields
    from identification.model.effects import EFFECTS, effect_from_dict
    cls = EFFECTS.get(name.strip())
    for f in fields(cls) if cls is not None else ():      # a list field given one value: a list of one
        if f.type in (list, "list") and isinstance(params.get(f.name), float):
            params[f.name] = [params[f.name]]
    try:
        return effect_from_dict({"effect": name.strip(), "params": params}).to_dict()
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--effect {text!r}: {exc}") from None


# ------------------------------------------------------------------ commands
def cmd_synth(args) -> int:
    from identification.logs import write_log
    from seekopt.drive.presets import default_truth_plant
    from seekopt.evaluate.synth import SynthConfig, synthesize
    check_output_file(args.output, "-o", LOG_SUFFIXES)
    check_output_file(args.truth, "--truth", (".json",))
    if args.seeks < 1:
        raise UsageError(f"--seeks must be at least 1 (got {args.seeks})")
    check_positive(args.imax, "--imax [A]")
    if not (math.isfinite(args.rro_scale) and args.rro_scale >= 0):
        raise UsageError(f"--rro-scale must be a number >= 0 (got {args.rro_scale})")
    cfg = SynthConfig(n_seeks=args.seeks, seed=args.seed, imax_a=args.imax, noise=not args.no_noise,
                      rro=not args.no_rro, rro_scale=args.rro_scale, log_substeps=not args.mean_current_only,
                      effects=[_parse_effect(e) for e in args.effect])
    plant, controller = load_pair(args.plant, args.controller,
                                  plant=None if args.plant else default_truth_plant())
    with progress(args, f"running the synthetic drive ({args.seeks} seeks)"):
        log, truth = synthesize(cfg, plant=plant, controller=controller)
    write_log(log, args.output)
    if args.truth:
        truth.to_json(args.truth)
    print(f"wrote {args.output}: {log.n} samples, {args.seeks} seeks at {log.sample_rate_hz:g} Hz")
    return 0


def cmd_identify(args) -> int:
    """``seekopt identify LOG [LOG ...] [-o plant.json | -o DIR] [--method robust|paper] [--figures DIR]
    [--current-unit mA]``: identify the modal plant of each log (several logs of one drive --
    temperatures, heads, zones -- give a family of plants), print the modes with one-standard-deviation
    uncertainties, k0, bias, delay, the held-out fit and the bands where a mode would have escaped
    detection; a bad log raises LogError (one line, exit 2 via :func:`main`) before anything is identified."""
    logs = list(args.log) if isinstance(args.log, (list, tuple)) else [args.log]
    outs = _identify_outputs(logs, args.output)
    for out in outs:
        if out is not None and len(logs) > 1:
            check_output_dir(str(Path(out).parent), "-o")
        else:
            check_output_file(out, "-o", (".json",))
    check_output_dir(args.figures, "--figures")
    loaded = [read_log_cli(x, args.current_unit, args) for x in logs]   # every log checked before the long work
    plants = []
    for path, log, out in zip(logs, loaded, outs):
        figs = args.figures if len(logs) == 1 or not args.figures else str(Path(args.figures) / Path(path).stem)
        plants.append(_identify_one(args, path, log, out, figs))
    if len(plants) > 1:
        from seekopt.design.family import family_spread
        sp = family_spread(plants[0], plants[1:])
        print(f"family of {len(plants)} plants, relative to {Path(logs[0]).name}:")
        for path, (t, z, g, d) in zip(logs[1:], sp["members"]):
            print(f"  {Path(path).name}: frequencies x{1 + t:.4f}, damping x{1 + z:.3f}, gain (k0) x{1 + g:.4f}, "
                  f"delay {d * 1e6:+.3f} us")
    return 0


def _identify_one(args, path, log, output, figures):
    """Identify one log and print its plant (see :func:`cmd_identify`); returns the plant."""
    from identification.estimate.identify import identify
    from identification.logs.checks import k0_warning
    from identification.logs.seeklog import segment_seeks
    which = f"of {path} " if len(getattr(args, "log", [])) > 1 else ""
    with progress(args, f"identifying the plant {which}from {len(segment_seeks(log))} seeks ({args.method})"):
        res = identify(log, method=args.method)
    p, sd = res.plant, res.plant.std
    w = k0_warning(p.k0, str(path))
    if w:
        warn(args, w)

    def pm(value, key, std, fmt):
        s = (std or {}).get(key)
        return f"{value:{fmt}} ± {s:.2g}" if s is not None and s == s else f"{value:{fmt}}"
    d = res.diagnostics
    print(f"{path}: {log.n} samples at {log.sample_rate_hz:g} Hz, {d.get('n_seeks')} seeks "
          f"({d.get('n_fit_seeks')} fitted, {d.get('n_heldout_seeks')} held out); method {res.method}")
    print(f"  k0    = {pm(p.k0, 'k0', sd, '.6g')} track/(A s^2)")
    print(f"  bias  = {pm(p.bias_a * 1e3, 'bias_a', {k: v * 1e3 for k, v in sd.items()}, '.4f')} mA")
    print(f"  delay = {pm(p.delay_s * 1e6, 'delay_s', {k: v * 1e6 for k, v in sd.items()}, '.3f')} us")
    print(f"  {'#':>3}  {'freq [Hz]':<20} {'zeta [-]':<20} {'gain g [-]':<24}")
    for i, m in enumerate(p.modes, 1):
        print(f"  {i:>3}  {pm(m.freq_hz, 'freq_hz', m.std, '.2f'):<20} {pm(m.zeta, 'zeta', m.std, '.5f'):<20} "
              f"{pm(m.gain, 'gain', m.std, '.4e'):<24}")
    if not p.modes:
        print("      (no significant mode)")
    fit, rig = res.fit_percent, res.fit_percent_rigid
    if fit == fit:
        print(f"  held-out fit (settle-window PES): {fit:.1f} % (rigid body only: {rig:.1f} %)")
        if fit < 0:
            print("    (negative: the log has disturbances the current does not carry -- force noise, which the rigid\n"
                  "     body integrates twice, run-out, flutter; an open-loop simulation cannot predict them.  The\n"
                  "     mode table above is not affected; see docs/results_identification.md)")
    else:
        print("  held-out fit: n/a (too few seeks to hold any out)")
    blind = p.meta.get("blind_bands")
    if blind is not None:
        det = p.meta.get("blind_detect", {})
        txt = "; ".join(f"{b['lo_hz']:.0f}-{b['hi_hz']:.0f} Hz ({b['reason']}"
                        + (f", up to g {b['min_detectable_gain']:.2g})" if b.get("min_detectable_gain") else ")")
                        for b in blind)
        print(f"  blind (a mode of gain {det.get('gain', float('nan')):g} would escape detection): {txt or 'none'}")
    if output:
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        p.to_json(output)
        print(f"wrote {output}")
    if figures:
        from identification.estimate.figures import plot_identification
        with progress(args, "drawing the figures"):
            paths = plot_identification(log, res, figures)
        for fig in paths:
            print(f"wrote {fig}")
    return p


def cmd_design(args) -> int:
    """``seekopt design``: minimum seek-settle-time profile -> Profile CSV (see :mod:`seekopt.design.designer`).

    ``--plant`` once, or once per member of a family (the first is the nominal plant; the profile holds
    the band on every member); ``--drift`` states the drift in physical terms (default: from the data).
    The problem is checked before any QP is built (closed loop of every plant of the robust set, a
    seek beyond the design horizon at ``--imax``): one line, exit 2.  Prints the predicted seek-settle
    time on the nominal plant, on each member and the worst over the set (which plant binds) and the
    unmodelled-mode guard's worst residual; all are in the profile's metadata."""
    from seekopt.design.designer import DesignError, SeekDesigner
    from seekopt.design.problem import ProblemError, SeekProblem
    check_output_file(args.output, "-o", (".csv",))
    for name, v in (("--imax [A]", args.imax), ("--settle [track]", args.settle)):
        check_positive(v, name)
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number of tracks (got {args.tracks})")
    plant, family, controller, names = _plant_family(args.plant, args.controller)
    robust = _robust_choice(args, plant)
    from seekopt.design.feasibility import StartError, resolve_start
    try:        # start track and direction: never outside the range the plant's effects were fitted on
        start = resolve_start(plant, args.tracks, args.start_track, source=_first(args.plant))
    except StartError as exc:
        raise UsageError(str(exc)) from None
    from seekopt.design.nlp import needs_nlp
    if needs_nlp(plant):    # input/force effects: the effect-aware NLP (seekopt.design.nlp)
        return _design_with_effects(args, plant, controller, robust, start, names)
    from seekopt.design.longseek import LongSeekDesigner, LongSeekError, LongSeekSpec
    for name, v in (("--vmax", args.vmax), ("--stroke", args.stroke)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise UsageError(f"{name} must be a positive number (got {v})")
    try:
        spec = LongSeekSpec.from_plant(plant, args.imax, args.vmax, args.stroke)
    except LongSeekError as exc:
        raise UsageError(f"{', '.join(names)}: {exc}") from None
    if spec.stroke_track is not None and abs(args.tracks) > spec.stroke_track:
        raise UsageError(f"--tracks {args.tracks:g} is longer than the stroke ({spec.stroke_track:g} tracks)")
    try:
        designer = SeekDesigner(SeekProblem(plant, controller, args.imax, args.settle, robust=robust, family=family))
        if spec.vmax_track_s is not None:   # long seeks coast at vmax (seekopt.design.longseek)
            designer = LongSeekDesigner(designer.problem, spec, short_designer=designer)
        designer.check_seek(args.tracks)            # impossible seeks: before any QP is built
    except (ProblemError, LongSeekError) as exc:
        raise UsageError(f"{', '.join(names)}: {exc}") from None
    try:
        with progress(args, f"designing the {args.tracks:g}-track seek on {len(getattr(designer, 'plants', [plant]))} plant(s)"):
            res = designer.design(args.tracks)
    except (DesignError, LongSeekError) as exc:
        print(f"seekopt design: solver failure: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    prof = res.profile
    prof.meta.update(plant_file=";".join(names), controller_name=controller.name, start_track=start,
                     direction="outward" if args.tracks > 0 else "inward")
    prof.to_csv(args.output)
    m = res.metrics
    extra = f", {res.fallback_solves} by a fallback solver" if res.fallback_solves else ""
    coast = (f"; coasts {prof.meta['coast_samples']} samples at {prof.meta['coast_velocity_track_s']:.4g} track/s"
             if prof.kind == "long_seek" else "")
    print(f"wrote {args.output}: {prof.n} samples; {args.tracks:g} tracks, seek {m.seek_time_s * 1e3:.3f} ms, "
          f"seek-settle {m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb) on the design plant, "
          f"peak current {m.peak_current_a:.3f} A{coast}; {res.n_solves} QPs ({res.solver}{extra}) in "
          f"{res.solve_time_s:.3f} s")
    if prof.kind != "long_seek":
        _print_predictions(res, names)
    return 0


def _design_with_effects(args, plant, controller, robust, start, names) -> int:
    """``seekopt design`` on a plant with effects: Ipopt over the full closed loop, from ``start``.
    Every failure (a band the loop cannot hold, Ipopt, the full-plant check) is one line, exit 2."""
    from seekopt.design.nlp import DesignUnholdable, EffectAwareDesigner, NLPDesignError

    def say(msg):
        if not getattr(args, "quiet", False):
            print(f"seekopt design: {msg}", file=sys.stderr, flush=True)
    try:
        res = EffectAwareDesigner(plant, controller, args.imax, args.settle, robust).design(
            args.tracks, start, progress=say)
    except (DesignUnholdable, NLPDesignError) as exc:
        print(f"seekopt design: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    prof = res.profile
    prof.meta.update(plant_file=";".join(names), controller_name=controller.name)
    prof.to_csv(args.output)
    m, lm = res.metrics, res.linear_metrics
    print(f"wrote {args.output}: {prof.n} samples; {args.tracks:g} tracks from track {res.start_track:g} "
          f"({prof.meta['direction']}), seek-settle {m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb) on the "
          f"design plant with its effects ({prof.meta['effects_in_design']}), peak current {m.peak_current_a:.3f} A; "
          f"linear design there {lm.settle_time_s * 1e3:.3f} ms; {len(res.solves)} NLPs, Ipopt "
          f"{res.ipopt_iterations} iterations in {res.ipopt_time_s:.2f} s")
    return 0


def cmd_bench(args) -> int:
    """``seekopt bench``: sine / windowed sine / optimal table (+ Fig. 9/10-style plots); see :mod:`seekopt.evaluate.bench`."""
    from seekopt.evaluate.bench import format_table, run_bench
    check_output_dir(args.figures, "--figures")
    for name, v in (("--imax [A]", args.imax), ("--settle [track]", args.settle)):
        check_positive(v, name)
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number of tracks (got {args.tracks})")
    plant, family, controller, names = _plant_family(args.plant, args.controller)
    robust = _robust_choice(args, plant)
    truth = _load_plant(args.truth) if args.truth else None
    if truth is not None:
        load_pair(args.truth, args.controller, plant=truth)
    from seekopt.design.nlp import needs_nlp
    if needs_nlp(plant):    # effects: played from the start track on the full plant (seekopt.evaluate.effect_bench)
        from seekopt.design.feasibility import StartError, resolve_start
        from seekopt.evaluate.effect_bench import run_effect_bench
        try:
            start = resolve_start(plant, args.tracks, args.start_track, source=_first(args.plant))
        except StartError as exc:
            raise UsageError(str(exc)) from None
        res = run_effect_bench(plant, controller, args.tracks, args.imax, args.settle, start_track=start,
                               truth=truth, robust=robust,
                               progress=lambda msg: print(f"seekopt bench: {msg}", file=sys.stderr, flush=True))
        print(f"design plant {', '.join(names)} with its effects; seek from track {start:g}, played on "
              f"{Path(args.truth).name if args.truth else 'the design plant'} (full plant)")
        print(format_table(res))
        return 0
    with progress(args, f"benchmarking the {args.tracks:g}-track seek"):
        res = run_bench(plant, controller, args.tracks, args.imax, args.settle, truth=truth, figures=args.figures,
                        robust=robust, family=family)
    print(f"design plant {', '.join(names)}, evaluated on "
          f"{Path(args.truth).name if args.truth else 'the design plant'}")
    print(format_table(res))
    for f in res.figures:
        print(f"figure: {f}")
    return 0


def _output_path(path, what: str) -> None:
    """A file we are about to write: its folder must exist and it must not be a folder."""
    p = Path(path)
    if p.is_dir():
        raise UsageError(f"{path}: {what} is a directory")
    if not p.parent.is_dir():
        raise UsageError(f"{path}: folder {p.parent} for the {what} does not exist")


def cmd_loop(args) -> int:
    """``seekopt loop LOG [--plant P.json] [--validate VAL] --report R.json [-o AUGMENTED.json]``: close the
    loop (:func:`identification.loop.closing.close_loop`) from the identified plant (or ``--plant``), write
    the report (JSON + Markdown, figures with ``--figures``) and, with ``-o``, the augmented plant (linear
    part + accepted effects, the plant JSON that ``design``, ``bench`` and ``sweep`` read).  Inputs are
    checked before any long computation; progress goes to stderr (one line per stage) unless ``--quiet``."""
    import time
    from identification.logs import read_log
    from identification.loop.closing import close_loop
    from identification.loop.report import write_report
    from identification.loop.windows import seek_windows
    t0 = time.time()
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    log = read_log(args.log)
    val = read_log(args.validate) if args.validate else None
    model = _load_plant(args.plant) if args.plant else None
    _output_path(args.report, "report")
    if args.output:
        _output_path(args.output, "augmented plant")
        if Path(args.output).resolve() == Path(args.report).resolve():
            raise UsageError(f"{args.output}: -o and --report name the same file")
    if val is None and seek_windows(log).n_groups < 4:
        raise UsageError(f"{args.log}: needs at least 4 seeks to hold some out for validation "
                         f"(has {seek_windows(log).n_groups}); give --validate LOG")
    if model is None:
        from identification.estimate.identify import identify
        ts = time.time()
        model = identify(log, method="robust").plant
        say(f"loop: identified the plant on {Path(args.log).name}: {len(model.modes)} modes, delay "
            f"{1e6 * model.total_delay_s:.2f} us ({time.time() - ts:.1f} s)")
    try:
        result = close_loop(log, model, validation=val, progress=say)
    except ValueError as exc:
        raise UsageError(f"{args.log}: {exc}") from None
    write_report(result, args.report, args.figures)
    if args.output:
        result.augmented_plant().to_json(args.output)
    acc = ", ".join(result.accepted) or "none"
    print(f"wrote {args.report}" + (f" and {args.output}" if args.output else "") +
          f": validation rms {result.error_before['rms_track']:.4g} -> {result.error_after['rms_track']:.4g} track; "
          f"accepted: {acc}; {len(result.unexplained)} unexplained item(s); {time.time() - t0:.1f} s")
    return 0


def cmd_sweep(args) -> int:
    """``seekopt sweep``: exit status 0 when every cell of the grid is saved without a failed row,
    1 (with a one-line summary on stderr) when any cell failed or could not be computed."""
    from seekopt.evaluate.sweep import SweepConfig, parse_tpi, parse_tracks, run_sweep
    check_output_dir(args.output, "-o")
    check_positive(args.imax, "--imax [A]")
    check_positive(args.settle, "--settle [track]")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1 (got {args.workers})")
    plant, family, controller, _ = _plant_family(args.plant, args.controller)
    if args.drift:
        _robust_choice(args, plant)                 # a bad --drift is an input error before anything runs
    cfg = SweepConfig(plant, controller, parse_tpi(args.tpi), parse_tracks(args.tracks), args.imax, args.settle,
                      designer=args.designer, family=family, drift=",".join(args.drift) or None)
    s = run_sweep(cfg, args.output, engine=args.dask or "process", workers=args.workers,
                  progress=not args.quiet, figures=not args.no_figures)
    others = f", {s.by_others} by another sweep" if s.by_others else ""
    print(f"sweep: {s.total} cells ({s.skipped} saved before, {s.computed} computed in {s.wall_s:.1f} s "
          f"on {s.engine}, {s.cells_per_s:.2f} cells/s{others}); table {s.table}")
    if s.failed_cells or s.engine_errors:
        import pandas as pd
        df = pd.read_csv(s.table, keep_default_na=False)
        bad = df[df["status"] != "ok"]
        kinds = ", ".join(f"{n} {st}" for st, n in bad["status"].value_counts().items())
        first = f"{bad.iloc[0]['tracks']:g} tracks at {bad.iloc[0]['tpi']:g} TPI ({bad.iloc[0]['kind']}): " \
                f"{bad.iloc[0]['error']}" if len(bad) else next(iter(s.engine_errors.values()))
        not_run = f", {len(s.engine_errors)} not computed (engine errors; rerun to retry)" if s.engine_errors else ""
        print(f"seekopt sweep: {len(s.failed_cells) + len(s.engine_errors)} of {s.total} cells failed "
              f"({kinds or 'none saved'}{not_run}; see the 'error' column of {s.table}); first: {first}"[:600],
              file=sys.stderr)
        return 1
    return 0


def cmd_export(args) -> int:
    """``seekopt export RESULTS|PROFILE.csv``: a sweep's designs (``seekopt_tables.*``) and, with the stroke known,
    tables for every length 1..stroke (``seekopt_seek.*``, :mod:`seekopt.export.playable`); or one design."""
    from seekopt.export import playable
    from seekopt.export.tables import load_tables, write_tables
    check_output_dir(args.output, "-o")
    src = Path(args.results)
    if src.is_file():
        ts = playable.table_set_from_profile(src)
        paths = write_tables(ts, args.format, args.output)
        t = ts.tables[0]
        print(f"export: one design ({t.tracks} tracks, {t.ff_len} feedforward samples, {ts.meta['ref_format']} "
              "reference) -> " + ", ".join(map(str, paths)))
        return 0
    if not (math.isfinite(args.budget_kib) and args.budget_kib > 0):
        raise UsageError(f"--budget-kib must be a positive number (got {args.budget_kib})")
    stroke_mm = playable.sweep_stroke_mm(src, args.stroke_mm, args.vmax_mps) if src.is_dir() else None
    with progress(args, f"quantising the tables of {args.results}"):
        ts = load_tables(args.results)
        paths = write_tables(ts, args.format, args.output)
    print(f"export: {len(ts.tables)} tables ({len(ts.tpis)} TPI x {len(ts.lengths)} lengths, "
          f"{ts.meta['ref_format']} reference) -> " + ", ".join(map(str, paths)))
    if stroke_mm is None:
        print("export: no stroke given (--stroke-mm or the plant's meta stroke_mm): only the swept lengths were "
              "exported; pass --stroke-mm for tables of every length")
        return 0
    rule = playable.build_rule(src, stroke_mm=args.stroke_mm, vmax_mps=args.vmax_mps, budget_kib=args.budget_kib,
                               progress=not getattr(args, "quiet", False))
    paths = playable.write_seek(rule, args.format, args.output)
    for s in rule.sets:
        pk = s.meta["peak_current_a"]
        print(f"export: {s.tpi} TPI: lengths 1..{s.stroke} in {len(s.classes)} rest-to-rest classes "
              f"(1..{s.classes[-1].k_hi}) + {len(s.coasts)} coast classes, {s.table_bytes()} bytes of "
              f"{int(args.budget_kib * 1024)}, peak current " + (f"{pk:.4g} A" if pk is not None else "not checked")
              + f", coast at {s.meta['coast_velocity_track_s']:.4g} track/s")
    print("export: playable tables -> " + ", ".join(map(str, paths)))
    return 0


def cmd_demo(args) -> int:
    from seekopt.app.demo import DemoConfig, run_demo
    check_output_dir(args.output, "-o")
    run_demo(DemoConfig(log=args.log, outdir=args.output, quick=args.quick,
                        quiet=bool(getattr(args, "quiet", False))))
    return 0


# ------------------------------------------------------------------ parser
_DESCRIPTION = ("seekopt: seek-profile optimisation for hard-disk-drive servo engineers. Seek logs -> modal "
                "plant (identify, loop) -> minimum seek-settle-time profiles (design, bench) -> TPI x length "
                "sweeps -> fixed-point firmware tables (export).")
_EPILOG = f"""\
units: position [track], current [A], time [s], frequency [Hz]; track density [track/inch] (TPI).
default controller (when --controller is not given):
  the IEEJ NSS benchmark's PID + 4 notches at 26400 Hz (notches at twice the PES rate;
  seekopt/data/nss_controller.json)
bad input is one line on stderr and exit status 2; 'seekopt COMMAND -h' lists a command's options.
"""
_CONTROLLER_HELP = ("the drive's feedback controller, JSON (default: the IEEJ NSS benchmark's PID + notch, "
                    "26400 Hz); must run at the plant's sample rate")


class _Formatter(argparse.RawDescriptionHelpFormatter):
    def __init__(self, prog):
        super().__init__(prog, max_help_position=32)


def build_parser() -> argparse.ArgumentParser:
    from seekopt import __version__
    import textwrap
    p = argparse.ArgumentParser(prog="seekopt", description=textwrap.fill(_DESCRIPTION, 88), epilog=_EPILOG,
                                formatter_class=_Formatter)
    p.add_argument("--version", action="version", version=f"seekopt {__version__}")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output (warnings and errors still shown)")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                        help="no progress output (warnings and errors still shown)")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name, help_text):
        return sub.add_parser(name, help=help_text, description=help_text, parents=[common], formatter_class=_Formatter)

    s = command("synth", "run the synthetic drive (closed loop, noise, run-out) and write a seek log")
    s.add_argument("-o", "--output", required=True, metavar="LOG", help="seek log to write (.csv, .npz or .mat)")
    s.add_argument("--seeks", type=int, default=120, help="number of seeks in the log (default 120)")
    s.add_argument("--seed", type=int, default=0,
                   help="random seed of the seek schedule and the noise (default 0; same seed, same log)")
    s.add_argument("--imax", type=float, default=0.3, metavar="A",
                   help="seek current limit [A] (default 0.3); each seek draws its limit in [0.5, 1] x IMAX")
    s.add_argument("--plant", metavar="PLANT.json",
                   help="truth plant JSON (default: NSS benchmark v2 plant + seek-induced modes at 420 and 1738 Hz)")
    s.add_argument("--controller", metavar="CONTROLLER.json", help=_CONTROLLER_HELP)
    s.add_argument("--effect", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                   help="undeclared effect added to the truth, e.g. friction:coulomb_a=0.002 (repeatable; units "
                        "in the key names)")
    s.add_argument("--no-noise", action="store_true", help="no sensor noise, force noise or flutter")
    s.add_argument("--no-rro", action="store_true", help="no repeatable run-out")
    s.add_argument("--rro-scale", type=float, default=1.0, metavar="X",
                   help="run-out amplitude relative to the benchmark's [-] (default 1)")
    s.add_argument("--mean-current-only", action="store_true",
                   help="log only the mean current per sample, not the multirate sub-step currents")
    s.add_argument("--truth", metavar="PLANT.json", help="also write the truth plant JSON here")
    s.set_defaults(func=cmd_synth)

    s = command("identify", "identify the modal plant (k0, bias, delay, modes) from a seek log (several logs: a family)")
    s.add_argument("log", nargs="+", help="seek log(s) (.csv, .npz, or .mat v5/v7/v7.3); several logs of one drive "
                                          "(temperatures, heads, zones) give a family of plants")
    s.add_argument("-o", "--output", metavar="PLANT.json",
                   help="plant JSON to write (several logs: a folder, or a pattern with {stem})")
    s.add_argument("--method", choices=["robust", "paper"], default="robust",
                   help="robust (default: pooled matrix pencil, exact multirate hold, uncertainties) or paper "
                        "(the paper's eqs. 4-11 exactly)")
    s.add_argument("--figures", metavar="DIR", help="folder for the figures (created)")
    s.add_argument("--current-unit", choices=["A", "mA", "uA"], default="A",
                   help="unit of the log's current columns: A (default), mA or uA; converted to A")
    s.set_defaults(func=cmd_identify)

    s = command("design", "design a minimum seek-settle-time seek profile (feedforward current + reference)")
    s.add_argument("--plant", required=True, action="append", metavar="PLANT.json",
                   help="design plant JSON (from 'seekopt identify'); repeat for a family of plants of one drive "
                        "(the first is the nominal one; the profile holds the band on every member)")
    s.add_argument("--controller", metavar="CONTROLLER.json", help=_CONTROLLER_HELP)
    s.add_argument("--tracks", type=float, required=True, metavar="K",
                   help="seek length [track] (non-zero; the sign gives the direction)")
    s.add_argument("--imax", type=float, required=True, metavar="A",
                   help="current limit [A] on the total current (feedforward + feedback), every sub-step")
    s.add_argument("--settle", type=float, default=0.1, metavar="TRACK", help="settle band half-width [track] (default 0.1)")
    s.add_argument("--drift", action="append", default=[], metavar="SPEC",
                   help="drift in physical terms, e.g. temp=±4%%,zeta=±20%%,gain=±5%%,delay=±1us, per mode "
                        "f1738=±5%%, f1738.zeta=±30%% (repeatable); unstated ranges come from the data (reported "
                        "std, the family's members; seek-induced modes ±5%%); see 'Operating range' in the README")
    s.add_argument("--robust", nargs="?", const="default", default=None, metavar="SPEC",
                   help="per-mode box instead of --drift (RobustSpec: freq=5,ofreq=1,zeta=30,gain=8,delay=1e-6,n=15, "
                        "percent / s); 'none' for a nominal design (family members still held)")
    s.add_argument("--vmax", type=float, metavar="TRACK/S",
                   help="velocity limit [track/s] (default: the plant's meta vmax_mps, or back_emf_v_per_mps and "
                        "supply_v); seeks long enough accelerate, coast at it and arrive (seekopt.design.longseek)")
    s.add_argument("--stroke", type=float, metavar="TRACK",
                   help="full stroke [track] (default: the plant's meta stroke_mm / stroke_track); longer seeks "
                        "are refused")
    s.add_argument("--start-track", type=float, default=None, metavar="TRACK",
                   help="track the seek starts from (default: the middle of the plant's position_range_track, 0 "
                        "without one); a plant with position-dependent effects never extrapolates beyond that range")
    s.add_argument("-o", "--output", required=True, metavar="PROFILE.csv", help="profile CSV to write")
    s.set_defaults(func=cmd_design)

    s = command("bench", "benchmark the optimal profiles against the paper's sine and windowed sine")
    s.add_argument("--plant", required=True, action="append", metavar="PLANT.json",
                   help="design plant JSON; repeat for a family (the robust variant holds every member)")
    s.add_argument("--controller", metavar="CONTROLLER.json", help=_CONTROLLER_HELP)
    s.add_argument("--truth", metavar="PLANT.json", help="play the profiles on this plant (default: the design plant)")
    s.add_argument("--drift", action="append", default=[], metavar="SPEC", help="drift of the robust variant (as for design)")
    s.add_argument("--robust", default=None, metavar="SPEC", help="per-mode box of the robust variant instead; 'none'")
    s.add_argument("--tracks", type=float, default=200.0, metavar="K", help="seek length [track] (default 200)")
    s.add_argument("--imax", type=float, required=True, metavar="A", help="current limit [A]")
    s.add_argument("--settle", type=float, default=0.1, metavar="TRACK", help="settle band half-width [track] (default 0.1)")
    s.add_argument("--figures", metavar="DIR", help="folder for Fig. 9/10-style plots (created)")
    s.add_argument("--start-track", type=float, default=None, metavar="TRACK",
                   help="start track of the seek on a plant with effects (default: the middle of its fitted range)")
    s.set_defaults(func=cmd_bench)

    s = command("loop", "close the loop: residual analysis and model augmentation")
    s.add_argument("log", help="seek log (.csv, .npz or .mat)")
    s.add_argument("--plant", metavar="PLANT.json", help="start from this plant JSON instead of identifying the log")
    s.add_argument("--validate", help="validation log (default: held-out seeks)")
    s.add_argument("--report", required=True, help="report JSON")
    s.add_argument("-o", "--output", help="write the augmented plant JSON (linear part + accepted effects)")
    s.add_argument("--figures", help="folder for residual figures and the Markdown report")
    s.set_defaults(func=cmd_loop)

    s = command("sweep", "sweep optimal designs over track density (TPI) and seek length")
    s.add_argument("--plant", required=True, action="append", metavar="PLANT.json",
                   help="plant JSON with track_pitch_nm; repeat for a family (the optimal designs hold every member)")
    s.add_argument("--drift", action="append", default=[], metavar="SPEC",
                   help="drift of the ocp-robust designer (as for design; default from the data)")
    s.add_argument("--controller", metavar="CONTROLLER.json", help=_CONTROLLER_HELP + " (its gain is scaled with the track pitch)")
    s.add_argument("--tpi", required=True, metavar="SPEC",
                   help="track densities [track/inch]: start:stop:count (e.g. 200k:1000k:9) or a list (200k,500k)")
    s.add_argument("--tracks", required=True, metavar="K,K,...",
                   help="seek lengths [track], comma-separated, e.g. 1,10,100,1000")
    s.add_argument("--imax", type=float, required=True, metavar="A", help="current limit [A]")
    s.add_argument("--settle", type=float, default=0.1, metavar="TRACK", help="settle band half-width [track] (default 0.1)")
    s.add_argument("--designer", default="ocp-robust",
                   help="ocp-robust (default: the robust design of 'seekopt design'), ocp (nominal), baseline "
                        "(shortest bang-bang, no optimiser) or module:attr")
    s.add_argument("--dask", metavar="ADDRESS",
                   help="run on Dask: 'local' (a loopback cluster of --workers processes) or tcp://HOST:PORT")
    s.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes (default: the CPU count, at most the cells to do); one BLAS thread each")
    s.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="results folder (created; rerunning resumes it, two sweeps into it share the cells)")
    s.add_argument("--no-figures", action="store_true", help="write the table only, no sweep figures (faster)")
    s.set_defaults(func=cmd_sweep)

    s = command("export", "export a sweep's optimal profiles (and tables for every seek length) as fixed-point "
                          "firmware tables, or one design")
    s.add_argument("results", metavar="RESULTS_DIR|PROFILE.csv",
                   help="sweep results folder (from 'seekopt sweep'), or a profile CSV of 'seekopt design' (one design)")
    s.add_argument("--format", choices=["c", "csv", "json"], default="c",
                   help="c: seekopt_tables.h + seekopt_tables.c (int16 Q15 feedforward of Imax, int32 reference "
                        "in tracks); csv: seekopt_tables.csv; json: seekopt_tables.json (default c); the same for "
                        "seekopt_seek.* (every length)")
    s.add_argument("--stroke-mm", type=float, metavar="MM",
                   help="full stroke [mm] (default: the plant's meta stroke_mm): also write tables for every seek "
                        "length 1..stroke at every TPI (seekopt_seek.*, with seekopt_seek_sample())")
    s.add_argument("--vmax-mps", type=float, metavar="M/S",
                   help="velocity limit [m/s] (default: the plant's meta vmax_mps, or back_emf_v_per_mps and supply_v)")
    s.add_argument("--budget-kib", type=float, default=64.0, metavar="KIB",
                   help="table memory per TPI [KiB] for seekopt_seek.* (default 64)")
    s.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="output folder (created; the table files in it are replaced atomically)")
    s.set_defaults(func=cmd_export)

    s = command("demo", "the whole pipeline on the bundled sample log, with an HTML report")
    s.add_argument("log", nargs="?", help="seek log to run on (default: the bundled synthetic sample log)")
    s.add_argument("-o", "--output", default="seekopt-out", metavar="DIR", help="output folder (default seekopt-out)")
    s.add_argument("--quick", action="store_true", help="fewer seeks and seek lengths (for tests)")
    s.set_defaults(func=cmd_demo)
    return p


def main(argv=None) -> int:
    """Run one command; returns the exit status (0 ok, 1 failed cells or a bug's traceback, 2 bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except _input_errors() as exc:
        print(f"seekopt {args.command}: error: {_message(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"seekopt {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
