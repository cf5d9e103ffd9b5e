"""Recipe: sweep track density x seek length, then export firmware tables.

Shows the evaluate and export stages: a ``SweepConfig`` (plant, controller, TPIs, lengths, Imax)
run into a results folder (resumable; cells reused by a second run), a summary of the optimal
profile's saving over the baselines per cell, and the optimal profiles quantised to C, CSV and
JSON tables the firmware plays (``u_ff`` in Q15 of Imax, the reference in fixed point).

    python examples/sweep_and_export.py [PLANT_JSON] [OUTDIR]
"""
import sys
from pathlib import Path

import pandas as pd

from identification.model.plant import ModalPlant
from seekopt.app.demo import sample_log_path
from seekopt.app.report import savings_table
from seekopt.drive.controller import Controller
from seekopt.evaluate.sweep import SweepConfig, run_sweep
from seekopt.export.tables import load_tables, write_tables


def main(plant_path=None, outdir="sweep-out", tpis=(100e3, 200e3), tracks=(10, 100), imax=0.3,
         designer="ocp-robust", engine="serial"):
    plant = ModalPlant.load(plant_path or Path(sample_log_path()).with_suffix(".truth.json"))
    cfg = SweepConfig(plant, Controller.nss(), tpis=list(tpis), tracks=list(tracks), imax=imax,
                      designer=designer)
    summary = run_sweep(cfg, Path(outdir) / "sweep", engine=engine, progress=False, figures=False)
    print(f"{summary.total} cells ({summary.computed} computed), all ok: {summary.ok}")
    table = savings_table(pd.read_csv(summary.table))           # one row per (TPI, length)
    print(table[["tpi", "tracks", "optimal_ms", "saving_vs_best_pct"]].round(3).to_string(index=False))
    tables = load_tables(Path(outdir) / "sweep")                # the optimal profiles, quantised
    written = []
    for fmt in ("c", "csv", "json"):
        written += write_tables(tables, fmt, Path(outdir) / "export")
    print(f"{len(tables.tables)} tables ({tables.meta['ff_format']}): "
          + ", ".join(p.name for p in written))
    return summary, tables


if __name__ == "__main__":
    main(*sys.argv[1:3])
