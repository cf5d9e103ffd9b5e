"""Building the length classes of :mod:`seekopt.export.classes` from designs (``seekopt export``).

Per TPI (the sweep's plant re-expressed at that TPI, its controller scaled, its designer):

1. **Rest-to-rest classes**, chained from 1 track up: the next anchor ``K_c`` is the longest length whose
   optimal design settles within ``rho`` times the previous anchor's settle (searched with a growth guess,
   then bisection); its class is ``previous anchor + 1 .. K_c``.  Where even ``previous + 1`` settles later
   than that, the class is that one length (an exact table).  The chain stops before an anchor longer than
   ``max_rest_samples`` or faster than the velocity limit.
2. **Coast classes** above: velocity steps (:class:`seekopt.design.longseek.LongSeekDesigner`) from the
   fastest one that still coasts at the first uncovered length, ``rho_velocity`` apart, up to the coast
   velocity: ``vmax`` when given (``--vmax-mps`` or the plant's metadata, see :mod:`seekopt.design.longseek`),
   else the velocity reached with a step of ``max_step_samples`` samples (capped at the stroke's bang-bang
   peak velocity) -- a drive without a stated velocity limit still gets tables, and the metadata says which
   velocity they coast at.
3. **Budget**: if the tables exceed ``budget_bytes``, the chain is rebuilt with a wider ``rho`` (designs are
   cached), and the achieved ``rho`` is recorded.

Every design is the designer's verified design; its settle is measured by the one simulator
(:func:`seekopt.design.metrics.evaluate_profile`) on the design plant.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seekopt.export.classes import (CoastClass, RestClass, RuleError, SeekSet, quantize_q15, quantize_ref_q,
                                    _trim_hold)

__all__ = ["ClassSettings", "Anchor", "AnchorDesigner", "build_seek_set", "RHO_LADDER"]

#: Settle ratios tried, in order, when a set exceeds its memory budget.
RHO_LADDER = (1.2, 1.3, 1.5, 2.0, 3.0)


@dataclass
class ClassSettings:
    """How the classes are drawn.

    Parameters
    ----------
    rho : float
        Settle ratio between consecutive rest-to-rest anchors (the bound on every length's settle relative
        to its own optimum, given a non-decreasing optimal settle).
    rho_velocity : float
        Velocity ratio between consecutive coast classes (rigid-body time penalty at most
        ``(rho_v^2 + 1) / (2 rho_v)``: 1.035 at 1.3).
    max_rest_samples : int
        Longest rest-to-rest anchor [samples] (longer seeks coast).
    max_step_samples : int
        Longest velocity step when no velocity limit is given [samples].
    budget_bytes : int
        Memory budget of one set's tables [bytes] (:meth:`SeekSet.table_bytes`).
    """

    rho: float = 1.12
    rho_velocity: float = 1.3
    max_rest_samples: int = 160
    max_step_samples: int = 256
    budget_bytes: int = 64 * 1024

    def __post_init__(self):
        if not (self.rho > 1 and self.rho_velocity > 1 and self.max_rest_samples >= 8
                and self.max_step_samples >= 8 and self.budget_bytes > 0):
            raise RuleError("class settings: rho, rho_velocity > 1, max_*_samples >= 8, budget > 0 required")


@dataclass
class Anchor:
    """A verified design used as a class anchor."""

    tracks: int
    current_a: np.ndarray
    reference_track: np.ndarray
    settle_samples: int
    n: int
    peak_velocity_track_s: float
    seek_samples: int


class AnchorDesigner:
    """``designer.design(K)`` with a cache, the measured settle and the rigid peak velocity.

    A length whose design fails (infeasible, solver, check) returns None.
    """

    def __init__(self, designer, plant, controller, settle: float, progress=None):
        self.designer, self.plant, self.controller, self.settle = designer, plant, controller, float(settle)
        self.fs = float(controller.sample_rate_hz)
        self.cache: dict = {}
        self.progress = progress
        self.n_designs = 0

    def __call__(self, K: int) -> Anchor | None:
        from seekopt.design.longseek import rigid_peak_velocity
        from seekopt.design.metrics import evaluate_profile
        K = int(K)
        if K in self.cache:
            return self.cache[K]
        try:
            prof = self.designer.design(float(K)).profile
        except Exception:   # noqa: BLE001 - an infeasible or failed length is not an anchor
            prof = None
        self.n_designs += 1
        if self.progress is not None:
            self.progress.update(1)
            self.progress.set_postfix_str(f"K={K}", refresh=False)
        a = None
        if prof is not None:
            m = evaluate_profile(self.plant, self.controller, prof, settle=self.settle)
            if m.settled:
                ns = int(prof.seek_samples)
                a = Anchor(K, np.asarray(prof.current_a[:ns], float), np.asarray(prof.reference_track, float),
                           int(round(m.settle_time_s * self.fs)), int(prof.n),
                           rigid_peak_velocity(prof.current_a, self.plant.k0, self.fs), ns)
        self.cache[K] = a
        return a


def _rest_class(a: Anchor, k_lo: int, imax: float, F: int) -> RestClass:
    ref = _trim_hold(quantize_ref_q(a.reference_track, F), a.tracks << F)
    return RestClass(k_lo, a.tracks, quantize_q15(a.current_a, imax), ref, a.settle_samples,
                     {"seek_samples": a.seek_samples, "peak_velocity_track_s": a.peak_velocity_track_s})


def _chain(design, k_top, st: ClassSettings, rho: float, vmax):
    """Rest-to-rest anchors ``[(k_lo, Anchor)]`` up to ``k_top`` at most (module notes, step 1)."""
    def fits(a):
        return a is not None and a.n <= st.max_rest_samples and (vmax is None or a.peak_velocity_track_s <= vmax)

    first = design(1)
    if not fits(first):
        raise RuleError("no verified design of a 1-track seek within the class limits")
    out = [(1, first)]
    alpha = 0.5
    bad: dict = {}          # limit -> shortest length seen to fail it (settle non-decreasing in K)
    while out[-1][1].tracks < k_top:
        prev = out[-1][1]
        K0, limit = prev.tracks + 1, rho * prev.settle_samples

        def ok(K):
            a = design(K)
            good = fits(a) and a.settle_samples <= limit
            if not good:
                bad[limit] = min(bad.get(limit, K), K)
            return good
        g = min(k_top, max(K0, int(prev.tracks * (limit / max(prev.settle_samples, 1)) ** (0.9 / alpha))))
        known = bad.get(limit)
        if known is None or known > g:
            if ok(g):
                best = g
                g2 = min(k_top, prev.tracks + 2 * (g - prev.tracks))
                if g2 > g and (known is None or g2 < known) and ok(g2):
                    best = g2
            known = bad.get(limit)
        if known is not None and known <= g:    # bisection below the shortest failure: exact while
            lo, hi = K0 - 1, known              # nothing fits, to ~1.5 % once something does
            while hi - lo > (1 if lo < K0 else max(1, lo // 64)):
                mid = (lo + hi) // 2
                lo, hi = (mid, hi) if ok(mid) else (lo, mid)
            best = lo if lo >= K0 else K0
        a = design(best)
        if not fits(a):
            break
        out.append((K0, a))
        if prev.settle_samples > 0 and a.settle_samples > prev.settle_samples and a.tracks > prev.tracks + 1:
            alpha = float(np.clip(math.log(a.settle_samples / prev.settle_samples) / math.log(a.tracks / prev.tracks),
                                  0.25, 1.0))
    return out


class _Steps:
    """Velocity steps on the ``2^-F`` velocity grid (so that the C rule's ramp is exact)."""

    def __init__(self, longseek, F):
        self.longseek, self.F = longseek, F

    def __call__(self, v):
        d_q = int(math.floor(v / self.longseek.fs * 2 ** self.F))
        return d_q, self.longseek.velocity_step(d_q / 2 ** self.F * self.longseek.fs)


def _coast_class(k_lo, d_q, s, imax, F):
    return CoastClass(k_lo, d_q, quantize_q15(s.current_a, imax), quantize_ref_q(s.reference_track, F),
                      int(s.settle_samples), {"velocity_track_s": s.velocity_track_s,
                                              "min_coast_samples": s.min_coast_samples, "step_samples": s.n})


def _coasts(steps, k_from: int, stroke: int, v_start: float, v_cap: float, rho_v: float, imax: float, F: int):
    """Coast classes from ``k_from`` to ``stroke`` (module notes, step 2): the fastest step (at most
    ``v_start``) that coasts at ``k_from``, then ``rho_v`` apart up to ``v_cap``."""
    v = min(v_start, v_cap)
    d_q, s = steps(v)
    for _ in range(400):
        if s.min_tracks <= k_from:
            break
        v *= max(0.8, min(0.98, math.sqrt(k_from / s.min_tracks)))
        d_q, s = steps(v)
    else:
        raise RuleError(f"no velocity step coasts at {k_from} tracks")
    out = [(k_from, d_q, s)]
    while v < v_cap * (1 - 1e-9):
        v = min(v_cap, v * rho_v)
        d_q, s = steps(v)
        k_lo = int(math.floor(s.min_tracks)) + 1
        if k_lo > stroke:
            break
        while out and k_lo <= out[-1][0]:         # a faster step that coasts as early replaces slower ones
            out.pop()
        out.append((max(k_lo, k_from), d_q, s))
    return [_coast_class(k_lo, d_q, s, imax, F) for k_lo, d_q, s in out]


def build_seek_set(design, longseek, stroke: int, frac_bits: int, imax: float, *, tpi: int, member: int = 0,
                   settings: ClassSettings | None = None) -> SeekSet:
    """The table set of one TPI (module notes).

    Parameters
    ----------
    design : AnchorDesigner
    longseek : seekopt.design.longseek.LongSeekDesigner
        Its ``spec.vmax_track_s`` is the velocity limit (None: none).
    stroke : int
        Full stroke [track].
    frac_bits : int
        ``F`` of the reference format (:func:`seekopt.export.classes.frac_bits_for`).
    """
    st = settings or ClassSettings()
    vmax = longseek.spec.vmax_track_s
    k0, fs = longseek.plant.k0, longseek.fs
    gam = longseek.gamma - abs(longseek.plant.bias_a) / imax
    if vmax is not None:
        v_cap, why = float(vmax), "velocity limit"
    else:
        v_cap = min(k0 * gam * imax * st.max_step_samples / 1.2 / fs, math.sqrt(stroke * k0 * imax))
        why = f"no velocity limit given: the velocity of a {st.max_step_samples}-sample step (or the stroke's)"
    steps = _Steps(longseek, frac_bits)
    k_stop = min(stroke, int(math.floor(steps(v_cap)[1].min_tracks)) + 1)   # coasting at v_cap from here
    last = None
    for rho in (st.rho,) + tuple(r for r in RHO_LADDER if r > st.rho):
        anchors = _chain(design, max(1, k_stop - 1), st, rho, vmax)
        classes = [_rest_class(a, k_lo, imax, frac_bits) for k_lo, a in anchors]
        k_end = classes[-1].k_hi
        coasts = []
        if k_end < stroke:
            v0 = min(v_cap, 1.3 * anchors[-1][1].peak_velocity_track_s)
            coasts = _coasts(steps, k_end + 1, stroke, v0, v_cap, st.rho_velocity, imax, frac_bits)
        s = SeekSet(int(tpi), int(member), int(stroke), int(frac_bits), classes, coasts,
                    {"rho": rho, "rho_velocity": st.rho_velocity, "coast_velocity_track_s": v_cap,
                     "coast_velocity_source": why, "vmax_track_s": vmax, "k0_track": k0,
                     "designs": design.n_designs})
        s.check()
        last = s
        if s.table_bytes() <= st.budget_bytes:
            return s
    raise RuleError(f"TPI {tpi}: tables need {last.table_bytes()} bytes even at rho = {last.meta['rho']} "
                    f"(budget {st.budget_bytes} bytes)")
