"""Modes a re-identification adds must be supported by the fit data (identification/loop/reidentify.py,
``_without_unsupported_modes``), on a log of the independent drive (tests/drives: its own RK4 plant,
controller and noise).

Measured on the 3 kHz amplifier-lag drive of ``studies/loop_to_design.py`` (main 89e039b): the loop's
re-identification on the lag-compensated log brought in a 10.2 kHz mode at the damping bound (zeta 1e-4,
gain 0.09 on the rate fit; none in the truth, inside the NSS controller's notches); the drive's loop with the
plant the loop wrote was unstable (|z| 1.0013) and every design exited 2.  With the rule: the mode is not kept
(rate BIC drop 3.7 against 6), the loop is stable, designs settle within 1.04x the effect-free reference.
"""
from __future__ import annotations

from functools import lru_cache

from identification.loop.fit_engine import Data
from identification.loop.reidentify import _without_unsupported_modes
from identification.loop.settings import LoopSettings
from identification.loop.windows import seek_windows
from identification.model.plant import Mode
from tests.drives import Schedule, make_log, modal_plant, nss_drive


@lru_cache(maxsize=None)
def _case():
    drive = nss_drive(seed=4)
    log = make_log(drive, Schedule(n_seeks=16, seed=4))
    st = LoopSettings()
    return Data(log, seek_windows(log, st.window_s, st.min_window_samples), effect_step_s=st.effect_step_s), \
        modal_plant(drive, effects=False), st


def test_an_added_mode_the_data_do_not_support_is_dropped():
    """The truth plus a lightly damped mode inside the NSS controller's 10 kHz notch region that the drive
    does not have: the rule drops it (and only it)."""
    data, truth, st = _case()
    spurious = Mode(10200.0, 1e-4, 0.09)
    new = truth.copy(modes=sorted(truth.modes + [spurious], key=lambda m: m.freq_hz))
    out = _without_unsupported_modes(new, truth, data, st, lambda *a: None)
    assert [m.freq_hz for m in out.modes] == [m.freq_hz for m in truth.modes]


def test_an_added_mode_the_drive_has_is_kept():
    """The truth's own first seek-induced mode, missing from the reference plant and brought in by the
    re-identification, is supported by the data and kept."""
    data, truth, st = _case()
    real = max(truth.modes, key=lambda m: abs(m.gain))
    ref = truth.copy(modes=[m for m in truth.modes if m is not real])
    out = _without_unsupported_modes(truth, ref, data, st, lambda *a: None)
    assert real.freq_hz in [m.freq_hz for m in out.modes]
