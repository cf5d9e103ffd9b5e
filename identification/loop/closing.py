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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from identification.logs.seeklog import SeekLog
from identification.loop.candidates import CANDIDATES, fit_candidate
from identification.loop.compensate import compensate, reidentified
from identification.loop.evidence import describe_residual, evidence_lines, unexplained_lines
from identification.loop.decision import OUT_OF_LIBRARY, passes, proxy_for
from identification.loop.fit_engine import Data, Fit, refit_base
from identification.loop.joint import held_base, joint_refit, needs_joint_refit
from identification.loop.residual import Residual, simulate
from identification.loop.result import LoopResult, Step, errors, improved_fraction
from identification.loop.settings import LoopSettings
from identification.loop.split import inside_groups, settled_range, split_data
from identification.loop.stats import bic, effective_n, lstsq
from identification.loop.windows import seek_windows
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
        return simulate(plant, data.log, data.windows, continuous=False, record=record, grid=data.grid,
                        cache=data.cache)
    keep = [e for e in plant.effects if e.kind != "output"]
    res = simulate(plant.copy(effects=keep), data.log, data.windows, continuous=False, record=record,
                   grid=data.grid, cache=data.cache)
    return Residual(res.windows, _harmonic_nuisance(res, plant), res.y_sim, res.log, res.cmd, res.force, res.state)


# ------------------------------------------------------------------------------ state
@dataclass
class _State:
    """The current model and its residuals (fit and validation) with the fit data's BIC."""

    plant: ModalPlant
    fit: Residual
    val: Residual
    n_eff: float = 0.0
    bic: float = 0.0

    def rescore(self, fit: Data) -> "_State":
        self.n_eff = effective_n(self.fit.e, fit.windows)
        self.bic = bic(self.fit.e, 0, self.n_eff)
        return self


def _backfit(name: str, cur: _State, fit: Data, val: Data, same: bool, it: int, why: str, st: LoopSettings):
    """Re-fit the (last) accepted effect ``name`` with the others in place; ``(Step, new state)``
    if the validation error drops, else ``(None, cur)``."""
    plant = cur.plant
    idx = [i for i, e in enumerate(plant.effects) if e.name == name]
    if not idx:
        return None, cur
    base = plant.copy(effects=[e for i, e in enumerate(plant.effects) if i != idx[-1]])
    try:
        F = fit_candidate(name, base, fit.freeze(base, evaluate(base, fit, record=True)), st)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None, cur
    if F is None:
        return None, cur
    rv = evaluate(F.plant, val, same, record=True)
    if rv.rms >= cur.val.rms:
        return None, cur
    step = Step(name, F.params, f"re-fitted {why} (backfitting)", cur.val.rms, rv.rms, True, it,
                float("nan"), rv.fit_percent, improved_fraction(rv, cur.val), 0, F.note, F.plant)
    return step, _State(F.plant, evaluate(F.plant, fit, record=True), rv)


def _joint(cur: _State, fit: Data, val: Data, same: bool, it: int, st: LoopSettings, say):
    """Joint output-error refit by simulation of the base and every accepted effect
    (:func:`identification.loop.joint.joint_refit`); ``(Step, new state)`` if the validation
    error drops, else ``(None, cur)``."""
    p = joint_refit(cur.plant, fit, st.joint_table_knots, st.joint_iters, progress=say)
    if p is cur.plant:
        return None, cur
    rv = evaluate(p, val, same, record=True)
    if rv.rms >= cur.val.rms:
        say(f"  joint refit: validation rms {rv.rms:.4g} (not below {cur.val.rms:.4g}): not kept")
        return None, cur
    step = Step("joint_refit", {}, "accepted effects and base re-fitted together by simulation", cur.val.rms, rv.rms,
                True, it, float("nan"), rv.fit_percent, improved_fraction(rv, cur.val), 0,
                "Levenberg-Marquardt on the output error of DiscretePlant simulations", p)
    return step, _State(p, evaluate(p, fit, record=True), rv)


