"""Firmware export of the optimal seek profiles of a sweep (``seekopt export``).

Reads a sweep results folder (:mod:`seekopt.evaluate.sweep`) and writes the optimal
designs as fixed-point tables, as C (``seekopt_tables.h`` + ``seekopt_tables.c``),
CSV (``seekopt_tables.csv``) or JSON (``seekopt_tables.json``); all three carry
the same integers and metadata.

Formats
-------
Feedforward
    ``int16`` Q15 with full scale ``Imax``: ``q = round(u / Imax * 32768)``, rounded half
    away from zero and saturated to ``[-32768, 32767]``; firmware plays
    ``I [A] = q * Imax / 32768`` for ``ff_len`` samples, then 0.
Reference
    ``int32`` with ``F`` fractional bits (``SEEKOPT_REF_FRAC_BITS``; Q16.16 unless the
    longest reference needs more integer bits, then the largest ``F`` that fits), in
    tracks relative to the seek start: ``r = q / 2^F`` for ``ref_len`` samples, then the
    seek length held.
Direction
    Tables are for positive seeks; a negative seek negates both tables.
Several TPIs
    One table set per TPI, all in the same files: ``seekopt_tpis[]`` lists the
    densities, ``seekopt_index[tpi][length]`` gives the table number (``-1`` where the
    sweep has no successful optimal design), ``seekopt_lookup(tpi, tracks)`` finds a
    table by exact TPI and length.  Seek lengths must be whole tracks and TPIs whole numbers.

Every file starts with a banner naming the tool version and the plant, controller
and sweep hashes; there are no dates, so the output is byte-reproducible.
"""
from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["ExportError", "SeekTable", "TableSet", "load_tables", "quantize_ff", "quantize_ref",
           "ref_frac_bits", "write_tables", "write_c", "write_csv", "write_json", "read_csv", "read_json", "export",
           "BASENAME"]

BASENAME = "seekopt_tables"
FF_Q = 15


class ExportError(ValueError):
    """Results that cannot be exported (one-line message)."""


@dataclass
class SeekTable:
    """One seek's fixed-point tables (and the float values they quantise)."""

    tpi: int
    tracks: int
    ff_q15: np.ndarray      # int16, length ff_len
    ref_q: np.ndarray       # int32, length ref_len
    ff_a: np.ndarray        # float, A
    ref_track: np.ndarray   # float, track

    @property
    def ff_len(self) -> int:
        return len(self.ff_q15)

    @property
    def ref_len(self) -> int:
        return len(self.ref_q)


@dataclass
class TableSet:
    """All tables of an export plus their metadata (``meta``: sample rate, Imax, formats, hashes)."""

    meta: dict
    tables: list = field(default_factory=list)

    @property
    def tpis(self) -> list:
        return sorted({t.tpi for t in self.tables})

    @property
    def lengths(self) -> list:
        return sorted({t.tracks for t in self.tables})

    def index(self) -> list:
        """``index[i_tpi][i_length]`` -> table number or -1."""
        pos = {(t.tpi, t.tracks): i for i, t in enumerate(self.tables)}
        return [[pos.get((tp, L), -1) for L in self.lengths] for tp in self.tpis]


def quantize_ff(u_a, imax: float) -> np.ndarray:
    """Current [A] -> int16 Q15 with full scale ``imax`` (round half away from zero, saturate)."""
    x = np.asarray(u_a, float) / imax * 32768.0
    q = np.sign(x) * np.floor(np.abs(x) + 0.5)
    return np.clip(q, -32768, 32767).astype(np.int16)


def ref_frac_bits(max_abs_track: float) -> int:
    """Fractional bits of the int32 reference: 16, or fewer if ``max_abs_track`` needs them."""
    if max_abs_track <= 0:
        return 16
    f = int(math.floor(math.log2((2 ** 31 - 1) / max_abs_track)))
    if f < 0:
        raise ExportError(f"reference of {max_abs_track:g} tracks does not fit an int32")
    return min(16, f)


