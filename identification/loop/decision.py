"""The loop's decision: does a fitted candidate pass, and is it only a proxy?

A candidate effect is accepted (:func:`passes`) when its output-error BIC on the fit data drops,
its validation RMS drops and most validation seeks improve (a re-parameterisation with fewer
parameters must only not be worse); it is refused as a proxy (:func:`proxy_for`) when a
free-form correction along a variable no library effect models explains clearly more and the
candidate adds nothing on top of it.  Thresholds: :class:`identification.loop.settings.LoopSettings`.
Units: track (validation RMS), nats (BIC).
"""
from __future__ import annotations

from identification.loop.evidence import dependence
from identification.loop.fit_engine import Data
from identification.loop.result import Step
from identification.loop.settings import LoopSettings

__all__ = ["OUT_OF_LIBRARY", "passes", "proxy_for", "rank", "validates"]

#: free-form dependences along variables that no library effect models; a candidate that
#: explains clearly less than one of them is a proxy and is not accepted
OUT_OF_LIBRARY = ("gain_vs_time", "force_vs_time", "current_error_vs_current")


def proxy_for(best, cur, fit: Data, val: Data, st: LoopSettings) -> list:
    """The free-form corrections along variables outside the library (:data:`OUT_OF_LIBRARY`)
    that make the candidate ``best`` (``(Step, fit residual, validation residual)``) a proxy.

    A free-form correction is flexible: on a log with several effects it can take up more of the
    misfit than any one library effect does, the real one included.  So a correction that lowers
    the validation RMS by more than ``st.proxy_margin`` beyond the candidate's drop makes it a
    proxy only if the candidate adds nothing to it: with the same correction fitted on top of
    the candidate, the validation RMS must not fall more than ``st.proxy_margin`` below the
    correction's alone (the candidate explains structure the free form does not)."""
    step, rf, rv = best
    best_drop = 1 - step.rms_after / cur.val.rms
    free = [d for d in dependence(cur.plant, fit.freeze(cur.plant, cur.fit), val.freeze(cur.plant, cur.val),
                                  OUT_OF_LIBRARY)
            if d.p < st.unexplained_p and d.val_drop > best_drop + st.proxy_margin]
    if not free or rf is None:
        return free
    on_top = {d.name: d for d in dependence(step.plant, fit.freeze(step.plant, rf), val.freeze(step.plant, rv),
                                            [d.name for d in free])}
    return [d for d in free
            if rv.rms * (1 - max(on_top[d.name].val_drop, 0.0)) > (1 - st.proxy_margin) * cur.val.rms * (1 - d.val_drop)]


def passes(step: Step, cur, st: LoopSettings) -> bool:
    """Does the candidate ``step`` (tried on the current state ``cur``) pass the acceptance rules
    of :class:`LoopSettings` (BIC drop, validation drop, seeks improved; see the module notes)?

    An added effect passes on the output error itself or on its rate (first difference within
    each window, :meth:`identification.loop.windows.Windows.rate`): the same three rules on the
    rate (its BIC on the fit data, its validation RMS, the seeks whose rate error drops), with the
    output error's validation RMS not risen by more than ``max_level_rise_on_rate``.  The RMS of
    the output error is dominated by the force noise the rigid body integrates twice; an
    amplifier lag that an identification absorbed as extra delay and bent mode gains changes
    it by 0.3 % on the combination drive of ``studies/loop_to_design.py`` but its rate by 17 %,
    and it is what the design needs (designed without it a K = 10 seek settles 3.4x later)."""
    if step.n_params <= 0:        # a re-parameterisation with fewer parameters: no worse
        return step.bic_drop > st.min_bic_drop and step.rms_after <= cur.val.rms
    return _on_level(step, cur, st) or _on_rate(step, cur, st)


def rank(step: Step, cur, st: LoopSettings) -> tuple:
    """Order of passing candidates: those passing on the output error first, by its BIC drop;
    then those passing on its rate only, by the rate's BIC drop (:func:`passes`)."""
    if step.n_params <= 0 or _on_level(step, cur, st):
        return (1, step.bic_drop)
    return (0, step.rate_bic_drop)


def validates(n_params: int, rms0: float, rms1: float, rate0: float, rate1: float, st: LoopSettings) -> bool:
    """The validation part of :func:`passes`, on the validation RMS of the output error (``rms0`` before,
    ``rms1`` with the candidate) and of its rate (``rate0``, ``rate1``): the candidate may pass at all
    (the loop computes the BIC on the fit data only for those)."""
    return _level_validates(n_params, rms0, rms1, st) or _rate_validates(n_params, rms0, rms1, rate0, rate1, st)


def _level_validates(n_params, rms0, rms1, st: LoopSettings) -> bool:
    return rms1 <= (1.0 if n_params <= 0 else 1.0 - st.min_validation_drop) * rms0


def _rate_validates(n_params, rms0, rms1, rate0, rate1, st: LoopSettings) -> bool:
    return (n_params > 0 and rate1 <= (1.0 - st.min_validation_drop) * rate0
            and rms1 <= (1.0 + st.max_level_rise_on_rate) * rms0)


def _on_level(step: Step, cur, st: LoopSettings) -> bool:
    return (step.bic_drop > st.min_bic_drop and _level_validates(step.n_params, cur.val.rms, step.rms_after, st)
            and step.improved_fraction >= st.min_improved_seeks)


def _on_rate(step: Step, cur, st: LoopSettings) -> bool:
    return (step.rate_bic_drop > st.min_bic_drop
            and _rate_validates(step.n_params, cur.val.rms, step.rms_after, step.rate_before, step.rate_after, st)
            and step.rate_improved_fraction >= st.min_improved_seeks)
