"""The blind-band mode's forced response in the settle window: rows on the PES a mode above Nyquist adds.

The residual guard (:mod:`seekopt.design.guard`) bounds the *free* vibration a missed mode keeps after the
inputs end.  A mode near and above Nyquist (``k0 g / (s^2 + 2 zeta w s + w^2)``, ``f`` in the guard's
``nyquist`` band) also responds *during* the arrival: below its frequency it is a compliance
``c = k0 g / w^2`` [track/A], and the seek's total current (0.1-0.16 A near the settle sample of
K = 50-3000 on the NSS drive, Imax 0.3 A) moves the head by ``c i`` (0.03-0.08 track for the NSS truth's
-1 gain mode at 16.4 kHz); the loop reacts through its sensitivity, and the PES after the settle sample
shifts by a few hundredths of a track -- a plant of the robust set with no headroom left then leaves
the band (measured, ``studies/operating_range.py``: every member that settled later than predicted did
so because of that mode).

Rule (units: tracks, A, samples; ``e_i(k) = (y_i(k) - K) / band`` the PES of band plant ``i`` of the set)::

    d_f(k) = (y_{P + m_f}(k) - y_{P - m_f}(k)) / (2 band)        (f on the nyquist band's grid)
    |e_i(k) + d_f(k)| <= tol  and  |e_i(k) - d_f(k)| <= tol        every operating plant i, every f, k >= N_i

``P`` the design plant's linear part, ``m_f`` a mode at ``f`` of the band's gain ``g`` (``hf_gain``) and
damping :data:`BLIND_PES_ZETA`; ``y`` the closed-loop head position under the drive's controller (the one
simulator, :func:`seekopt.drive.simulator.closed_loop_responses`, for the loop without the mode; the loop
with it follows exactly by superposition, :func:`add_output_path`, from the mode's own response in the
engine's discretisation, :func:`mode_response`; equal to simulating the loops with the mode to 5e-13
relative; 5 frequencies, 200-500 samples: 17-41 ms CPU against 78-155 ms), so ``d_f`` is the loop's
sensitivity-filtered forced *and* free response to the mode, linear in the profile (``u_ff``, ``r``).  The
half difference of the ``+g`` and ``-g`` loops is the part linear in ``g``; with ``+-d_f`` the rows hold for
either sign of the mode and any smaller gain (linear in ``g``).  The mode's PES is taken from the design
plant's loop and added to every set plant's (first order in the drift: a drifted plant with the mode is
not simulated -- such loops may be unstable); ``tol`` (default ``(1 + band_margin) / 2``: half the margin
above the design band, the other half left for identification error) leaves each plant's own rows at
``band_margin`` and spends only the headroom a plant has at each sample (a bound on ``d_f`` alone,
``|d_f| <= 1 - band_margin``, measured: the operating-range ``--drift`` design K = 200 33 -> 37 samples,
these rows 34 with ``tol`` 1, 35 with 0.95).  The rows' ``N_i`` are the band rows' (the nominal plant's may start earlier: ``nominal_first``).

The *operating* plants (:func:`blind_pes_plants`) are the set's plants that stand for the drive in another
condition -- the nominal plant, the family members, the nominal plant at each member's drift, the corners and
axial points of the common drifts -- not the per-mode corners and orthogonal-array rows that stand for the
identification's own error (``meta["set_role"] ==`` :data:`ID_ERROR_ROLE`, set by
:func:`seekopt.design.driftset.drift_set`): ``tol`` leaves the other half of the margin for that error, so
adding the worst-sign blind mode to the plants that *are* that error as well counts it twice.  The missed
mode is the drive's, present at every temperature: it is stacked on every operating condition.  Measured
(studies/operating_range.py, K = 200, samples, set / room member): ``--drift`` 35 / 35 -> 35 / 34, family
35 / 33 -> 33 / 33, every member still no later than predicted (K = 1 ... 3000); in the certificate of the
infeasible length before, the blind rows on the per-mode corners held a third of the blind rows' weight.

Measured (studies/operating_range.py plants, ``--drift temp=+-4%,zeta=+-20%,gain=+-5%``, K = 200, hot
member's mode at 15.74 kHz): zeta 0.02 gives an honest prediction with 4, 5 or 12 grid points (35 / 35);
zeta 0.005 leaves gaps between grid points the design uses (hot 41 against 35 predicted); zeta 0.05
costs one more sample.  The compliance alone (a quasi-static stand-in ``k0 g / w_lo^2``) is not enough
(hot 42 against 35): the mode's resonant response during the arrival matters too.  The free vibration
left after the seek is the residual guard's (undamped modes, fine grid).
"""
from __future__ import annotations

