"""Closing the loop: residual analysis, candidate effects, re-fit and decision.

:func:`close_loop` takes a seek log and an identified plant and:

1. splits the data: fit on the log, validate on ``validation`` (another log) or, by
   default, on held-out seeks (odd-numbered seeks validate, even ones fit);
2. simulates the model per seek (:func:`identification.loop.residual.simulate`, one
   ``DiscretePlant`` per seek from rest at its start, initial position and velocity
   fitted by least squares) and analyses the residual (evidence);
3. fits every candidate of :data:`identification.loop.candidates.CANDIDATES` on the fit
   data (jointly with ``k0``, ``bias_a``, the declared modes' gains and the linear
   parameters of the effects already accepted), simulates it, and accepts the one with
   the lowest validation RMS if (a) its BIC on the fit data (output error on an
   effective sample size) is lower than the current model's by more than ``min_bic``,
   (b) its validation RMS is at most ``(1 - min_drop)`` times the current one,
   (c) it lowers the error of at least ``min_seeks`` of the validation seeks and
   (d) no free-form correction along a variable outside the library does clearly
   better (else it is a proxy); earlier accepted effects are then re-fitted
   (backfitting);
4. repeats greedily until no candidate passes, then lists in ``unexplained`` the
   structure that is still in the validation residual.

Every reported error is on validation data, from the reference simulation.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass, field

import numpy as np

from identification.loop.candidates import CANDIDATES, fit_candidate
from identification.loop.fit_engine import Data, bic, effective_n, lstsq, refit_base
from identification.logs.seeklog import SeekLog
from identification.loop.report import dependence, describe_residual, evidence_lines, unexplained_lines
from identification.model.plant import ModalPlant
from identification.loop.residual import Residual, seek_windows, simulate, velocity_estimate

__all__ = ["Step", "LoopResult", "close_loop", "evaluate", "errors", "improved_fraction", "split_data",
           "compensate", "reidentified", "REPEATABLE", "OUT_OF_LIBRARY", "SIMULATION_NOTE"]

#: candidates that may be accepted more than once
REPEATABLE = ("extra_mode",)

#: free-form dependences along variables that no library effect models; a candidate that
#: explains clearly less than one of them is a proxy and is not accepted
OUT_OF_LIBRARY = ("gain_vs_time", "force_vs_time", "current_error_vs_current")

SIMULATION_NOTE = ("each seek (target change to next target change) simulated with DiscretePlant "
                   "from rest at its start (previous current held); the rigid-body position and "
                   "velocity are fitted by least squares at the start of every window of at most "
                   "10 ms inside the seek (linear nuisance parameters)")


@dataclass
class Step:
    """One candidate tried at one iteration (errors: validation RMS [track])."""

    effect: str
    params: dict
    evidence: str
    rms_before: float
    rms_after: float
    accepted: bool
    iteration: int = 0
    bic_drop: float = 0.0
    fit_percent_after: float = float("nan")
    improved_fraction: float = float("nan")
    plant: ModalPlant | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        return {"effect": self.effect, "params": _jsonable(self.params), "evidence": self.evidence,
                "rms_before": float(self.rms_before), "rms_after": float(self.rms_after),
                "accepted": bool(self.accepted)}


@dataclass
class LoopResult:
    """Outcome of :func:`close_loop`; :meth:`report` is the JSON report."""

    plant: ModalPlant
    model: ModalPlant
    error_before: dict
    error_after: dict
    steps: list
    unexplained: list
    res_before: Residual
    res_after: Residual
    fit: Data
    val: Data
    analysis_before: dict
    analysis_after: dict
    runtime_s: float
    notes: list = field(default_factory=list)

    @property
    def accepted(self) -> list:
        """Accepted effects in order of first acceptance (those still in the final plant: a linear
        effect with its own states, e.g. an extra mode, is re-estimated by a kept re-identification
        as part of the linear plant)."""
        have = {e.name for e in self.plant.effects}
        return list(dict.fromkeys(s.effect for s in self.steps if s.accepted and s.effect in have))

    def report(self) -> dict:
        """The JSON report: ``plant`` (ModalPlant JSON, accepted effects included),
        ``error_before``/``error_after`` (validation RMS [track], fit [%]), ``steps``,
        ``unexplained``."""
        plant = _jsonable(self.plant.to_dict())
        return {"plant": plant, "error_before": self.error_before, "error_after": self.error_after,
                "steps": [s.to_dict() for s in self.steps], "unexplained": list(self.unexplained)}


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return x


# ----------------------------------------------------------------------- evaluation
def _harmonic_nuisance(res: Residual, plant: ModalPlant) -> np.ndarray:
    """For a separate validation log: the periodic disturbance's phase at the log start is
    unknown, so its cos/sin coefficients are re-estimated on one half of the windows and
    applied to the other (2-fold, halves in time) -- the error stays out of sample."""
    from identification.model.effects import PeriodicDisturbance
    pd = [e for e in plant.effects if isinstance(e, PeriodicDisturbance)]
    if not pd:
        return res.e
    t = res.log.time_s
    idx = res.windows.index()
    cols = []
    for e in pd:
        for h in e.harmonics:
            ph = 2 * np.pi * h * e.spindle_hz * t[idx]
            cols += [np.cos(ph), np.sin(ph)]
    X = np.column_stack(cols)
    half = np.zeros(len(idx), bool)
    half[:len(idx) // 2] = True
    e = res.e.copy()
    for a, b in ((half, ~half), (~half, half)):
        th = lstsq(res.e[a], X[a])[0]
        e[b] = res.e[b] - X[b] @ th
    return e


def evaluate(plant: ModalPlant, data: Data, same_log: bool = True, record: bool = False) -> Residual:
    """Reference residual of ``plant`` on ``data`` (per-seek simulation).  On a log other than
    the fit log, output effects (periodic disturbance) are re-phased out of sample."""
    if same_log:
        return simulate(plant, data.log, data.windows, continuous=False, record=record)
    keep = [e for e in plant.effects if e.kind != "output"]
    res = simulate(plant.copy(effects=keep), data.log, data.windows, continuous=False, record=record)
    return Residual(res.windows, _harmonic_nuisance(res, plant), res.y_sim, res.log, res.cmd, res.force)


def improved_fraction(new: Residual, old: Residual) -> float:
    """Fraction of validation seeks whose squared error the new model lowers [-]."""
    def per_seek(r):
        out, i = {}, 0
        for (a, b), g in zip(r.windows.bounds, r.windows.groups):
            out[g] = out.get(g, 0.0) + float(r.e[i:i + b - a] @ r.e[i:i + b - a])
            i += b - a
        return out
    n, o = per_seek(new), per_seek(old)
    return float(np.mean([n[g] < o[g] for g in n]))


def errors(res: Residual) -> dict:
    """``{"rms_track", "fit_percent"}`` of a residual."""
    return {"rms_track": float(res.rms), "fit_percent": float(res.fit_percent)}


# ------------------------------------------------------------------------------ loop
def _backfit(name: str, plant: ModalPlant, fit: Data, val: Data, same: bool, cur_val: Residual,
             it: int, why: str):
    """Re-fit the (last) accepted effect ``name`` with the others in place; a Step if the
    validation error drops, else None."""
    idx = [i for i, e in enumerate(plant.effects) if e.name == name]
    if not idx:
        return None, None
    base = plant.copy(effects=[e for i, e in enumerate(plant.effects) if i != idx[-1]])
    try:
        F = fit_candidate(name, base, fit.freeze(base, evaluate(base, fit, record=True)))
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None, None
    if F is None:
        return None, None
    rv = evaluate(F.plant, val, same, record=True)
    if rv.rms >= cur_val.rms:
        return None, None
    st = Step(name, F.params, f"re-fitted {why} (backfitting)", cur_val.rms, rv.rms, True, it,
              float("nan"), rv.fit_percent, improved_fraction(rv, cur_val), F.plant)
    return st, (evaluate(F.plant, fit, record=True), rv)



# ----------------------------------------------------------------- re-identification
_SUBSTEP = re.compile(r"current_sub\d+_a")


def _n_states(plant: ModalPlant) -> int:
    return plant.state_space()[0].shape[0]


def reidentified(plant: ModalPlant) -> tuple:
    """``(kept, absorbed)`` effects of ``plant`` when its linear part is identified again.

    An effect that adds states of its own to the linear dynamics (an amplifier lag, an extra
    mode) is part of what the identification estimates (delay and modes): absorbed.  Every
    other effect is kept and compensated in the data by :func:`compensate`: ``input``,
    ``force`` and ``output`` effects, pure delays, and structural effects that change the
    rigid body's own dynamics (a pivot spring), which the identification cannot represent."""
    n0 = _n_states(plant.copy(effects=[]))
    kept, absorbed = [], []
    for e in plant.effects:
        own = e.kind == "structural" and _n_states(plant.copy(effects=[e])) > n0
        (absorbed if own else kept).append(e)
    return kept, absorbed