def quantize_ref(r_track, frac_bits: int) -> np.ndarray:
    """Reference [track] -> int32 with ``frac_bits`` fractional bits (round half away from zero)."""
    x = np.asarray(r_track, float) * 2.0 ** frac_bits
    q = np.sign(x) * np.floor(np.abs(x) + 0.5)
    return np.clip(q, -2 ** 31, 2 ** 31 - 1).astype(np.int32)


# ------------------------------------------------------------------ from a results folder
def read_sweep_json(results_dir) -> tuple[Path, dict]:
    """``(folder, the parsed sweep.json)`` of a sweep results folder (:mod:`seekopt.evaluate.sweep`);
    :class:`ExportError` naming the folder when it is missing, is not a sweep folder or its
    ``sweep.json`` is not valid JSON."""
    root = Path(results_dir)
    if not root.is_dir():
        raise ExportError(f"{root}: no such results folder")
    try:
        return root, json.loads((root / "sweep.json").read_text())
    except OSError:
        raise ExportError(f"{root}: not a sweep results folder (no sweep.json)") from None
    except ValueError:
        raise ExportError(f"{root / 'sweep.json'}: not valid JSON") from None


def load_tables(results_dir, sweep_json: dict | None = None) -> TableSet:
    """The optimal profiles of a sweep results folder, quantised (``sweep_json``: the folder's parsed
    ``sweep.json`` when already read, :func:`read_sweep_json`).

    Raises
    ------
    ExportError
        Missing folder, not a sweep folder, no successful optimal design, lengths or TPIs
        that are not whole numbers, tables longer than 65535 samples.
    """
    from seekopt import __version__
    from seekopt.design.profiles import Profile
    from seekopt.evaluate.sweep import cell_key, load_cells
    root, cfg = (Path(results_dir), sweep_json) if sweep_json is not None else read_sweep_json(results_dir)
    cells = load_cells(root)
    profiles = []
    for tpi in cfg["tpis"]:
        for k in cfg["tracks"]:
            c = cells.get(cell_key(tpi, k))
            if c and c.get("config_hash") == cfg["config_hash"] and c.get("optimal_profile"):
                if any(r["kind"] == "optimal" and r["status"] == "ok" for r in c["rows"]):
                    profiles.append((tpi, k, Profile.from_dict(c["optimal_profile"])))
    if not profiles:
        raise ExportError(f"{root}: no successful optimal designs to export (run `seekopt sweep` first)")
    for tpi, k, p in profiles:
        if tpi != round(tpi) or k != round(k):
            raise ExportError(f"{root}: TPI {tpi:g} / seek length {k:g} is not a whole number; "
                              "firmware tables are indexed by whole TPI and tracks")
        if p.n > 65535:
            raise ExportError(f"{root}: {k:g}-track profile at {tpi:g} TPI has {p.n} samples (> 65535)")
    fs = {p.sample_rate_hz for _, _, p in profiles}
    if len(fs) != 1:
        raise ExportError(f"{root}: profiles at different sample rates {sorted(fs)}")
    imax = float(cfg["imax"])
    frac = ref_frac_bits(max(float(np.max(np.abs(p.reference_track))) for _, _, p in profiles))
    tables = []
    for tpi, k, p in profiles:
        ff = np.asarray(p.current_a[:p.seek_samples], float)
        ref = np.asarray(p.reference_track, float)
        tables.append(SeekTable(int(round(tpi)), int(round(k)), quantize_ff(ff, imax),
                                quantize_ref(ref, frac), ff, ref))
    meta = {"tool_version": __version__, "plant_hash": cfg.get("plant_hash", ""),
            "controller_hash": cfg.get("controller_hash", ""), "sweep_hash": cfg["config_hash"],
            "designer": cfg.get("designer", ""), "sample_rate_hz": float(fs.pop()), "imax_a": imax,
            "settle_track": float(cfg["settle"]), "ff_format": "int16 Q15, full scale = imax_a",
            "ff_q": FF_Q, "ref_format": f"int32 Q{32 - frac}.{frac} (sign included, {frac} fractional bits) track, "
                          "relative to seek start",
            "ref_frac_bits": frac, "controller_scaled_per_tpi": bool(cfg.get("scale_controller", True))}
    if cfg.get("family_hashes"):      # designed for a family of plants (and its drift)
        meta["family_hashes"] = ";".join(cfg["family_hashes"])
        meta["drift"] = cfg.get("drift") or "from the data"
    return TableSet(meta, tables)