import numpy as np

from identification.model.plant import Mode
from seekopt.drive.simulator import closed_loop_responses

__all__ = ["BLIND_PES_ZETA", "ID_ERROR_ROLE", "blind_pes_freqs", "blind_pes_maps", "blind_pes_plants", "mode_response",
           "add_output_path"]

#: Damping ratio of the hypothetical mode: its half-power width ``2 zeta f`` (475-690 Hz over the NSS band)
#: is about the grid's spacing at 5 points, so the rows hold between grid points (module docstring); the
#: residual guard's undamped modes bound the slower free vibration separately.
BLIND_PES_ZETA = 0.02

#: ``meta["set_role"]`` of a set plant that stands for the identification's own error (a per-mode corner, an
#: orthogonal-array row): no blind-band mode's PES rows on it (module docstring).
ID_ERROR_ROLE = "identification error"


def blind_pes_plants(plants: list) -> list:
    """Indices of the operating plants of a design's set (every plant but those whose ``meta["set_role"]``
    is :data:`ID_ERROR_ROLE`; the nominal plant, index 0, always): the plants the blind-band mode's PES is
    added to."""
    return [i for i, p in enumerate(plants)
            if i == 0 or (getattr(p, "meta", None) or {}).get("set_role") != ID_ERROR_ROLE]


def blind_pes_freqs(bands: list, points: int) -> tuple:
    """``(freqs_hz, gains)``: ``points`` frequencies [Hz] evenly across each ``nyquist`` band of
    ``bands`` (:class:`seekopt.design.guard_bands.GuardBand`) and the band's gain at each."""
    f, g = [], []
    for b in bands:
        if b.reason != "nyquist" or points <= 0 or b.gain <= 0:
            continue
        x = np.linspace(b.lo_hz, b.hi_hz, int(points)) if points > 1 else np.array([0.5 * (b.lo_hz + b.hi_hz)])
        f.append(x); g.append(np.full(x.size, float(b.gain)))
    if not f:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(f), np.concatenate(g)


def blind_pes_maps(plant, controller, horizon: int, freqs_hz, gains, zeta: float = BLIND_PES_ZETA,
                   base: dict | None = None) -> list:
    """Impulse responses of the PES a mode at each frequency adds, ``[(dy_u, dy_r), ...]``.

    ``dy_u`` [track/A] and ``dy_r`` [track/track] (length ``horizon``) are half the difference of the
    closed-loop position responses (to a unit feedforward impulse and a unit reference impulse) of the
    design plant's linear part with the mode ``(f, zeta, +g)`` and ``(f, zeta, -g)`` added.  A sign whose
    loop is unstable is replaced by the difference from the plant without the mode; a frequency whose
    loops are both unstable is skipped (no design can hold it anyway; the residual guard still covers it).

    The loops with the mode are not simulated: they follow exactly from the loop without it (``base``,
    :func:`seekopt.drive.simulator.closed_loop_responses` of the linear part, computed when not given)
    and the mode's own open-loop response (:func:`mode_response`), by :func:`add_output_path`.
    """
    lin = plant.linear_part().copy(meta={})     # a hypothetical plant (an identified one may not carry modes above Nyquist)
    n = int(horizon)
    if base is None:
        base = closed_loop_responses(lin, controller, n)
    base = {k: np.asarray(base[k])[:n] for k in ("y_uff", "y_r", "u_sub_uff", "u_sub_r")}
    out = []
    for f, g in zip(np.atleast_1d(freqs_hz), np.atleast_1d(gains)):
        h = mode_response(lin, controller, Mode(float(f), float(zeta), float(g)), n)
        resp = {}
        for s in (1.0, -1.0):
            d = add_output_path(base, s * h)
            if all(np.all(np.isfinite(a)) for a in d) and np.max(np.abs((base["y_r"] + d[1])[-10:])) < 1e3:
                resp[s] = d
        if len(resp) == 2:
            out.append(tuple(0.5 * (a - b) for a, b in zip(resp[1.0], resp[-1.0])))
        elif resp:
            (s, d), = resp.items()
            out.append(tuple(s * a for a in d))
    return out


