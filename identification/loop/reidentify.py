"""Backfitting between the linear identification and the loop's effects: the linear plant identified
again on the log compensated by the effects (:func:`identification.loop.closing.close_loop`, step 3)."""
from __future__ import annotations

import time

import numpy as np

from identification.logs.seeklog import SeekLog
from identification.loop.compensate import compensate, reidentified
from identification.loop.fit_engine import Data, Fit
from identification.loop.residual import simulate
from identification.loop.settings import LoopSettings
from identification.loop.state import _backfit, _State, evaluate
from identification.loop.windows import seek_windows
from identification.model.plant import ModalPlant

__all__ = ["reidentified_meta"]


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
    ``st.reidentify_min_gain``.  Modes the identification adds are kept only where the fit data support
    them (:func:`_without_unsupported_modes`).  Returns ``(state, steps, absorbed names)``; the input state when
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
        new = _without_unsupported_modes(new, plant, fit, st, say)
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
    (:func:`_identified_again`).  That variant is the candidate only if the rate of its output
    error on the fit data (first difference within windows, :meth:`Windows.rate`: the lag's
    signature) is below both the fit on ``plant``'s linear part and ``plant`` identified again
    without the candidate (the control: the gain must come from the candidate, not from
    identifying again)."""
    new = _identified_again(F.plant, fit, same, st)
    if new is None:
        return F
    new = _without_unsupported_modes(new, F.plant, fit, st, say)

    def rate_sse(p):   # of the output error's rate, the lag's signature (Windows.rate), as the lag's fit
        return float(np.sum(fit.windows.rate(evaluate(p, fit).e)[0] ** 2))
    sse = {"new": rate_sse(new), "old": rate_sse(F.plant)}
    ctrl = _identified_again(plant, fit, same, st) if sse["new"] < sse["old"] else None
    sse["control"] = rate_sse(ctrl) if ctrl is not None else float("inf")
    n = max(fit.windows.rate(np.zeros(fit.n))[1].n_samples, 1)     # samples of the rate (one fewer per window)
    say(f"  {F.effect}: fit rate rms {np.sqrt(sse['old'] / n):.4g} on the identified linear part, "
        f"{np.sqrt(sse['new'] / n):.4g} with it identified again (identified again without it: "
        f"{np.sqrt(sse['control'] / n):.4g})")
    if sse["new"] >= min(sse["old"], sse["control"]):
        return F
    k = F.n_params + 3 * (len(new.modes) - len(F.plant.modes))
    return Fit(F.effect, new, k, dict(F.params, delay_s=float(new.delay_s), modes=len(new.modes)),
               (F.note + "; " if F.note else "") + "linear part identified again with it")


def _without_unsupported_modes(new: ModalPlant, ref: ModalPlant, fit: Data, st: LoopSettings, say,
                               tol: float = 0.03) -> ModalPlant:
    """``new`` (a linear part identified again) without the modes it adds to ``ref`` (none of ``ref``'s
    within ``tol`` relative frequency) that the fit data do not support: each is kept only if removing it
    raises the BIC of the output error's rate (:meth:`Windows.rate`, the signature the re-identification
    is judged on) by more than ``st.min_bic_drop`` beyond its 3 parameters -- the rule an added effect
    passes.  Measured on the 3 kHz amplifier-lag drive of ``studies/loop_to_design.py``: the log identified
    again with the lag brought in a 10.2 kHz mode at the damping bound (1e-4, gain 0.69; none in the truth;
    inside the NSS controller's notches, where the log cannot see it), and the drive's loop with it was
    unstable (|z| 1.0013), so no design could start from the plant the loop wrote."""
    from identification.loop.stats import bic, effective_n
    f0 = np.array([m.freq_hz for m in ref.modes]) if ref.modes else np.array([np.inf])
    added = [m for m in new.modes if np.min(np.abs(np.log(m.freq_hz / f0))) > tol]
    if not added:
        return new
    r, w = fit.windows.rate(evaluate(new, fit).e)
    n = effective_n(r, w)
    for m in added:
        trial = new.copy(modes=[x for x in new.modes if x is not m])
        r_wo = fit.windows.rate(evaluate(trial, fit).e)[0]
        drop = bic(r_wo, 0, n) - bic(r, 3, n)
        if drop <= st.min_bic_drop:
            say(f"  identified again: the added mode {m.freq_hz:.0f} Hz (zeta {m.zeta:.2g}, gain {m.gain:.3g}) "
                f"lowers the rate BIC by {drop:.3g} only: not kept")
            new, r = trial, r_wo
    return new


def _same_data(a: SeekLog, b: SeekLog, current_a: float = 1e-5, position_track: float = 2e-3) -> bool:
    """Two compensated logs an identification cannot tell apart: currents within ``current_a`` [A]
    (a tenth of the benchmark's force noise per sample) and positions within ``position_track``
    [track] (a tenth of its sensor noise) everywhere."""
    return (float(np.max(np.abs(a.input_current() - b.input_current()))) < current_a
            and float(np.max(np.abs(a.position_track - b.position_track))) < position_track)
