"""The seekopt command line: the parser and the dispatcher, a thin layer over the Python API.

Every command checks its arguments and paths before it computes anything (output folders exist
and are writable, numbers are in range, the controller closes a stable loop with the plant at
the plant's sample rate), reports bad input as one line on stderr naming the user's file and
the problem, and exits with status 2.  An unexpected internal error is a bug: it keeps its
traceback (exit status 1).  Outputs are written atomically.  Steps that take more than a moment
print a one-line stage log with the elapsed time on stderr (``--quiet`` silences it; warnings
and errors are always printed).

BLAS threads: every command runs with one BLAS/OpenMP thread (``threadpoolctl``); the matrices
of identification and design are small, and a multi-threaded BLAS on a shared or loaded machine
spins more CPU than it saves.  Set ``SEEKOPT_BLAS_THREADS=N`` to allow ``N`` (``0``: leave the
libraries' own setting).  Sweep workers hold one thread each (:mod:`seekopt.evaluate.engines`).

One module per command in :mod:`seekopt.app.commands` maps parsed arguments onto the API of one
module (``cmd_<name>``); the logic lives in those modules.  Helpers the commands share live in
:mod:`seekopt.app.commands.common` (:class:`UsageError`, :func:`progress`, :func:`warn`,
:func:`check_output_file`, :func:`check_output_dir`, :func:`check_positive`) and
:mod:`seekopt.app.commands.inputs` (:func:`read_log_cli`, :func:`load_pair`); they are re-exported here.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys

from seekopt.app.commands.bench import cmd_bench
from seekopt.app.commands.common import (DEFAULT_CONTROLLER, LOG_SUFFIXES, PROGRESS_AFTER_S, UsageError,  # noqa: F401
                                         check_output_dir, check_output_file, check_positive, input_errors,
                                         message, progress, warn)
from seekopt.app.commands.demo import cmd_demo
from seekopt.app.commands.design import cmd_design
from seekopt.app.commands.export import cmd_export
from seekopt.app.commands.identify import cmd_identify
from seekopt.app.commands.inputs import load_pair, read_log_cli
from seekopt.app.commands.loop import cmd_loop
from seekopt.app.commands.sweep import cmd_sweep
from seekopt.app.commands.synth import cmd_synth

__all__ = ["main", "build_parser", "UsageError", "read_log_cli", "progress", "warn", "check_output_file",
           "check_output_dir", "check_positive", "load_pair", "DEFAULT_CONTROLLER"]


# ------------------------------------------------------------------ parser
_DESCRIPTION = ("seekopt: seek-profile optimisation for hard-disk-drive servo engineers. Seek logs -> modal "
                "plant (identify, loop) -> minimum seek-settle-time profiles (design, bench) -> TPI x length "
                "sweeps -> fixed-point firmware tables (export).")
_EPILOG = """\
units: position [track], current [A], time [s], frequency [Hz]; track density [track/inch] (TPI).
default controller (when --controller is not given):
  the IEEJ NSS benchmark's PID + 4 notches at 26400 Hz (notches at twice the PES rate;
  seekopt/data/nss_controller.json)
bad input is one line on stderr and exit status 2; 'seekopt COMMAND -h' lists a command's options.
"""
_CONTROLLER_HELP = ("the drive's feedback controller, JSON (default: the IEEJ NSS benchmark's PID + notch, "
                    "26400 Hz); must run at the plant's sample rate")
_SLACK_HELP = ("let the worst case over the plant set settle up to this much later than its minimum (e.g. 0.04ms, "
               "40us; rounded down to servo samples) so that the design plant settles earlier (default 0: the "
               "set's minimum); see 'Operating range' in the README")


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
    s.add_argument("--rest-to-rest-up-to", type=float, default=None, metavar="TRACK",
                   help="design seeks up to this length by the rest-to-rest QP (settles sooner, cost grows with the "
                        "length) instead of the acceleration step (default: from its shortest seek on, ~1600 tracks "
                        "on the bundled drive)")
    s.add_argument("--start-track", type=float, default=None, metavar="TRACK",
                   help="track the seek starts from (default: the middle of the plant's position_range_track, 0 "
                        "without one); a plant with position-dependent effects never extrapolates beyond that range")
    s.add_argument("--worst-case-slack", default="0", metavar="TIME", help=_SLACK_HELP)
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
    s.add_argument("--worst-case-slack", default="0", metavar="TIME",
                   help=_SLACK_HELP.replace("so that", "(ocp designers; kept in the sweep's configuration, so "
                                                         "'seekopt export' designs with it too) so that"))
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
    args.progress_after_s = PROGRESS_AFTER_S
    try:
        with _blas_threads():
            return int(args.func(args) or 0)
    except input_errors() as exc:
        print(f"seekopt {args.command}: error: {message(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"seekopt {args.command}: interrupted", file=sys.stderr)
        return 130


def _blas_threads():
    """Context limiting BLAS to ``SEEKOPT_BLAS_THREADS`` threads (default 1; 0 leaves it as is)."""
    raw = os.environ.get("SEEKOPT_BLAS_THREADS", "1").strip()
    n = int(raw) if raw.isdigit() else 1
    if n == 0:
        return contextlib.nullcontext()
    from seekopt.design.blas import limit_blas
    return limit_blas(n, override_env=False)

if __name__ == "__main__":
    sys.exit(main())
