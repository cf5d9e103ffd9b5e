"""Recipe: design minimum-settle-time seek profiles and bench them against sine / windowed sine.

Shows the design stage: build one designer from the plant, the drive's 2DOF controller, the
current limit and the settle band (robust against the identified uncertainty), call it for
several seek lengths (it reuses what it built), and bench each optimal profile against the
shortest-within-Imax and the best-length sine and windowed-sine profiles on an evaluation plant
(the truth of the synthetic drive here: designs made on an identified model, played on the drive).

    python examples/design_and_bench.py [PLANT_JSON] [OUTDIR]
"""
import sys
from pathlib import Path

from identification.model.plant import ModalPlant
from seekopt.app.demo import sample_log_path
from seekopt.design.ocp import RobustSpec, SeekDesigner
from seekopt.drive.controller import Controller
from seekopt.evaluate.bench import format_table, run_bench


def main(plant_path=None, outdir="bench-out", lengths=(10, 100, 1000), imax=0.3, settle=0.1,
         robust=True):
    truth = ModalPlant.load(Path(sample_log_path()).with_suffix(".truth.json"))
    plant = ModalPlant.load(plant_path) if plant_path else truth
    controller = Controller.nss()               # the drive's controller (Controller.from_json for yours)
    designer = SeekDesigner(plant, controller, imax, settle, RobustSpec() if robust else None)
    results = []
    for i, tracks in enumerate(lengths):        # one designer, many lengths
        res = run_bench(plant, controller, tracks, imax, settle, truth=truth,
                        designers={"optimal": designer},
                        figures=Path(outdir) if i == len(lengths) - 1 else None)
        print(format_table(res))
        results.append(res)
    return results


if __name__ == "__main__":
    main(*sys.argv[1:3])
