"""Statistical analysis of an output-error residual (closing the loop).

All pooled over the simulation windows (:class:`identification.loop.windows.Windows`), never
across a gap: auto- and cross-correlation with coloured-signal confidence bands
(:func:`correlations`, Ljung's ``sqrt(P/N)`` band), Welch spectra and coherence of residual vs
current (:func:`spectra`), the spindle frequency from the log's metadata
(:func:`spindle_from_metadata`) or detected (:func:`detect_spindle`), the synchronous average
over revolutions (:func:`synchronous_average`) and Billings-Zhu / Billings-Voon nonlinear
correlation tests (:func:`nonlinear_tests`) with thresholds from a stated false-alarm rate.
Residuals in tracks, currents in A, frequencies in Hz, lags in samples.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from identification.loop.windows import Windows

__all__ = ["pooled_xcorr", "CorrelationTest", "correlations", "Spectra", "spectra", "spindle_from_metadata",
           "detect_spindle", "significant_spindle", "synchronous_average", "nonlinear_tests"]


def _segments(windows: Windows, *arrays):
    """Per-window, mean-removed segments of full-length arrays."""
    return [[x[a:b] - x[a:b].mean() for a, b in windows.bounds] for x in arrays]


def pooled_xcorr(xs: list, ys: list, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``rho_xy(tau) = E[x(t) y(t - tau)]/(sx sy)`` for
    ``tau = -max_lag..max_lag``, pooled over segments (products never cross a gap)."""
    acc = np.zeros(2 * max_lag + 1)
    sxx = sum(float(x @ x) for x in xs)
    syy = sum(float(y @ y) for y in ys)
    for x, y in zip(xs, ys):
        n = len(x)
        c = np.correlate(x, y, mode="full")          # c[tau + n - 1] = sum_t x(t + tau) y(t)
        k = min(max_lag, n - 1)
        acc[max_lag - k:max_lag + k + 1] += c[n - 1 - k:n + k]
    return acc / np.sqrt(max(sxx * syy, 1e-300))


@dataclass
class CorrelationTest:
    """Correlations of the residual [-] with 95 % bands.

    ``auto[tau]`` (tau >= 0) with the white band ``1.96/sqrt(N)``; ``cross[tau]`` =
    rho(e(t), u(t - tau)) for tau = -M..M with Ljung's band ``1.96 sqrt(P/N)``,
    ``P = sum_k rho_e(k) rho_u(k)`` (valid when both are coloured)."""

    lags: np.ndarray
    auto: np.ndarray
    white_band: float
    cross: np.ndarray
    cross_band: float
    n: int

    @property
    def whiteness_fraction(self) -> float:
        """Fraction of lags 1..M outside the white band."""
        k = self.lags > 0
        return float(np.mean(np.abs(self.auto[k]) > self.white_band))

    @property
    def past_input_violations(self) -> np.ndarray:
        """Lags tau >= 0 (current in the past) where ``|cross| > band``."""
        k = self.lags >= 0
        return self.lags[k][np.abs(self.cross[k]) > self.cross_band]


def correlations(e_full: np.ndarray, u: np.ndarray, windows: Windows, max_lag: int = 50) -> CorrelationTest:
    """Whiteness and residual-current cross-correlation (see :class:`CorrelationTest`)."""
    es, us = _segments(windows, e_full, u)
    n = windows.n_samples
    re_ = pooled_xcorr(es, es, max_lag)
    ru = pooled_xcorr(us, us, max_lag)
    rc = pooled_xcorr(es, us, max_lag)
    P = float(np.sum(re_ * ru))
    lags = np.arange(-max_lag, max_lag + 1)
    return CorrelationTest(lags, re_, 1.96 / np.sqrt(n), rc, 1.96 * np.sqrt(max(P, 0) / n), n)


