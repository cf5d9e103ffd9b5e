"""The blind bands of the unmodelled-mode guard (:mod:`seekopt.design.guard`): where an identified model
cannot see a mode, and the gain of the largest mode that could hide there.

An identification from seek logs cannot see a mode where the log carries no excitation above the
noise: near and above the Nyquist frequency (aliasing), and inside the controller's notches and
multirate-filter zeros (the feedback current is notched there, so the loop's own noise and the
closed-loop seek current hardly drive the mode).  Bands (:class:`GuardBand`) come from

* the servo rate: ``[nyquist[0], nyquist[1]] * fs`` (:func:`nyquist_band`);
* the controller, read from its frequency response (:func:`controller_notches`): every notch at
  least ``notch_depth_db`` below the line joining the controller's response an octave either side,
  the band being where it is at least 3 dB below that line;
* the identification: ``plant.meta["blind_bands"]`` (written by
  :func:`identification.estimate.blind.blind_bands`), with the gain a mode there could have and
  still escape detection (:func:`plant_blind_bands`; across a band, :func:`band_gains` on the
  identification's detectable-gain curve, :func:`plant_gain_curve`);
* bands the user states (``SeekProblem.guard_bands_hz``).

:func:`problem_bands` gathers every band of a seek problem.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["GuardBand", "controller_notches", "nyquist_band", "plant_blind_bands", "plant_gain_curve", "curve_gain",
           "band_gains", "merge_bands", "problem_bands"]


@dataclass
class GuardBand:
    """One band where an unmodelled mode may hide.

    Attributes
    ----------
    lo_hz, hi_hz : float
        Band edges [Hz].
    reason : str
        ``nyquist``, ``notch``, ``blind`` (identification) or ``user``.
    gain : float
        Gain (relative to the rigid body) of the hypothetical mode guarded against.
    """

    lo_hz: float
    hi_hz: float
    reason: str = "user"
    gain: float = 1.0

    def to_dict(self) -> dict:
        return {k: (float(v) if k != "reason" else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "GuardBand":
        return cls(float(d["lo_hz"]), float(d["hi_hz"]), str(d.get("reason", "user")), float(d.get("gain", 1.0)))

    def __str__(self) -> str:
        return f"{self.lo_hz:.0f}-{self.hi_hz:.0f} Hz ({self.reason}, g {self.gain:g})"


def nyquist_band(fs: float, lo_frac: float = 0.45, hi_frac: float = 0.65, gain: float = 1.0) -> GuardBand:
    """Near and above Nyquist: ``[lo_frac, hi_frac] * fs`` [Hz] (``fs`` the servo rate)."""
    return GuardBand(lo_frac * fs, hi_frac * fs, "nyquist", gain)


def _section_groups(controller):
    """``{rate_multiple: [sections]}`` of a controller (each rate group's own frequency response
    is valid up to half its own rate)."""
    groups = {}
    for sec in controller.sections:
        groups.setdefault(int(sec.get("rate_multiple", 1)), []).append(sec)
    return groups


def _notches_of(f: np.ndarray, g: np.ndarray, depth_db: float, edge_db: float, top_edge: bool = True) -> list:
    """Index ranges ``(j0, j1)`` of the notches of the dB response ``g`` on the log grid ``f``."""
    lf = np.log(f)
    octave = math.log(2.0)
    out = []
    n = len(f)
    for i in range(1, n if top_edge else n - 1):
        if not (g[i] < g[i - 1] and (i == n - 1 or g[i] <= g[i + 1])):
            continue                      # interior minima, and the top edge (a zero at the group's Nyquist)
        left = np.nonzero((lf >= lf[i] - octave) & (lf <= lf[i]))[0]
        right = np.nonzero((lf >= lf[i]) & (lf <= lf[i] + octave))[0]
        a, b = left[np.argmax(g[left])], right[np.argmax(g[right])]

        def ref(j, a=a, b=b):
            if b == i:
                return g[a]
            return g[a] + (g[b] - g[a]) * (lf[j] - lf[a]) / (lf[b] - lf[a])
        if a == i or ref(i) - g[i] < depth_db:
            continue
        j0, j1 = i, i
        while j0 > a and ref(j0 - 1) - g[j0 - 1] >= edge_db:
            j0 -= 1
        while j1 < b and ref(j1 + 1) - g[j1 + 1] >= edge_db:
            j1 += 1
        out.append((j0, j1))
    return out


def controller_notches(controller, depth_db: float = 6.0, edge_db: float = 3.0, f_min_hz: float | None = None,
                       n: int = 4000, gain: float = 1.0) -> list:
    """Notches and filter zeros of ``controller``, read from its frequency response.

    Each rate group of the cascade (the sections running at ``m fs``) is evaluated on its own, on a
    log grid from ``f_min_hz`` (default ``fs / 100``) to just below its own Nyquist frequency
    ``m fs / 2`` (a group's response is only meaningful there; the PES-rate part's images above
    ``fs / 2`` are not notches).  At each local minimum of ``|C_m(f)|`` [dB] the reference level is the
    straight line (in log frequency) between the largest values within an octave below and above it
    (the group's trend: integral action, lead, roll-off); a minimum at least ``depth_db`` below that
    line is a notch, and its band is where the response stays at least ``edge_db`` below the line.
    A zero on the unit circle (e.g. of a multirate averaging filter) is a notch of unbounded depth,
    also at the top edge of a multirate group's grid (the PES-rate group's roll-off towards ``fs / 2``
    is left to :func:`nyquist_band`).

    Returns
    -------
    list of GuardBand
        ``reason="notch"``, sorted by frequency, overlapping bands joined.
    """
    fs = float(controller.sample_rate_hz)
    out = []
    for m, secs in _section_groups(controller).items():
        f = np.geomspace(f_min_hz or fs / 100.0, 0.5 * m * fs * (1 - 1e-5), int(n))
        h = type(controller)(f"rate {m}", fs, secs).freqresp(f)     # this group alone, each section at m fs
        g = 20 * np.log10(np.maximum(np.abs(h), 1e-300))
        # a multirate section's zero at its own Nyquist counts; the PES-rate part's roll-off towards
        # fs / 2 is the Nyquist band's business (nyquist_band)
        out += [GuardBand(float(f[a]), float(f[b]), "notch", gain)
                for a, b in _notches_of(f, g, depth_db, edge_db, top_edge=m > 1)]
    return merge_bands(out)


def plant_blind_bands(plant, gain_cap: float = 1.0) -> list:
    """The identification's low-excitation blind bands, ``plant.meta["blind_bands"]`` (a list of dicts
    with ``lo_hz``, ``hi_hz``, ``reason`` and ``min_detectable_gain``): the gain guarded is the gain a
    mode could have there and still escape detection, at most ``gain_cap``.  The band above the
    identification's range is left to the Nyquist band (:func:`nyquist_band`), which states how far
    above Nyquist modes are guarded."""
    out = []
    for d in (getattr(plant, "meta", {}) or {}).get("blind_bands", []) or []:
        if str(d.get("reason", "")).startswith("above"):
            continue                      # near and above Nyquist: the Nyquist band states its own range
        try:
            lo, hi = float(d["lo_hz"]), float(d["hi_hz"])
        except (KeyError, TypeError, ValueError):
            continue
        g = d.get("min_detectable_gain")
        g = gain_cap if g is None or not math.isfinite(float(g)) else min(float(g), gain_cap)
        if hi > lo and g > 0:
            out.append(GuardBand(lo, hi, "blind", g))
    return out


def plant_gain_curve(plant):
    """The identification's detectable-gain curve ``plant.meta["detectable_gain_curve"]`` as
    ``(freqs_hz, g_min)`` arrays (``inf`` where unbounded), or None when the plant has none."""
    pts = (getattr(plant, "meta", {}) or {}).get("detectable_gain_curve")
    if not pts:
        return None
    try:
        f = np.array([float(a) for a, _ in pts])
        g = np.array([np.inf if b is None else float(b) for _, b in pts])
    except (TypeError, ValueError):
        return None
    ok = np.isfinite(f) & (f > 0)
    return (f[ok], g[ok]) if ok.sum() >= 2 else None


def curve_gain(curve, freqs_hz) -> np.ndarray:
    """``g_min`` of ``curve`` at ``freqs_hz`` (log-log interpolation; ``inf`` outside its range)."""
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    cf, cg = curve
    lg = np.log(np.where(np.isfinite(cg), cg, 1e300))
    out = np.exp(np.interp(np.log(f), np.log(cf), lg))
    out[(f < cf[0]) | (f > cf[-1])] = np.inf
    return np.where(out > 1e299, np.inf, out)


def merge_bands(bands: list) -> list:
    """Bands sorted by frequency; overlapping bands of the same reason and gain are joined."""
    out = []
    for b in sorted(bands, key=lambda b: (b.lo_hz, b.hi_hz)):
        if out and b.lo_hz <= out[-1].hi_hz and b.reason == out[-1].reason and b.gain == out[-1].gain:
            out[-1] = GuardBand(out[-1].lo_hz, max(out[-1].hi_hz, b.hi_hz), b.reason, b.gain)
        else:
            out.append(b)
    return out


def problem_bands(problem) -> list:
    """Every guard band of a :class:`seekopt.design.problem.SeekProblem`: its Nyquist band
    (``hf_guard``, gain ``hf_gain``), the controller's notches (``guard_notch_depth_db``, gain
    ``hf_gain``), the design plant's blind bands (``plant.meta``) and ``guard_bands_hz``
    (``(lo, hi)`` or ``(lo, hi, gain)``)."""
    fs = problem.sample_rate_hz
    bands = []
    if problem.hf_guard:
        bands.append(nyquist_band(fs, *problem.hf_guard, gain=problem.hf_gain))
    depth = getattr(problem, "guard_notch_depth_db", None)
    if depth:
        bands += controller_notches(problem.controller, depth, gain=problem.hf_gain)
    bands += plant_blind_bands(problem.plant, gain_cap=problem.hf_gain)
    for b in getattr(problem, "guard_bands_hz", ()) or ():
        bands.append(GuardBand(float(b[0]), float(b[1]), "user", float(b[2]) if len(b) > 2 else problem.hf_gain))
    return merge_bands(bands)


def band_gains(band: GuardBand, freqs_hz, curve=None) -> np.ndarray:
    """Guard gain at ``freqs_hz`` in ``band``: ``band.gain``, or for notch and blind bands, where the
    identification's detectable-gain ``curve`` (:func:`plant_gain_curve`) says a smaller mode would
    have been seen, that smaller gain (the largest mode that could hide there)."""
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    g = np.full(f.shape, float(band.gain))
    if curve is not None and band.reason in ("notch", "blind"):
        g = np.minimum(g, curve_gain(curve, f))
    return g
