"""Identification accuracy study.

Part 1 (:func:`prony_vs_crb_table`): Monte-Carlo RMSE of the natural frequency and damping ratio estimated
by the paper's LS Prony (eqs. 4-7), the pooled matrix pencil and the matrix pencil polished by variable
projection (``refine_poles``), against the Cramér–Rao bound, for one window of n = 200 samples at
fs = 26.4 kHz: a single mode (1738 Hz, zeta 0.02) and two modes (350 Hz zeta 0.03 + 1738 Hz zeta 0.02,
equal amplitudes). Phases are uniform random per run; the noise std is set from the per-record SNR
(``identification.prony.snr_db``: phase-averaged signal energy / (n sigma^2), all modes together). All
estimators are given the true model order (2 poles per mode); each true mode is matched to the estimated
pole with the nearest natural frequency. The CRB column is ``sqrt(mean over runs of the CRB variance at
that run's phases)``.

Part 2 (:func:`end_to_end_table`) is filled in by the identification pipeline.

Run: ``python studies/identification_accuracy.py`` (or ``python -m studies.identification_accuracy``).
"""
from __future__ import annotations

import os
import sys

import numpy as np

try:
    from identification.prony import (crb_modes, damped_sinusoid, ls_prony, matrix_pencil, refine_poles, snr_db,
                                      z_to_modal)
except ImportError:  # run as a script from anywhere
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from identification.prony import (crb_modes, damped_sinusoid, ls_prony, matrix_pencil, refine_poles, snr_db,
                                      z_to_modal)

FS = 26_400.0
N = 200
CASES = {
    "single mode (1738 Hz, zeta 0.02)": ([1738.0], [0.02], [1.0]),
    "two modes (350 Hz zeta 0.03 + 1738 Hz zeta 0.02)": ([350.0, 1738.0], [0.03, 0.02], [1.0, 1.0]),
}
METHODS = ("LS Prony", "matrix pencil", "pencil + VarPro")


def _match(z, freqs):
    """(f_n, zeta) of the pole (Im z >= 0) nearest in natural frequency to each true mode."""
    z = np.asarray(z, dtype=complex)
    z = z[z.imag >= 0] if np.any(z.imag >= 0) else z
    f, zeta = z_to_modal(z, FS)
    idx = [int(np.argmin(np.abs(f - f0))) for f0 in freqs]
    return np.column_stack([f[idx], zeta[idx]])


def _monte_carlo(freqs, zetas, amps, snr, runs, rng):
    freqs, zetas, amps = (np.asarray(v, dtype=float) for v in (freqs, zetas, amps))
    m = len(freqs)
    truth = np.column_stack([freqs, zetas])
    sigma = 10 ** ((snr_db(amps, zetas, freqs, N, FS, 1.0) - snr) / 20)
    sq = {k: np.zeros((m, 2)) for k in METHODS}
    crb_var = np.zeros((m, 2))
    for _ in range(runs):
        ph = rng.uniform(0, 2 * np.pi, m)
        x = sum(damped_sinusoid(N, FS, f, z, a, p) for f, z, a, p in zip(freqs, zetas, amps, ph))
        x = x + sigma * rng.standard_normal(N)
        crb_var += np.square(np.column_stack(crb_modes(N, FS, freqs, zetas, amps, ph, sigma)))
        poles, _ = matrix_pencil(x, FS, order=2 * m)
        zp = np.array([p.z for p in poles], dtype=complex)
        est = {"LS Prony": ls_prony(x, m, FS), "matrix pencil": zp,
               "pencil + VarPro": refine_poles(x, FS, zp) if len(zp) else zp}
        for k, z in est.items():
            sq[k] += np.square(_match(z, freqs) - truth) if len(z) else np.square(truth)
    crb = np.sqrt(crb_var / runs)
    return {k: np.sqrt(v / runs) for k, v in sq.items()}, crb


def prony_vs_crb_table(snrs_db=(10, 15, 20, 25, 30), runs=500, seed=0):
    """Markdown table of RMSE vs CRB of frequency and damping for LS Prony, matrix pencil and
    matrix pencil + VarPro, per SNR, for the single-mode and two-mode cases.

    Parameters
    ----------
    snrs_db : sequence of float
        Per-record SNRs (dB, see ``snr_db``).
    runs : int
        Monte-Carlo runs per SNR and case.
    seed : int
        Seed of ``numpy.random.default_rng``.

    Returns
    -------
    str
        Markdown; each cell is ``RMSE (RMSE/CRB)``, frequency in Hz.
    """
    rng = np.random.default_rng(seed)
    head = ("| SNR dB | mode | CRB f Hz | " + " | ".join(f"{k} f" for k in METHODS) + " | CRB zeta | "
            + " | ".join(f"{k} zeta" for k in METHODS) + " |")
    lines = []
    for title, (freqs, zetas, amps) in CASES.items():
        lines += ["", f"**{title}**, n = {N}, fs = {FS:g} Hz, {runs} runs per SNR, cells: RMSE (RMSE/CRB)", "",
                  head, "|" + "---|" * (4 + 2 * len(METHODS))]
        for snr in snrs_db:
            rmse, crb = _monte_carlo(freqs, zetas, amps, snr, runs, rng)
            for r, f0 in enumerate(freqs):
                cf = " | ".join(f"{rmse[k][r, 0]:.3g} ({rmse[k][r, 0] / crb[r, 0]:.2f})" for k in METHODS)
                cz = " | ".join(f"{rmse[k][r, 1]:.3g} ({rmse[k][r, 1] / crb[r, 1]:.2f})" for k in METHODS)
                lines.append(f"| {snr:g} | {f0:g} Hz | {crb[r, 0]:.3g} | {cf} | {crb[r, 1]:.3g} | {cz} |")
    return "\n".join(lines).lstrip("\n")


def end_to_end_table():
    """Part 2: end-to-end identification accuracy (seek logs -> identified plant)."""
    raise NotImplementedError("filled in by the identification pipeline")


if __name__ == "__main__":
    print(prony_vs_crb_table())