def reidentified_meta(previous: dict, identification: dict) -> dict:
    """``meta`` of a plant identified again: the previous plant's entries (its source, the user's
    notes) with what the new identification says about the plant it produced (method, held-out fit,
    and the blind bands and detectable-gain curve, :data:`identification.estimate.blind.BLIND_KEYS`)
    in place of the previous identification's.  Blind bands belong to the plant they were computed
    for: next to a mode that plant has, a band is narrow; a re-identified plant that lacks the mode
    (e.g. one in a controller notch that the fewer, compensated seeks do not reveal) needs the wide
    band its own identification found, or the designer's guard trusts a mode that is not modelled."""
    from identification.estimate.blind import BLIND_KEYS
    meta = {k: v for k, v in (previous or {}).items() if k not in BLIND_KEYS}
    meta.update({k: v for k, v in (identification or {}).items() if k != "log"})
    return meta


def _reidentify(cur: _State, fit: Data, val: Data, same: bool, it: int, st: LoopSettings, say, notes: list):
    """Backfitting between the linear identification and the effects: identify the linear plant
    on the fit log compensated by the current effects (:func:`compensate`; with held-out seeks
    the identification fits the even seeks only, as the loop), put the kept effects on it and
    re-fit each of them (:func:`_backfit`); repeat while the validation RMS drops by more than
    ``st.reidentify_min_gain``.  Returns ``(state, steps, absorbed names)``; the input state when
    no round lowers the validation RMS."""
    from identification.estimate.identify import identify
    from identification.model.effects import effect_from_dict
    kept, _ = reidentified(cur.plant)
    A0 = cur.plant.copy(effects=[]).state_space()[0]
    if not any(e.kind != "structural" or e.name == "amplifier_lag"
               or not np.array_equal(cur.plant.copy(effects=[e]).state_space()[0], A0) for e in kept):
        return cur, [], []       # nothing to compensate (at most pure delays): the data are the same
    best, steps_all, absorbed_all = cur, [], []
    plant = cur.plant
    whole = seek_windows(fit.log, st.window_s, st.min_window_samples)
    prev = None
    for r in range(st.reidentify_rounds):
        tr = time.time()
        kept, absorbed = reidentified(plant)
        comp = compensate(plant, fit.log, simulate(plant, fit.log, whole, continuous=False, record=True,
                                                   grid=fit.grid, cache=fit.cache), st.effect_step_s)
        if prev is not None and _same_data(prev, comp):
            say(f"  re-identification round {r + 1}: the compensated log is the previous round's: converged")
            break
        prev = comp
        try:
            ident = identify(comp, method="robust", holdout_every=2 if same else 0)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            notes.append(f"iteration {it}: re-identification on the compensated log failed ({exc})")
            break
        new = ident.plant.copy(effects=[effect_from_dict(e.to_dict()) for e in kept],
                               meta=reidentified_meta(cur.plant.meta, ident.plant.meta))
        state = _State(new, None, evaluate(new, val, same, record=True))
        steps = []
        for name in dict.fromkeys(e.name for e in new.effects):
            s, state2 = _backfit(name, state, fit, val, same, it, "after re-identification", st)
            if s is not None:
                steps.append(s)
                state = state2
        say(f"  re-identification round {r + 1}: validation rms {state.val.rms:.4g} (was {best.val.rms:.4g}; "
            f"k0 {state.plant.k0:.4g}, {len(state.plant.modes)} modes, delay {1e6 * state.plant.total_delay_s:.2f} us; "
            f"{time.time() - tr:.1f} s)")
        if state.val.rms >= best.val.rms:
            break
        gain = 1 - state.val.rms / best.val.rms
        if state.fit is None:
            state.fit = evaluate(state.plant, fit, record=True)
        best, steps_all = state, steps_all + steps
        absorbed_all = list(dict.fromkeys(absorbed_all + [e.name for e in absorbed]))
        plant = state.plant
        if gain < st.reidentify_min_gain:
            break
    return best, steps_all, absorbed_all


