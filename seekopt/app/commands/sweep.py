"""``seekopt sweep``: optimal designs over a TPI x seek-length grid (:mod:`seekopt.evaluate.sweep`)."""
from __future__ import annotations

import sys

from seekopt.app.commands.common import UsageError, check_output_dir, check_positive, parse_duration
from seekopt.app.commands.inputs import plant_family

__all__ = ["cmd_sweep"]


def cmd_sweep(args) -> int:
    """``seekopt sweep``: exit status 0 when every cell of the grid is saved without a failed row,
    1 (with a one-line summary on stderr) when any cell failed or could not be computed."""
    from seekopt.evaluate.sweep import SweepConfig, parse_tpi, parse_tracks, run_sweep
    check_output_dir(args.output, "-o")
    check_positive(args.imax, "--imax [A]")
    check_positive(args.settle, "--settle [track]")
    slack = parse_duration(args.worst_case_slack, "--worst-case-slack")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1 (got {args.workers})")
    plant, family, controller, _ = plant_family(args.plant, args.controller)
    cfg = SweepConfig(plant, controller, parse_tpi(args.tpi), parse_tracks(args.tracks), args.imax, args.settle,
                      designer=args.designer, family=family, drift=",".join(args.drift) or None,
                      worst_case_slack_s=slack)
    s = run_sweep(cfg, args.output, engine=args.dask or "process", workers=args.workers,
                  progress=not args.quiet, figures=not args.no_figures)
    others = f", {s.by_others} by another sweep" if s.by_others else ""
    work = f", {s.cell_cpu_s / s.computed:.2f} s CPU per cell, {sum(s.designers_built.values())} designers " \
        f"built on {len(s.designers_built)} workers" if s.computed else ""
    print(f"sweep: {s.total} cells ({s.skipped} saved before, {s.computed} computed in {s.wall_s:.1f} s "
          f"on {s.engine}, {s.cells_per_s:.2f} cells/s{work}{others}); table {s.table}")
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