def compensate(plant: ModalPlant, log: SeekLog, res: Residual | None = None) -> SeekLog:
    """The log as the linear part of ``plant`` (rigid body, modes, bias, delay ``plant.delay_s``:
    what :func:`identification.estimate.identify.identify` models) sees it, given its effects.

    Every current column (``current_a`` and the sub-step columns of a multirate log) is mapped
    through the ``input`` effects at the measured position (``DiscretePlant.command``) and
    delayed by the extra delay of the ``input_delay`` effects; the current-equivalent of the
    state-dependent forces beyond the constant bias (``DiscretePlant.net_force`` minus
    ``bias_a``, plus the terms structural effects add to the rigid body's row of
    ``ModalPlant.state_space``, e.g. the pivot's stiffness and damping), advanced by
    ``plant.delay_s`` (it enters undelayed), is added; ``output`` effects are subtracted from the
    position.  Effects are evaluated on the measured position and on the rigid-body velocity
    of the reference simulation ``res`` (``simulate(..., record=True)`` of ``plant``, which
    reproduces the model's own sticking in dwell) where it ran, else on the velocity estimated
    from the position."""
    dp = plant.discretize(log.dt)
    t = log.time_s
    y = log.position_track - sum((e.output(t) for e in plant.effects if e.kind == "output"), np.zeros(log.n))
    v = velocity_estimate(log)
    if res is not None and res.state is not None:
        v = np.where(np.isfinite(res.state[:, 1]), res.state[:, 1], v)
    A = plant.state_space()[0]
    f = np.array([dp.net_force(a, b) for a, b in zip(y, v)]) - plant.bias_a + (A[1, 0] * y + A[1, 1] * v) / plant.k0
    k = np.arange(log.n, dtype=float)
    f = np.interp(k + plant.delay_s / log.dt, k, f)
    extra_delay = (plant.total_delay_s - plant.delay_s) / log.dt

    def cur(u):
        c = np.array([dp.command(a, b) for a, b in zip(u, y)]) if dp._inputs else np.asarray(u, float)
        return (np.interp(k - extra_delay, k, c) if extra_delay else c) + f

    extra = {key: (cur(col) if _SUBSTEP.fullmatch(key) else col.copy()) for key, col in log.extra.items()}
    return SeekLog(t.copy(), cur(log.current_a), y, log.target_track.copy(), log.sample_rate_hz,
                   log.track_pitch_nm, dict(log.metadata), extra, log.source)


