"""``seekopt demo``: the whole pipeline on the bundled sample log (:mod:`seekopt.app.demo`)."""
from __future__ import annotations

from seekopt.app.commands.common import check_output_dir

__all__ = ["cmd_demo"]


def cmd_demo(args) -> int:
    from seekopt.app.demo import DemoConfig, run_demo
    check_output_dir(args.output, "-o")
    run_demo(DemoConfig(log=args.log, outdir=args.output, quick=args.quick,
                        quiet=bool(getattr(args, "quiet", False))))
    return 0

