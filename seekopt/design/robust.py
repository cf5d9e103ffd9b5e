"""The robust plant set of a seek design: uncertainty ranges of the identified plant and the
vertices of that box the design must hold on (:class:`RobustSpec`)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from identification.model.plant import ModalPlant, Mode

__all__ = ["RobustSpec", "seek_induced"]


def seek_induced(mode: Mode) -> bool:
    """True for a seek-induced mode: gain below the rigid body at resonance, ``|g| / (2 zeta) < 1``
    (the paper's modes that a frequency response cannot see; :data:`seekopt.drive.presets.SEEK_MODES`)."""
    return abs(mode.gain) < 2.0 * mode.zeta


@dataclass
class RobustSpec:
    """Uncertainty of the identified plant for robust design (the robust set of plants).

    Every range is a half-width around the identified value, and never narrower than
    ``n_sigma`` reported standard deviations of that parameter (``Mode.std``,
    ``ModalPlant.std["delay_s"]``, ``ModalPlant.std["k0"]``).  The defaults are what the
    identification can promise, not what one truth plant needs:

    * ``freq_pct = 5`` on the **seek-induced** modes (:func:`seek_induced`): they move by a few
      percent with temperature, flex-cable shape and head position, far more than the reported
      std (0.01-0.1 %); the robust option promises tolerance to +-5 % of them.
    * ``other_freq_pct = 1`` on the other (high-gain) modes: the identification pins them to about
      0.5 % on synthetic logs and the notches hold them; 5 % on a mode of gain ~1 costs seek time.
    * ``gain_pct = 8``: about three times the identification's gain error on synthetic logs
      (2.8 %), at least three reported std of every mode below 0.45 fs (at most 7.5 %).  15 % cost
      2-4 samples at K = 200 (2.0-2.1 T_bb) with the array's column draw; 8 % is within one sample
      for every draw.  ``zeta_pct = 30``: damping is the least certain parameter (the 7 kHz
      mode's comes out 30 % low on the multirate drive).
    * ``delay_s = 1 us`` (2.6 % of a 26.4 kHz sample): the reported std (0.01 us) is noise only;
      the delay also absorbs unmodelled amplifier lag and sub-sample timing.
    * modes above ``nyquist_guard * fs / 2`` keep their identified values: near Nyquist the
      identification cannot pin them (aliasing); the unmodelled-mode guard covers that band.

    Parameters
    ----------
    freq_pct : float
        Frequency half-width of the seek-induced modes [%].
    zeta_pct, gain_pct : float
        Damping and gain half-widths of every mode [%].
    delay_s : float
        Delay half-width [s].
    n_samples : int
        Orthogonal-array vertices besides the nominal and the corners (all frequencies x delay x
        ``k0`` at +-, all gains +-): rows of a Sylvester-Hadamard array, one +-1 column per varied
        factor (each mode's frequency and gain, delay, ``k0``), damping uniform (seeded).  15 rows
        and at most 15 factors (7 modes and the delay) make a strength-2 array: every pair of
        factors meets all four sign pairs.  (Random signs moved T_ss by 3 samples with the draw.)
    objective : {"worst", "mean"}
        ``worst``: settle band (or residual epigraph) enforced on every plant; ``mean``: on the
        nominal plant, tail energy averaged over the set.
    k0_pct : float
        Half-width of the rigid-body gain range [%].
    seed : int
    other_freq_pct : float
        Frequency half-width of the other modes [%].
    n_sigma : float
        Floor of every range in reported standard deviations.
    nyquist_guard : float
        Modes above ``nyquist_guard * fs / 2`` (``fs`` the plant's sample rate) are not varied.
    """

    freq_pct: float = 5.0
    zeta_pct: float = 30.0
    gain_pct: float = 8.0
    delay_s: float = 1e-6
    n_samples: int = 15
    objective: str = "worst"
    k0_pct: float = 0.0
    seed: int = 0
    other_freq_pct: float = 1.0
    n_sigma: float = 3.0
    nyquist_guard: float = 0.9

    _KEYS = {"freq": "freq_pct", "zeta": "zeta_pct", "gain": "gain_pct", "delay": "delay_s",
             "n": "n_samples", "samples": "n_samples", "objective": "objective", "k0": "k0_pct",
             "seed": "seed", "ofreq": "other_freq_pct", "sigma": "n_sigma", "nyq": "nyquist_guard"}

    def __post_init__(self):
        if self.objective not in ("worst", "mean"):
            raise ValueError(f"robust objective must be 'worst' or 'mean', not {self.objective!r}")
        vals = (self.freq_pct, self.zeta_pct, self.gain_pct, self.delay_s, self.k0_pct, self.other_freq_pct,
                self.n_sigma, self.nyquist_guard)
        if any((not math.isfinite(v)) or v < 0 for v in vals) or self.n_samples < 0:
            raise ValueError("robust ranges must be finite and >= 0")

    @classmethod
    def from_string(cls, text: str | None) -> "RobustSpec":
        """``"freq=5,ofreq=1,zeta=30,gain=8,delay=1e-6,n=15,objective=worst,k0=0,sigma=3"``
        (percent / s); ``""``, ``"default"`` or None give the defaults."""
        kw = {}
        for item in filter(None, (text or "").replace(" ", "").split(",")):
            if item == "default":
                continue
            k, eq, v = item.partition("=")
            if not eq or k not in cls._KEYS:
                raise ValueError(f"robust spec {text!r}: unknown item {item!r} "
                                 f"(keys: {', '.join(sorted(cls._KEYS))})")
            name = cls._KEYS[k]
            try:
                kw[name] = v if name == "objective" else (int(float(v)) if name in ("n_samples", "seed")
                                                          else float(v))
            except ValueError:
                raise ValueError(f"robust spec {text!r}: {k} is not a number") from None
        return cls(**kw)

    def to_dict(self) -> dict:
        """Field values (JSON-ready; ``from_dict`` inverts it)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "RobustSpec":
        return cls(**d)

    def to_string(self) -> str:
        return (f"freq={self.freq_pct:g},ofreq={self.other_freq_pct:g},zeta={self.zeta_pct:g},"
                f"gain={self.gain_pct:g},delay={self.delay_s:g},k0={self.k0_pct:g},sigma={self.n_sigma:g},"
                f"nyq={self.nyquist_guard:g},n={self.n_samples},seed={self.seed},objective={self.objective}")

    def ranges(self, plant: ModalPlant):
        """Relative half-widths ``(df, dz, dg)`` per mode [fraction], delay [s] and ``k0`` [fraction]."""
        ns = self.n_sigma
        fny = self.nyquist_guard * 0.5 * plant.sample_rate_hz if plant.sample_rate_hz else math.inf
        df, dz, dg = [], [], []
        for m in plant.modes:
            sd = m.std or {}
            if m.freq_hz >= fny:
                df.append(0.0); dz.append(0.0); dg.append(0.0)
                continue
            base = self.freq_pct if seek_induced(m) else self.other_freq_pct
            df.append(max(base / 100, ns * sd.get("freq_hz", 0.0) / m.freq_hz))
            dz.append(max(self.zeta_pct / 100, ns * sd.get("zeta", 0.0) / m.zeta if m.zeta else 0.0))
            dg.append(max(self.gain_pct / 100, ns * sd.get("gain", 0.0) / abs(m.gain) if m.gain else 0.0))
        dd = max(self.delay_s, ns * float(plant.std.get("delay_s", 0.0))) if (self.delay_s or ns) else 0.0
        dk = max(self.k0_pct / 100, ns * float(plant.std.get("k0", 0.0)) / plant.k0) if self.k0_pct else 0.0
        return np.array(df), np.array(dz), np.array(dg), dd, dk

    def plants(self, plant: ModalPlant) -> list:
        """Nominal first, then the corners, then ``n_samples`` orthogonal-array vertices of the box (each
        mode's frequency and gain, the delay and ``k0`` at +- their range; damping uniform): the settle
        residual is linear in the gains, so its worst case sits on vertices."""
        f, z, g, d, k = self.ranges(plant)

        def var(sf=0.0, sz=0.0, sg=0.0, sd=0.0, sk=0.0):
            modes = [Mode(m.freq_hz * (1 + a), m.zeta * (1 + b), m.gain * (1 + c))
                     for m, a, b, c in zip(plant.modes, sf * f, sz * z, sg * g)]
            return plant.copy(modes=modes, delay_s=max(0.0, plant.delay_s + sd * d), k0=plant.k0 * (1 + sk * k))

        out = [plant]
        anyf, anyg = bool(np.any(f)), bool(np.any(g))
        for sf in ((1, -1) if anyf else (0,)):            # corners: frequency x delay x k0 (all signs)
            for sd in ((1, -1) if d else (0,)):
                for sk in ((1, -1) if k else (0,)):
                    if sf or sd or sk:
                        out.append(var(sf=sf, sd=sd, sk=sk))
        if anyg:
            out += [var(sg=1.0), var(sg=-1.0)]
        n = len(plant.modes)
        # orthogonal-array vertices: the varied factors (frequency and gain sign of each varied mode,
        # delay and k0 sign) are columns 1.. of a Sylvester-Hadamard matrix of order > n_samples, rows
        # 1..n_samples (row 0, all +, is a corner): with at most order - 1 factors and n_samples =
        # order - 1 every pair of factors sees all four sign pairs equally often (strength 2).
        factors = ([("f", i) for i in range(n) if f[i]] + [("g", i) for i in range(n) if g[i]]
                   + [("d", 0)] * bool(d) + [("k", 0)] * bool(k))
        if self.n_samples and factors:
            rng = np.random.default_rng(self.seed)
            for sg in orthogonal_array_signs(factors, self.n_samples, {"f": n, "g": n, "d": 1, "k": 1}, rng):
                out.append(var(sf=sg["f"], sg=sg["g"], sd=sg["d"][0], sk=sg["k"][0], sz=rng.uniform(-1, 1, n)))
        return out


def orthogonal_array_signs(factors: list, n_rows: int, sizes: dict, rng) -> list:
    """Sign rows of an orthogonal array of strength 2 over ``factors``.

    ``factors``: ``(kind, index)`` pairs; ``sizes``: the length of each kind's sign array.  The factors
    are columns (a random permutation from ``rng``) of rows ``1..n_rows`` of the Sylvester-Hadamard
    matrix of the smallest order ``> n_rows`` (row 0, all +, is a corner): every pair of factors sees
    all four sign pairs equally often.  Returns one ``{kind: signs}`` dict per row.
    """
    H = _sylvester(n_rows)
    cols = 1 + np.resize(rng.permutation(H.shape[1] - 1), len(factors))
    rows = []
    for row in H[1:1 + n_rows]:
        s = {kind: np.zeros(m) for kind, m in sizes.items()}
        for (kind, i), c in zip(factors, cols):
            s[kind][i] = row[c]
        rows.append(s)
    return rows


def _sylvester(nrows: int) -> np.ndarray:
    """Sylvester-Hadamard matrix (+-1 entries) of the smallest order ``2^m > nrows``."""
    H = np.ones((1, 1))
    while H.shape[1] <= nrows:
        H = np.block([[H, H], [H, -H]])
    return H
