"""Recipe: close the loop -- find what the linear model misses, from measured data.

Shows the loop stage: start from a plant (identified here, or a ``plant.json``), let
``close_loop`` try the effect library (friction, run-out, amplifier lag, ...) on half of the
seeks and validate on the other half, then report the validation RMS before/after, one line per
accepted effect, and the per-seek fit % defined as MATLAB's ``compare`` (NRMSE of the settle PES
against the model simulated from the measured current).

    python examples/close_the_loop.py [LOG] [PLANT_JSON]
"""
import sys

from identification.estimate.identify import identify
from identification.logs.formats import read_log
from identification.loop.closing import close_loop
from identification.model.plant import ModalPlant
from seekopt.app.demo import first_seeks, sample_log_path
from seekopt.app.report import COMPARE_DEFINITION, compare_fit


def main(log_path=None, plant_path=None, max_seeks=None):
    log = first_seeks(read_log(log_path or sample_log_path()), max_seeks)   # fewer seeks: faster
    plant = ModalPlant.load(plant_path) if plant_path else identify(log).plant
    res = close_loop(log, plant)                # odd-numbered seeks validate
    eb, ea = res.error_before, res.error_after
    print(f"validation RMS {eb['rms_track']:.4g} -> {ea['rms_track']:.4g} track")
    for eff in res.plant.effects:               # one line per effect of the final plant
        if eff.name in res.accepted:
            print(f"  accepted {eff.name}: {eff.params}")
    print(COMPARE_DEFINITION)
    before, after = compare_fit(res.res_before), compare_fit(res.res_after)
    print(f"fit % per seek (median over {len(after)} validation seeks): "
          f"{before.fit_percent.median():.1f} -> {after.fit_percent.median():.1f}")
    return res


if __name__ == "__main__":
    main(*sys.argv[1:3])
