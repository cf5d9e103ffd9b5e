"""The results folder of a sweep: ``sweep.json`` (the configuration), ``cells/<key>.json`` (one file per
finished cell, written atomically), the fsync'ed ``journal.log`` and the assembled ``results.csv`` with
``profiles/`` (layout in :mod:`seekopt.evaluate.sweep`).
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from identification.fileio import atomic_write_text as write_atomic

from seekopt.evaluate.sweep_config import ALL_KINDS, COLUMNS, SweepConfig, SweepError, cell_key, code_hash

__all__ = ["write_atomic", "journal", "load_cells", "load_cell", "prepare", "assemble"]


# ------------------------------------------------------------------ persistence
def journal(outdir: Path, line: str) -> None:
    fd = os.open(outdir / "journal.log", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, f"{line.rstrip()} t={time.time():.3f}\n".encode())
        os.fsync(fd)
    finally:
        os.close(fd)


def load_cells(outdir) -> dict:
    """All saved cells of a results folder, keyed by cell key (unreadable files skipped)."""
    out = {}
    for p in sorted((Path(outdir) / "cells").glob("*.json")):
        try:
            d = json.loads(p.read_text())
            out[d["key"]] = d
        except (OSError, ValueError, KeyError):
            continue
    return out


def prepare(cfg: SweepConfig, outdir: Path) -> dict:
    """Create or check the results folder; return the saved cells of this configuration."""
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / "cells").mkdir(exist_ok=True)
    meta = outdir / "sweep.json"
    if meta.exists():
        try:
            old = json.loads(meta.read_text())
        except ValueError:
            raise SweepError(f"{meta}: not valid JSON; remove it or use another results folder") from None
        if old.get("config_hash") != cfg.hash():
            raise SweepError(f"{outdir}: holds a sweep with another plant/controller/imax/settle/designer "
                             f"({old.get('config_hash')} != {cfg.hash()}); use another results folder")
        if old.get("code_hash") not in (None, code_hash()):
            print(f"sweep: warning: {outdir} was computed with other seekopt code (code hash "
                  f"{old.get('code_hash')} != {code_hash()}); its saved cells are reused as they are - "
                  "use a new results folder to recompute them", file=sys.stderr)
    write_atomic(meta, json.dumps(cfg.to_dict(), indent=1))
    return {k: c for k, c in load_cells(outdir).items() if c.get("config_hash") == cfg.hash()}



def load_cell(outdir: Path, key: str, config_hash: str) -> dict | None:
    try:
        c = json.loads((outdir / "cells" / f"{key}.json").read_text())
    except (OSError, ValueError):
        return None
    return c if c.get("config_hash") == config_hash else None


# ------------------------------------------------------------------ assembly
def assemble(outdir, cfg: SweepConfig | None = None) -> Path:
    """Build ``results.csv`` (and ``profiles/*.csv``) from the saved cells of the grid in ``sweep.json``."""
    import pandas as pd
    from seekopt.design.profiles import Profile
    outdir = Path(outdir)
    cfgd = cfg.to_dict() if cfg is not None else json.loads((outdir / "sweep.json").read_text())
    cells = load_cells(outdir)
    rows = []
    (outdir / "profiles").mkdir(exist_ok=True)
    for tpi in cfgd["tpis"]:
        for k in cfgd["tracks"]:
            c = cells.get(cell_key(tpi, k))
            if c is None or c.get("config_hash") != cfgd["config_hash"]:
                continue
            rows += sorted(c["rows"], key=lambda r: ALL_KINDS.index(r["kind"]))
            if c.get("optimal_profile"):
                p = outdir / "profiles" / f"optimal_{c['key']}.csv"
                if not p.exists():
                    Profile.from_dict(c["optimal_profile"]).to_csv(p)
    df = pd.DataFrame(rows, columns=list(COLUMNS))
    path = outdir / "results.csv"
    write_atomic(path, df.to_csv(index=False))
    return path
