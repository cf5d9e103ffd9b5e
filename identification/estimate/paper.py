"""The seed paper's identification method (Sections 2-3), step by step.

1. eq. (8): rigid-body ``b0, b1`` by LS over each seek (start to end, position relative to the
   start), pooled; ``k0 = b0 / Ts^2`` (:func:`identification.estimate.rigid.eq8_fit`; ERRATA item 5:
   not the printed ``2 b0 / Ts^2``).  No delay (the paper has none).
2. LS Prony (eqs. (4)-(7), :func:`identification.estimate.prony.ls_prony`, ``prony_order`` mode
   pairs) on the PES after settling, pooled over the settle windows.  As in the paper the PES is
   used as it is: no rigid-body prediction is removed (the paper treats the PES after settling as
   the modes' response).  Stable roots with a natural frequency in ``freq_range`` and
   ``zeta < max_zeta`` are kept.
3. eqs. (9)-(11) (:func:`identification.estimate.gains.modal_gains`): gains by LS of the
   settle-window PES on each mode's response to the measured current (regressors over the whole
   log, :func:`identification.estimate.gains.mode_regressors`).

Only ``current_a`` (held over the sample, the paper's model), ``position_track`` and
``target_track`` are used.
"""
from __future__ import annotations

import time

import numpy as np

from identification.estimate.gains import modal_gains, mode_regressors
from identification.estimate.prony import fit_amplitudes, ls_prony, modal_to_z, z_to_modal
from identification.estimate.result import Identification
from identification.estimate.rigid import eq8_fit
from identification.estimate.settings import PaperSettings
from identification.logs.seeklog import LogError, SeekLog
from identification.model.plant import ModalPlant, Mode

__all__ = ["PaperIdentifier"]


class PaperIdentifier:
    """The paper's method, built once from :class:`PaperSettings` and run on any number of logs."""

    def __init__(self, settings: PaperSettings | None = None):
        self.settings = settings if settings is not None else PaperSettings()

    def run(self, log: SeekLog, fit_seeks, timing: dict | None = None) -> Identification:
        """Identify from the seeks ``fit_seeks`` of ``log`` (:func:`identification.logs.segment_seeks`);
        seconds per stage go to ``timing``."""
        s, timing = self.settings, ({} if timing is None else timing)
        fs, dt = log.sample_rate_hz, log.dt
        lo, hi = s.band(fs)
        t = time.perf_counter()
        e8 = eq8_fit(log.current_a, log.position_track, [(q.start, q.end) for q in fit_seeks], dt)   # eq. (8)
        timing["rigid"] = time.perf_counter() - t
        t = time.perf_counter()
        windows = [(q.settle, q.end) for q in fit_seeks if q.settled]
        pes = log.pes
        wins = [pes[a:b] for a, b in windows]
        ppo = {}
        roots = None
        for n in range(1, int(s.prony_order) + 1):                    # eqs. (4)-(7) at each order
            try:
                roots = ls_prony(wins, n, fs)
            except ValueError:
                break
            up = _stable_upper(roots)
            ppo[f"prony n={n}"] = sorted(zip(*[v.tolist() for v in z_to_modal(up, fs)]))
        if roots is None:
            raise LogError(log.source or "<log>", "settle windows too short for LS Prony")
        f, z = z_to_modal(_stable_upper(roots), fs)
        keep = (f >= lo) & (f <= hi) & (z < s.max_zeta)
        f, z = f[keep], z[keep]
        timing["prony"] = time.perf_counter() - t
        t = time.perf_counter()
        Y = mode_regressors(log.current_a, f, z, dt, 0.0)            # eq. (9), the paper has no delay
        gf = modal_gains(pes, Y, windows)                             # eqs. (10)-(11)
        timing["gains"] = time.perf_counter() - t
        g = gf.coef / e8.k0
        modes = [Mode(float(fi), float(zi), float(gi), {"gain": float(si / e8.k0)})
                 for fi, zi, gi, si in sorted(zip(f, z, g, gf.std))]
        plant = ModalPlant(k0=e8.k0, modes=modes, bias_a=e8.bias_a, delay_s=0.0, sample_rate_hz=fs,
                           track_pitch_nm=log.track_pitch_nm, std={"k0": float(np.sqrt(e8.cov[0, 0]) / dt ** 2)})
        amps = [2 * np.abs(fit_amplitudes(w, modal_to_z(f, z, fs), fs)) for w in wins if len(w) > 2 * len(f) + 2 and len(f)]
        amp = np.mean(amps, axis=0) if amps else np.full(len(f), np.nan)
        diag = {"eq8": {"b0": e8.b0, "b1": e8.b1, "residual_rms": e8.residual_rms},
                "settle_modes": [(float(a), float(b), float(c)) for a, b, c in zip(f, z, amp)],
                "prony_order": int(s.prony_order)}
        return Identification(plant, "paper", ppo, residual_rms=gf.residual_rms, diagnostics=diag, settings=s)


def _stable_upper(roots):
    """The roots of eq. (4) that are modes: inside the unit circle, one of each conjugate pair (Im > 0)."""
    return roots[(roots.imag > 1e-12) & (np.abs(roots) < 1)]