def _identified_again(plant: ModalPlant, fit: Data, same: bool, st: LoopSettings):
    """``plant``'s effects on a linear part identified again on the fit log compensated by them
    (one round of :func:`_reidentify`), or None if that identification fails."""
    from identification.estimate.identify import identify
    from identification.model.effects import effect_from_dict
    kept, _ = reidentified(plant)
    whole = seek_windows(fit.log, st.window_s, st.min_window_samples)
    try:
        comp = compensate(plant, fit.log, simulate(plant, fit.log, whole, continuous=False, record=True,
                                                   grid=fit.grid, cache=fit.cache), st.effect_step_s)
        ident = identify(comp, method="robust", holdout_every=2 if same else 0)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None
    return ident.plant.copy(effects=[effect_from_dict(e.to_dict()) for e in kept],
                            meta=reidentified_meta(plant.meta, ident.plant.meta))


def _relinearised(F, plant: ModalPlant, fit: Data, same: bool, st: LoopSettings, say):
    """A candidate whose absence the identification absorbed into the linear part (an amplifier
    lag: extra delay and a damped "mode", with the other modes bent around them): its fit on
    that linear part ``plant`` is also tried with the linear part identified again with it
    (:func:`_identified_again`).  That variant is the candidate only if its output error on the
    fit data is below both the fit on ``plant``'s linear part and ``plant`` identified again
    without the candidate (the control: the gain must come from the candidate, not from
    identifying again)."""
    new = _identified_again(F.plant, fit, same, st)
    if new is None:
        return F
    sse = {k: float(np.sum(evaluate(p, fit).e ** 2)) for k, p in (("new", new), ("old", F.plant))}
    ctrl = _identified_again(plant, fit, same, st) if sse["new"] < sse["old"] else None
    sse["control"] = float(np.sum(evaluate(ctrl, fit).e ** 2)) if ctrl is not None else float("inf")
    n = fit.n
    say(f"  {F.effect}: fit rms {np.sqrt(sse['old'] / n):.4g} on the identified linear part, "
        f"{np.sqrt(sse['new'] / n):.4g} with it identified again (identified again without it: "
        f"{np.sqrt(sse['control'] / n):.4g})")
    if sse["new"] >= min(sse["old"], sse["control"]):
        return F
    k = F.n_params + 3 * (len(new.modes) - len(F.plant.modes))
    return Fit(F.effect, new, k, dict(F.params, delay_s=float(new.delay_s), modes=len(new.modes)),
               (F.note + "; " if F.note else "") + "linear part identified again with it")


def _same_data(a: SeekLog, b: SeekLog, current_a: float = 1e-5, position_track: float = 2e-3) -> bool:
    """Two compensated logs an identification cannot tell apart: currents within ``current_a`` [A]
    (a tenth of the benchmark's force noise per sample) and positions within ``position_track``
    [track] (a tenth of its sensor noise) everywhere."""
    return (float(np.max(np.abs(a.input_current() - b.input_current()))) < current_a
            and float(np.max(np.abs(a.position_track - b.position_track))) < position_track)


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
        rf, drop = None, float("nan")
        need = 1.0 if F.n_params <= 0 else 1.0 - st.min_validation_drop
        if rv.rms <= need * cur.val.rms:       # information criterion on the fit data
            rf = evaluate(F.plant, fit, record=True)
            drop = cur.bic - bic(rf.e, F.n_params, cur.n_eff)
        step = Step(name, F.params, ev.get(name, ""), cur.val.rms, rv.rms, False, it, drop,
                    rv.fit_percent, improved_fraction(rv, cur.val), F.n_params, F.note, F.plant)
        tried.append((step, rf, rv))
        say(f"  {name}: val rms {rv.rms:.4g} ({100 * (1 - rv.rms / cur.val.rms):+.1f} %), "
            f"BIC drop {drop:.1f}, {F.n_params:+.3g} parameters, seeks improved {100 * step.improved_fraction:.0f} % "
            f"({time.time() - tc:.1f} s)")
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
        best, rf, rv = max(ok, key=lambda t: t[0].bic_drop)     # one criterion for all: the BIC on the fit data
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
