"""Where a seek on a nonlinear plant starts, what holds it there, and what no feedforward can fix.

A plant with effects (:mod:`identification.model.effects`) is not shift-invariant: a
torque constant ``Kt(x)`` or a position bias makes the same seek different at another track,
and an effect fitted on the positions of a log says nothing outside them.  This module holds
the pieces the effect-aware designer (:mod:`seekopt.design.nlp`), the CLI and the studies
share:

* :func:`position_dependent_effects` -- effects whose input map or force changes with position
  (found by evaluating the effect's own hooks, not by a list of class names);
* :func:`fitted_range` and :func:`resolve_start` -- the start track (default: the middle of
  ``plant.meta["position_range_track"]``, the range of the log the loop fitted) and the
  one-line error for a seek that starts or ends outside the fitted range (no extrapolation);
* :func:`hold_current` -- the current that holds the head at rest at a track (the drive's
  integrator carries it before the seek; :func:`play_seek` adds it to the feedforward);
* :func:`play_seek` -- a profile played from a start track on the full plant by the one
  simulator :func:`seekopt.drive.simulator.simulate_2dof`;
* :func:`hold_check` -- the closed loop at rest around the target, effects included: if the
  drive's controller cannot keep the PES in the band there (a friction limit cycle, run-out
  larger than the band), no feedforward can, and the design says so instead of writing a profile.

Units: tracks, A, s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from identification.model.effects import effect_from_dict
from identification.model.plant import ModalPlant

from seekopt.design.metrics import seek_metrics
from seekopt.design.profiles import Profile
from seekopt.drive.simulator import simulate_2dof

__all__ = ["StartError", "position_dependent_effects", "fitted_range", "resolve_start", "hold_current",
           "play_seek", "HoldCheck", "hold_check", "nonlinear_effects", "compensate", "kt_scaled"]

#: Positions [track] at which an effect's hooks are compared to find position dependence.
_PROBE_TRACKS = (-1.0e5, -1.3e4, 0.0, 7.7e3, 2.9e4, 6.1e4, 1.0e5)


class StartError(ValueError):
    """A start track or seek the plant's fitted effects do not cover (one-line message)."""


def nonlinear_effects(plant: ModalPlant) -> list:
    """The plant's effects that act on the input or as a force (not structural, not output)."""
    return [e for e in plant.effects if e.kind in ("input", "force")]


def position_dependent_effects(plant: ModalPlant) -> list:
    """Names of the effects whose input map or force changes with the head position.

    Found by evaluating each effect's own hooks (numpy backend) at a spread of tracks, so a new
    effect needs no entry here."""
    names = []
    for e in nonlinear_effects(plant):
        vals = [(e.input_map(1.0, p), e.force(p, 0.0)) for p in _PROBE_TRACKS]
        if np.ptp(np.asarray(vals, dtype=float), axis=0).max() > 0:
            names.append(e.name)
    return names


def fitted_range(plant: ModalPlant):
    """``(lo, hi)`` [track]: the positions the plant's effects were fitted on
    (``plant.meta["position_range_track"]``, written by the loop from its log), or None."""
    rng = plant.meta.get("position_range_track") if isinstance(plant.meta, dict) else None
    if rng is None:
        return None
    try:
        lo, hi = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise StartError(f"plant meta position_range_track {rng!r} is not [lo, hi] in tracks") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise StartError(f"plant meta position_range_track {rng!r} is not an increasing [lo, hi]")
    return lo, hi


def resolve_start(plant: ModalPlant, tracks: float, start_track: float | None = None,
                  source: str = "plant") -> float:
    """Start track of a seek of ``tracks`` (signed: negative = towards lower track numbers).

    Default: the middle of the fitted range; with no range, 0 if no effect depends on position.
    Raises :class:`StartError` (one line, naming ``source``) when the plant has position-dependent
    effects and no fitted range, or when the start or the end ``start + tracks`` lies outside the
    fitted range: an effect fitted on a range of positions is never extrapolated.
    """
    rng = fitted_range(plant)
    dep = position_dependent_effects(plant)
    if start_track is None:
        if rng is None:
            if dep:
                raise StartError(f"{source}: effects {', '.join(dep)} depend on position but the plant has no "
                                 "position_range_track (meta); give --start-track and the range")
            return 0.0
        start_track = 0.5 * (rng[0] + rng[1])
    start = float(start_track)
    if not math.isfinite(start):
        raise StartError(f"start track {start_track!r} is not a number")
    if dep:
        if rng is None:
            raise StartError(f"{source}: effects {', '.join(dep)} depend on position but the plant has no "
                             "position_range_track (meta); the fitted range is unknown")
        end = start + float(tracks)
        for what, p in (("start", start), ("end", end)):
            if not rng[0] <= p <= rng[1]:
                raise StartError(f"{source}: seek {what} at track {p:g} is outside the range the effects "
                                 f"({', '.join(dep)}) were fitted on, [{rng[0]:g}, {rng[1]:g}]")
    return start


