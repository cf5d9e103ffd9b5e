"""An independent drive simulator for the tests (issue 9, item 5).

It shares no dynamics code with ``identification/model/discrete.py`` or
``seekopt/drive/simulator.py``: the plant is integrated on a fine grid (RK4) between the exact
break points of the delayed, held commands; the digital controller (PID/notch or state-space
sections, multirate) is stepped here; the seek profiles, reference and noise are generated here.
Only the log format (:class:`identification.logs.seeklog.SeekLog`) and, in :mod:`.truth`, the
plant data class for comparisons are taken from the package.

Typical use::

    from tests.drives import Schedule, make_log, nss_drive, modal_plant
    drive = nss_drive(noise=False)
    log = make_log(drive, Schedule(n_seeks=30, seed=1))
    truth = modal_plant(drive)
"""
from .controller import DigitalController, Section, from_json, notch, nss_json, pid_lead
from .disturbance import Noise, nss_noise
from .drive import Drive, Trace, closed_loop_poles, make_log, run
from .plant import ModeSpec, PlantStepper, TruthPlant, damped_free_response, open_loop, rk4_flow
from .presets import (drive_50k, nss_drive, nss_single_rate_controller, nss_truth, other_nss_truth, truth_50k)
from .seeks import Schedule, rigid_reference, seek_current
from .truth import effect_dicts, from_modal_plant, modal_plant

__all__ = ["DigitalController", "Section", "from_json", "notch", "nss_json", "pid_lead", "Noise", "nss_noise",
           "Drive", "Trace", "closed_loop_poles", "make_log", "run", "ModeSpec", "PlantStepper", "TruthPlant",
           "damped_free_response", "open_loop", "rk4_flow", "drive_50k", "nss_drive", "nss_single_rate_controller",
           "nss_truth", "other_nss_truth", "truth_50k", "Schedule", "rigid_reference", "seek_current",
           "effect_dicts", "from_modal_plant", "modal_plant"]