# ------------------------------------------------------------------ C
def _banner(ts: TableSet, prefix: str, what: str) -> str:
    m = ts.meta
    lines = [f"Generated by seekopt {m['tool_version']} (seekopt export) - do not edit.", what,
             f"plant {m['plant_hash']}, controller {m['controller_hash']}, sweep {m['sweep_hash']}, "
             f"designer {m['designer']}"]
    if m.get("family_hashes"):
        drift = str(m["drift"]).replace("±", "+-").encode("ascii", "replace").decode()    # C / CSV banners stay ASCII
        lines.append(f"holds the plant family {m['family_hashes']} (drift {drift})")
    lines += [
             f"sample rate {float(m['sample_rate_hz'])!r} Hz, Imax {float(m['imax_a'])!r} A, "
             f"settle band {float(m['settle_track'])!r} track",
             f"feedforward: {m['ff_format']}: I[A] = q * Imax / 32768 (round half away from zero, saturated)",
             f"reference: {m['ref_format']}: r[track] = q / 2^{m['ref_frac_bits']}",
             "one table set per TPI; negative seeks negate both tables"]
    if prefix == "/*":
        return "/*\n" + "".join(f" * {x}\n" for x in lines) + " */\n"
    return "".join(f"{prefix} {x}\n" for x in lines)


