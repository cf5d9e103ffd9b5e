"""``seekopt loop``: close the loop with measured data (:func:`identification.loop.closing.close_loop`)
and write the report and the augmented plant."""
from __future__ import annotations

import sys
from pathlib import Path

from seekopt.app.commands.common import UsageError, check_output_dir, check_output_file
from seekopt.app.commands.inputs import load_plant

__all__ = ["cmd_loop"]


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
    model = load_plant(args.plant) if args.plant else None
    check_output_file(args.report, "--report")
    check_output_file(args.output, "-o")
    check_output_dir(args.figures, "--figures")
    if args.output and Path(args.output).resolve() == Path(args.report).resolve():
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

