"""Closing the loop: residual analysis, candidate effects, re-fit and decision.

:func:`close_loop` takes a seek log and a plant (identified, or given) and:

1. splits the data: fit on the log, validate on ``validation`` (another log) or, by default,
   on held-out seeks (odd-numbered seeks validate, even ones fit);
2. simulates the model per seek (:func:`identification.loop.residual.simulate`, ``DiscretePlant``
   from rest at each seek start, re-anchored every window) and analyses the residual;
3. fits every candidate of :data:`identification.loop.candidates.CANDIDATES` on the fit data
   (jointly with ``k0``, ``bias_a``, the declared modes' gains and the linear parameters of the
   effects already accepted), simulates it, and accepts, among those that pass, the one with
   the largest BIC drop, a candidate passing if (a) its BIC on the fit data (output error on an effective sample size) drops by more
   than ``settings.min_bic_drop``, (b) its validation RMS drops by ``min_validation_drop`` --
   or, for a re-parameterisation with fewer parameters (an amplifier lag in place of extra
   delay and a damped "mode"), does not rise -- (c) it lowers the error of at least
   ``min_improved_seeks`` of the validation seeks (additions) and (d) no free-form correction
   along a variable outside the library does clearly better (else it is a proxy); earlier
   accepted effects are then re-fitted (backfitting) and the linear plant is re-identified on
   the log compensated by the effects (:mod:`identification.loop.compensate`); when the plant
   has friction (whose force only its own simulation reproduces, so the fast fits are
   co-adapted with one simulation's sticking) the base and all accepted effects are then
   re-fitted together by simulation (:mod:`identification.loop.joint`), kept if the validation
   RMS drops;
4. repeats greedily until no candidate passes, then lists in ``unexplained`` the structure
   that is still in the validation residual.

Every reported error is on validation data, from the reference simulation.  The thresholds
are the named, unit-bearing fields of :class:`LoopSettings`.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from identification.logs.seeklog import SeekLog
from identification.loop.candidates import CANDIDATES, fit_candidate
from identification.loop.compensate import compensate, reidentified
from identification.loop.evidence import describe_residual, evidence_lines, unexplained_lines
from identification.loop.decision import OUT_OF_LIBRARY, passes, proxy_for, rank, validates
from identification.loop.fit_engine import Data, Fit, refit_base
from identification.loop.joint import held_base, needs_joint_refit
from identification.loop.reidentify import _relinearised, _reidentify, reidentified_meta
from identification.loop.residual import Residual
from identification.loop.result import LoopResult, Step, errors, improved_fraction
from identification.loop.settings import LoopSettings
from identification.loop.split import inside_groups, settled_range, split_data
from identification.loop.state import _backfit, _joint, _State, evaluate
from identification.loop.stats import bic
from identification.model.plant import ModalPlant

__all__ = ["LoopSettings", "LoopResult", "Step", "close_loop", "evaluate", "split_data", "REPEATABLE",
           "OUT_OF_LIBRARY", "compensate", "reidentified", "reidentified_meta", "errors", "improved_fraction",
           "settled_range", "inside_groups"]

#: candidates that may be accepted more than once
REPEATABLE = ("extra_mode",)

#: candidates whose absence the identification absorbs into the linear part: also tried with the
#: linear part identified again on the log compensated by them (:func:`_relinearised`)
RELINEARISED = ("amplifier_lag",)

#: effects that depend on the head's position (defined on the positions they were fitted on)
POSITION_EFFECTS = ("position_bias", "torque_constant_variation", "pivot_spring_damper")



def _protocol(settings: LoopSettings) -> str:
    return (f"each seek (target change to next target change) simulated with DiscretePlant from rest at its start "
            f"(previous current held), at the drive's sub-step with the logged sub-step currents and state-dependent "
            f"effects evaluated every <= {1e6 * settings.effect_step_s:g} us; the rigid-body position and velocity are "
            f"fitted by least squares at the start of every window of at most {1e3 * settings.window_s:g} ms inside "
            f"the seek (linear nuisance parameters)")


def _outside(model: ModalPlant, plant: ModalPlant, out: Data | None, same: bool, rng) -> dict:
    """Validation RMS [track] on the validation seeks left out (outside ``rng``), before and after."""
    if out is None:
        return {"position_range_track": list(rng), "seeks": 0, "rms_before_track": None, "rms_after_track": None}
    return {"position_range_track": list(rng), "seeks": int(out.windows.n_groups),
            "rms_before_track": float(evaluate(model, out, same).rms),
            "rms_after_track": float(evaluate(plant, out, same).rms)}


# ------------------------------------------------------------------------------ loop
def _with_table_refitted(F: Fit, rv: Residual, fit: Data, val: Data, same: bool, st: LoopSettings, say):
    """A candidate is fitted with an accepted position-bias table held (the table is re-fitted
    by its own penalised fit, not jointly: :meth:`Engine.base_cols`).  A table fitted before
    the candidate was in the model has absorbed what of it is a function of position -- on a
    log with Kt(p) and a flex-cable bias the table fitted first takes part of Kt(p) times the
    seek current, and the Kt candidate on top of it then improves too few validation seeks to
    pass.  So the candidate is scored with the table re-fitted on top of it (one backfitting
    pass) when that lowers its validation RMS.  Returns ``(Fit, validation residual)``."""
    idx = [i for i, e in enumerate(F.plant.effects) if e.name == "position_bias"]
    if F.effect == "position_bias" or not idx:
        return F, rv
    base = F.plant.copy(effects=[e for i, e in enumerate(F.plant.effects) if i != idx[-1]])
    try:
        T = fit_candidate("position_bias", base, fit.freeze(base, evaluate(base, fit, record=True)), st)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return F, rv
    if T is None:
        return F, rv
    rt = evaluate(T.plant, val, same, record=True)
    if rt.rms >= rv.rms:
        return F, rv
    say(f"  {F.effect}: with the position-bias table re-fitted on top: val rms {rv.rms:.4g} -> {rt.rms:.4g}")
    note = (F.note + "; " if F.note else "") + "scored with the position-bias table re-fitted on top of it"
    return Fit(F.effect, T.plant, F.n_params, F.params, note), rt


def _try_candidates(names, accepted, cur: _State, fit: Data, val: Data, same: bool, it: int,
                    st: LoopSettings, say) -> list:
    """Fit and score every candidate on top of the current plant: ``[(Step, fit residual)]``."""
    fdata = fit.freeze(cur.plant, cur.fit)
    ev = evidence_lines(cur.plant, fdata, cur.fit)
    tried = []
    for name in names:
        if name in accepted and name not in REPEATABLE:
            continue
        tc = time.time()
        try:
            F = fit_candidate(name, cur.plant, fdata, st)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            say(f"  {name}: fit failed ({exc})")
            continue
        if F is None:
            say(f"  {name}: not applicable ({time.time() - tc:.1f} s)")
            continue
        if needs_joint_refit(cur.plant):
            F = held_base(F, cur.plant, fit)
        if name in RELINEARISED:
            F = _relinearised(F, cur.plant, fit, same, st, say)
        rv = evaluate(F.plant, val, same, record=True)
        if rv.rms < cur.val.rms:
            F, rv = _with_table_refitted(F, rv, fit, val, same, st, say)
        rf, drop, rdrop = None, float("nan"), float("nan")
        rate0, rate1 = cur.val.rate_rms, rv.rate_rms
        if validates(F.n_params, cur.val.rms, rv.rms, rate0, rate1, st):     # information criteria on the fit data
            rf = evaluate(F.plant, fit, record=True)
            drop = cur.bic - bic(rf.e, F.n_params, cur.n_eff)
            rdrop = cur.bic_rate - bic(fit.windows.rate(rf.e)[0], F.n_params, cur.n_eff_rate)
        step = Step(name, F.params, ev.get(name, ""), cur.val.rms, rv.rms, False, it, drop,
                    rv.fit_percent, improved_fraction(rv, cur.val), F.n_params, F.note, F.plant,
                    rate0, rate1, rdrop, improved_fraction(rv, cur.val, rate=True))
        tried.append((step, rf, rv))
        say(f"  {name}: val rms {rv.rms:.4g} ({100 * (1 - rv.rms / cur.val.rms):+.1f} %), "
            f"BIC drop {drop:.1f}, {F.n_params:+.3g} parameters, seeks improved {100 * step.improved_fraction:.0f} %; "
            f"rate {rate1:.4g} ({100 * (1 - rate1 / rate0):+.1f} %), BIC drop {rdrop:.1f}, seeks improved "
            f"{100 * step.rate_improved_fraction:.0f} % ({time.time() - tc:.1f} s)")
    return tried


def close_loop(log: SeekLog, model: ModalPlant, validation: SeekLog | None = None,
               settings: LoopSettings | None = None, progress=None, verbose: bool = False) -> LoopResult:
    """Augment ``model`` with effects that the data support (see the module notes).

    Parameters
    ----------
    log : SeekLog
        Fit log (current [A], sub-step currents of a multirate drive, position [track] and
        the targets for seeks).
    model : ModalPlant
        The plant to start from (identified or given; its own effects are kept).
    validation : SeekLog, optional
        Validation log; default: the odd-numbered seeks of ``log`` are held out.
    settings : LoopSettings, optional
        Thresholds and simulation protocol.
    progress : callable, optional
        Called with one line per stage (with its elapsed time).
    verbose : bool
        Also report every candidate tried (through ``progress``, default ``print``).
    """
    st = settings or LoopSettings()
    t0 = time.time()
    tell = progress or (print if verbose else (lambda *a, **k: None))
    say = tell if verbose else (lambda *a, **k: None)
    stage_s = {}

    def stage(name, t_start, msg):
        stage_s[name] = stage_s.get(name, 0.0) + time.time() - t_start
        tell(f"loop: {msg} ({time.time() - t_start:.1f} s)")

    names = list(st.candidates or CANDIDATES)
    unknown = [n for n in names if n not in CANDIDATES]
    if unknown:
        raise ValueError(f"unknown candidate(s) {unknown}; known: {sorted(CANDIDATES)}")
    ts = time.time()
    fit, val, same, out = split_data(log, validation, st, outside=True)
    res0 = evaluate(model, val, same, record=True)
    refit = refit_base(model, fit)       # k0, bias, mode gains re-estimated (output error, fit data)
    rv_base = evaluate(refit, val, same, record=True)
    base_refit = rv_base.rms < res0.rms  # kept only if it lowers the validation error
    plant0, v0 = (refit, rv_base) if base_refit else (model, res0)
    cur = _State(plant0, evaluate(plant0, fit, record=True), v0).rescore(fit)
    analysis_before = describe_residual(cur.plant, val.freeze(cur.plant, cur.val), cur.val, st)
    stage("baseline", ts, f"baseline: validation rms {res0.rms:.4g} track, after the k0/bias re-fit {cur.val.rms:.4g}")
    steps, accepted, reids, notes = [], [], [], []
    for it in range(1, st.max_effects + 1):
        ts = time.time()
        tried = _try_candidates(names, accepted, cur, fit, val, same, it, st, say)
        steps += [t[0] for t in tried]
        ok = [t for t in tried if passes(t[0], cur, st)]
        if ok:      # is the best one only a proxy for structure outside the library?
            free = proxy_for(min(ok, key=lambda t: t[0].rms_after), cur, fit, val, st)
            if free:
                best_drop = 1 - min(t[0].rms_after for t in ok) / cur.val.rms
                notes.append(f"iteration {it}: the best candidate ({min(ok, key=lambda t: t[0].rms_after)[0].effect}, "
                             f"-{100 * best_drop:.0f} %) explains less than a free-form "
                             + ", ".join(f"{d.name} correction (-{100 * d.val_drop:.0f} %)" for d in free)
                             + ": taken as a proxy, not accepted")
                say("  " + notes[-1])
                ok = []
        if not ok:
            stage("candidates", ts, f"iteration {it}: {len(tried)} candidates fitted, none accepted")
            break
        best, rf, rv = max(ok, key=lambda t: rank(t[0], cur, st))     # the BIC on the fit data (of the level, then the rate)
        best.accepted = True
        accepted.append(best.effect)
        before = cur.val.rms
        cur = _State(best.plant, rf, rv)
        for old in accepted[:-1]:     # backfitting
            s, cur = _backfit(old, cur, fit, val, same, it, f"after accepting {best.effect}", st)
            if s is not None:
                steps.append(s)
        stage("candidates", ts, f"iteration {it}: {len(tried)} candidates fitted, accepted {best.effect}: "
                                f"validation rms {before:.4g} -> {cur.val.rms:.4g}")
        if st.reidentify_rounds:
            ts = time.time()
            prev = cur.val.rms
            cur, rsteps, absorbed = _reidentify(cur, fit, val, same, it, st, say, notes)
            if cur.val.rms < prev:
                steps += rsteps
                accepted = [a for a in accepted if a not in absorbed]
                reids.append({"iteration": it, "rms_before": float(prev), "rms_after": float(cur.val.rms),
                              "k0": float(cur.plant.k0), "modes_hz": [float(m.freq_hz) for m in cur.plant.modes],
                              "delay_s": float(cur.plant.delay_s), "absorbed": absorbed})
                notes.append(f"iteration {it}: linear plant re-identified on the log compensated by the accepted "
                             f"effects and the effects re-fitted: validation rms {prev:.4g} -> {cur.val.rms:.4g}"
                             + (f" ({', '.join(absorbed)} re-estimated as part of the linear plant)" if absorbed else ""))
            stage("reidentify", ts, f"iteration {it}: re-identification: validation rms {prev:.4g} -> {cur.val.rms:.4g}")
        if st.joint_iters and needs_joint_refit(cur.plant):
            ts = time.time()
            prev = cur.val.rms
            s, cur = _joint(cur, fit, val, same, it, st, say)
            if s is not None:
                steps.append(s)
            stage("joint", ts, f"iteration {it}: joint output-error refit by simulation: validation rms {prev:.4g} -> "
                               f"{cur.val.rms:.4g}")
        cur.rescore(fit)
    ts = time.time()
    # the positions the fit log settled on: position-dependent effects are pinned there by the
    # dwell (a seek only passes the positions beyond them); a seek may start and end inside
    pos = settled_range(fit.log, fit.windows)
    plant = cur.plant.copy()
    plant.meta = dict(plant.meta, log=Path(log.source).name if log.source else None,
                      position_range_track=[pos[0], pos[1]],
                      closed_loop={"accepted": list(dict.fromkeys(e.name for e in plant.effects
                                                                  if e.name in accepted)),
                                   "validation_rms_track": [float(res0.rms), float(cur.val.rms)]})
    info = {"simulation": _protocol(st),
            "validation": "validation log" if not same else "held-out odd seeks of the log",
            "base_refit": {"kept": bool(base_refit), "k0": float(refit.k0), "bias_a": float(refit.bias_a),
                           "rms_track": float(rv_base.rms)},
            "validation_outside_range": _outside(model, cur.plant, out, same, pos),
            "reidentified": reids, "accepted": accepted, "substeps": fit.grid.L, "effect_evaluations": fit.grid.M}
    vo = info["validation_outside_range"]
    n_in = len(inside_groups(val.log, val.windows, *pos))
    if out is None and n_in < val.windows.n_groups:
        notes.append(f"only {n_in} of {val.windows.n_groups} validation seeks stay inside the positions the fit log "
                     f"settled on ({pos[0]:.0f}..{pos[1]:.0f} track): all are used, so a position-dependent effect is "
                     f"judged where it can only be extrapolated; give a validation log over the same positions")
    if vo["seeks"]:
        notes.append(f"{vo['seeks']} validation seek(s) leave the positions the fit log settled on "
                     f"({vo['position_range_track'][0]:.0f}..{vo['position_range_track'][1]:.0f} track; the plant is "
                     f"defined there) and are not used: validation rms there {vo['rms_before_track']:.4g} -> "
                     f"{vo['rms_after_track']:.4g} track"
                     + (" (position-dependent effects extrapolated)" if any(e.name in POSITION_EFFECTS
                                                                            for e in cur.plant.effects) else ""))
    fdata, vdata = fit.freeze(cur.plant, cur.fit), val.freeze(cur.plant, cur.val)
    analysis_after = describe_residual(cur.plant, vdata, cur.val, st)
    unexplained = unexplained_lines(cur.plant, fdata, vdata, cur.val, analysis_after, st)
    stage("analysis", ts, f"residual analysis: {len(unexplained)} unexplained item(s)")
    return LoopResult(plant, model, errors(res0), errors(cur.val), steps, unexplained, res0, cur.val, fit, val,
                      analysis_before, analysis_after, time.time() - t0, notes, info, st, stage_s)