def kt_scaled(plant: ModalPlant, factor: float) -> ModalPlant:
    """``plant`` on a drive whose torque constant is ``factor`` times the plant's, the forces [N] unchanged.

    The rigid-body gain ``k0`` [track/(A s^2)] is multiplied by ``factor``; every current-equivalent force
    (``bias_a`` and the parameters in A -- names ending ``_a`` or holding ``_a_per`` -- of the force effects:
    position bias, friction) is divided by it, so that ``k0 * force`` stays; input effects (``Kt(x)``
    relative to its nominal, the amplifier's current limit) and the modes' relative gains are kept.
    The plants the effect-aware design holds its current headroom on
    (:attr:`seekopt.design.nlp_problem.NLPSettings.kt_uncertainty`)."""
    f = float(factor)
    if not (math.isfinite(f) and f > 0):
        raise ValueError(f"torque-constant factor must be positive, not {factor!r}")
    effects = []
    for e in plant.effects:
        if e.kind == "force":
            d = e.to_dict()
            d["params"] = {k: (np.asarray(v, float) / f).tolist() if (k.endswith("_a") or "_a_per" in k) else v
                           for k, v in d["params"].items()}
            e = effect_from_dict(d)
        effects.append(e)
    return plant.copy(k0=plant.k0 * f, bias_a=plant.bias_a / f, effects=effects)


def hold_current(plant: ModalPlant, position: float, dt: float, limit_a: float = 10.0) -> float:
    """Current [A] that holds the head at rest at ``position``: the command whose delivered
    current (after the input effects) cancels the force channel (bias, position effects) there.

    Solved on the plant's own stepping engine (``DiscretePlant.command`` and ``net_force``)."""
    dp = plant.discretize(dt)

    def net(u):
        return dp.command(u, position) + dp.net_force(position, 0.0)

    a, b = -limit_a, limit_a
    if net(a) * net(b) > 0:
        raise StartError(f"no current within +-{limit_a:g} A holds the head at track {position:g}")
    from scipy.optimize import brentq    # imported on first use (~0.2 s of a seekopt design start-up)
    return float(brentq(net, a, b, xtol=1e-14, rtol=1e-14))


def play_seek(plant: ModalPlant, controller, profile: Profile, start_track: float = 0.0, *,
              settle: float | None = None, horizon_s: float = 0.015, k0_for_tbb: float | None = None,
              disturbances=None):
    """Play ``profile`` from rest at ``start_track`` on ``plant`` (effects included) by the one simulator.

    The drive holds the head at the start with :func:`hold_current` (its integrator's pre-seek
    state; added to the feedforward over the whole run), the reference is ``start + r``.  Returns
    ``(SeekMetrics, SimResult)``; PES = position - (start + tracks).  ``horizon_s``: simulated time
    after the profile [s].
    """
    fs = float(controller.sample_rate_hz)
    L = int(controller.fast_multiple)
    band = profile.settle_track if settle is None else float(settle)
    n = profile.n + max(int(round(horizon_s * fs)), 1)
    u, r = profile.padded(n)
    uh = hold_current(plant, start_track, 1.0 / (fs * L))
    sim = simulate_2dof(plant, controller, u + uh, start_track + r, position0=start_track, current0=uh,
                        disturbances=disturbances)
    pes = sim.true_position_track - (start_track + profile.tracks)
    m = seek_metrics(pes, sim.peak_current_a, profile, fs, band, k0_for_tbb or plant.k0)
    return m, sim


@dataclass
class HoldCheck:
    """The closed loop at rest around a target track, full plant.

    ``residual_track``: worst ``|PES|`` over the last ``window_s`` of every run; ``holds``:
    residual within the band; ``culprits``: the effects without which the loop holds the band
    (all nonlinear/output effects if no single one is to blame)."""

    target_track: float
    band_track: float
    residual_track: float
    holds: bool
    culprits: list
    window_s: float

    def message(self) -> str:
        names = ", ".join(self.culprits) or "the linear loop"
        return (f"the drive's controller cannot hold the {self.band_track:g}-track band at track "
                f"{self.target_track:g} whatever the feedforward: {names} leaves a residual of "
                f"{self.residual_track:.3g} track (peak |PES| at rest over {self.window_s * 1e3:.0f} ms)")


def _rest_residual(plant, controller, target, offsets, run_s, window_s) -> float:
    fs = float(controller.sample_rate_hz)
    L = int(controller.fast_multiple)
    n = int(round(run_s * fs))
    w = max(int(round(window_s * fs)), 1)
    uh = hold_current(plant, target, 1.0 / (fs * L))
    worst = 0.0
    for off in offsets:
        sim = simulate_2dof(plant, controller, np.full(n, uh), np.full(n, target), position0=target + off,
                            current0=uh)
        pes = sim.true_position_track[-w:] - target
        worst = max(worst, float(np.max(np.abs(pes))) if np.all(np.isfinite(pes)) else math.inf)
    return worst


