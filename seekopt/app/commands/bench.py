"""``seekopt bench``: the paper's sine and windowed sine against the optimal profiles
(:mod:`seekopt.evaluate.bench`)."""
from __future__ import annotations

from pathlib import Path

from seekopt.app.commands.common import check_output_dir, check_seek_args, progress
from seekopt.app.commands.inputs import load_pair, load_plant, plant_family, robust_choice

__all__ = ["cmd_bench"]


def cmd_bench(args) -> int:
    """``seekopt bench``: sine / windowed sine / optimal table (+ Fig. 9/10-style plots); see :mod:`seekopt.evaluate.bench`."""
    from seekopt.evaluate.bench import format_table, run_bench
    check_output_dir(args.figures, "--figures")
    check_seek_args(args)
    plant, family, controller, names = plant_family(args.plant, args.controller)
    robust = robust_choice(args, plant)
    truth = load_plant(args.truth) if args.truth else None
    if truth is not None:
        load_pair(args.truth, args.controller, plant=truth)
    from seekopt.design.nlp import needs_nlp
    if needs_nlp(plant):    # effects: played from the start track on the full plant (seekopt.evaluate.effect_bench)
        import sys
        from seekopt.app.commands.common import UsageError
        from seekopt.app.commands.design import first_path
        from seekopt.design.feasibility import StartError, resolve_start
        from seekopt.evaluate.effect_bench import run_effect_bench
        try:
            start = resolve_start(plant, args.tracks, args.start_track, source=first_path(args.plant))
        except StartError as exc:
            raise UsageError(str(exc)) from None
        quiet = getattr(args, "quiet", False)
        res = run_effect_bench(plant, controller, args.tracks, args.imax, args.settle, start_track=start,
                               truth=truth, robust=robust,
                               progress=None if quiet else
                               (lambda msg: print(f"seekopt bench: {msg}", file=sys.stderr, flush=True)))
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

