"""Recipe: identify a drive's modal plant from one seek log.

Shows the identification stage on its own: read a seek log (``.csv``, ``.npz`` or ``.mat``), run the
robust identification (rigid body by the ZOH fit, modes by matrix pencil + output error; the paper's
eqs. 4-11 with ``method="paper"``), print the modes with their standard deviations and the held-out
fit, save ``plant.json`` and draw the paper's Fig. 5 (each mode's transfer function).

    python examples/identify_a_log.py [LOG] [OUTDIR]      # default: the bundled sample log
"""
import sys
from pathlib import Path

from identification.estimate.figures import fig5_transfer_functions
from identification.estimate.identify import identify
from identification.logs.formats import read_log
from seekopt.app.demo import first_seeks, sample_log_path


def main(log_path=None, outdir="identify-out", max_seeks=None):
    log = read_log(log_path or sample_log_path())
    if max_seeks:                               # a short log identifies faster (and less precisely)
        log = first_seeks(log, max_seeks)
    ident = identify(log)                       # method="robust"; "paper" for the paper's steps
    plant = ident.plant
    print(f"k0 = {plant.k0:.5g} track/(A s^2), bias {plant.bias_a * 1e3:.3g} mA, "
          f"delay {plant.delay_s * 1e6:.2f} us")
    for m in plant.modes:
        s = m.std or {}
        print(f"  mode {m.freq_hz:8.1f} Hz (+-{s.get('freq_hz', float('nan')):.2g})  "
              f"zeta {m.zeta:.4f}  gain {m.gain:+.4f}")
    print(f"held-out fit {ident.fit_percent:.1f} % (rigid body alone {ident.fit_percent_rigid:.1f} %)")
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    plant.to_json(out / "plant.json")           # ModalPlant.load() reads it back
    fig = fig5_transfer_functions(ident)
    fig.savefig(out / "fig5_tf.png", dpi=110)
    return ident


if __name__ == "__main__":
    main(*sys.argv[1:3])