def c_array(ctype: str, name: str, values, per_line: int = 12) -> str:
    """A C99 ``const`` array definition of integer ``values``, ``per_line`` to a line (at least one element)."""
    vals = [str(int(v)) for v in values] or ["0"]
    body = ",\n".join("    " + ", ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line))
    return f"const {ctype} {name}[{len(vals)}] = {{\n{body}\n}};\n"


def write_c(ts: TableSet, outdir, basename: str = BASENAME) -> list[Path]:
    """Write ``<basename>.h`` and ``<basename>.c``; returns their paths."""
    from identification.fileio import atomic_write_text as write_atomic
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    m, guard = ts.meta, basename.upper() + "_H"
    tpis, lengths = ts.tpis, ts.lengths
    h = [_banner(ts, "/*", "Fixed-point seek feedforward and reference tables."),
         f"#ifndef {guard}\n#define {guard}\n\n#include <stdint.h>\n#include <stddef.h>\n\n",
         f"#define SEEKOPT_SAMPLE_RATE_HZ {float(m['sample_rate_hz'])!r}\n",
         f"#define SEEKOPT_IMAX_A {float(m['imax_a'])!r}\n",
         f"#define SEEKOPT_FF_Q {FF_Q}            /* feedforward int16 Q15, full scale SEEKOPT_IMAX_A */\n",
         f"#define SEEKOPT_REF_FRAC_BITS {m['ref_frac_bits']}   /* reference int32, r[track] = q / 2^F */\n",
         f"#define SEEKOPT_N_TABLES {len(ts.tables)}\n#define SEEKOPT_N_TPI {len(tpis)}\n",
         f"#define SEEKOPT_N_LENGTHS {len(lengths)}\n",
         f"#define SEEKOPT_MAX_FF_LEN {max(t.ff_len for t in ts.tables)}\n",
         f"#define SEEKOPT_MAX_REF_LEN {max(t.ref_len for t in ts.tables)}\n",
         "#define SEEKOPT_TPIS_INIT {" + ", ".join(f"{t}u" for t in tpis) + "}\n",
         "#define SEEKOPT_LENGTHS_INIT {" + ", ".join(map(str, lengths)) + "}\n\n",
         "typedef struct {\n    uint32_t tpi;          /* track density [track/inch] */\n"
         "    int32_t tracks;        /* seek length [track] */\n"
         "    uint16_t ff_len;       /* feedforward samples; 0 A afterwards */\n"
         "    uint16_t ref_len;      /* reference samples; `tracks` held afterwards */\n"
         "    const int16_t *ff;     /* Q15, full scale SEEKOPT_IMAX_A */\n"
         "    const int32_t *ref;    /* SEEKOPT_REF_FRAC_BITS fractional bits, track from seek start */\n"
         "} seekopt_seek_t;\n\n",
         "extern const seekopt_seek_t seekopt_tables[SEEKOPT_N_TABLES];\n",
         "extern const uint32_t seekopt_tpis[SEEKOPT_N_TPI];\n",
         "extern const int32_t seekopt_lengths[SEEKOPT_N_LENGTHS];\n",
         "/* table number for (TPI, length), -1 where the sweep has no optimal design */\n",
         "extern const int16_t seekopt_index[SEEKOPT_N_TPI][SEEKOPT_N_LENGTHS];\n",
         "/* exact lookup; NULL if absent */\n",
         "const seekopt_seek_t *seekopt_lookup(uint32_t tpi, int32_t tracks);\n\n",
         f"#endif /* {guard} */\n"]
    c = [_banner(ts, "/*", "Fixed-point seek feedforward and reference tables."),
         f'#include "{basename}.h"\n\n']
    for i, t in enumerate(ts.tables):
        c.append(f"/* table {i}: {t.tracks} tracks at {t.tpi} TPI */\n")
        c.append("static " + c_array("int16_t", f"ff_{i}", t.ff_q15))
        c.append("static " + c_array("int32_t", f"ref_{i}", t.ref_q) + "\n")
    c.append("const seekopt_seek_t seekopt_tables[SEEKOPT_N_TABLES] = {\n")
    c += [f"    {{{t.tpi}u, {t.tracks}, {t.ff_len}u, {t.ref_len}u, ff_{i}, ref_{i}}},\n"
          for i, t in enumerate(ts.tables)]
    c.append("};\n\n")
    c.append("const uint32_t seekopt_tpis[SEEKOPT_N_TPI] = SEEKOPT_TPIS_INIT;\n")
    c.append("const int32_t seekopt_lengths[SEEKOPT_N_LENGTHS] = SEEKOPT_LENGTHS_INIT;\n\n")
    c.append("const int16_t seekopt_index[SEEKOPT_N_TPI][SEEKOPT_N_LENGTHS] = {\n")
    c += ["    {" + ", ".join(map(str, row)) + "},\n" for row in ts.index()]
    c.append("};\n\n")
    c.append("const seekopt_seek_t *seekopt_lookup(uint32_t tpi, int32_t tracks)\n{\n"
             "    size_t i, j;\n"
             "    for (i = 0; i < SEEKOPT_N_TPI; i++) {\n"
             "        if (seekopt_tpis[i] != tpi) continue;\n"
             "        for (j = 0; j < SEEKOPT_N_LENGTHS; j++)\n"
             "            if (seekopt_lengths[j] == tracks && seekopt_index[i][j] >= 0)\n"
             "                return &seekopt_tables[seekopt_index[i][j]];\n"
             "    }\n    return NULL;\n}\n")
    hp, cp = outdir / f"{basename}.h", outdir / f"{basename}.c"
    write_atomic(hp, "".join(h))
    write_atomic(cp, "".join(c))
    return [hp, cp]


# ------------------------------------------------------------------ CSV / JSON
_CSV_COLS = ["table", "tpi", "tracks", "sample", "ff_q15", "ref_q", "ff_a", "ref_track"]


def write_csv(ts: TableSet, outdir, basename: str = BASENAME) -> list[Path]:
    """One long CSV: ``##`` banner lines, ``# key: value`` metadata lines, then a row per table sample
    (``ff_q15``/``ff_a`` empty after the feedforward ends)."""
    from identification.fileio import atomic_write_text as write_atomic
    buf = io.StringIO()
    buf.write(_banner(ts, "##", "Fixed-point seek tables, one row per sample."))
    for k, v in ts.meta.items():
        buf.write(f"# {k}: {v}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_CSV_COLS)
    for i, t in enumerate(ts.tables):
        for s in range(t.ref_len):
            ff = s < t.ff_len
            w.writerow([i, t.tpi, t.tracks, s, int(t.ff_q15[s]) if ff else "", int(t.ref_q[s]),
                        repr(float(t.ff_a[s])) if ff else "", repr(float(t.ref_track[s]))])
    Path(outdir).mkdir(parents=True, exist_ok=True)
    p = Path(outdir) / f"{basename}.csv"
    write_atomic(p, buf.getvalue())
    return [p]


def write_json(ts: TableSet, outdir, basename: str = BASENAME) -> list[Path]:
    """JSON ``{"meta": ..., "tables": [{tpi, tracks, ff_len, ref_len, ff_q15, ref_q, ff_a, ref_track}]}``."""
    from identification.fileio import atomic_write_text as write_atomic
    d = {"generated_by": f"seekopt {ts.meta['tool_version']} (seekopt export)", "meta": ts.meta,
         "tables": [{"tpi": t.tpi, "tracks": t.tracks, "ff_len": t.ff_len, "ref_len": t.ref_len,
                     "ff_q15": [int(v) for v in t.ff_q15], "ref_q": [int(v) for v in t.ref_q],
                     "ff_a": [float(v) for v in t.ff_a], "ref_track": [float(v) for v in t.ref_track]}
                    for t in ts.tables]}
    Path(outdir).mkdir(parents=True, exist_ok=True)
    p = Path(outdir) / f"{basename}.json"
    write_atomic(p, json.dumps(d, indent=1, sort_keys=True) + "\n")
    return [p]


def read_json(path) -> TableSet:
    """Read a table set written by :func:`write_json`."""
    try:
        d = json.loads(Path(path).read_text())
        tables = [SeekTable(t["tpi"], t["tracks"], np.array(t["ff_q15"], np.int16),
                            np.array(t["ref_q"], np.int32), np.array(t["ff_a"], float),
                            np.array(t["ref_track"], float)) for t in d["tables"]]
        return TableSet(d["meta"], tables)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ExportError(f"{path}: not a seekopt table file ({type(exc).__name__})") from None


def read_csv(path) -> TableSet:
    """Read a table set written by :func:`write_csv` (metadata values come back typed)."""
    try:
        lines = Path(path).read_text().splitlines()
        meta, body = {}, []
        for line in lines:
            if line.startswith("##"):
                continue
            if line.startswith("#"):
                k, sep, v = line[1:].partition(": ")
                if sep and " " not in k.strip():
                    meta[k.strip()] = _typed(v.strip())
            elif line.strip():
                body.append(line)
        rows = list(csv.DictReader(body))
        groups: dict = {}
        for r in rows:
            groups.setdefault(int(r["table"]), []).append(r)
        tables = []
        for i in sorted(groups):
            g = sorted(groups[i], key=lambda r: int(r["sample"]))
            ff = [r for r in g if r["ff_q15"] != ""]
            tables.append(SeekTable(int(g[0]["tpi"]), int(g[0]["tracks"]),
                                    np.array([int(r["ff_q15"]) for r in ff], np.int16),
                                    np.array([int(r["ref_q"]) for r in g], np.int32),
                                    np.array([float(r["ff_a"]) for r in ff]),
                                    np.array([float(r["ref_track"]) for r in g])))
        return TableSet(meta, tables)
    except (OSError, ValueError, KeyError) as exc:
        raise ExportError(f"{path}: not a seekopt table CSV ({type(exc).__name__})") from None


def _typed(v: str):
    if v in ("True", "False"):
        return v == "True"
    for cast in (int, float):
        try:
            return cast(v)
        except ValueError:
            pass
    return v


_WRITERS = {"c": write_c, "csv": write_csv, "json": write_json}


def write_tables(ts: TableSet, fmt: str, outdir) -> list[Path]:
    """Write ``ts`` as ``fmt`` (``c``, ``csv``, ``json``) into ``outdir``; returns the paths."""
    if fmt not in _WRITERS:
        raise ExportError(f"unknown format {fmt!r} (expected c, csv or json)")
    return _WRITERS[fmt](ts, outdir)


def export(results_dir, fmt: str, outdir) -> list[Path]:
    """Export the optimal designs of ``results_dir`` as ``fmt`` into ``outdir``."""
    return write_tables(load_tables(results_dir), fmt, outdir)
