"""``seekopt synth``: run the synthetic drive (:mod:`seekopt.evaluate.synth`) and write a seek log."""
from __future__ import annotations

import math

from seekopt.app.commands.common import LOG_SUFFIXES, UsageError, check_output_file, check_positive, progress
from seekopt.app.commands.inputs import load_pair

__all__ = ["cmd_synth", "parse_effect"]


def parse_effect(text: str) -> dict:
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
                      effects=[parse_effect(e) for e in args.effect])
    plant, controller = load_pair(args.plant, args.controller,
                                  plant=None if args.plant else default_truth_plant())
    with progress(args, f"running the synthetic drive ({args.seeks} seeks)"):
        log, truth = synthesize(cfg, plant=plant, controller=controller)
    write_log(log, args.output)
    if args.truth:
        truth.to_json(args.truth)
    print(f"wrote {args.output}: {log.n} samples, {args.seeks} seeks at {log.sample_rate_hz:g} Hz")
    return 0

