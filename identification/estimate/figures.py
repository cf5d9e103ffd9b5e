"""Paper-style figures of an identification (the seed paper's Figs. 3-6).

* Fig. 3 -- identified modes: settle-window amplitude [track] and damping ratio against frequency.
* Fig. 4 -- averaged amplitude spectra of the PES after settling [track] and of the current [A].
* Fig. 5 -- each mode's transfer function ``|k0 g_r / (s^2 + 2 zeta_r w_r s + w_r^2)|`` [track/A]
  against the rigid-body line ``k0 / w^2``.
* Fig. 6 -- measured and estimated PES after settling [track] for a few seeks.

:func:`plot_identification` writes all four PNGs; each ``fig*`` function draws one figure and
returns it.  Uses the non-interactive Agg backend.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from identification.estimate.gains import mode_regressors
from identification.estimate.heldout import predict_segments
from identification.estimate.result import Identification
from identification.logs.seeklog import SeekLog, segment_seeks

__all__ = ["plot_identification", "fig3_modes", "fig4_spectra", "fig5_transfer_functions", "fig6_settle_pes",
           "settle_amplitudes"]


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _settled(log, min_len=16):
    return [s for s in segment_seeks(log) if s.settled and s.end - s.settle >= min_len]


def settle_amplitudes(log: SeekLog, ident: Identification) -> np.ndarray:
    """Peak |response| [track] of each identified mode in the settle windows, averaged over the
    seeks: the mode's response to the measured current (eq. (9)) times its gain ``k0 g_r``."""
    p = ident.plant
    if not p.modes:
        return np.zeros(0)
    M = mode_regressors(log.current_a, [m.freq_hz for m in p.modes], [m.zeta for m in p.modes], log.dt, p.delay_s)
    M = M * (p.k0 * np.array([m.gain for m in p.modes]))
    peaks = [np.abs(M[s.settle:s.end] - M[s.settle:s.end].mean(axis=0)).max(axis=0) for s in _settled(log)]
    return np.mean(peaks, axis=0) if peaks else np.full(len(p.modes), np.nan)


def fig3_modes(log: SeekLog, ident: Identification, truth=None):
    """Fig. 3: amplitude in the settle windows and damping ratio of each mode against frequency."""
    plt = _plt()
    p = ident.plant
    f = np.array([m.freq_hz for m in p.modes])
    z = np.array([m.zeta for m in p.modes])
    zs = np.array([(m.std or {}).get("zeta", np.nan) for m in p.modes])
    amp = settle_amplitudes(log, ident)
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(7.5, 6.0))
    a1.stem(f, amp, basefmt=" ")
    a1.set_ylabel("settle amplitude [track]")
    a1.set_title(f"Fig. 3  identified modes ({ident.method} method)")
    a2.errorbar(f, z, yerr=np.nan_to_num(zs), fmt="o", capsize=3, label="identified ±1 std")
    if truth is not None:
        a2.plot([m.freq_hz for m in truth.modes], [m.zeta for m in truth.modes], "x", color="k", label="truth")
    a2.set_ylabel("damping ratio ζ [-]")
    a2.set_xlabel("natural frequency [Hz]")
    a2.set_xscale("log")
    a2.set_yscale("log")
    a2.legend(loc="best", fontsize=8)
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig


def _avg_spectrum(x, windows, nfft):
    spec = [np.abs(np.fft.rfft(x[a:b] - x[a:b].mean(), nfft)) * 2.0 / (b - a) for a, b in windows]
    return np.mean(spec, axis=0)


def fig4_spectra(log: SeekLog, ident: Identification, nfft: int = 512):
    """Fig. 4: amplitude spectra of the PES after settling and of the current, averaged over the
    settle windows (each window mean-removed, zero-padded to ``nfft``)."""
    plt = _plt()
    wins = [(s.settle, s.end) for s in _settled(log)]
    f = np.fft.rfftfreq(nfft, log.dt)
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(7.5, 6.0))
    if wins:
        a1.semilogy(f[1:], _avg_spectrum(log.pes, wins, nfft)[1:], lw=1.0)
        a2.semilogy(f[1:], _avg_spectrum(log.current_a, wins, nfft)[1:], lw=1.0, color="C1")
    for m in ident.plant.modes:
        for a in (a1, a2):
            a.axvline(m.freq_hz, color="0.6", lw=0.8, ls="--")
    a1.set_ylabel("PES amplitude [track]")
    a1.set_title(f"Fig. 4  spectra after settling ({len(wins)} windows; dashed: identified modes)")
    a2.set_ylabel("current amplitude [A]")
    a2.set_xlabel("frequency [Hz]")
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
    a2.set_xlim(0, log.sample_rate_hz / 2)
    fig.tight_layout()
    return fig


