"""Identification accuracy study.

Part 1 (:func:`prony_vs_crb_table`): Monte-Carlo RMSE of the natural frequency and damping ratio estimated
by the paper's LS Prony (eqs. 4-7), the pooled matrix pencil and the matrix pencil polished by variable
projection (``refine_poles``), against the Cramér–Rao bound, for one window of n = 200 samples at
fs = 26.4 kHz: a single mode (1738 Hz, zeta 0.02) and two modes (350 Hz zeta 0.03 + 1738 Hz zeta 0.02,
equal amplitudes). Phases are uniform random per run; the noise std is set from the per-record SNR
(``identification.estimate.prony.snr_db``: phase-averaged signal energy / (n sigma^2), all modes together). All
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
    from identification.estimate.pencil import matrix_pencil
    from identification.estimate.prony import (crb_modes, damped_sinusoid, ls_prony, refine_poles, snr_db,
                                      z_to_modal)
except ImportError:  # run as a script from anywhere
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from identification.estimate.pencil import matrix_pencil
    from identification.estimate.prony import (crb_modes, damped_sinusoid, ls_prony, refine_poles, snr_db,
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


def end_to_end_table(seeds=(0, 1), n_seeks=120, big_samples=1_000_000, single_rate=True, cache_dir=None):
    """Part 2: end-to-end identification accuracy and speed (seek log -> identified plant).

    For each seed, a synthetic log of the default truth (NSS v2 + 420 Hz flex + 1738 Hz coil,
    benchmark noise: sensor, force noise, flutter, RRO) with ``n_seeks`` seeks on the default
    (multirate) drive, identified by ``method="robust"`` and ``method="paper"``; errors of every truth
    mode between 200 Hz and 0.45 fs against the identified mode nearest in frequency, with the
    mode's pooled settle-window SNR (``tests/test_identify.py::required_modes``).  With
    ``single_rate`` the first seed is repeated on a drive whose notches run at the PES rate (the
    plant is then stepped at the log rate, isolating the multirate model error).  Speed: wall time
    and samples per second of both methods on the first log and on a log of at least ``big_samples``
    samples (enough seeks synthesised; the synthesis time is reported too).

    Parameters
    ----------
    seeds : sequence of int
    n_seeks : int
    big_samples : int or None
        Size of the speed-test log (None: skip).
    single_rate : bool
    cache_dir : str, optional
        Folder to keep synthesised logs (``.npz``) and truths between runs.

    Returns
    -------
    str
        Markdown.
    """
    import time
    from identification.estimate.identify import identify
    rows, speed, notes = [], [], []
    cases = [(seed, "multirate") for seed in seeds] + ([(seeds[0], "single-rate")] if single_rate else [])
    for seed, drive in cases:
        (log, truth), t_syn = _e2e_log(seed, n_seeks, drive, cache_dir)
        ids = {}
        for method in ("robust", "paper"):
            t = time.perf_counter()
            ids[method] = identify(log, method=method)
            if drive == "multirate" and seed == seeds[0]:
                speed.append((f"{n_seeks} seeks", log.n, method, time.perf_counter() - t, t_syn))
        rows += _e2e_rows(seed, drive, log, truth, ids)
        r = ids["robust"]
        notes.append(f"| {seed} | {drive} | {_pct(r.plant.k0 / truth.k0 - 1, 4)} | "
                     f"{_pct(ids['paper'].plant.k0 / truth.k0 - 1, 3)} | {1e3 * r.plant.bias_a:.4f} "
                     f"({1e3 * truth.bias_a:.4f}) | {1e6 * r.plant.delay_s:.3f} ({1e6 * truth.delay_s:.3f}) | "
                     + " | ".join(f"{x.fit_percent:.1f} / {x.diagnostics['fit_percent_window_init']:.1f}"
                                  for x in (r, ids["paper"]))
                     + f" | {r.fit_percent_rigid:.1f} / {r.diagnostics['fit_percent_rigid_window_init']:.1f} |")
    if big_samples:
        n_big = int(np.ceil(big_samples / (log.n / n_seeks) * 1.02))
        (big, _), t_syn = _e2e_log(seeds[0], n_big, "multirate", cache_dir)
        for method in ("robust", "paper"):
            t = time.perf_counter()
            res = identify(big, method=method)
            speed.append((f"{n_big} seeks", big.n, method, time.perf_counter() - t, t_syn))
            if method == "robust":
                stages = ", ".join(f"{k} {v:.1f} s" for k, v in res.timing.items() if k != "total")
    out = ["**Mode errors** (identified - truth, %; nearest identified mode in frequency), default truth, "
           f"benchmark noise, {n_seeks} seeks, every 5th seek held out; SNR: pooled settle-window SNR "
           "of the truth mode (required if >= 3)", "",
           "| seed | drive | truth mode | SNR | robust df % | robust dzeta % | robust dgain % | "
           "paper df % | paper dzeta % | paper dgain % |", "|---|---|---|---|---|---|---|---|---|---|"] + rows
    out += ["", "**Rigid body and held-out fit** (fit %: initial position/velocity fitted on the whole seek / "
            "on the settle window)", "",
            "| seed | drive | robust dk0 % | paper dk0 % | robust bias mA (truth) | robust delay us (truth) | "
            "robust fit % | paper fit % | rigid-only fit % |", "|---|---|---|---|---|---|---|---|---|"] + notes
    out += ["", "**Speed** (wall time of `identify`, this machine)", "",
            "| log | samples | method | identify s | samples/s | synthesis s |", "|---|---|---|---|---|---|"]
    out += [f"| {a} | {n} | {m} | {t:.1f} | {n / t:,.0f} | {ts:.0f} |" for a, n, m, t, ts in speed]
    if big_samples:
        out += ["", f"Robust stages on the big log: {stages}."]
    return "\n".join(out)


def _pct(x, nd=2):
    return f"{100 * x:+.{nd}f}"


def _e2e_log(seed, n_seeks, drive, cache_dir):
    """Synthesise (or load from ``cache_dir``) a log of the default truth; returns ((log, truth), seconds)."""
    import time
    from identification.logs import read_log, write_log
    from identification.model.plant import ModalPlant
    from seekopt.drive.presets import nss_controller_single_rate
    from seekopt.evaluate.synth import SynthConfig, synthesize
    name = f"e2e_{drive}_{seed}_{n_seeks}"
    if cache_dir and os.path.exists(os.path.join(cache_dir, name + ".npz")):
        return (read_log(os.path.join(cache_dir, name + ".npz")),
                ModalPlant.load(os.path.join(cache_dir, name + ".json"))), float("nan")
    controller = nss_controller_single_rate() if drive == "single-rate" else None
    t = time.perf_counter()
    log, truth = synthesize(SynthConfig(n_seeks=n_seeks, seed=seed), controller=controller)
    t = time.perf_counter() - t
    if cache_dir:
        os.makedirs(cache_dir, exist_ok=True)
        write_log(log, os.path.join(cache_dir, name + ".npz"))
        truth.to_json(os.path.join(cache_dir, name + ".json"))
    return (log, truth), t


def _e2e_rows(seed, drive, log, truth, ids):
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
    from test_identify import required_modes
    snr = {m.freq_hz: s for m, s in required_modes(log, truth, min_snr=0.0)}
    rows = []
    for m in truth.modes:
        if m.freq_hz not in snr:
            continue
        cells = []
        for res in (ids["robust"], ids["paper"]):
            e = min(res.plant.modes, key=lambda q: abs(np.log(q.freq_hz / m.freq_hz)), default=None)
            cells += ([_pct(e.freq_hz / m.freq_hz - 1, 3), _pct(e.zeta / m.zeta - 1, 1), _pct(e.gain / m.gain - 1, 1)]
                      if e is not None else ["-"] * 3)
        rows.append(f"| {seed} | {drive} | {m.freq_hz:g} Hz, zeta {m.zeta:g}, g {m.gain:g} | {snr[m.freq_hz]:.1f} | "
                    + " | ".join(cells) + " |")
    return rows


def std_calibration_table(seeds=(0, 1, 2, 3), n_seeks=100, cache_dir=None):
    """Are the reported standard deviations honest?  On the single-rate drive (no multirate model
    error), default truth, benchmark noise: for every required truth mode (pooled settle-window
    SNR >= 3) and each seed, ``z = (estimate - truth) / std``; the table gives the RMS of ``z`` per
    parameter (1 if the std are right, > 1 if optimistic) and the largest ``|z|``.

    Returns
    -------
    str
        Markdown.
    """
    from identification.estimate.identify import identify
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests"))
    from test_identify import required_modes
    z = {"freq_hz": [], "zeta": [], "gain": [], "k0": []}
    for seed in seeds:
        (log, truth), _ = _e2e_log(seed, n_seeks, "single-rate", cache_dir)
        res = identify(log)
        z["k0"].append((res.plant.k0 - truth.k0) / res.plant.std["k0"])
        for m, _snr in required_modes(log, truth):
            e = min(res.plant.modes, key=lambda q: abs(np.log(q.freq_hz / m.freq_hz)))
            if abs(e.freq_hz / m.freq_hz - 1) > 0.01:
                continue
            for k in ("freq_hz", "zeta", "gain"):
                z[k].append((getattr(e, k) - getattr(m, k)) / e.std[k])
    out = [f"**Standard deviations vs actual errors**, single-rate drive, default truth, benchmark noise, "
           f"{n_seeks} seeks, seeds {list(seeds)}", "", "| parameter | n | RMS z | max abs z |", "|---|---|---|---|"]
    for k, v in z.items():
        v = np.asarray(v)
        out.append(f"| {k} | {len(v)} | {np.sqrt(np.mean(v ** 2)):.2f} | {np.max(np.abs(v)):.2f} |")
    return "\n".join(out)


if __name__ == "__main__":
    print(prony_vs_crb_table())
