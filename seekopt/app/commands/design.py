"""``seekopt design``: one minimum seek-settle-time profile (:mod:`seekopt.design.designer`), with the
predicted settle times on every plant of the robust set and the unmodelled-mode guard."""
from __future__ import annotations

import sys

from seekopt.app.commands.common import (UsageError, check_output_file, check_positive, check_seek_args,
                                         parse_duration, progress)
from seekopt.app.commands.inputs import plant_family, robust_choice

__all__ = ["cmd_design", "first_path"]


def first_path(paths) -> str:
    """The first ``--plant`` path as the user gave it (for one-line errors)."""
    return str(paths[0] if isinstance(paths, (list, tuple)) else paths)


def _print_predictions(res, names) -> None:
    """Predicted seek-settle times (nominal, each family member, worst over the set) and the guard."""
    pred, g = res.prediction, res.guard
    spent = res.set_settle_samples - res.set_min_settle_samples
    if spent:
        print(f"  worst-case slack: the set settles by sample {res.set_settle_samples} instead of its minimum "
              f"{res.set_min_settle_samples} ({spent} sample(s) spent), the design plant by "
              f"{res.settle_samples}")
    if pred is not None:
        ms = lambda m: f"{m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb)"     # noqa: E731
        shown = set()
        for lab, m in pred.members():      # the member itself comes first, its per-mode corners after it
            i = 0 if lab == "nominal" else int(lab.split()[1].rstrip(":"))
            if i not in shown:
                shown.add(i)
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
    The problem is checked before any QP is built (closed loop of every plant of the robust set, a
    seek beyond the design horizon at ``--imax``): one line, exit 2.  Prints the predicted seek-settle
    time on the nominal plant, on each member and the worst over the set (which plant binds) and the
    unmodelled-mode guard's worst residual; all are in the profile's metadata."""
    from seekopt.design.designer import DesignError, SeekDesigner
    from seekopt.design.problem import ProblemError, SeekProblem
    check_output_file(args.output, "-o", (".csv",))
    check_seek_args(args)
    slack = parse_duration(args.worst_case_slack, "--worst-case-slack")
    plant, family, controller, names = plant_family(args.plant, args.controller)
    robust = robust_choice(args, plant)
    from seekopt.design.feasibility import StartError, resolve_start
    try:        # start track and direction: never outside the range the plant's effects were fitted on
        start = resolve_start(plant, args.tracks, args.start_track, source=first_path(args.plant))
    except StartError as exc:
        raise UsageError(str(exc)) from None
    from seekopt.design.nlp import needs_nlp
    if needs_nlp(plant):    # input/force effects: the effect-aware NLP (seekopt.design.nlp)
        return _design_with_effects(args, plant, controller, robust, start, names)
    from seekopt.design.longseek import LongSeekDesigner, LongSeekError, LongSeekSpec
    r2r = getattr(args, "rest_to_rest_up_to", None)
    for name, v in (("--vmax", args.vmax), ("--stroke", args.stroke), ("--rest-to-rest-up-to", r2r)):
        if v is not None:
            check_positive(v, name)
    try:
        spec = LongSeekSpec.from_plant(plant, args.imax, args.vmax, args.stroke, r2r)
    except LongSeekError as exc:
        raise UsageError(f"{', '.join(names)}: {exc}") from None
    if spec.stroke_track is not None and abs(args.tracks) > spec.stroke_track:
        raise UsageError(f"--tracks {args.tracks:g} is longer than the stroke ({spec.stroke_track:g} tracks)")
    try:
        designer = SeekDesigner(SeekProblem(plant, controller, args.imax, args.settle, robust=robust, family=family,
                                               worst_case_slack_s=slack))
        # long seeks (with or without --vmax) are accelerate-coast-arrive, shorter ones rest-to-rest QPs
        # (the dispatch rule of seekopt.design.longseek)
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
    if prof.kind == "long_seek" and len(getattr(designer, "plants", [])) > 1 and res.prediction is None:
        res.prediction = _played_on_set(designer, res, args.settle)
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
    _print_predictions(res, names)
    return 0


def _played_on_set(designer, res, settle: float):
    """A long seek's settle on every plant of the designer's set, played by the one simulator
    (:func:`seekopt.design.predict.predict_on_set`); written into the profile's metadata.  The long-seek
    designer predicts the set's worst by superposing its step's responses
    (``set_settle_samples_predicted``); this plays the composed profile itself, as the rest-to-rest
    designs' predictions do.  Not done inside the designer: on the 22-plant sets of the studies it would
    cost more than the long seek's design."""
    from seekopt.design.predict import predict_on_set
    pred = predict_on_set(designer.plants, designer.controller, res.profile, settle, first=res.metrics)
    res.profile.meta.update(pred.to_meta())
    return pred


def _design_with_effects(args, plant, controller, robust, start, names) -> int:
    """``seekopt design`` on a plant with effects: Ipopt over the full closed loop, from ``start``
    (:class:`seekopt.design.nlp.EffectAwareDesigner`).  Every failure (a band the loop cannot hold,
    Ipopt, the full-plant check) is one line, exit 2, and nothing is written."""
    from seekopt.design.nlp import DesignUnholdable, EffectAwareDesigner, NLPDesignError

    def say(msg):
        if not getattr(args, "quiet", False):
            print(f"seekopt design: {msg}", file=sys.stderr, flush=True)
    try:
        res = EffectAwareDesigner(plant, controller, args.imax, args.settle, robust).design(
            args.tracks, start, progress=say)
    except (DesignUnholdable, NLPDesignError) as exc:
        print(f"seekopt design: error: {first_path(args.plant)}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    prof = res.profile
    prof.meta.update(plant_file=";".join(names), controller_name=controller.name)
    prof.to_csv(args.output)
    m, lm = res.metrics, res.linear_metrics
    print(f"wrote {args.output}: {prof.n} samples; {args.tracks:g} tracks from track {res.start_track:g} "
          f"({prof.meta['direction']}), seek-settle {m.settle_time_s * 1e3:.3f} ms ({m.ratio_tbb:.2f} T_bb) on the "
          f"design plant with its effects ({prof.meta['effects_in_design']}), peak current {m.peak_current_a:.3f} A; "
          f"linear design there {lm.settle_time_s * 1e3:.3f} ms; {len(res.solves)} NLPs, Ipopt "
          f"{res.ipopt_iterations} iterations in {res.ipopt_time_s:.2f} s ({res.ipopt_cpu_s:.2f} s CPU)")
    return 0
