"""The demo's report: one section per stage of :func:`seekopt.app.demo.run_demo`, from its
:class:`~seekopt.app.demo.DemoResult` (nothing is read back from disk), written by
:func:`seekopt.app.report.write_report` as ``report.md`` and a self-contained ``report.html``."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from seekopt.app.report import (COMPARE_DEFINITION, KIND_LABELS, compare_fit, markdown_table,
                                plot_frequency_response, savings_table, write_report)

__all__ = ["demo_report", "demo_summary", "fit_summary", "current_explanation"]

_BENCH_KIND = {"sine": "sine", "windowed_sine": "windowed_sine", "sine tuned": "sine_tuned",
               "windowed_sine tuned": "windowed_sine_tuned", "optimal": "optimal"}


def demo_summary(result):
    """One row per (seek length, profile): seek time and seek-settle time [ms] on the identified
    (design) plant and on the evaluation plant of the bench."""
    import pandas as pd
    rows = []
    for res in result.bench.results:
        for r in res.rows:
            kind = _BENCH_KIND.get(r.label, r.label)
            rows.append({"tracks": res.tracks, "profile": KIND_LABELS.get(kind, kind),
                         "seek [ms]": 1e3 * r.profile.n / r.profile.sample_rate_hz if r.profile else np.nan,
                         "seek-settle, model [ms]": 1e3 * result.bench.model_settle_s.get((res.tracks, r.label), np.nan),
                         f"seek-settle, {result.bench.evaluated_on} [ms]":
                             1e3 * r.settle_time_s if r.settled else np.nan})
    return pd.DataFrame(rows).round(3)


def fit_summary(fits) -> dict:
    """Median, quartiles and the count of negative per-window fits [%] (:func:`compare_fit`)."""
    f = fits["fit_percent"].to_numpy(float)
    f = f[np.isfinite(f)]
    if not f.size:
        return {"windows": 0}
    return {"windows": int(f.size), "median": float(np.median(f)), "q25": float(np.percentile(f, 25)),
            "q75": float(np.percentile(f, 75)), "negative": int((f < 0).sum())}


def _negative_words(fits) -> str:
    neg = fits[fits["fit_percent"] < 0]
    if not len(neg):
        return ""
    pes, err = np.median(neg.pes_rms_track), np.median(neg.error_rms_track)
    trend = np.median(neg.error_trend_rms_track)
    text = (f" {len(neg)} of {len(fits)} windows have a negative fit: in them the settled PES varies by "
            f"{pes:.3g} track RMS (median) about its mean while the model's error is {err:.3g} track RMS, so the "
            "simulation predicts the window worse than the window's own mean would.")
    if trend >= 0.5 * err:
        text += (f" Most of that error ({trend:.3g} track RMS) is a straight line, an offset plus a drift: the "
                 "seek-anchored simulation is not corrected after the seek, and the unlogged force noise integrated "
                 "twice by the rigid body during the seek leaves a position offset and velocity the model of the "
                 "current cannot know. The residual vibration after settling is small against that offset, so a "
                 "negative fit here means little deterministic response is left to predict, not that the model diverges.")
    else:
        text += (f" The error is not mainly an offset or drift (straight-line part {trend:.3g} track RMS): "
                 "the model misses part of the settling response in these windows.")
    return text


def current_explanation(result) -> str:
    """A sentence on why the optimal current looks as it does, from the bench traces of the shown length
    (only the claims the numbers support)."""
    from seekopt.design.metrics import simulate_profile
    from seekopt.evaluate.bench import mode_response
    res = next((r for r in result.bench.results if r.tracks == 1000), result.bench.results[len(result.bench.results) // 2])
    plant = result.truth or result.loop.design_plant
    fs = float(result.controller.sample_rate_hz)
    modes = plant.all_modes()
    if not modes:
        return ""
    mode = min(modes, key=lambda m: abs(m.freq_hz - 1738.0))
    stats = {}
    for r in res.rows:
        if r.profile is None or r.label not in ("optimal", "sine"):
            continue
        sim = simulate_profile(plant, result.controller, r.profile, horizon_s=r.profile.n / fs + 0.004)
        n = r.profile.seek_samples
        u = np.asarray(r.profile.current_a[:n], float)
        y = mode_response(plant, mode, sim.current_a + plant.bias_a, fs)
        stats[r.label] = {"at_limit": float(np.mean(np.abs(u) >= 0.9 * res.imax)), "peak": float(np.max(np.abs(u))),
                          "jump": float(np.max(np.abs(np.diff(u)))) if n > 1 else 0.0,
                          "in_seek": float(np.max(np.abs(y[:n]))), "after": float(np.max(np.abs(y[n:])))}
    o, s = stats.get("optimal"), stats.get("sine")
    if not o or not s:
        return ""
    text = f"Why the optimal current looks as it does ({res.tracks:g}-track seek): "
    if o["at_limit"] >= 0.05:
        text += (f"the optimiser drives the feedforward within 10 % of the current limit for "
                 f"{100 * o['at_limit']:.0f} % of the seek samples (peak {o['peak']:.3g} A, Imax {res.imax:g} A): "
                 "a shorter seek needs the full Imax wherever the settle-band constraints allow it")
    else:
        text += (f"the feedforward peaks at {o['peak']:.3g} A and is within 10 % of Imax ({res.imax:g} A) for only "
                 f"{100 * o['at_limit']:.0f} % of the seek samples: at this length the "
                 "settle-band constraints (the seek-induced modes' response must stay small), not the current "
                 "limit, set the seek time")
    text += (f"; its largest sample-to-sample step is {o['jump']:.3g} A (the sine's {s['jump']:.3g} A): the "
             "current is shaped sample by sample, not a smooth pulse.")
    if o["after"] < 0.5 * s["after"]:
        text += (" The shaping leaves the seek-induced modes nearly at rest when the seek ends: the "
                 f"{mode.freq_hz:.0f} Hz mode moves up to {o['in_seek']:.3g} track during the seek "
                 f"(sine: {s['in_seek']:.3g}) but only {o['after']:.3g} track after it (sine: {s['after']:.3g}), "
                 "which is what lets the PES enter the band sooner.")
    else:
        text += (f" The {mode.freq_hz:.0f} Hz mode's residual vibration after the seek is {o['after']:.3g} track "
                 f"(sine: {s['after']:.3g}): at this length the optimal profile does not win by cancelling that mode.")
    return text


def _pipeline(result) -> str:
    import pandas as pd
    from seekopt import __version__
    cfg, log = result.config, result.log
    rows = [{"stage": s[0], "status": s[1], "wall [s]": s[2], "CPU [s]": s[4], "note": s[3]} for s in result.stages]
    rows[-1]["wall [s]"], rows[-1]["CPU [s]"], rows[-1]["note"] = float("nan"), float("nan"), "(this report)"
    return (f"seekopt {__version__}; log `{cfg.log or 'bundled sample_log.npz'}`, {log.n} samples at "
            f"{log.sample_rate_hz:g} Hz; controller `{result.controller.name}`; Imax {cfg.imax:g} A; settle band "
            f"±{cfg.settle:g} track. CPU [s] is this process's; with the sweep's workers the run used "
            f"{result.cpu_s:.0f} s CPU before the report.\n\n" + markdown_table(pd.DataFrame(rows), fmt=".1f"))


def _modes(plant):
    import pandas as pd
    return pd.DataFrame([{"freq [Hz]": m.freq_hz, "zeta": m.zeta, "gain": m.gain} for m in plant.modes],
                        columns=["freq [Hz]", "zeta", "gain"])


def _identified(result, figs: Path):
    from identification.estimate.figures import fig5_transfer_functions
    ids, truth = result.identify, result.truth
    p = ids.plant
    text = (f"k0 = {p.k0:.5g} track/(A s²) (physical gain {p.physical_gain:.4g} m/(A s²)), bias {p.bias_a:.3g} A, "
            f"delay {1e6 * p.delay_s:.2f} µs, {len(p.modes)} modes (method {ids.ident.method}):\n\n"
            + markdown_table(_modes(p), fmt=".4g"))
    if ids.warning:
        text += f"\n**Warning**: {ids.warning}\n"
    if truth is not None:
        text += (f"\nTruth of the synthetic drive: k0 = {truth.k0:.5g}, bias {truth.bias_a:.3g} A, "
                 f"{len(truth.modes)} modes:\n\n" + markdown_table(_modes(truth), fmt=".4g"))
    fit = fit_summary(compare_fit(result.loop.result.res_before, result.config.settle))
    if fit["windows"]:
        text += (f"\nValidation fit of this model (the loop's {fit['windows']} held-out seeks): median "
                 f"{fit['median']:.1f} % per settle window (quartiles {fit['q25']:.1f} … {fit['q75']:.1f} %); "
                 "definition under *Closing the loop*.\n")
    text += ("\nFig. 5 shows each mode's transfer function k0·g/(s²+2ζωs+ω²) against the rigid body, so the "
             "seek-induced low-frequency modes are visible; the second figure is the whole plant's frequency "
             "response, magnitude and phase (delay included).\n")
    f5 = fig5_transfer_functions(ids.ident, truth)
    figs.mkdir(parents=True, exist_ok=True)
    f5.savefig(figs / "fig5_tf.png", dpi=110)
    import matplotlib.pyplot as plt
    plt.close(f5)
    curves = {"identified": p, "after closing the loop": result.loop.design_plant}
    if truth is not None:
        curves["truth (synthetic drive)"] = truth
    return text, [figs / "fig5_tf.png", plot_frequency_response(curves, figs / "plant_frf.png")]


def _loop(result) -> str:
    import pandas as pd
    lp, cfg = result.loop, result.config
    res = lp.result
    before, after = compare_fit(res.res_before, cfg.settle), compare_fit(res.res_after, cfg.settle)
    fb, fa = fit_summary(before), fit_summary(after)
    text = (f"`close_loop` on {lp.seeks} seeks (even seeks fit, odd seeks validate). Validation RMS "
            f"error {res.error_before['rms_track']:.4g} → {res.error_after['rms_track']:.4g} track.\n\n"
            + COMPARE_DEFINITION + "\n\n")
    if fb["windows"] and fa["windows"]:
        rows = [{"model": name, "windows": f["windows"], "median fit [%]": f["median"], "25 % [%]": f["q25"],
                 "75 % [%]": f["q75"], "negative": f["negative"]} for name, f in (("identified", fb), ("augmented", fa))]
        text += markdown_table(pd.DataFrame(rows), fmt=".1f") + _negative_words(after) + "\n"
    acc = [e for e in res.plant.effects if e.name in res.accepted]
    text += "\nAccepted effects (one row per effect in the final plant):\n\n"
    if acc:
        rows = []
        for e in acc:
            st = [s for s in res.steps if s.accepted and s.effect == e.name]
            params = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                               for k, v in e.params.items() if not isinstance(v, list))
            rows.append({"effect": e.name, "parameters": params[:90],
                         "validation RMS before [track]": st[0].rms_before if st else np.nan,
                         "after [track]": st[-1].rms_after if st else np.nan})
        text += markdown_table(pd.DataFrame(rows), fmt=".4g")
    else:
        text += "none.\n"
    if lp.dropped:
        text += (f"\nOutput effects ({', '.join(lp.dropped)}) are kept in `plant.json` but left out of the design and "
                 "bench plant: settle metrics are disturbance-free, as on the truth plant.\n")
    if len(res.plant.modes) != len(result.identify.plant.modes):
        text += (f"\nThe loop re-identified the linear plant: {len(res.plant.modes)} modes after it "
                 f"({len(result.identify.plant.modes)} identified).\n")
    tried, seen = [], set()
    for s in res.steps:
        outcome = "no" if not s.accepted else "re-fit" if s.effect in seen else "accepted"
        seen |= {s.effect} if s.accepted else set()
        tried.append({"iteration": s.iteration, "candidate": s.effect, "validation RMS before": s.rms_before,
                      "after": s.rms_after, "BIC drop": s.bic_drop, "outcome": outcome})
    if tried:
        text += ("\nEvery step of the loop (re-fit: an effect accepted earlier re-estimated after a later acceptance "
                 "or a re-identification of the linear plant, not a new effect; BIC drop – : not computed, the "
                 "candidate did not lower the validation RMS by the required 5 %, or a re-fit):\n\n"
                 + markdown_table(pd.DataFrame(tried), fmt=".4g"))
    if res.unexplained:
        text += "\nStill in the residual:\n\n" + "\n".join(f"- {u}" for u in res.unexplained) + "\n"
    return text


def _bench(result):
    b = result.bench
    L = next((r.tracks for r in b.results if r.tracks == 1000), b.results[len(b.results) // 2].tracks)
    text = ("Seek-settle time [ms] (seek start until the error stays within the band) of the optimal design "
            "(robust, on the identified plant after closing the loop) against the shortest-within-Imax sine and "
            "windowed sine and their best-length variants, on the identified plant and on the "
            f"{b.evaluated_on} plant; – : not settled.\n\n" + markdown_table(demo_summary(result), fmt=".3g")
            + f"\nTraces of the {L:g}-track seek on the {b.evaluated_on} plant (time axis to the last "
            "settling):\n\n" + current_explanation(result) + "\n")
    return text, [b.figure] if b.figure else []


def _sweep(result):
    sw = result.sweep
    sv = savings_table(sw.table)
    cols = [c for c in ("tpi", "tracks", "optimal_ms", "sine_tuned_ms", "windowed_sine_tuned_ms",
                        "saving_vs_best_pct") if c in sv]
    heads = {"tpi": "TPI", "tracks": "tracks", "optimal_ms": "optimal [ms]", "sine_tuned_ms": "sine, best T [ms]",
             "windowed_sine_tuned_ms": "windowed sine, best T [ms]", "saving_vs_best_pct": "saved vs best [%]"}
    return ("The design plant re-expressed per TPI (physical gain kept, controller gain scaled with the track "
            f"pitch, settle band in tracks). {sw.summary.total} cells, {len(sw.summary.failed_cells)} failed; "
            "every column in `sweep/results.csv`.\n\n"
            + markdown_table(sv, columns=cols, headers=[heads[c] for c in cols], fmt=".3g"), sw.summary.figures)


def demo_report(result, out) -> Path:
    """Write ``report.md`` and the self-contained ``report.html`` of a demo run into ``out``."""
    out = Path(out)
    ex = result.export
    text, figs = _identified(result, out / "figures")
    sections = [("Pipeline", _pipeline(result), []), ("Identified plant", text, figs),
                ("Closing the loop", _loop(result), []), ("Bench: optimal vs sine and windowed sine", *_bench(result)),
                ("TPI sweep", *_sweep(result)),
                ("Firmware export", f"{len(ex.tables.tables)} tables; feedforward {ex.tables.meta['ff_format']}; "
                 f"reference {ex.tables.meta['ref_format']}. Files: "
                 + ", ".join(f"`{Path(p).relative_to(out)}`" for p in ex.paths), [])]
    return write_report(out, "seekopt demo report", sections, html_too=result.config.html)
