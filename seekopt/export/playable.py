"""``seekopt export``: playable tables for every seek length of a sweep's drive, and the export of one design.

From a sweep results folder (:mod:`seekopt.evaluate.sweep`), per TPI: the sweep's plant at that TPI, its
controller (scaled as in the sweep), its designer, the full stroke and the velocity limit give the
length classes of :mod:`seekopt.export.classes` (built by :mod:`seekopt.export.build`), written as C
(:mod:`seekopt.export.ctable`), JSON or CSV, ``seekopt_seek.*``.

Physical settings (converted to tracks per TPI with the TPI's track pitch)
    ``stroke_mm`` (``--stroke-mm``, else the plant's ``meta["stroke_mm"]`` / ``meta["stroke_track"]`` at the
    plant's own pitch) and ``vmax_mps`` (``--vmax-mps``, else the plant's metadata, see
    :mod:`seekopt.design.longseek`; none: see :mod:`seekopt.export.build`).
Designers
    The sweep's own (:func:`seekopt.evaluate.sweep_cell.designer_factory`): the ``ocp`` designers on the
    problem its cells designed on (:func:`seekopt.evaluate.sweep_cell.designer_problem`: the default
    :class:`~seekopt.design.family.Drift` or the sweep's ``drift``, the family members at the TPI), the long
    seeks on that same problem.  ``sweep.json`` is read once (:func:`read_sweep`) and passed down.
Current margin
    Tables play both directions, and the hold current ``-bias_a`` adds to one of them: the anchors of the
    ``ocp`` designers are designed with ``current_margin = 0.97 - 2 |bias_a| / Imax`` so that both directions
    stay within ``0.97 Imax`` (velocity steps bound ``|i| <= 0.97 Imax - |bias|`` themselves).  Other
    designers are used as the sweep built them; the peak current of every class in both directions is
    measured on a linear plant (:func:`seekopt.export.verify.play_rule`: superposition, or the simulator when
    the loop does not superpose) and recorded (``meta["peak_current_a"]``), and a warning printed when it
    exceeds Imax.

A single design (a Profile CSV from ``seekopt design``) is exported as one table in the format of
:mod:`seekopt.export.tables` (:func:`table_set_from_profile`).
"""
from __future__ import annotations

import csv
import io
import json
import math
import sys
from pathlib import Path

import numpy as np

from seekopt.export.classes import RuleError, SeekRule, frac_bits_for
from seekopt.export.tables import ExportError, read_sweep_json

__all__ = ["read_sweep", "resolve_physical", "sweep_stroke_mm", "build_rule", "write_seek", "write_seek_json",
           "write_seek_csv", "table_set_from_profile", "export_designer", "export_longseek", "SEEK_BASENAME"]

SEEK_BASENAME = "seekopt_seek"


def read_sweep(results_dir):
    """``(SweepConfig, the parsed sweep.json)`` of a sweep results folder, read once for the whole export
    (one-line :class:`ExportError` for a missing folder, no or unreadable ``sweep.json``)."""
    from seekopt.evaluate.sweep import SweepConfig
    root, d = read_sweep_json(results_dir)
    try:
        return SweepConfig.from_dict(d), d
    except Exception as exc:  # noqa: BLE001 - any unreadable configuration is bad input
        raise ExportError(f"{root / 'sweep.json'}: not a sweep configuration ({type(exc).__name__})") from None


