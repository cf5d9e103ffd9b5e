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
        from seekopt.design.ocp import DesignInfeasible
        errs.append(DesignInfeasible)
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


def cmd_identify(args) -> int:
    """``seekopt identify LOG [-o plant.json] [--method robust|paper] [--figures DIR]``: identify the
    modal plant, print the modes with one-standard-deviation uncertainties, k0, bias, delay and the
    held-out fit; a bad log raises LogError (one line, exit 2 via :func:`main`)."""
    from identification.estimate.identify import identify
    from identification.logs.seeklog import read_log
    log = read_log(args.log)
    res = identify(log, method=args.method)
    p, sd = res.plant, res.plant.std

    def pm(value, key, std, fmt):
        s = (std or {}).get(key)
        return f"{value:{fmt}} ± {s:.2g}" if s is not None and s == s else f"{value:{fmt}}"
    d = res.diagnostics
    print(f"{args.log}: {log.n} samples at {log.sample_rate_hz:g} Hz, {d.get('n_seeks')} seeks "
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
    if args.output:
        p.to_json(args.output)
        print(f"wrote {args.output}")
    if args.figures:
        from identification.estimate.figures import plot_identification
        for path in plot_identification(log, res, args.figures):
            print(f"wrote {path}")
    return 0


def cmd_design(args) -> int:
    """``seekopt design``: minimum seek-settle-time profile -> Profile CSV (see :mod:`seekopt.design.ocp`)."""
    import math
    from seekopt.design.ocp import DesignError, RobustSpec, SeekDesigner
    plant, controller = _load_plant(args.plant), _load_controller(args.controller)
    for name, v in (("--imax", args.imax), ("--settle", args.settle)):
        if not (math.isfinite(v) and v > 0):
            raise UsageError(f"{name} must be a positive number (got {v})")
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number (got {args.tracks})")
    try:
        robust = None if str(args.robust).lower() == "none" else RobustSpec.from_string(args.robust)
    except ValueError as exc:
        raise UsageError(f"--robust: {exc}") from None
    from seekopt.design.nlp import needs_nlp
    if needs_nlp(plant):    # input/force effects: the effect-aware NLP (seekopt.design.nlp)
        return _design_with_effects(args, plant, controller, robust)
    from seekopt.design.feasibility import StartError, resolve_start
    try:
        start = resolve_start(plant, args.tracks, args.start_track, source=args.plant)
    except StartError as exc:
        raise UsageError(str(exc)) from None
    try:
        res = SeekDesigner(plant, controller, args.imax, args.settle, robust).design(args.tracks)
    except DesignError as exc:
        print(f"seekopt design: solver failure: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 1
    prof = res.profile
    prof.meta.update(plant_file=Path(args.plant).name, controller_name=controller.name, start_track=start,
                     direction="outward" if args.tracks > 0 else "inward")
    prof.to_csv(args.output)
    m = res.metrics
    print(f"wrote {args.output}: {prof.n} samples; {args.tracks:g} tracks, seek {m.seek_time_s * 1e3:.3f} ms, "
          f"seek-settle {m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb) on the design plant, "
          f"peak current {m.peak_current_a:.3f} A; {res.n_solves} QPs ({res.solver}) in {res.solve_time_s:.3f} s")
    return 0


def _design_with_effects(args, plant, controller, robust) -> int:
    """``seekopt design`` on a plant with effects: Ipopt over the full closed loop, from ``--start-track``.
    Every failure (range, a band the loop cannot hold, Ipopt, the full-plant check) is one line, exit 2."""
    from seekopt.design.feasibility import StartError, resolve_start
    from seekopt.design.nlp import DesignUnholdable, EffectAwareDesigner, NLPDesignError

    def say(msg):
        print(f"seekopt design: {msg}", file=sys.stderr, flush=True)
    try:
        start = resolve_start(plant, args.tracks, args.start_track, source=args.plant)
    except StartError as exc:
        raise UsageError(str(exc)) from None
    try:
        res = EffectAwareDesigner(plant, controller, args.imax, args.settle, robust).design(
            args.tracks, start, progress=say)
    except (DesignUnholdable, NLPDesignError) as exc:
        print(f"seekopt design: error: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    prof = res.profile
    prof.meta.update(plant_file=Path(args.plant).name, controller_name=controller.name)
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
    import math
    from seekopt.evaluate.bench import format_table, run_bench
    plant, controller = _load_plant(args.plant), _load_controller(args.controller)
    truth = _load_plant(args.truth) if args.truth else None
    for name, v in (("--imax", args.imax), ("--settle", args.settle)):
        if not (math.isfinite(v) and v > 0):
            raise UsageError(f"{name} must be a positive number (got {v})")
    if not math.isfinite(args.tracks) or args.tracks == 0:
        raise UsageError(f"--tracks must be a non-zero number (got {args.tracks})")
    from seekopt.design.nlp import needs_nlp
    if needs_nlp(plant):    # effects: played from the start track on the full plant (seekopt.evaluate.effect_bench)
        from seekopt.design.feasibility import StartError, resolve_start
        from seekopt.evaluate.effect_bench import run_effect_bench
        from seekopt.design.ocp import RobustSpec
        try:
            start = resolve_start(plant, args.tracks, args.start_track, source=args.plant)
        except StartError as exc:
            raise UsageError(str(exc)) from None
        res = run_effect_bench(plant, controller, args.tracks, args.imax, args.settle, start_track=start,
                               truth=truth, robust=RobustSpec(),
                               progress=lambda msg: print(f"seekopt bench: {msg}", file=sys.stderr, flush=True))
        print(f"design plant {Path(args.plant).name} with its effects; seek from track {start:g}, played on "
              f"{Path(args.truth).name if args.truth else 'the design plant'} (full plant)")
        print(format_table(res))
        return 0
    res = run_bench(plant, controller, args.tracks, args.imax, args.settle, truth=truth, figures=args.figures)
    print(f"design plant {Path(args.plant).name}, evaluated on "
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
    cfg = SweepConfig(_load_plant(args.plant), _load_controller(args.controller), parse_tpi(args.tpi),
                      parse_tracks(args.tracks), args.imax, args.settle, designer=args.designer)
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

    s = sub.add_parser("identify", help="identify the modal plant from a seek log")
    s.add_argument("log")
    s.add_argument("-o", "--output", help="plant JSON")
    s.add_argument("--method", choices=["robust", "paper"], default="robust")
    s.add_argument("--figures", help="folder for figures")
    s.set_defaults(func=cmd_identify)

    s = sub.add_parser("design", help="design an optimal seek profile")
    s.add_argument("--plant", required=True)
    s.add_argument("--controller")
    s.add_argument("--tracks", type=float, required=True)
    s.add_argument("--imax", type=float, required=True)
    s.add_argument("--settle", type=float, default=0.1, help="settle band [track]")
    s.add_argument("--robust", nargs="?", const="default", default="default",
                   help="robust design set (default: RobustSpec() -- seek-induced modes +-5 %%, others +-1 %%, "
                        "zeta +-30 %%, gain +-8 %%, delay +-1 us); e.g. freq=5,ofreq=1,zeta=30,gain=8,delay=1e-6,n=15 "
                        "(percent / s); 'none' for a nominal design")
    s.add_argument("--start-track", type=float, default=None,
                   help="track the seek starts from (default: middle of the plant's position_range_track; the sign "
                        "of --tracks gives the direction, negative = inward)")
    s.add_argument("-o", "--output", required=True, help="profile CSV")
    s.set_defaults(func=cmd_design)

    s = sub.add_parser("bench", help="benchmark optimal profiles against sine and windowed sine")
    s.add_argument("--plant", required=True)
    s.add_argument("--controller")
    s.add_argument("--truth", help="evaluate on this plant (default: the design plant)")
    s.add_argument("--tracks", type=float, default=200.0)
    s.add_argument("--imax", type=float, required=True)
    s.add_argument("--settle", type=float, default=0.1)
    s.add_argument("--figures", help="folder for Fig. 9/10-style plots")
    s.add_argument("--start-track", type=float, default=None,
                   help="start track of the seek on a plant with effects (default: middle of its fitted range)")
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("loop", help="close the loop: residual analysis and model augmentation")
    s.add_argument("log")
    s.add_argument("--validate", help="validation log (default: held-out seeks)")
    s.add_argument("--report", required=True, help="report JSON")
    s.add_argument("--figures", help="folder for residual figures and the Markdown report")
    s.set_defaults(func=cmd_loop)

    s = sub.add_parser("sweep", help="sweep designs over TPI and seek length")
    s.add_argument("--plant", required=True)
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
