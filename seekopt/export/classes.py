"""Seek tables a drive can play: every integer length from 1 track to the full stroke, by length class.

The rule (implemented here in exact integer arithmetic, and in C by :mod:`seekopt.export.ctable`)
-----------------------------------------------------------------------------------------------
A seek of ``K`` tracks (``|K| >= 1``; negative seeks negate both outputs, rounding included) plays:

Rest-to-rest class ``[k_lo, k_hi]`` (``k_lo <= |K| <= k_hi``)
    The optimal design of the class's top length ``K_c = k_hi`` scaled in amplitude by ``|K| / K_c`` at
    the same duration::

        u(k) = round(U(k) |K| / K_c),   r(k) = round(R(k) |K| / K_c)

    with ``U``, ``R`` the class tables (``U = 0`` and ``R = K_c 2^F`` after them).  Why amplitude and not
    time: the design loop is linear, so the scaled seek's position is ``|K|/K_c`` times the anchor's (it
    ends at rest at exactly ``|K|``: rest-to-rest exactness is kept for any plant the anchor was exact
    for), its error is ``|K|/K_c <= 1`` times the anchor's (it settles no later than the anchor), and its
    total current is a convex combination of the anchor's and the hold current (within Imax).  Stretching
    in time would change the spectrum the modes see (the anchor's mode quenching is for its duration) and,
    at a non-integer ratio on the sample grid, break rest-to-rest exactness.  The price is time: a length
    plays its class top's duration, so classes are chained such that each anchor settles within ``rho``
    (default 1.12) times the previous anchor's settle -- with the optimal settle non-decreasing in ``K``,
    every length then settles within ``rho`` of its own optimum.  Where the settle grows fast (short
    seeks) the classes hold one length: exact designed tables.

Coast class (among those with ``k_lo <= |K|``, the first with the least ``m + settle_samples``)
    Accelerate - coast - arrive with a velocity step of ``D / 2^F`` track/sample
    (:mod:`seekopt.design.longseek`): with ``m = ceil(|K| 2^F / D)`` samples between the steps::

        u(k) = round((U(k) - U(k - m)) |K| 2^F / (m D)),   r(k) = round((R(k) - R(k - m)) |K| 2^F / (m D))

    ``U`` zero after its table; ``R`` continues as the ramp ``R_last + D (k - n_R + 1)`` and is 0 before
    0.  After both steps ``R(k) - R(k - m) = m D``: the reference ends at exactly ``|K|``.  The scale is
    ``|K| / (m d) <= 1``: the same argument as above (error and current scale down).

Number formats
--------------
``u``: int16 Q15, full scale Imax: ``I [A] = u Imax / 32768``, saturated to [-32767, 32767] (tables and rule).  ``r``: int32
with ``F`` fractional bits, track relative to the seek start: ``r [track] = r / 2^F``; ``F`` is the largest
value <= 16 with ``stroke 2^F <= 2^30``, so every product of the rule fits an int64.  ``round`` is half away
from zero: ``q = |a| / b``, ``+1`` if ``2 (|a| mod b) >= b``, sign of ``a``.  After ``n(K)`` samples
(:meth:`SeekSet.n_samples`) the drive holds ``u = 0``, ``r = K 2^F``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RestClass", "CoastClass", "SeekSet", "SeekRule", "RuleError", "div_round", "frac_bits_for",
           "quantize_q15", "quantize_ref_q", "FF_Q", "U_SAT", "DESCRIPTOR_BYTES",
           "SET_DESCRIPTOR_BYTES"]

FF_Q = 15
#: Feedforward saturation (symmetric): ``|u| <= 32767``.
U_SAT = 32767
#: Bytes of one class descriptor in the C tables (int32 x 2, uint32 x 2, uint16 x 3, padding to 4).
DESCRIPTOR_BYTES = 24
#: Bytes of a set descriptor (6 integers and 4 pointers; 64-bit pointers, the larger case).
SET_DESCRIPTOR_BYTES = 48


class RuleError(ValueError):
    """A table set that cannot be built or played (one-line message)."""


def div_round(a, b):
    """``a / b`` rounded half away from zero, ``b > 0`` (exact integers; scalar or int64 arrays)."""
    if isinstance(a, np.ndarray):
        mag = np.abs(a)
        q = mag // b
        q = q + (2 * (mag - q * b) >= b)
        return np.where(a < 0, -q, q)
    mag = abs(int(a))
    q, rem = divmod(mag, int(b))
    q += 2 * rem >= b
    return -q if a < 0 else q


def frac_bits_for(stroke_track: float) -> int:
    """Fractional bits ``F`` of the reference: largest ``F <= 16`` with ``stroke 2^F <= 2^30``."""
    if not stroke_track >= 1:
        raise RuleError(f"stroke {stroke_track!r} must be at least one track")
    f = int(math.floor(math.log2(2.0 ** 30 / stroke_track)))
    if f < 0:
        raise RuleError(f"stroke of {stroke_track:g} tracks does not fit the int32 reference")
    return min(16, f)


def quantize_q15(u_a, imax: float) -> np.ndarray:
    """Current [A] -> int16 Q15 of ``imax`` (half away from zero, saturated symmetrically to +-32767 so
    that a negated value is representable)."""
    x = np.asarray(u_a, float) / imax * 32768.0
    return np.clip(np.sign(x) * np.floor(np.abs(x) + 0.5), -U_SAT, U_SAT).astype(np.int16)


def quantize_ref_q(r_track, frac_bits: int) -> np.ndarray:
    """Reference [track] -> int32 with ``frac_bits`` fractional bits (half away from zero)."""
    x = np.asarray(r_track, float) * 2.0 ** frac_bits
    q = np.sign(x) * np.floor(np.abs(x) + 0.5)
    if np.any(np.abs(q) > 2 ** 31 - 1):
        raise RuleError("reference does not fit int32")
    return q.astype(np.int32)


def _trim_hold(ref_q: np.ndarray, hold: int) -> np.ndarray:
    """Drop trailing samples equal to the hold value (the rule supplies them)."""
    nz = np.nonzero(ref_q != hold)[0]
    return ref_q[:nz[-1] + 1 if nz.size else 0]


class _ClassTables:
    """What rest-to-rest and coast classes share: their two tables (``ff_q15`` int16 Q15 of Imax, ``ref_q``
    int32 track / 2^F), the settle samples and metadata."""

    @property
    def n(self) -> int:
        """Samples of the class (the longer of its two tables)."""
        return max(len(self.ff_q15), len(self.ref_q))

    def _tables_dict(self, **head) -> dict:
        return {**head, "ff_q15": [int(v) for v in self.ff_q15], "ref_q": [int(v) for v in self.ref_q],
                "settle_samples": self.settle_samples, "meta": self.meta}


@dataclass
class RestClass(_ClassTables):
    """Lengths ``k_lo..k_hi`` play the ``k_hi`` design scaled by ``|K| / k_hi`` (module notes)."""

    k_lo: int
    k_hi: int
    ff_q15: np.ndarray
    ref_q: np.ndarray
    settle_samples: int
    meta: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return self._tables_dict(k_lo=self.k_lo, k_hi=self.k_hi)


@dataclass
class CoastClass(_ClassTables):
    """Lengths from ``k_lo`` play the velocity step of ``d_q / 2^F`` track/sample twice (module notes)."""

    k_lo: int
    d_q: int
    ff_q15: np.ndarray
    ref_q: np.ndarray
    settle_samples: int
    meta: dict = field(default_factory=dict)

    def coast_samples(self, tracks: int, frac_bits: int) -> int:
        return -(-(abs(int(tracks)) << frac_bits) // self.d_q)

    def to_dict(self) -> dict:
        return self._tables_dict(k_lo=self.k_lo, d_q=self.d_q)


def _rest_from(d):
    return RestClass(int(d["k_lo"]), int(d["k_hi"]), np.array(d["ff_q15"], np.int16), np.array(d["ref_q"], np.int32),
                     int(d["settle_samples"]), dict(d.get("meta") or {}))


def _coast_from(d):
    return CoastClass(int(d["k_lo"]), int(d["d_q"]), np.array(d["ff_q15"], np.int16), np.array(d["ref_q"], np.int32),
                      int(d["settle_samples"]), dict(d.get("meta") or {}))


@dataclass
class SeekSet:
    """The classes of one TPI (and family member): rest-to-rest classes covering ``1..classes[-1].k_hi``
    contiguously, coast classes (ascending ``k_lo`` and velocity) covering the rest up to ``stroke``."""

    tpi: int
    member: int
    stroke: int
    frac_bits: int
    classes: list
    coasts: list = field(default_factory=list)
    meta: dict = field(default_factory=dict)

    def check(self) -> None:
        """Coverage and integer ranges (raises :class:`RuleError`)."""
        k = 0
        for c in self.classes:
            if c.k_lo != k + 1 or c.k_hi < c.k_lo:
                raise RuleError(f"TPI {self.tpi}: rest classes not contiguous at {c.k_lo}..{c.k_hi}")
            k = c.k_hi
        for i, c in enumerate(self.coasts):
            if (i == 0 and c.k_lo > k + 1) or (i > 0 and c.k_lo <= self.coasts[i - 1].k_lo):
                raise RuleError(f"TPI {self.tpi}: coast classes must start at {k + 1} and ascend ({c.k_lo})")
        top = k if not self.coasts else self.stroke
        if top < self.stroke:
            raise RuleError(f"TPI {self.tpi}: lengths {top + 1}..{self.stroke} are not covered")
        if (self.stroke << self.frac_bits) > 2 ** 30:
            raise RuleError(f"TPI {self.tpi}: stroke {self.stroke} x 2^{self.frac_bits} exceeds 2^30")
        for c in self.classes + self.coasts:
            if c.n > 65535:
                raise RuleError(f"TPI {self.tpi}: a class table has {c.n} samples (> 65535)")

    def table_bytes(self) -> int:
        """Memory of this set's tables [bytes]: 2 per feedforward sample, 4 per reference sample,
        :data:`DESCRIPTOR_BYTES` per class and :data:`SET_DESCRIPTOR_BYTES` for the set (the code of
        ``seekopt_seek_sample`` is shared by all sets and not counted)."""
        data = sum(2 * len(c.ff_q15) + 4 * len(c.ref_q) for c in self.classes + self.coasts)
        return data + DESCRIPTOR_BYTES * (len(self.classes) + len(self.coasts)) + SET_DESCRIPTOR_BYTES

    def lookup(self, tracks: int):
        """``("rest", RestClass)`` or ``("coast", CoastClass)`` for ``|tracks|``; None if out of range."""
        K = abs(int(tracks))
        if K < 1 or K > self.stroke:
            return None
        if self.classes and K <= self.classes[-1].k_hi:
            tops = [c.k_hi for c in self.classes]
            return "rest", self.classes[int(np.searchsorted(tops, K))]
        best, t_best = None, None
        for c in self.coasts:       # the coast class whose seek settles first: least m + settle
            if c.k_lo <= K:
                t = c.coast_samples(K, self.frac_bits) + c.settle_samples
                if t_best is None or t < t_best:
                    best, t_best = c, t
        return None if best is None else ("coast", best)

    def n_samples(self, tracks: int) -> int:
        """Samples of the seek before the hold (0 for 0 tracks)."""
        hit = self.lookup(tracks)
        if hit is None:
            if int(tracks) == 0:
                return 0
            raise RuleError(f"TPI {self.tpi}: no seek of {tracks} tracks (stroke {self.stroke})")
        kind, c = hit
        return c.n if kind == "rest" else c.coast_samples(tracks, self.frac_bits) + c.n

    def play(self, tracks: int, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(u int16 Q15, r int32 Q.F)`` for samples ``0..n-1`` (default :meth:`n_samples`), the hold after."""
        K, F = int(tracks), self.frac_bits
        ns = self.n_samples(K)
        n = ns if n is None else int(n)
        k = np.arange(n)
        if K == 0:
            return np.zeros(n, np.int16), np.zeros(n, np.int32)
        kind, c = self.lookup(K)
        aK, sgn = abs(K), (1 if K > 0 else -1)
        ff, ref = c.ff_q15.astype(np.int64), c.ref_q.astype(np.int64)

        def U(j):
            out = np.zeros(len(j), np.int64)
            ok = (j >= 0) & (j < len(ff))
            out[ok] = ff[j[ok]]
            return out

        if kind == "rest":
            hold = c.k_hi << F
            R = np.full(n, hold, np.int64)
            ok = k < len(ref)
            R[ok] = ref[k[ok]]
            u, r = div_round(U(k) * aK, c.k_hi), div_round(R * aK, c.k_hi)
        else:
            m = c.coast_samples(K, F)

            def R(j):
                last = ref[-1] if len(ref) else 0
                out = last + c.d_q * (j - len(ref) + 1)
                ok = (j >= 0) & (j < len(ref))
                out[ok] = ref[j[ok]]
                out[j < 0] = 0
                return out
            num, den = aK << F, m * c.d_q
            u, r = div_round((U(k) - U(k - m)) * num, den), div_round((R(k) - R(k - m)) * num, den)
        u = np.clip(u, -U_SAT, U_SAT)   # only overlapping steps could reach it (the builder checks)
        after = k >= ns
        u[after], r[after] = 0, aK << F
        return (sgn * u).astype(np.int16), (sgn * r).astype(np.int32)

    def sample(self, tracks: int, k: int) -> tuple[int, int, int]:
        """``(status, u, r)`` of sample ``k``: status 1 within the seek, 0 in the hold; the C function's
        contract (-2 for a length outside ``1..stroke``)."""
        if int(tracks) != 0 and self.lookup(tracks) is None:
            return -2, 0, 0
        ns = self.n_samples(tracks)
        u, r = self.play(tracks, k + 1)
        return (1 if k < ns else 0), int(u[k]), int(r[k])

    def to_dict(self) -> dict:
        return {"tpi": self.tpi, "member": self.member, "stroke": self.stroke, "frac_bits": self.frac_bits,
                "classes": [c.to_dict() for c in self.classes], "coasts": [c.to_dict() for c in self.coasts],
                "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> "SeekSet":
        return cls(int(d["tpi"]), int(d.get("member", 0)), int(d["stroke"]), int(d["frac_bits"]),
                   [_rest_from(c) for c in d["classes"]], [_coast_from(c) for c in d.get("coasts", [])],
                   dict(d.get("meta") or {}))


@dataclass
class SeekRule:
    """Every table set of an export plus the shared metadata (sample rate, Imax, formats, hashes)."""

    meta: dict
    sets: list

    @property
    def frac_bits(self) -> int:
        return int(self.meta["ref_frac_bits"])

    def find(self, tpi: int, member: int = 0) -> SeekSet | None:
        for s in self.sets:
            if s.tpi == int(tpi) and s.member == int(member):
                return s
        return None

    def to_dict(self) -> dict:
        return {"meta": self.meta, "sets": [s.to_dict() for s in self.sets]}

    @classmethod
    def from_dict(cls, d: dict) -> "SeekRule":
        return cls(dict(d["meta"]), [SeekSet.from_dict(s) for s in d["sets"]])
