"""The ``seekopt`` command line: a thin layer over the Python API.

Every command reports bad input as one line on stderr naming the file and the
problem, and exits with status 2; outputs are written atomically.

Each ``cmd_*`` function below maps parsed arguments onto the API of one module;
the logic lives in those modules.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["main", "build_parser", "UsageError"]


class UsageError(ValueError):
    """Bad command-line input (reported as one line, exit status 2)."""


def _input_errors() -> tuple:
    from identification.logs.seeklog import LogError
    from identification.model.plant import PlantError
    from seekopt.drive.controller import ControllerError
    from seekopt.design.profiles import ProfileError
    errs = [UsageError, LogError, PlantError, ControllerError, ProfileError, FileNotFoundError,
            IsADirectoryError, PermissionError]
    try:
        from seekopt.design.problem import ProblemError     # DesignInfeasible is one
        errs.append(ProblemError)
    except ImportError:
        pass
    try:
        from seekopt.app.demo import DemoError
        from seekopt.export.tables import ExportError
        from seekopt.evaluate.sweep import SweepError
        errs += [SweepError, ExportError, DemoError]
    except ImportError:
        pass
    return tuple(errs)


def _load_plant(path):
    from identification.model.plant import ModalPlant
    return ModalPlant.load(path)


def _load_controller(path):
    from seekopt.drive.controller import Controller
    return Controller.nss() if path is None else Controller.from_json(path)


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
    from identification.model.effects import effect_from_dict
    try:
        return effect_from_dict({"effect": name.strip(), "params": params}).to_dict()
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--effect {text!r}: {exc}") from None


# ------------------------------------------------------------------ commands
def cmd_synth(args) -> int:
    from identification.logs.seeklog import write_log
    from seekopt.evaluate.synth import SynthConfig, synthesize
    cfg = SynthConfig(n_seeks=args.seeks, seed=args.seed, imax_a=args.imax, noise=not args.no_noise,
                      rro=not args.no_rro, rro_scale=args.rro_scale, log_substeps=not args.mean_current_only,
                      effects=[_parse_effect(e) for e in args.effect])
    plant = _load_plant(args.plant) if args.plant else None
    log, truth = synthesize(cfg, plant=plant, controller=_load_controller(args.controller))
    write_log(log, args.output)
    if args.truth:
        truth.to_json(args.truth)
    print(f"wrote {args.output}: {log.n} samples, {args.seeks} seeks at {log.sample_rate_hz:g} Hz")
    return 0


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


def cmd_identify(args) -> int:
    """``seekopt identify LOG [LOG ...] [-o plant.json | -o DIR] [--method robust|paper] [--figures DIR]``:
    identify the modal plant of each log (several logs of one drive -- temperatures, heads, zones --
    give a family of plants), print the modes with one-standard-deviation uncertainties, k0, bias,
    delay, the held-out fit and the bands where a mode would have escaped detection; a bad log raises
    LogError (one line, exit 2 via :func:`main`) before anything is identified."""
    from identification.logs.seeklog import read_log
    logs = list(args.log) if isinstance(args.log, (list, tuple)) else [args.log]
    outs = _identify_outputs(logs, args.output)
    loaded = [read_log(x) for x in logs]          # every log checked before the long work
    plants = []
    for path, log, out in zip(logs, loaded, outs):
        plants.append(_identify_one(args, path, log, out, args.figures if len(logs) == 1 else
                                    (str(Path(args.figures) / Path(path).stem) if args.figures else None)))
    if len(plants) > 1:
        from seekopt.design.family import family_spread
        sp = family_spread(plants[0], plants[1:])
        print(f"family of {len(plants)} plants, relative to {Path(logs[0]).name}:")
        for path, (t, z, g, d) in zip(logs[1:], sp["members"]):
            print(f"  {Path(path).name}: frequencies x{1 + t:.4f}, damping x{1 + z:.3f}, gain (k0) x{1 + g:.4f}, "
                  f"delay {d * 1e6:+.3f} us")
    return 0


def _identify_one(args, path, log, output, figures):
    from identification.estimate.identify import identify
    res = identify(log, method=args.method)
    p, sd = res.plant, res.plant.std

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
        for fig in plot_identification(log, res, figures):
            print(f"wrote {fig}")
    return p


def _plant_family(paths):
    """``--plant`` given once or more: ``(nominal, [other members], names)``."""
    paths = list(paths) if isinstance(paths, (list, tuple)) else [paths]
    plants = [_load_plant(p) for p in paths]
    if len(plants) > 1:
        for p, path in zip(plants, paths):
            p.meta.setdefault("family_name", Path(path).stem)
    return plants[0], plants[1:], [Path(p).name for p in paths]


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


def cmd_design(args) -> int:
    """``seekopt design``: minimum seek-settle-time profile -> Profile CSV (see :mod:`seekopt.design.designer`).

    ``--plant`` once, or once per member of a family (the first is the nominal plant; the profile holds
    the band on every member); ``--drift`` states the drift in physical terms (default: from the data).
    The problem is checked before any QP is built (closed-loop stability of every plant of the set, a
    seek beyond the design horizon at ``--imax``): one line, exit 2."""
    import math
    from seekopt.design.designer import DesignError, SeekDesigner
    from seekopt.design.problem import ProblemError, SeekProblem
    plant, family, names = _plant_family(args.plant)
    controller = _load_controller(args.controller)
    for name, v in (("--imax", args.imax), ("--settle", args.settle)):
        if not (math.isfinite(v) and v > 0):
            raise UsageError(f"{name} must be a positive number (got {v})")
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number (got {args.tracks})")
    robust = _robust_choice(args, plant)
    try:
        designer = SeekDesigner(SeekProblem(plant, controller, args.imax, args.settle, robust=robust, family=family))
        designer.check_seek(args.tracks)            # closed loop and impossible seeks: before any QP is built
    except ProblemError as exc:
        raise UsageError(f"{', '.join(names)}: {exc}") from None
    try:
        res = designer.design(args.tracks)
    except DesignError as exc:
        print(f"seekopt design: solver failure: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    prof = res.profile
    prof.meta.update(plant_file=";".join(names), controller_name=controller.name)
    prof.to_csv(args.output)
    m = res.metrics
    extra = f", {res.fallback_solves} by the fallback solver" if res.fallback_solves else ""
    print(f"wrote {args.output}: {prof.n} samples; {args.tracks:g} tracks, seek {m.seek_time_s * 1e3:.3f} ms, "
          f"seek-settle {m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb) on the design plant, "
          f"peak current {m.peak_current_a:.3f} A; {res.n_solves} QPs ({res.solver}{extra}) in {res.solve_time_s:.3f} s")
    _print_predictions(res, names)
    return 0


def cmd_bench(args) -> int:
    """``seekopt bench``: sine / windowed sine / optimal table (+ Fig. 9/10-style plots); see :mod:`seekopt.evaluate.bench`."""
    import math
    from seekopt.evaluate.bench import format_table, run_bench
    plant, family, names = _plant_family(args.plant)
    controller = _load_controller(args.controller)
    truth = _load_plant(args.truth) if args.truth else None
    robust = _robust_choice(args, plant)
    for name, v in (("--imax", args.imax), ("--settle", args.settle)):
        if not (math.isfinite(v) and v > 0):
            raise UsageError(f"{name} must be a positive number (got {v})")
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number (got {args.tracks})")
    res = run_bench(plant, controller, args.tracks, args.imax, args.settle, truth=truth, figures=args.figures,
                    robust=robust, family=family)
    print(f"design plant {', '.join(names)}, evaluated on "
          f"{Path(args.truth).name if args.truth else 'the design plant'}")
    print(format_table(res))
    for f in res.figures:
        print(f"figure: {f}")
    return 0


def cmd_loop(args) -> int:
    from identification.loop.closing import close_loop
    from identification.estimate.identify import identify
    from identification.logs.seeklog import read_log
    from identification.loop.report import write_report
    log = read_log(args.log)
    val = read_log(args.validate) if args.validate else None
    model = identify(log, method="robust").plant
    try:
        result = close_loop(log, model, validation=val)
    except ValueError as exc:
        raise UsageError(f"{args.log}: {exc}") from None
    write_report(result, args.report, args.figures)
    acc = ", ".join(result.accepted) or "none"
    print(f"wrote {args.report}: validation rms {result.error_before['rms_track']:.4g} -> "
          f"{result.error_after['rms_track']:.4g} track; accepted: {acc}; "
          f"{len(result.unexplained)} unexplained item(s)")
    return 0


def cmd_sweep(args) -> int:
    from seekopt.evaluate.sweep import SweepConfig, parse_tpi, parse_tracks, run_sweep
    plant, family, _ = _plant_family(args.plant)
    if args.drift:
        _robust_choice(args, plant)                 # a bad --drift is an input error before anything runs
    cfg = SweepConfig(plant, _load_controller(args.controller), parse_tpi(args.tpi),
                      parse_tracks(args.tracks), args.imax, args.settle, designer=args.designer,
                      family=family, drift=",".join(args.drift) or None)
    engine = args.dask or "process"
    s = run_sweep(cfg, args.output, engine=engine, workers=args.workers)
    print(f"sweep: {s.total} cells ({s.skipped} saved before, {s.computed} computed in {s.wall_s:.1f} s "
          f"on {s.engine}, {s.cells_per_s:.2f} cells/s); table {s.table}")
    if s.failed_cells:
        print(f"sweep: {len(s.failed_cells)} cells with a failed design or evaluation (see 'error' column): "
              + ", ".join(s.failed_cells[:5]) + (" ..." if len(s.failed_cells) > 5 else ""))
    if s.engine_errors:
        print(f"sweep: {len(s.engine_errors)} cells not computed (engine errors, rerun to retry): "
              + next(iter(s.engine_errors.values())), file=sys.stderr)
        return 1
    return 0


def cmd_export(args) -> int:
    from seekopt.export.tables import load_tables, write_tables
    ts = load_tables(args.results)
    paths = write_tables(ts, args.format, args.output)
    print(f"export: {len(ts.tables)} tables ({len(ts.tpis)} TPI x {len(ts.lengths)} lengths, "
          f"{ts.meta['ref_format']} reference) -> " + ", ".join(map(str, paths)))
    return 0


def cmd_demo(args) -> int:
    from seekopt.app.demo import DemoConfig, run_demo
    run_demo(DemoConfig(log=args.log, outdir=args.output, quick=args.quick))
    return 0


# ------------------------------------------------------------------ parser
def build_parser() -> argparse.ArgumentParser:
    from seekopt import __version__
    p = argparse.ArgumentParser(prog="seekopt", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"seekopt {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("synth", help="run the synthetic drive and write a seek log")
    s.add_argument("-o", "--output", required=True, help="log file (.csv, .npz or .mat)")
    s.add_argument("--seeks", type=int, default=120)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--imax", type=float, default=0.3, help="seek current limit [A]")
    s.add_argument("--plant", help="truth plant JSON (default: NSS v2 + seek modes)")
    s.add_argument("--controller", help="controller JSON (default: NSS PID + notch)")
    s.add_argument("--effect", action="append", default=[],
                   help="undeclared effect, e.g. friction:coulomb_a=0.002 (repeatable)")
    s.add_argument("--no-noise", action="store_true")
    s.add_argument("--no-rro", action="store_true")
    s.add_argument("--rro-scale", type=float, default=1.0)
    s.add_argument("--mean-current-only", action="store_true",
                   help="log only the mean current per sample, not the multirate sub-step currents")
    s.add_argument("--truth", help="also write the truth plant JSON here")
    s.set_defaults(func=cmd_synth)

    s = sub.add_parser("identify", help="identify the modal plant from a seek log (several logs: a family)")
    s.add_argument("log", nargs="+", help="seek log(s) of one drive (temperatures, heads, zones)")
    s.add_argument("-o", "--output", help="plant JSON (several logs: a folder, or a pattern with {stem})")
    s.add_argument("--method", choices=["robust", "paper"], default="robust")
    s.add_argument("--figures", help="folder for figures")
    s.set_defaults(func=cmd_identify)

    s = sub.add_parser("design", help="design an optimal seek profile")
    s.add_argument("--plant", required=True, action="append",
                   help="plant JSON; repeat for a family of plants of one drive (the first is nominal)")
    s.add_argument("--controller")
    s.add_argument("--tracks", type=float, required=True)
    s.add_argument("--imax", type=float, required=True)
    s.add_argument("--settle", type=float, default=0.1, help="settle band [track]")
    s.add_argument("--drift", action="append", default=[],
                   help="drift in physical terms, e.g. temp=±4%%,zeta=±20%%,gain=±5%%,delay=±1us, per mode "
                        "f1738=±5%%, f1738.zeta=±30%% (repeatable); unstated ranges come from the data (reported "
                        "std, the family's spread; seek-induced modes ±5%%)")
    s.add_argument("--robust", nargs="?", const="default", default=None,
                   help="per-mode box instead of --drift (RobustSpec: freq=5,ofreq=1,zeta=30,gain=8,delay=1e-6,n=15, "
                        "percent / s); 'none' for a nominal design (family members still held)")
    s.add_argument("-o", "--output", required=True, help="profile CSV")
    s.set_defaults(func=cmd_design)

    s = sub.add_parser("bench", help="benchmark optimal profiles against sine and windowed sine")
    s.add_argument("--plant", required=True, action="append",
                   help="design plant JSON; repeat for a family (the robust variant holds every member)")
    s.add_argument("--drift", action="append", default=[], help="drift of the robust variant (as for design)")
    s.add_argument("--robust", default=None, help="per-mode box of the robust variant instead of --drift; 'none'")
    s.add_argument("--controller")
    s.add_argument("--truth", help="evaluate on this plant (default: the design plant)")
    s.add_argument("--tracks", type=float, default=200.0)
    s.add_argument("--imax", type=float, required=True)
    s.add_argument("--settle", type=float, default=0.1)
    s.add_argument("--figures", help="folder for Fig. 9/10-style plots")
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("loop", help="close the loop: residual analysis and model augmentation")
    s.add_argument("log")
    s.add_argument("--validate", help="validation log (default: held-out seeks)")
    s.add_argument("--report", required=True, help="report JSON")
    s.add_argument("--figures", help="folder for residual figures and the Markdown report")
    s.set_defaults(func=cmd_loop)

    s = sub.add_parser("sweep", help="sweep designs over TPI and seek length")
    s.add_argument("--plant", required=True, action="append",
                   help="plant JSON; repeat for a family (the optimal designs hold every member)")
    s.add_argument("--drift", action="append", default=[], help="drift of the ocp-robust designer (as for design)")
    s.add_argument("--controller")
    s.add_argument("--tpi", required=True, help="start:stop:count in TPI, e.g. 200k:1000k:9")
    s.add_argument("--tracks", required=True, help="comma-separated seek lengths")
    s.add_argument("--imax", type=float, required=True)
    s.add_argument("--settle", type=float, default=0.1)
    s.add_argument("--designer", default="ocp-robust",
                   help="ocp-robust (default: the robust design of 'seekopt design'), ocp (nominal), or module:attr")
    s.add_argument("--dask", help="'local' or tcp://HOST:PORT")
    s.add_argument("--workers", type=int, default=None)
    s.add_argument("-o", "--output", required=True, help="results folder")
    s.set_defaults(func=cmd_sweep)

    s = sub.add_parser("export", help="export feedforward tables for firmware")
    s.add_argument("results")
    s.add_argument("--format", choices=["c", "csv", "json"], default="c")
    s.add_argument("-o", "--output", required=True)
    s.set_defaults(func=cmd_export)

    s = sub.add_parser("demo", help="the whole pipeline on the bundled sample log")
    s.add_argument("log", nargs="?")
    s.add_argument("-o", "--output", default="seekopt-out")
    s.add_argument("--quick", action="store_true", help="fewer seek lengths (for tests)")
    s.set_defaults(func=cmd_demo)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except _input_errors() as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if isinstance(exc, (FileNotFoundError, IsADirectoryError, PermissionError)) and exc.filename:
            msg = f"{exc.filename}: {exc.strerror}"
        print(f"seekopt {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"seekopt {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