def hold_check(plant: ModalPlant, controller, target_track: float, band: float, *, run_s: float = 0.04,
               window_s: float = 0.01, offsets=None) -> HoldCheck:
    """Can the drive's feedback hold the head within ``band`` at ``target_track`` on the full plant?

    The loop (feedforward = the hold current only) starts at rest at the target and at offsets of
    +-0.5 and +-1 band (where a settling seek hands over to the feedback) and runs ``run_s``; the
    residual is the worst ``|PES|`` over the last ``window_s``.  A limit cycle (friction) or a
    disturbance larger than the band (run-out) shows as a residual above the band; each nonlinear
    or output effect is then removed in turn to name the one(s) responsible.
    """
    offsets = (0.0, 0.5 * band, -0.5 * band, band, -band) if offsets is None else tuple(offsets)
    res = _rest_residual(plant, controller, target_track, offsets, run_s, window_s)
    holds = bool(res <= band)
    culprits = []
    if not holds:
        suspects = [e for e in plant.effects if e.kind in ("input", "force", "output")]
        for e in suspects:
            without = plant.copy(effects=[x for x in plant.effects if x is not e])
            if _rest_residual(without, controller, target_track, offsets, run_s, window_s) <= band:
                culprits.append(e.name)
        if not culprits:
            culprits = [e.name for e in suspects]
    return HoldCheck(float(target_track), float(band), res, holds, culprits, float(window_s))


def compensate(plant: ModalPlant, controller, profile: Profile, start_track: float = 0.0,
               horizon_s: float = 0.004, input_gain: bool = False) -> tuple:
    """The feedforward that makes the full plant deliver, along the seek the linear design plans,
    the current its linear part would: the warm start of the effect-aware NLP.

    ``profile`` (designed on ``plant.linear_part()``) is played on the linear part from rest at
    ``start_track``; at every sample ``k`` the command ``c_k`` solves, with the plant's own stepping
    engine (``DiscretePlant.command`` / ``net_force``)::

        command(c_k + u_hold + fb_k, x_k) + net_force(x_k, v_k) = u_k + u_hold,lin + fb_k + force0,lin

    (``x, v``: the planned head position and velocity, ``fb``: the feedback current of that run).
    If the full plant then follows the plan, its loop sees exactly the linear design's run.
    Returns ``(Profile, peak)``: the compensated profile (reference unchanged) and the peak total
    current [A] of the planned run through the compensation.  With ``input_gain``, also
    ``(gain, offset)`` (``(n,)`` each): the plant's input map linearised along the plan, so that the
    current-equivalent force a feedforward ``c`` delivers is ``gain * c + offset`` to first order
    (``gain``: local ``d command / d current``, e.g. ``Kt(x)``; at ``c = comp`` exactly the linear
    design's ``u``).  The effect-aware NLP applies the unmodelled-mode guard to that force, which is
    what excites the modes, rather than to the command.
    """
    fs, L = float(controller.sample_rate_hz), int(controller.fast_multiple)
    dt = 1.0 / (fs * L)
    lin = plant.linear_part()
    n = profile.n
    m = n + max(int(round(horizon_s * fs)), 1)
    u, r = profile.padded(m)
    uhl, uh = hold_current(lin, start_track, dt), hold_current(plant, start_track, dt)
    sim = simulate_2dof(lin, controller, u + uhl, start_track + r, position0=start_track, current0=uhl)
    x = sim.true_position_track
    v = np.gradient(x) * fs
    fb = sim.feedback_a
    dl, dp = lin.discretize(dt), plant.discretize(dt)
    out = np.empty(m)
    from scipy.optimize import brentq    # imported on first use (~0.2 s of a seekopt design start-up)
    for k in range(m):
        target = dl.command(u[k] + uhl + fb[k], x[k]) + dl.net_force(x[k], v[k])
        out[k] = brentq(lambda c: dp.command(c + uh + fb[k], x[k]) + dp.net_force(x[k], v[k]) - target,
                                 -10.0, 10.0, xtol=1e-12)
    peak = float(np.max(np.abs(out + uh + fb)))
    comp = Profile(out[:n], profile.reference_track.copy(), profile.sample_rate_hz, profile.tracks, profile.imax_a,
                   profile.settle_track, profile.kind, profile.seek_samples, dict(profile.meta))
    if not input_gain:
        return comp, peak
    h = 1e-4 * max(float(np.max(np.abs(out[:n]))), 1e-3)      # central difference of the input map [A]
    gain = np.array([(dp.command(out[k] + h + uh + fb[k], x[k]) - dp.command(out[k] - h + uh + fb[k], x[k]))
                     / (2 * h) for k in range(n)]) / np.array([(dl.command(u[k] + h + uhl + fb[k], x[k])
                                                                 - dl.command(u[k] - h + uhl + fb[k], x[k])) / (2 * h)
                                                                for k in range(n)])
    return comp, peak, (gain, u[:n] - gain * out[:n])