def _reidentify(current: ModalPlant, fit: Data, val: Data, same: bool, cur_fit: Residual, cur_val: Residual,
                it: int, rounds: int, say, notes: list):
    """Backfitting between the linear identification and the effects: identify the linear plant
    on the fit log compensated by ``current``'s effects (:func:`compensate`; with held-out seeks
    the identification fits the even seeks only, as the loop), put the kept effects on it and
    re-fit each of them (:func:`_backfit`); repeat while the validation RMS drops by > 1 %.
    Returns ``(plant, fit residual, validation residual, steps, absorbed names)``; the input
    plant when no round lowers the validation RMS."""
    from identification.model.effects import effect_from_dict
    from identification.estimate.identify import identify
    kept, _ = reidentified(current)
    A0 = current.copy(effects=[]).state_space()[0]
    if not any(e.kind != "structural" or not np.array_equal(current.copy(effects=[e]).state_space()[0], A0)
               for e in kept):       # nothing to compensate (at most pure delays): the data are the same
        return current, cur_fit, cur_val, [], []
    log = fit.log
    best = (current, cur_fit, cur_val, [], [])
    plant = current
    whole = seek_windows(log)
    for r in range(rounds):
        tr = time.time()
        kept, absorbed = reidentified(plant)
        comp = compensate(plant, log, simulate(plant, log, whole, continuous=False, record=True))
        try:
            ident = identify(comp, method="robust", holdout_every=2 if same else 0)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            notes.append(f"iteration {it}: re-identification on the compensated log failed ({exc})")
            break
        new = ident.plant.copy(effects=[effect_from_dict(e.to_dict()) for e in kept])
        new.meta = dict(current.meta)
        rv = evaluate(new, val, same, record=True)
        rf, steps = None, []
        for name in dict.fromkeys(e.name for e in new.effects):
            st, fitted = _backfit(name, new, fit, val, same, rv, it, "after re-identification")
            if st is not None:
                steps.append(st)
                new, (rf, rv) = st.plant, fitted
        say(f"  re-identification round {r + 1}: validation rms {rv.rms:.4g} (was {best[2].rms:.4g}; "
            f"k0 {new.k0:.4g}, {len(new.modes)} modes, delay {1e6 * new.total_delay_s:.2f} us; "
            f"{time.time() - tr:.1f} s)")
        if rv.rms >= best[2].rms:
            break
        gain = 1 - rv.rms / best[2].rms
        best = (new, rf if rf is not None else evaluate(new, fit, record=True), rv, best[3] + steps,
                list(dict.fromkeys(best[4] + [e.name for e in absorbed])))
        plant = new
        if gain < 0.01:
            break
    return best