def mode_response(lin, controller, mode: Mode, n: int) -> np.ndarray:
    """Open-loop response [track/A] of ``mode`` alone at the drive's sub-step rate, ``n`` servo samples
    (``n L`` sub-steps) long: ``h[t]`` the mode's deflection ``t`` sub-steps after a unit current held
    over sub-step 0, with the plant's delay and amplifier lag.  The engine's own linear system
    (:meth:`identification.model.discrete.DiscretePlant.augmented_ss` of ``lin`` with ``mode`` as its
    only declared mode) read at the mode's two states (the blocks of ``Phi`` are independent)."""
    L = int(controller.fast_multiple)
    dp = lin.copy(modes=[mode]).discretize(1.0 / (float(controller.sample_rate_hz) * L))
    A, B, C, _ = dp.augmented_ss()
    c = np.zeros(A.shape[0])
    c[2:4] = C[0, 2:4]                          # the declared mode is the block after the rigid body
    h = np.zeros(n * L)
    x = B[:, 0].copy()
    for t in range(1, n * L):                   # h[0] = 0: the output is read before the step
        h[t] = c @ x
        x = A @ x
    return h


def add_output_path(base: dict, h: np.ndarray) -> tuple:
    """``(dy_u, dy_r)``: the change of the closed-loop position responses when an LTI path ``h`` (sub-step
    rate, current to position, ``h[0] = 0``) is added to the plant of the loop ``base``.

    Exact superposition: with ``d = h * u`` the added path's output, the drive's loop sees
    ``y = P u + d``, so it runs as the loop without the path at the reference ``r - d``; ``d`` itself
    is ``h`` on the currents of that loop.  Per unit impulse (``a`` the path's output under the base
    loop's currents, ``a_r`` under its reference-impulse currents; ``*`` convolution at the servo rate)::

        d = a - a_r * d          (solved sample by sample: a_r[0] = 0)
        dy = d - y_r * d         (position: the path's output plus the loop's reaction to it)
    """
    y_r = base["y_r"]
    n = len(y_r)
    L = base["u_sub_r"].shape[1]

    def path(u_sub):                            # the path's output at the servo instants, h on the currents
        return np.convolve(h, np.asarray(u_sub).ravel())[:n * L:L]
    a_u, a_r = path(base["u_sub_uff"]), path(base["u_sub_r"])
    D = np.column_stack([a_u, a_r])             # d = a - a_r * d, forward substitution (a_r[0] = 0)
    rev = a_r[::-1]                             # rev[n - 1 - j] = a_r[j]
    with np.errstate(all="ignore"):
        for k in range(1, n):
            D[k] -= rev[n - 1 - k:n - 1] @ D[:k]      # sum_{q < k} a_r[k - q] d[q]
        dy = [D[:, i] - np.convolve(y_r, D[:, i])[:n] for i in range(2)]
    return dy[0], dy[1]
