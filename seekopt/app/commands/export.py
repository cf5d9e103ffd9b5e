"""``seekopt export``: fixed-point firmware tables of a sweep (and of every seek length when the stroke
is known), or of one design (:mod:`seekopt.export`)."""
from __future__ import annotations

from pathlib import Path

from seekopt.app.commands.common import check_output_dir, check_positive, progress

__all__ = ["cmd_export"]


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
    check_positive(args.budget_kib, "--budget-kib")
    sweep = playable.read_sweep(src) if src.is_dir() else None        # sweep.json, read once
    stroke_mm = playable.sweep_stroke_mm(src, args.stroke_mm, args.vmax_mps, sweep) if sweep else None
    with progress(args, f"quantising the tables of {args.results}"):
        ts = load_tables(args.results, None if sweep is None else sweep[1])
        paths = write_tables(ts, args.format, args.output)
    print(f"export: {len(ts.tables)} tables ({len(ts.tpis)} TPI x {len(ts.lengths)} lengths, "
          f"{ts.meta['ref_format']} reference) -> " + ", ".join(map(str, paths)))
    if stroke_mm is None:
        print("export: no stroke given (--stroke-mm or the plant's meta stroke_mm): only the swept lengths were "
              "exported; pass --stroke-mm for tables of every length")
        return 0
    rule = playable.build_rule(src, stroke_mm=args.stroke_mm, vmax_mps=args.vmax_mps, budget_kib=args.budget_kib,
                               progress=not getattr(args, "quiet", False), sweep=sweep)
    paths = playable.write_seek(rule, args.format, args.output)
    for s in rule.sets:
        pk = s.meta["peak_current_a"]
        print(f"export: {s.tpi} TPI: lengths 1..{s.stroke} in {len(s.classes)} rest-to-rest classes "
              f"(1..{s.classes[-1].k_hi}) + {len(s.coasts)} coast classes, {s.table_bytes()} bytes of "
              f"{int(args.budget_kib * 1024)}, peak current " + (f"{pk:.4g} A" if pk is not None else "not checked")
              + f", coast at {s.meta['coast_velocity_track_s']:.4g} track/s")
    print("export: playable tables -> " + ", ".join(map(str, paths)))
    return 0