def split_data(log: SeekLog, validation: SeekLog | None = None):
    """Fit and validation :class:`Data` (held-out odd seeks when no validation log)."""
    w = seek_windows(log)
    if validation is not None:
        return Data(log, w), Data(validation, seek_windows(validation)), False
    if len(set(w.groups)) < 4:
        raise ValueError(f"{log.source or 'log'}: needs at least 4 seeks to hold some out "
                         f"(has {len(set(w.groups))}); give a validation log")
    fw, vw = w.split(2)
    return Data(log, fw), Data(log, vw), True


def close_loop(log: SeekLog, model: ModalPlant, validation: SeekLog | None = None,
               candidates=None, min_drop: float = 0.05, min_bic: float = 6.0, min_seeks: float = 0.6,
               proxy_margin: float = 0.05, max_steps: int = 6, reidentify: int = 3,
               verbose: bool = False) -> LoopResult:
    """Augment ``model`` with effects that the data support (see the module notes).

    Parameters
    ----------
    log : SeekLog
        Fit log (current [A] and position [track] only are used, with the targets for seeks).
    model : ModalPlant
        The identified plant (its own effects are kept).
    validation : SeekLog, optional
        Validation log; default: the odd-numbered seeks of ``log`` are held out.
    candidates : list of str, optional
        Names from :data:`CANDIDATES` (default all).
    min_drop : float
        Required relative drop of the validation RMS for an acceptance [-].
    min_bic : float
        Required BIC drop on the fit data.
    min_seeks : float
        Required fraction of validation seeks whose error the candidate lowers [-] (the RMS
        is dominated by the longest seeks; the improvement must be consistent).
    proxy_margin : float
        A candidate whose relative validation drop is smaller by more than this than that of
        a free-form correction along a variable outside the library (:data:`OUT_OF_LIBRARY`)
        is only a proxy for that structure and is not accepted [-].
    max_steps : int
        Maximum number of accepted effects.
    reidentify : int
        After each acceptance, at most this many rounds of backfitting between the linear
        identification (:func:`identification.estimate.identify.identify` on the fit log compensated by
        the accepted effects, :func:`compensate`) and the effects' re-fit; a round is kept only
        if it lowers the validation RMS (0: never re-identify).
    """
    t0 = time.time()
    names = list(candidates or CANDIDATES)
    fit, val, same = split_data(log, validation)
    say = print if verbose else (lambda *a, **k: None)
    res0 = evaluate(model, val, same, record=True)
    error_before = errors(res0)
    refit = refit_base(model, fit)       # k0, bias, mode gains re-estimated (output error, fit data)
    rv_base = evaluate(refit, val, same, record=True)
    base_refit = rv_base.rms < res0.rms  # kept only if it lowers the validation error
    current, cur_val = (refit, rv_base) if base_refit else (model, res0)
    notes = []
    cur_fit = evaluate(current, fit, record=True)
    n_eff = effective_n(cur_fit.e, fit)
    cur_bic = bic(cur_fit.e, fit, 0, n_eff)
    analysis_before = describe_residual(current, val.freeze(current, cur_val), cur_val)
    say(f"start: validation rms {cur_val.rms:.4g} track ({time.time() - t0:.1f} s)")
    steps, accepted, reids = [], [], []
    for it in range(1, max_steps + 1):
        fdata = fit.freeze(current, cur_fit)
        ev = evidence_lines(current, fdata, cur_fit)
        tried = []
        for name in names:
            if name in accepted and name not in REPEATABLE:
                continue
            tc = time.time()
            try:
                F = fit_candidate(name, current, fdata)
            except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
                say(f"  {name}: fit failed ({exc})")
                continue
            if F is None:
                say(f"  {name}: not applicable ({time.time() - tc:.1f} s)")
                continue
            rv = evaluate(F.plant, val, same, record=True)
            rf, drop = None, float("nan")
            if rv.rms <= (1 - min_drop) * cur_val.rms:      # information criterion on the fit data
                rf = evaluate(F.plant, fit, record=True)
                drop = cur_bic - bic(rf.e, fit, F.n_params, n_eff)
            st = Step(name, F.params, ev.get(name, ""), cur_val.rms, rv.rms, False, it, drop,
                      rv.fit_percent, improved_fraction(rv, cur_val), F.plant)
            tried.append((st, rf, rv))
            say(f"  {name}: val rms {rv.rms:.4g} ({100 * (1 - rv.rms / cur_val.rms):+.1f} %), "
                f"BIC drop {drop:.1f}, seeks improved {100 * st.improved_fraction:.0f} % "
                f"({time.time() - tc:.1f} s)")
        ok = [t for t in tried if t[1] is not None and t[0].bic_drop > min_bic
              and t[0].rms_after <= (1 - min_drop) * cur_val.rms and t[0].improved_fraction >= min_seeks]
        steps += [t[0] for t in tried]
        if ok:      # is the best one only a proxy for structure outside the library?
            best_drop = 1 - min(t[0].rms_after for t in ok) / cur_val.rms
            free = [d for d in dependence(current, fdata, val.freeze(current, cur_val), OUT_OF_LIBRARY)
                    if d.p < 1e-4 and d.val_drop > best_drop + proxy_margin]
            if free:
                notes.append(f"iteration {it}: the best candidate ({min(ok, key=lambda t: t[0].rms_after)[0].effect}, "
                             f"-{100 * best_drop:.0f} %) explains less than a free-form "
                             + ", ".join(f"{d.name} correction (-{100 * d.val_drop:.0f} %)" for d in free)
                             + ": taken as a proxy, not accepted")
                say("  " + notes[-1])
                break
        if not ok:
            break
        best, rf, rv = min(ok, key=lambda t: t[0].rms_after)
        best.accepted = True
        accepted.append(best.effect)
        current, cur_fit, cur_val = best.plant, rf, rv
        say(f"accepted {best.effect}: validation rms {rv.rms:.4g}")
        for old in accepted[:-1]:     # backfitting
            st, fitted = _backfit(old, current, fit, val, same, cur_val, it, f"after accepting {best.effect}")
            if st is not None:
                steps.append(st)
                current, cur_fit, cur_val = st.plant, fitted[0], fitted[1]
                say(f"  re-fitted {old}: validation rms {cur_val.rms:.4g}")
        if reidentify:
            before = cur_val.rms
            current, cur_fit, cur_val, rsteps, absorbed = _reidentify(current, fit, val, same, cur_fit, cur_val,
                                                                      it, reidentify, say, notes)
            if cur_val.rms < before:
                steps += rsteps
                accepted = [a for a in accepted if a not in absorbed]
                reids.append({"iteration": it, "rms_before": float(before), "rms_after": float(cur_val.rms),
                              "k0": float(current.k0), "modes_hz": [float(m.freq_hz) for m in current.modes],
                              "delay_s": float(current.delay_s), "absorbed": absorbed})
                notes.append(f"iteration {it}: linear plant re-identified on the log compensated by the accepted "
                             f"effects and the effects re-fitted: validation rms {before:.4g} -> {cur_val.rms:.4g}"
                             + (f" ({', '.join(absorbed)} re-estimated as part of the linear plant)" if absorbed else ""))
                say("  " + notes[-1])
        n_eff = effective_n(cur_fit.e, fit)
        cur_bic = bic(cur_fit.e, fit, 0, n_eff)
    plant = current.copy()
    plant.meta = dict(plant.meta, loop={
        "simulation": SIMULATION_NOTE,
        "validation": "validation log" if not same else "held-out odd seeks of the log",
        "base_refit": {"kept": bool(base_refit), "k0": float(refit.k0), "bias_a": float(refit.bias_a),
                       "rms_track": float(rv_base.rms)},
        "reidentified": reids,
        "accepted": accepted})
    fdata, vdata = fit.freeze(current, cur_fit), val.freeze(current, cur_val)
    analysis_after = describe_residual(current, vdata, cur_val)
    unexplained = unexplained_lines(current, fdata, vdata, cur_val, analysis_after)
    return LoopResult(plant, model, error_before, errors(cur_val), steps, unexplained, res0,
                      cur_val, fit, val, analysis_before, analysis_after, time.time() - t0, notes)