@dataclass
class Spectra:
    """Welch estimates over windows: ``f`` [Hz], PSDs ``See`` [track^2/Hz], ``Suu``
    [A^2/Hz], coherence ``coh`` [-] and its 95 % null threshold ``coh_band``."""

    f: np.ndarray
    See: np.ndarray
    Suu: np.ndarray
    Seu: np.ndarray
    coh: np.ndarray
    coh_band: float
    n_segments: int

    def coherent_peaks(self, fmin: float = 0.0, max_peaks: int = 5) -> list:
        """``(freq_hz, coherence)`` of local maxima above the null threshold."""
        c = self.coh
        pk = [i for i in range(1, len(c) - 1) if c[i] >= c[i - 1] and c[i] >= c[i + 1]
              and c[i] > self.coh_band and self.f[i] >= fmin]
        pk.sort(key=lambda i: -c[i])
        return [(float(self.f[i]), float(c[i])) for i in pk[:max_peaks]]


def spectra(e_full: np.ndarray, u: np.ndarray, windows: Windows, fs: float, nperseg: int = 128) -> Spectra:
    """Welch spectra and coherence of residual vs current, Hann segments inside windows."""
    win = np.hanning(nperseg)
    scale = 1.0 / (fs * (win ** 2).sum())
    nf = nperseg // 2 + 1
    See = np.zeros(nf); Suu = np.zeros(nf); Seu = np.zeros(nf, complex)
    nseg = 0
    for a, b in windows.bounds:
        for s in range(a, b - nperseg + 1, nperseg // 2):
            x = e_full[s:s + nperseg]; v = u[s:s + nperseg]
            X = np.fft.rfft(win * (x - x.mean())); V = np.fft.rfft(win * (v - v.mean()))
            See += (X * X.conj()).real; Suu += (V * V.conj()).real; Seu += X * V.conj()
            nseg += 1
    nseg = max(nseg, 1)
    See, Suu, Seu = See * scale / nseg, Suu * scale / nseg, Seu * scale / nseg
    coh = np.abs(Seu) ** 2 / np.maximum(See * Suu, 1e-300)
    n_ind = max(nseg / 1.9, 2.0)   # 50 % overlap Hann: ~1.9 overlapped segments per independent one
    band = 1.0 - 0.05 ** (1.0 / (n_ind - 1.0))
    return Spectra(np.fft.rfftfreq(nperseg, 1.0 / fs), See, Suu, Seu, coh, float(band), nseg)


_NUMBER = re.compile(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def _number(text) -> float | None:
    m = _NUMBER.match(str(text).strip())
    return float(m.group()) if m else None


def spindle_from_metadata(metadata: dict, sample_rate_hz: float | None = None):
    """Spindle frequency [Hz] and its source from a log's metadata, or ``(None, reason)``.

    Keys (case-insensitive): ``spindle_hz``; ``rpm`` or ``spindle_rpm`` (/60); ``sectors``
    (servo sectors per revolution: ``f = sample_rate_hz / sectors``, the servo rate being one
    PES sample per sector).  When both ``rpm`` and ``sectors`` are given they must agree with
    the sample rate within 1 % (else the rpm is used and the disagreement is reported)."""
    md = {str(k).lower(): v for k, v in (metadata or {}).items()}
    f_rpm = src = None
    for key, scale in (("spindle_hz", 1.0), ("spindle_rpm", 1 / 60.0), ("rpm", 1 / 60.0)):
        x = _number(md[key]) if key in md else None
        if x and x > 0:
            f_rpm, src = x * scale, f"metadata {key}"
            break
    sec = _number(md["sectors"]) if "sectors" in md else None
    f_sec = sample_rate_hz / sec if (sec and sec > 0 and sample_rate_hz) else None
    if f_rpm and f_sec and abs(f_rpm / f_sec - 1) > 0.01:
        return f_rpm, f"{src} (disagrees with sample rate / sectors = {f_sec:.3f} Hz)"
    if f_rpm:
        return f_rpm, src + (" (= sample rate / sectors)" if f_sec else "")
    if f_sec:
        return f_sec, "metadata sectors (sample rate / sectors)"
    return None, "no spindle in the metadata"


def detect_spindle(e_full: np.ndarray, windows: Windows, fs: float, fmin: float = 20.0,
                   fmax: float = 400.0, harmonics: int = 4, pad: int = 8, top: int = 1,
                   band_hz: float = 15.0) -> list:
    """Spindle-frequency candidates [Hz] from the residual (zero outside the windows).

    Score ``S(f0) = sum_h (P(h f0) / M(h f0)) / h / sum_h (1/h)`` over ``h = 1..harmonics``,
    ``P`` the periodogram and ``M`` its running median over ``band_hz`` (the local noise
    level, so that the large low-frequency residual does not dominate); the ``1/h``
    weights favour the fundamental over its sub-harmonics.  Returns the ``top`` local
    maxima as ``[(f0, S)]``, best first.  The score of noise at a given frequency is about 1, its
    maximum over the band several times that: see :func:`significant_spindle`."""
    from scipy.ndimage import median_filter
    x = np.zeros(len(e_full))
    idx = windows.index()
    x[idx] = e_full[idx]
    nfft = int(2 ** np.ceil(np.log2(len(x) * pad)))
    P = np.abs(np.fft.rfft(x, nfft)) ** 2
    fgrid = np.fft.rfftfreq(nfft, 1.0 / fs)
    df = fgrid[1]
    hi = min(len(P), int((harmonics * fmax + 2 * band_hz) / df) + 2)
    M = median_filter(P[:hi], size=max(3, int(band_hz / df)) | 1, mode="nearest")
    snr = P[:hi] / np.maximum(M, 1e-300)
    cand = fgrid[(fgrid >= fmin) & (fgrid <= min(fmax, fs / 2 / harmonics))]
    if len(cand) < 3:
        return []
    w = 1.0 / np.arange(1, harmonics + 1)
    score = sum(wh * np.interp(h * cand, fgrid[:hi], snr) for h, wh in zip(range(1, harmonics + 1), w)) / w.sum()
    pk = [i for i in range(1, len(score) - 1) if score[i] >= score[i - 1] and score[i] >= score[i + 1]]
    pk.sort(key=lambda i: -score[i])
    return [(float(cand[i]), float(score[i])) for i in pk[:top]]


def significant_spindle(e_full: np.ndarray, windows: Windows, fs: float, false_alarm: float = 0.05,
                        seed: int = 0):
    """The best :func:`detect_spindle` peak if it beats chance, else None: ``(f0 [Hz], score, threshold)``.

    The harmonic-sum score of pure noise is far above 1 at its maximum over the candidate band
    (thousands of candidates), so the peak is compared with the maxima of surrogates that keep
    each window's spectrum but not a line's phase from window to window (each window's
    residual multiplied by a random sign): the threshold is the largest of ``ceil(1 /
    false_alarm) - 1`` surrogate maxima (a peak of noise beats it with probability
    ``false_alarm``)."""
    best = detect_spindle(e_full, windows, fs, top=1)
    if not best:
        return None
    rng = np.random.default_rng(seed)
    null = []
    for _ in range(max(int(math.ceil(1.0 / false_alarm)) - 1, 1)):
        s = np.array(e_full, float)
        for a, b in windows.bounds:
            s[a:b] *= rng.choice((-1.0, 1.0))
        pk = detect_spindle(s, windows, fs, top=1)
        null.append(pk[0][1] if pk else 0.0)
    f0, score = best[0]
    thr = float(max(null))
    return (f0, score, thr) if score > thr else None


def synchronous_average(e_full: np.ndarray, t: np.ndarray, windows: Windows, f0: float,
                        nbins: int | None = None, fs: float | None = None):
    """Residual averaged over spindle revolutions, by angle.

    Returns ``(phase [0, 1), mean [track], std_error [track], repeatable_fraction)``;
    the fraction is the variance of the binned mean (minus its estimation noise) over
    the residual variance."""
    idx = windows.index()
    nbins = nbins or int(min(256, max(16, round((fs or 1.0 / np.median(np.diff(t))) / f0))))
    ph = np.mod(t[idx] * f0, 1.0)
    k = np.minimum((ph * nbins).astype(int), nbins - 1)
    e = e_full[idx]
    cnt = np.bincount(k, minlength=nbins)
    s1 = np.bincount(k, e, nbins); s2 = np.bincount(k, e * e, nbins)
    mean = s1 / np.maximum(cnt, 1)
    var = np.maximum(s2 / np.maximum(cnt, 1) - mean ** 2, 0)
    se = np.sqrt(var / np.maximum(cnt, 1))
    frac = max(float(np.var(mean) - np.mean(se ** 2)), 0.0) / max(float(np.var(e)), 1e-300)
    return (np.arange(nbins) + 0.5) / nbins, mean, se, frac


def nonlinear_tests(e_full: np.ndarray, u: np.ndarray, y_model: np.ndarray, windows: Windows,
                    max_lag: int = 20, false_alarm: float = 0.01) -> dict:
    """Billings-Zhu and Billings-Voon correlation tests, calibrated for a seek log.

    ``'`` denotes removal of the mean; ``y_model`` is the model's output (the anchored
    simulation, per window minus its mean: the head motion; the measured position would add the
    residual itself).  Tests (lags ``tau = 0..max_lag`` of the second argument):
    ``BZ_ye_e2`` = rho((y e)', (e^2)'), ``BZ_ye_u2`` = rho((y e)', (u^2)'),
    ``BV_u2_e`` = rho((u^2)', e), ``BV_u2_e2`` = rho((u^2)', e^2), ``BV_e_eu`` = rho(e, (e u)').

    Calibration: the residual is coloured and its products with the seek motion are dominated by
    a few long seeks, so the white band ``1.96/sqrt(N)`` (and even Bartlett's coloured band) fires
    on linear drives.  The seeks are the independent units (the effective sample size is their
    number ``G``, not the number of samples): each lag's cross-product sum is the sum over seeks
    of per-seek sums ``S_g(tau)``, independent and zero-mean under "no such correlation", so it
    is studentised by the seeks themselves, ``z(tau) = sum_g S_g / sqrt(G/(G-1) sum_g S_g^2)``
    (robust to any correlation and scale within a seek), and ``max_tau |z|`` is compared with
    the Student-t quantile (``G - 1`` degrees of freedom) at the two-sided level
    ``false_alarm / (max_lag + 1)`` (Bonferroni over lags): each test fires on a linear drive with
    probability at most ``false_alarm``.  The price is power: ``|z| <= sqrt(G - 1)``, and a
    residual dominated by one seek gives ``|z|`` near 1.  (In closed loop the current carries the
    fed-back noise, so these open-loop tests are weak evidence either way; the loop's decisions
    rest on the candidates' fits and the dependence tests.)

    Returns ``{name: (max_tau |z(tau)|, threshold)}`` (both dimensionless)."""
    from scipy.stats import t as student_t
    segs = []
    for a, b in windows.bounds:
        w = np.nan_to_num(y_model[a:b] - np.nanmean(y_model[a:b]))
        segs.append((e_full[a:b], u[a:b], w))
    groups = list(windows.groups)
    G = len(set(groups))
    thr = float(student_t.isf(false_alarm / (2.0 * (max_lag + 1)), max(G - 1, 1)))

    def test(fx, fy):
        xs = [fx(*s) for s in segs]; ys = [fy(*s) for s in segs]
        mx = np.mean(np.concatenate(xs)); my = np.mean(np.concatenate(ys))
        S = {}
        for g, x, y in zip(groups, xs, ys):
            n = len(x)
            c = np.correlate(x - mx, y - my, mode="full")[n - 1:]   # c[tau] = sum_t x(t) y(t - tau)
            row = np.zeros(max_lag + 1)
            row[:min(max_lag + 1, n)] = c[:max_lag + 1]
            S[g] = S.get(g, 0.0) + row
        S = np.array(list(S.values()))
        z = S.sum(axis=0) / np.sqrt(np.maximum((S ** 2).sum(axis=0) * G / max(G - 1, 1), 1e-300))
        return float(np.max(np.abs(z))), thr

    return {
        "BZ_ye_e2": test(lambda e, v, w: w * e, lambda e, v, w: e * e),
        "BZ_ye_u2": test(lambda e, v, w: w * e, lambda e, v, w: v * v),
        "BV_u2_e": test(lambda e, v, w: e, lambda e, v, w: v * v),
        "BV_u2_e2": test(lambda e, v, w: e * e, lambda e, v, w: v * v),
        "BV_e_eu": test(lambda e, v, w: e, lambda e, v, w: e * v),
    }