def fig5_transfer_functions(ident: Identification, truth=None):
    """Fig. 5: ``|k0 g_r / (s^2 + 2 zeta_r w_r s + w_r^2)|`` of each mode and the rigid line ``k0/w^2``."""
    plt = _plt()
    p = ident.plant
    fs = p.sample_rate_hz or 2.0 * max([m.freq_hz for m in p.modes] + [1000.0])
    f = np.logspace(np.log10(50.0), np.log10(fs / 2), 800)
    w = 2 * np.pi * f
    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    ax.loglog(f, p.k0 / w ** 2, "k", lw=2, label="rigid body k0/ω²")
    for m in p.modes:
        h = p.k0 * abs(m.gain) / np.abs(-w ** 2 + 2j * m.zeta * m.omega * w + m.omega ** 2)
        ax.loglog(f, h, lw=1.0, label=f"{m.freq_hz:.0f} Hz")
    if truth is not None:
        for i, m in enumerate(truth.modes):
            h = truth.k0 * abs(m.gain) / np.abs(-w ** 2 + 2j * m.zeta * m.omega * w + m.omega ** 2)
            ax.loglog(f, h, color="0.5", lw=0.8, ls=":", label="truth" if i == 0 else None)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("|P| [track/A]")
    ax.set_title(f"Fig. 5  mode transfer functions ({ident.method} method)")
    lo = p.k0 / w[-1] ** 2 / 100
    ax.set_ylim(lo, None)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2, loc="lower left")
    fig.tight_layout()
    return fig


def fig6_settle_pes(log: SeekLog, ident: Identification, seeks=None, n_seeks: int = 4, window_init: bool = False):
    """Fig. 6: measured and estimated PES after settling for ``n_seeks`` seeks (default: the
    longest settle windows of the held-out seeks if any, else of all seeks); the estimate is
    :func:`identification.estimate.heldout.predict_segments` (model response to the measured current,
    initial position and velocity fitted over the seek, or over the settle window if
    ``window_init``); the rigid-body-only estimate is dotted."""
    plt = _plt()
    if seeks is None:
        every = ident.diagnostics.get("holdout_every") or 0
        allk = [s for s in segment_seeks(log)]
        held = [s for i, s in enumerate(allk) if every and i % every == every - 1]
        pool = [s for s in (held or allk) if s.settled and s.end - s.settle >= 16]
        seeks = sorted(pool, key=lambda s: s.settle - s.end)[:n_seeks]
    seeks = sorted(seeks, key=lambda s: s.start)
    fig, axes = plt.subplots(len(seeks), 1, figsize=(7.5, 1.9 * max(len(seeks), 1) + 0.6), squeeze=False)
    if seeks:
        segs = [(s.start, s.end) for s in seeks]
        init = [(s.settle, s.end) for s in seeks] if window_init else None
        ro = ident.diagnostics.get("runout")
        full = predict_segments(log, ident.plant, segs, init, runout=ro)
        rig = predict_segments(log, ident.plant.copy(modes=[]), segs, init, runout=ro)
        pes = log.pes
        for ax, s, yh, yr in zip(axes[:, 0], seeks, full, rig):
            i = slice(s.settle, s.end)
            t = (np.arange(s.settle, s.end) - s.start) * log.dt * 1e3
            ax.plot(t, pes[i], lw=1.8, color="C0", alpha=0.8, label="measured")
            ax.plot(t, yh[s.settle - s.start:] - log.target_track[i], "--", lw=1.1, color="C3", label="estimated")
            ax.plot(t, yr[s.settle - s.start:] - log.target_track[i], ":", color="0.4", lw=0.9, label="rigid only")
            ax.set_ylabel("PES [track]")
            ax.text(0.99, 0.95, f"seek of {s.length_track:+.0f} tracks", ha="right", va="top",
                    transform=ax.transAxes, fontsize=8)
            ax.grid(True, alpha=0.3)
        axes[0, 0].legend(fontsize=8, ncol=3, loc="best", framealpha=0.7)
        axes[-1, 0].set_xlabel("time from seek start [ms]")
    fp = ident.diagnostics.get("fit_percent_window_init", np.nan) if window_init else ident.fit_percent
    how = "settle window" if window_init else "whole seek"
    axes[0, 0].set_title(f"Fig. 6  PES after settling, measured vs estimated\n"
                         f"(initial position/velocity fitted on the {how}; held-out fit {fp:.1f} %)", fontsize=10)
    fig.tight_layout()
    return fig


def plot_identification(log: SeekLog, ident: Identification, outdir, truth=None, prefix: str = "") -> list:
    """Write ``fig3_modes.png``, ``fig4_spectra.png``, ``fig5_tf.png``, ``fig6_settle_pes.png`` and
    ``fig6_settle_pes_window_init.png`` to ``outdir`` (created) and return their paths.
    ``truth``: a :class:`ModalPlant` to overlay (synthetic logs)."""
    plt = _plt()
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    figs = {"fig3_modes": fig3_modes(log, ident, truth), "fig4_spectra": fig4_spectra(log, ident),
            "fig5_tf": fig5_transfer_functions(ident, truth), "fig6_settle_pes": fig6_settle_pes(log, ident),
            "fig6_settle_pes_window_init": fig6_settle_pes(log, ident, window_init=True)}
    paths = []
    for name, fig in figs.items():
        path = out / f"{prefix}{name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths
