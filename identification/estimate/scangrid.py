"""The frequency grids of the robust identification's scan for missed modes
(:meth:`identification.estimate.modescan.ModeScan.search`).
"""
from __future__ import annotations

import math

import numpy as np

from identification.estimate.prony import z_to_modal
from identification.estimate.settings import RobustSettings

__all__ = ["scan_grids"]


def scan_grids(s: RobustSettings, ar, lo_hz: float, hi_hz: float, fs: float) -> list[tuple[float, np.ndarray]]:
    """The scan's ``[(zeta, frequencies [Hz]), ...]`` for a whitened problem: for each
    damping ratio of ``scan_zetas`` a log-spaced grid whose step follows that resonance's
    bandwidth, plus a local grid around each lightly damped pole of its noise model ``ar``.

    A mode's scan statistic falls off over about its half-power band ``+-zeta f``, and after
    whitening it can fall off faster: an AR noise model fitted to a residual that still holds
    an unmodelled lightly damped mode takes the resonance as a pole, the whitening FIR nearly
    cancels the mode, and what is left is a spike of about the pole's bandwidth.  On the loop's
    re-identification of the Kt drive's compensated log (a 5 kHz, zeta 0.01, gain 0.3 mode in the
    controller's notch, missing from the model): AR pole 5000.6 Hz, zeta 0.0093 (every other pole
    damped more than 0.03); statistic 87 residual variances at 5000 Hz, 56 / 60 at -0.25 / +0.25 %,
    and 5.5 / 13.8 at the 2 % grid's points 4946 / 5045 Hz (gate 25).  So the grid of the column
    of damping ``zeta`` is stepped by ``min(scan_step_rel, scan_step_zeta * zeta)`` (relative;
    0.5 % for zeta 0.01), and around each noise-model pole of damping ``zeta_p < scan_ar_zeta_max``
    every column is also evaluated at the pole's frequency and at
    relative steps of ``scan_step_zeta * zeta_p`` out to +-``scan_step_rel``.

    Parameters
    ----------
    s : RobustSettings
        ``scan_zetas``, ``scan_step_rel``, ``scan_step_zeta``, ``scan_ar_zeta_max``.
    ar : array or None
        The whitening FIR ``[1, a_1..a_p]`` (the noise model's denominator); None: no noise model.
    lo_hz, hi_hz : float
        The band scanned [Hz].
    fs : float
        Sample rate [Hz].
    """
    extra = []
    if ar is not None and len(ar) >= 3 and s.scan_ar_zeta_max:
        z = np.roots(ar)
        for fp, zp in zip(*z_to_modal(z[z.imag > 0], fs)):
            if lo_hz <= fp <= hi_hz and 0 < zp < s.scan_ar_zeta_max:
                step = min(s.scan_step_zeta * zp, s.scan_step_rel)
                n = int(math.ceil(s.scan_step_rel / step))
                extra.append(fp * np.exp(np.arange(-n, n + 1) * step))
    out = []
    for zt in s.scan_zetas:
        step = min(s.scan_step_rel, s.scan_step_zeta * zt)
        grid = np.exp(np.arange(math.log(lo_hz), math.log(hi_hz), math.log1p(step)))
        out.append((zt, np.unique(np.concatenate([grid] + extra))))
    return out