def resolve_physical(plant0, imax: float, stroke_mm=None, vmax_mps=None):
    """``(stroke_mm, vmax_mps or None)`` from the arguments or the plant's metadata (one-line errors)."""
    from seekopt.design.longseek import LongSeekError, stroke_from_plant, vmax_from_plant
    for name, v in (("--stroke-mm", stroke_mm), ("--vmax-mps", vmax_mps)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ExportError(f"{name} must be a positive number (got {v})")
    pitch = plant0.track_pitch_nm
    try:
        if stroke_mm is None:
            st = stroke_from_plant(plant0)
            stroke_mm = None if st is None else st * pitch * 1e-6
        if vmax_mps is None:
            v = vmax_from_plant(plant0, imax)
            vmax_mps = None if v is None else v * pitch * 1e-9
    except LongSeekError as exc:
        raise ExportError(f"plant: {exc}") from None
    return stroke_mm, vmax_mps


def sweep_stroke_mm(results_dir, stroke_mm=None, vmax_mps=None, sweep=None):
    """The stroke [mm] of a sweep's drive (argument or plant metadata; None if neither), after checking the
    physical settings (one-line :class:`ExportError`); ``sweep``: :func:`read_sweep` of the folder when
    already read."""
    cfg, _ = sweep or read_sweep(results_dir)
    return resolve_physical(cfg.plant, cfg.imax, stroke_mm, vmax_mps)[0]


def export_designer(spec: str, plant, controller, imax: float, settle: float, family=(), drift: str | None = None,
                    **options):
    """The anchor designer for a sweep's designer ``spec``: the sweep's own
    (:func:`seekopt.evaluate.sweep_cell.designer_factory`: the same robust set, ``drift`` and ``family``
    members at the plant's TPI, the sweep's problem ``options`` such as its worst-case slack), the ``ocp``
    ones with the export's current margin (module notes)."""
    from seekopt.evaluate.sweep_cell import OCP_SPECS, designer_factory
    if spec not in OCP_SPECS:
        return designer_factory(spec)(plant, controller, imax, settle)
    margin = 0.97 - 2 * abs(plant.bias_a) / imax
    if margin <= 0.5:
        raise ExportError(f"bias {plant.bias_a:g} A is too large for Imax {imax:g} A")
    return designer_factory(spec, family, drift, long_seeks=False, current_margin=margin, **options)(
        plant, controller, imax, settle)


def export_longseek(spec: str, plant, controller, imax: float, settle: float, long_spec, family=(),
                    drift: str | None = None, **options):
    """The long-seek designer (:class:`seekopt.design.longseek.LongSeekDesigner`) of a sweep's designer
    ``spec``: the ``ocp`` ones on the sweep's problem (:func:`seekopt.evaluate.sweep_cell.designer_problem`:
    the same robust set and family as the anchors; the velocity steps bound their current with the hold
    themselves), any other designer on the nominal plant."""
    from seekopt.design.longseek import LongSeekDesigner
    from seekopt.evaluate.sweep_cell import designer_problem
    problem = designer_problem(spec, plant, controller, imax, settle, family, drift, **options)
    if problem is None:
        return LongSeekDesigner(plant, controller, imax, settle, None, long_spec)
    return LongSeekDesigner(problem, long_spec)


def build_rule(results_dir, *, stroke_mm=None, vmax_mps=None, budget_kib: float = 64.0, settings=None,
               progress: bool = True, sweep=None) -> SeekRule:
    """Playable tables (every length 1..stroke, per TPI) for a sweep results folder (module notes);
    ``sweep``: :func:`read_sweep` of the folder when already read.

    Raises :class:`ExportError` (one line) for a missing folder, no stroke, bad settings -- before designing.
    """
    from tqdm.auto import tqdm
    from seekopt import __version__
    from seekopt.design.longseek import LongSeekSpec
    from seekopt.evaluate.sweep import controller_at_tpi
    from seekopt.export.build import AnchorDesigner, ClassSettings, build_seek_set
    from seekopt.export.verify import play_rule
    cfg, raw = sweep or read_sweep(results_dir)
    if not (math.isfinite(budget_kib) and budget_kib > 0):
        raise ExportError(f"--budget-kib must be a positive number (got {budget_kib})")
    stroke_mm, vmax_mps = resolve_physical(cfg.plant, cfg.imax, stroke_mm, vmax_mps)
    if stroke_mm is None:
        raise ExportError(f"{results_dir}: playable tables need the full stroke (--stroke-mm, or the plant's "
                          "meta stroke_mm / stroke_track)")
    st = settings or ClassSettings()
    st.budget_bytes = int(budget_kib * 1024)
    tpis = [t for t in cfg.tpis]
    for t in tpis:
        if t != round(t):
            raise ExportError(f"{results_dir}: TPI {t:g} is not a whole number; tables are indexed by whole TPI")
    plants = {t: cfg.plant.at_tpi(t) for t in tpis}
    strokes = {t: int(math.floor(stroke_mm * 1e6 / plants[t].track_pitch_nm)) for t in tpis}
    if min(strokes.values()) < 1:
        raise ExportError(f"stroke {stroke_mm:g} mm is shorter than one track")
    try:
        F = frac_bits_for(max(strokes.values()))
    except RuleError as exc:
        raise ExportError(str(exc)) from None
    sets, peaks = [], {}
    slack = {"worst_case_slack_s": cfg.worst_case_slack_s} if cfg.worst_case_slack_s else {}   # the sweep's
    for t in tpis:
        plant = plants[t]
        ctrl = controller_at_tpi(cfg.controller, cfg.plant, t) if cfg.scale_controller else cfg.controller
        family = [m.at_tpi(t) for m in cfg.family]         # as the sweep's cells hold them
        vmax = None if vmax_mps is None else vmax_mps / (plant.track_pitch_nm * 1e-9)
        ls = export_longseek(cfg.designer, plant, ctrl, cfg.imax, cfg.settle,
                             LongSeekSpec(vmax_track_s=vmax, stroke_track=strokes[t]), family, cfg.drift, **slack)
        with tqdm(desc=f"export {t:g} TPI", unit="design", file=sys.stderr, disable=not progress) as bar:
            ad = AnchorDesigner(export_designer(cfg.designer, plant, ctrl, cfg.imax, cfg.settle, family, cfg.drift,
                                                **slack),
                                plant, ctrl, cfg.settle, progress=bar)
            try:
                s = build_seek_set(ad, ls, strokes[t], F, cfg.imax, tpi=int(round(t)), settings=st)
            except RuleError as exc:
                raise ExportError(str(exc)) from None
        tops = [c.k_hi for c in s.classes] + [c.k_lo for c in s.coasts] + [s.stroke]
        pk = play_rule(s, plant, ctrl, sorted(set(tops)), cfg.imax, cfg.settle) if plant.is_linear else None
        peak = None if pk is None else float(max(pk["peak_current_a"].max(), pk["peak_current_neg_a"].max()))
        s.meta.update(peak_current_a=peak, plant_hash=plant.hash(), controller_hash=ctrl.hash(),
                      stroke_mm=stroke_mm, table_bytes=s.table_bytes(), budget_bytes=st.budget_bytes)
        if peak is not None and peak > cfg.imax * (1 + 1e-9):
            print(f"export: warning: {t:g} TPI: a class peaks at {peak:.4g} A > Imax {cfg.imax:g} A "
                  f"(designer {cfg.designer})", file=sys.stderr)
        sets.append(s)
        peaks[t] = peak
    meta = {"tool_version": __version__, "plant_hash": cfg.plant.hash(), "controller_hash": cfg.controller.hash(),
            "source": f"sweep {raw.get('config_hash', '')}", "designer": cfg.designer,
            "sample_rate_hz": float(cfg.controller.sample_rate_hz), "imax_a": float(cfg.imax),
            "settle_track": float(cfg.settle), "ref_frac_bits": F, "stroke_mm": stroke_mm, "vmax_mps": vmax_mps,
            "ff_format": "int16 Q15 of imax_a, |u| <= 32767",
            "ref_format": f"int32 track from the seek start, {F} fractional bits",
            "rule": "seekopt.export.classes (rest classes scaled in amplitude; coast classes of velocity steps)"}
    return SeekRule(meta, sets)


def write_seek_json(rule: SeekRule, outdir, basename: str = SEEK_BASENAME) -> list[Path]:
    """``<basename>.json``: :meth:`SeekRule.to_dict` (every integer of the C tables)."""
    from identification.fileio import atomic_write_text as write_atomic
    Path(outdir).mkdir(parents=True, exist_ok=True)
    p = Path(outdir) / f"{basename}.json"
    write_atomic(p, json.dumps(rule.to_dict(), indent=1, sort_keys=True) + "\n")
    return [p]


def write_seek_csv(rule: SeekRule, outdir, basename: str = SEEK_BASENAME) -> list[Path]:
    """``<basename>.csv``: ``# key: value`` metadata, then one row per table sample (``kind`` rest/coast,
    ``k_lo``, ``k_hi`` of a rest class or ``d_q`` of a coast class)."""
    from identification.fileio import atomic_write_text as write_atomic
    buf = io.StringIO()
    for k, v in rule.meta.items():
        buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["tpi", "member", "stroke", "kind", "class", "k_lo", "k_hi_or_d_q", "settle_samples", "sample",
                "ff_q15", "ref_q"])
    for s in rule.sets:
        for kind, cls in (("rest", s.classes), ("coast", s.coasts)):
            for i, c in enumerate(cls):
                top = c.k_hi if kind == "rest" else c.d_q
                for j in range(c.n):
                    w.writerow([s.tpi, s.member, s.stroke, kind, i, c.k_lo, top, c.settle_samples, j,
                                int(c.ff_q15[j]) if j < len(c.ff_q15) else "",
                                int(c.ref_q[j]) if j < len(c.ref_q) else ""])
    Path(outdir).mkdir(parents=True, exist_ok=True)
    p = Path(outdir) / f"{basename}.csv"
    write_atomic(p, buf.getvalue())
    return [p]


