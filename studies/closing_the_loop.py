"""Study: closing the loop on synthetic logs with undeclared effects.

For each case (each library effect at a random, seeded strength; a clean log; the
benchmark's RRO; two effects; effects outside the library) a log is synthesised,
the loop (:func:`identification.loop.closing.close_loop`) is run on it with held-out
seeks as validation, and the table of validation RMS / fit % before and after,
accepted effects and parameter errors is written, with the Markdown report and
figures per case::

    python studies/closing_the_loop.py [--model standin|identify] [--seeks 80] [--jobs 2]
        [--cases friction,clean,...] [--out docs/loop_study] [--refresh]

``--model standin`` (default): the truth plant without the undeclared effect,
slightly perturbed (k0 +-0.2 %, mode frequencies +-0.3 %, damping +-5 %, gains
+-3 %, bias +-0.1 mA).  ``--model identify``: ``identify(log, method="robust").plant``
as ``seekopt loop`` does (cached per case in ``<out>/identify/<case>/identified_plant.json``;
the identification sees every seek of the log, the loop fits on the even seeks only and
every reported error is on the odd, held-out seeks).  ``rms_truth`` is the validation RMS
of the truth plant (undeclared effects included): the floor no model can beat.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from identification.loop.closing import close_loop, evaluate  # noqa: E402
from identification.model.effects import Effect  # noqa: E402
from identification.loop.figures import FIGURES, figures  # noqa: E402
from identification.loop.report import markdown  # noqa: E402
from identification.model.plant import Mode, atomic_write_text  # noqa: E402
from seekopt.drive.presets import default_truth_plant  # noqa: E402
from seekopt.evaluate.synth import SynthConfig, synthesize  # noqa: E402

FULL_FIGURES = ("friction", "rro", "dead_zone")   #: cases with every figure; others: residual_seeks.png only
EFFECTS = ["input_delay", "amplifier_lag", "pivot_spring_damper", "position_bias", "friction",
           "torque_constant_variation", "current_saturation", "periodic_disturbance", "extra_mode"]
OTHER = ["clean", "rro", "two", "dead_zone", "time_varying_gain"]


# --------------------------------------------------------------- effect generator
def random_effect(name: str, rng: np.random.Generator, imax_a: float = 0.3,
                  stroke=(0.0, 60000.0), declared_hz=()) -> dict:
    """One effect at a random strength from physically plausible ranges [SI-ish units:
    s, Hz, A, track].  The ranges are the study's choice, not the synthetic drive's defaults;
    position-dependent effects are drawn over ``stroke``, the range the seeks visit.  A
    position-bias table is redrawn until it departs from a straight line by >= 0.3 mA (a
    linear table is exactly a pivot spring and is reported as one).  An extra mode is kept
    >= 15 % away from the declared modes ``declared_hz`` (closer, it is a misfit of that mode)."""
    lo, hi = stroke
    span = hi - lo
    u = rng.uniform
    if name == "input_delay":
        p = {"delay_s": u(3e-6, 15e-6)}
    elif name == "amplifier_lag":
        p = {"bandwidth_hz": u(2000.0, 10000.0)}
    elif name == "pivot_spring_damper":
        p = {"freq_hz": u(2.0, 10.0), "zeta": u(0.1, 0.5), "rest_track": lo + span * u(0.2, 0.8)}
    elif name == "position_bias":
        k = int(rng.integers(4, 7))
        x = np.linspace(lo, hi, k)
        while True:
            b = u(-1.5e-3, 1.5e-3, k)
            if np.max(np.abs(b - np.polyval(np.polyfit(x, b, 1), x))) >= 0.3e-3:
                break
        p = {"knots_track": list(x), "bias_a": list(b)}
    elif name == "friction":
        p = {"coulomb_a": u(0.5e-3, 3e-3), "viscous_a_per_tps": u(0.0, 3e-9)}
    elif name == "torque_constant_variation":
        p = {"coeffs": [float(rng.choice([-1, 1]) * u(0.02, 0.08)), u(-0.02, 0.02)],
             "center_track": lo + span * u(0.3, 0.7), "scale_track": span * u(0.15, 0.5)}
    elif name == "current_saturation":
        p = {"limit_a": imax_a * u(0.75, 0.95)}
    elif name == "periodic_disturbance":
        amp = u(0.2, 0.5)
        ph = u(0, 2 * np.pi, 2)
        a = np.array([amp, amp * u(0.2, 0.6)])
        p = {"spindle_hz": u(60.0, 200.0), "harmonics": [1, 2], "cos_track": list(a * np.cos(ph)),
             "sin_track": list(a * np.sin(ph))}
    elif name == "extra_mode":
        z = u(0.01, 0.08)
        while True:
            f = float(np.exp(u(np.log(300.0), np.log(3000.0))))
            if all(abs(f / d - 1) > 0.15 for d in declared_hz):
                break
        p = {"freq_hz": f, "zeta": z,
             "gain": float(rng.choice([-1, 1]) * 2 * z * u(0.3, 0.8))}
    else:
        raise ValueError(name)
    return {"effect": name, "params": {k: (float(v) if np.isscalar(v) else [float(x) for x in v])
                                       for k, v in p.items()}}


@dataclass
class DeadZone(Effect):
    """Test-only effect outside the library: the amplifier delivers nothing below ``width_a``."""

    width_a: float
    name: ClassVar[str] = "dead_zone"
    kind: ClassVar[str] = "input"

    def input_map(self, u, position):
        return float(np.sign(u) * max(abs(u) - self.width_a, 0.0))


def standin_model(truth_base, seed: int):
    """The truth without undeclared effects, slightly perturbed (the 'identified' model)."""
    rng = np.random.default_rng(seed + 99991)
    n = rng.standard_normal
    modes = [Mode(m.freq_hz * (1 + 0.003 * n()), m.zeta * (1 + 0.05 * n()), m.gain * (1 + 0.03 * n()))
             for m in truth_base.modes]
    return truth_base.copy(k0=truth_base.k0 * (1 + 0.002 * n()), modes=modes,
                           bias_a=truth_base.bias_a + 1e-4 * n(), effects=[])


def visited_range(cfg: SynthConfig, base) -> tuple:
    """Range of seek targets [track] of a synthetic schedule (5..95 % of them)."""
    from seekopt.drive.controller import Controller
    from seekopt.evaluate.synth import schedule_seeks
    seeks, _ = schedule_seeks(cfg, base.k0, Controller.nss().sample_rate_hz)
    t = np.array([s.to_track for s in seeks] + [seeks[0].from_track])
    return float(np.quantile(t, 0.05)), float(np.quantile(t, 0.95))


def make_case(case: str, seed: int, n_seeks: int):
    """(log, truth, declared effects [dicts], model base plant) of one study case."""
    rng = np.random.default_rng(seed)
    base = default_truth_plant()
    rro = case == "rro"
    vis = visited_range(SynthConfig(n_seeks=n_seeks, seed=seed), base)
    for _ in range(8):   # the synthetic drive's PID has no anti-windup: redraw if its loop diverged
        if case in EFFECTS:
            effs = [random_effect(case, rng, stroke=vis, declared_hz=[m.freq_hz for m in base.modes])]
        elif case == "two":
            effs = [random_effect("friction", rng, stroke=vis),
                    random_effect("torque_constant_variation", rng, stroke=vis)]
        elif case == "dead_zone":
            effs = [DeadZone(float(rng.uniform(1e-3, 4e-3)))]
        else:
            effs = []
        log, truth = synthesize(SynthConfig(n_seeks=n_seeks, seed=seed, rro=rro, effects=effs))
        if np.max(np.abs(log.current_a)) < 3 * 0.3 and np.max(np.abs(log.pes)) < 1e5:
            break
    if case == "time_varying_gain":     # +-2..6 % drift over the log, added open loop (post-processing)
        g = rng.choice([-1, 1]) * rng.uniform(0.02, 0.06) * (log.time_s - log.time_s[0]) / log.time_s[-1]
        log.position_track = log.position_track + truth.copy(bias_a=0.0).simulate_open_loop(
            g * log.current_a, log.dt, history_a=0.0)
        effs = [{"effect": "time_varying_gain", "params": {"drift": float(g[-1])}}]
    return log, truth, [e if isinstance(e, dict) else {"effect": e.name, "params": e.params} for e in effs], base


# ---------------------------------------------------------------- parameter error
def _visited(log):
    return np.quantile(log.position_track, np.linspace(0.05, 0.95, 41))


def param_error(name: str, truth, plant, log) -> dict:
    """Error of the fitted effect against the truth, in physical terms (see the docs).

    The input delay is compared as the total delay of the model and an extra mode as the
    model's mode nearest the truth (declared or added): an identification may already hold
    them.  Other effects: the accepted effect (``{}`` when none was accepted)."""
    te = next((e for e in truth.effects if e.name == name), None)
    if te is None:
        return {}
    # effects the declared model can hold by itself (identification may have absorbed them)
    if name == "input_delay":
        return {"delay_error_us": 1e6 * (plant.total_delay_s - truth.total_delay_s)}
    if name == "extra_mode":
        fe = min(plant.all_modes(), key=lambda m: abs(math.log(m.freq_hz / te.freq_hz)))
        if abs(fe.freq_hz / te.freq_hz - 1) < 0.1:
            return {"freq_rel_error": fe.freq_hz / te.freq_hz - 1, "gain_rel_error": fe.gain / te.gain - 1}
        return {}
    fe = [e for e in plant.effects if e.name == name]
    if not fe:
        return {}
    fe = fe[-1]
    if name == "amplifier_lag":
        return {"bandwidth_rel_error": fe.bandwidth_hz / te.bandwidth_hz - 1}
    if name == "pivot_spring_damper":
        return {"freq_rel_error": fe.freq_hz / te.freq_hz - 1, "zeta_error": fe.zeta - te.zeta}
    if name == "position_bias":
        p = _visited(log)
        err = (plant.bias_a + np.interp(p, fe.knots_track, fe.bias_a)) - (truth.bias_a + np.interp(p, te.knots_track, te.bias_a))
        return {"bias_max_error_mA": 1e3 * float(np.max(np.abs(err)))}
    if name == "friction":
        return {"coulomb_rel_error": fe.coulomb_a / te.coulomb_a - 1,
                "viscous_error": fe.viscous_a_per_tps - te.viscous_a_per_tps}
    if name == "torque_constant_variation":
        p = _visited(log)
        g = plant.k0 * fe.factor(p) / (truth.k0 * te.factor(p)) - 1
        return {"gain_max_rel_error": float(np.max(np.abs(g)))}
    if name == "current_saturation":
        return {"limit_rel_error": fe.limit_a / te.limit_a - 1}
    if name == "periodic_disturbance":
        amp = lambda e, h: math.hypot(e.cos_track[e.harmonics.index(h)], e.sin_track[e.harmonics.index(h)]) \
            if h in e.harmonics else 0.0
        return {"spindle_error_hz": fe.spindle_hz - te.spindle_hz,
                "h1_amplitude_rel_error": amp(fe, 1) / amp(te, 1) - 1}
    return {}


# --------------------------------------------------------------------------- run
def identified_model(log, case: str, seed: int, n_seeks: int, out: Path | None = None):
    """``identify(log, method="robust").plant`` (as ``seekopt loop`` does) and its runtime [s].

    Cached as ``<out>/<case>/identified_plant.json`` (with the case, seed and number of
    seeks): identification takes 1-2 min per log and does not depend on the loop."""
    from identification.model.plant import ModalPlant
    path = None if out is None else out / case / "identified_plant.json"
    key = {"case": case, "seed": seed, "n_seeks": n_seeks}
    if path is not None and path.exists():
        d = json.loads(path.read_text())
        if d.get("key") == key:
            return ModalPlant.from_dict(d["plant"]), float(d["identify_s"])
    from identification.estimate.identify import identify
    t = time.time()
    m = identify(log, method="robust").plant
    t_id = time.time() - t
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps({"key": key, "identify_s": t_id, "plant": m.to_dict()}, indent=1,
                                           default=float))
    return m, t_id


def run_case(case: str, seed: int, n_seeks: int, model: str = "standin", out: Path | None = None) -> dict:
    log, truth, effs, base = make_case(case, seed, n_seeks)
    note = ""
    if model == "identify":
        try:
            m, t_id = identified_model(log, case, seed, n_seeks, out)
        except ValueError as exc:     # LogError: seekopt loop would stop here
            note = f"identify failed ({exc}); the loop ran from the stand-in model instead"
            m, t_id = standin_model(base, seed), 0.0
    else:
        m, t_id = standin_model(base, seed), 0.0
    R = close_loop(log, m)
    named = effs[0]["effect"] if effs else None
    floor = truth_rms(truth, R.val, case)
    row = {"case": case, "seed": seed, "model": model, "declared": effs, "rms_truth": floor,
           "accepted": R.accepted, "first": R.accepted[0] if R.accepted else None,
           "rms_before": R.error_before["rms_track"], "rms_after": R.error_after["rms_track"],
           "fit_before": R.error_before["fit_percent"], "fit_after": R.error_after["fit_percent"],
           "ratio": R.error_after["rms_track"] / R.error_before["rms_track"],
           "runtime_s": R.runtime_s, "identify_s": t_id, "unexplained": R.unexplained, "note": note,
           "notes": R.notes,
           "params": {e.name: e.params for e in R.plant.effects},
           "error": param_error(named, truth, R.plant, log) if named in EFFECTS else {}}
    if case == "two":
        row["error"] = {k: v for n in ("friction", "torque_constant_variation")
                        for k, v in param_error(n, truth, R.plant, log).items()}
    if out is not None:
        d = out / f"{case}"
        if case in FULL_FIGURES:
            figs = figures(R, d)
        else:
            d.mkdir(parents=True, exist_ok=True)
            FIGURES["residual_seeks.png"](R, d / "residual_seeks.png")
            figs = ["residual_seeks.png"]
        atomic_write_text(d / "loop_report.md", markdown(R, figs, "."))
        atomic_write_text(d / "report.json", json.dumps(R.report(), indent=2))
    return row


def table(rows) -> str:
    L = ["| case | declared (truth) | accepted (in order) | first = named | val RMS before [track] | after | "
         "after/before | truth model [track] | fit % before | after | parameter error | identify [s] | loop [s] |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        dec = "; ".join(f"{e['effect']}({', '.join(f'{k}={_short(v)}' for k, v in e['params'].items())})"
                        for e in r["declared"]) or "-"
        named = r["declared"][0]["effect"] if r["declared"] else None
        first = "-" if named not in EFFECTS and r["case"] != "two" else ("yes" if r["first"] == named or
                                                                        (r["case"] == "two" and r["first"]) else "no")
        err = ", ".join(f"{k}={v:+.3g}" for k, v in r["error"].items()) or "-"
        L.append(f"| {r['case']} | {dec} | {', '.join(r['accepted']) or 'none'} | {first} | {r['rms_before']:.4g} | "
                 f"{r['rms_after']:.4g} | {r['ratio']:.3f} | {r.get('rms_truth', float('nan')):.4g} | {r['fit_before']:.4f} | {r['fit_after']:.4f} | {err} | "
                 f"{r['identify_s']:.0f} | {r['runtime_s']:.0f} |")
    return "\n".join(L)


def _short(v):
    if isinstance(v, list):
        return "[" + ",".join(f"{x:.3g}" for x in v) + "]"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def truth_rms(truth, val, case: str) -> float:
    """Validation RMS [track] of the truth plant, undeclared effects included: the floor no
    model reaches (NaN where the truth is not a plant: a test-only effect, a drift added open loop)."""
    if case in ("time_varying_gain", "dead_zone"):
        return float("nan")
    from identification.model.effects import PeriodicDisturbance
    fs = val.log.sample_rate_hz       # the synthetic log's time starts preroll - 2 ms into the simulation
    t0 = (round(SynthConfig().preroll_s * fs) - round(0.002 * fs)) / fs
    effs = []
    for e in truth.effects:
        if isinstance(e, PeriodicDisturbance):   # the same disturbance on the log's time axis
            ph = [2 * np.pi * h * e.spindle_hz * t0 for h in e.harmonics]
            e = PeriodicDisturbance(e.spindle_hz, list(e.harmonics),
                                    [a * math.cos(p) + b * math.sin(p) for a, b, p in zip(e.cos_track, e.sin_track, ph)],
                                    [b * math.cos(p) - a * math.sin(p) for a, b, p in zip(e.cos_track, e.sin_track, ph)])
        effs.append(e)
    return evaluate(truth.copy(effects=effs), val, True).rms


def refresh(out: Path, n_seeks: int) -> list:
    """Recompute the truth-model RMS and the parameter errors of ``out/results.json`` from the
    saved ``report.json`` plants (after a change of :func:`param_error`; no loop is run)."""
    from identification.loop.closing import split_data
    from identification.model.plant import ModalPlant
    rows = json.loads((out / "results.json").read_text())
    for row in rows:
        case, seed = row["case"], row["seed"]
        log, truth, effs, base = make_case(case, seed, n_seeks)
        plant = ModalPlant.from_dict(json.loads((out / case / "report.json").read_text())["plant"])
        _, val, _ = split_data(log)
        row["rms_truth"] = truth_rms(truth, val, case)
        named = effs[0]["effect"] if effs else None
        row["error"] = param_error(named, truth, plant, log) if named in EFFECTS else {}
        if case == "two":
            row["error"] = {k: v for n in ("friction", "torque_constant_variation")
                            for k, v in param_error(n, truth, plant, log).items()}
    atomic_write_text(out / "results.json", json.dumps(rows, indent=1, default=float))
    atomic_write_text(out / "summary.md", table(rows) + "\n")
    return rows


def _run(args):
    case, seed, n_seeks, model, out = args
    t = time.time()
    row = run_case(case, seed, n_seeks, model, out)
    row["wall_s"] = time.time() - t
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", choices=["standin", "identify"], default="standin")
    ap.add_argument("--seeks", type=int, default=80)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--cases", default=",".join(EFFECTS + OTHER))
    ap.add_argument("--jobs", type=int, default=1, help="cases run in parallel processes")
    ap.add_argument("--out", default=str(ROOT / "docs" / "loop_study"))
    ap.add_argument("--refresh", action="store_true", help="only recompute truth RMS and parameter errors")
    a = ap.parse_args(argv)
    out = Path(a.out) / a.model
    if a.refresh:
        return refresh(out, a.seeks)
    cases = a.cases.split(",")
    jobs = [(c, a.seed + 17 * (EFFECTS + OTHER).index(c), a.seeks, a.model, out) for c in cases]
    rows = {}
    prev = json.loads((out / "results.json").read_text()) if (out / "results.json").exists() else []
    order = list(dict.fromkeys([r["case"] for r in prev] + cases))     # other cases' rows are kept
    if a.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        pool = ProcessPoolExecutor(a.jobs)
        it = pool.map(_run, jobs)
    else:
        it = map(_run, jobs)
    for case, row in zip(cases, it):
        rows[case] = row
        print(f"{case:27s} first={row['first']!s:26s} {row['rms_before']:.4g} -> {row['rms_after']:.4g} "
              f"({row['ratio']:.3f}) accepted={row['accepted']} err={row['error']} [{row['wall_s']:.0f} s]",
              flush=True)
        old = {r["case"]: r for r in prev}
        done = [rows.get(c, old.get(c)) for c in order if c in rows or c in old]
        atomic_write_text(out / "results.json", json.dumps(done, indent=1, default=float))
        atomic_write_text(out / "summary.md", table(done) + "\n")
    return [rows[c] for c in cases]


if __name__ == "__main__":
    main()