def write_seek(rule: SeekRule, fmt: str, outdir) -> list[Path]:
    """Write the playable tables as ``fmt`` (``c``, ``csv``, ``json``)."""
    from seekopt.export.ctable import write_seek_c
    writers = {"c": write_seek_c, "csv": write_seek_csv, "json": write_seek_json}
    if fmt not in writers:
        raise ExportError(f"unknown format {fmt!r} (expected c, csv or json)")
    return writers[fmt](rule, outdir)


def table_set_from_profile(path):
    """One design (a Profile CSV of ``seekopt design``) as a :class:`seekopt.export.tables.TableSet`
    (TPI from the profile's ``tpi`` metadata, else 0)."""
    from seekopt import __version__
    from seekopt.design.profiles import Profile, ProfileError
    from seekopt.export.tables import FF_Q, SeekTable, TableSet, quantize_ff, quantize_ref, ref_frac_bits
    try:
        p = Profile.from_csv(path)
    except ProfileError as exc:
        raise ExportError(str(exc)) from None
    if p.tracks != round(p.tracks) or p.tracks == 0:
        raise ExportError(f"{path}: seek length {p.tracks:g} is not a non-zero whole number of tracks")
    if p.n > 65535:
        raise ExportError(f"{path}: profile has {p.n} samples (> 65535)")
    try:
        tpi = int(round(float(p.meta.get("tpi", 0))))
    except ValueError:
        raise ExportError(f"{path}: tpi {p.meta.get('tpi')!r} is not a number") from None
    frac = ref_frac_bits(float(np.max(np.abs(p.reference_track))))
    ff = np.asarray(p.current_a[:p.seek_samples], float)
    t = SeekTable(tpi, int(round(p.tracks)), quantize_ff(ff, p.imax_a), quantize_ref(p.reference_track, frac), ff,
                  np.asarray(p.reference_track, float))
    meta = {"tool_version": __version__, "plant_hash": p.meta.get("plant_hash", ""),
            "controller_hash": p.meta.get("controller_hash", ""), "sweep_hash": "none (one design)",
            "designer": p.meta.get("design_objective", p.kind), "sample_rate_hz": float(p.sample_rate_hz),
            "imax_a": float(p.imax_a), "settle_track": float(p.settle_track),
            "ff_format": "int16 Q15, full scale = imax_a", "ff_q": FF_Q,
            "ref_format": f"int32 Q{32 - frac}.{frac} (sign included, {frac} fractional bits) track, "
                          "relative to seek start",
            "ref_frac_bits": frac, "controller_scaled_per_tpi": False, "source_profile": Path(path).name}
    return TableSet(meta, [t])
