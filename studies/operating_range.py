"""Study: seeks that stay fast over a drive's operating range (issue 11).

Run::

    python studies/operating_range.py [--quick] [--cache DIR] [--no-readme] [--worst-case-slack TIME]

1. **A synthetic drive family**: the default truth (NSS v2 seek mode + 420 Hz and 1738 Hz seek-induced
   modes) plus a mode inside the controller's 8.2 kHz notch (gain 0.1, zeta 0.01), at three
   temperatures: cold (every resonance x1.04, damping x0.8, gain x1.05), room (x1) and hot (x0.96,
   x1.2, x0.95).  Each member writes its own log (``seekopt.evaluate.synth``, seeds 0/1/2, benchmark
   noise and run-out) and is identified from it (``identification.estimate.identify``, which also
   writes the bands where a mode would have escaped detection).
2. **Designs** (Imax 0.3 A, band 0.1 track) for K = 1, 10, 50, 200, 1000, 3000: from the identified
   room plant with the default drift (ranges from the data), from the identified family (three
   plants), and from the room plant with ``--drift temp=±4%,zeta=±20%,gain=±5%``.
3. **Played on every member** (the truth plants, the notch mode included; each member's drive scales
   the feedforward by its own identified gain, as drives calibrate their seek gain), against the
   shortest sine and windowed sine within Imax played on the same member.
4. **Predicted vs actual**: the worst seek-settle time ``design`` predicts over its set against the
   worst the members do (the notch mode is in no design plant unless the identification saw it).
5. **NSS-like default drive** (the default truth, no notch mode, identified from seed 0): the robust
   default design at K = 200 and 1000 on the truth and on the truth with its seek-induced modes
   shifted +-5 %, with the former default (``RobustSpec()``) and the nominal design for comparison.

``--worst-case-slack 0.04ms``: every design lets its set's worst case settle up to that much after its
minimum so that the nominal plant settles earlier (``SeekProblem.worst_case_slack_s``); the tables then
show the set's samples (its minimum) and go into the README section between the ``operating_range_slack``
markers.  Writes the tables into the README section between the ``operating_range`` markers (unless
``--no-readme``) and prints them.  Identified plants are cached in ``--cache`` (default
``/tmp/seekopt_operating_range``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from identification.estimate.identify import identify  # noqa: E402
from identification.model.plant import ModalPlant, Mode  # noqa: E402
from seekopt.app.commands.common import parse_duration  # noqa: E402
from seekopt.design.baselines import baseline_profile  # noqa: E402
from seekopt.design.designer import DesignInfeasible, SeekDesigner  # noqa: E402
from seekopt.design.family import Drift, calibrated, drifted, played_on  # noqa: E402
from seekopt.design.guard_bands import curve_gain, plant_gain_curve  # noqa: E402
from seekopt.design.metrics import evaluate_profile  # noqa: E402
from seekopt.design.problem import SeekProblem  # noqa: E402
from seekopt.design.profiles import t_bang_bang  # noqa: E402
from seekopt.design.robust import RobustSpec, seek_induced  # noqa: E402
from seekopt.drive.controller import Controller  # noqa: E402
from seekopt.drive.presets import default_truth_plant  # noqa: E402
from seekopt.evaluate.synth import SynthConfig, synthesize  # noqa: E402

README = ROOT / "README.md"
IMAX, BAND = 0.3, 0.1
KS = (1.0, 10.0, 50.0, 200.0, 1000.0, 3000.0)
NOTCH_MODE = Mode(8200.0, 0.01, 0.1)
#: (name, frequency scale, damping scale, gain scale) of the temperatures, seed of each log
MEMBERS = (("room", 0.0, 0.0, 0.0, 0), ("cold", 0.04, -0.2, 0.05, 1), ("hot", -0.04, 0.2, -0.05, 2))
DRIFT = "temp=±4%,zeta=±20%,gain=±5%"


def family_truths() -> dict:
    base = default_truth_plant()
    base = base.copy(modes=sorted(base.modes + [NOTCH_MODE], key=lambda m: m.freq_hz))
    return {name: drifted(base, t, z, g, label=name) for name, t, z, g, _ in MEMBERS}


def identified(name: str, truth: ModalPlant, seed: int, cache: Path) -> ModalPlant:
    path = cache / f"{name}.json"
    if path.exists():
        return ModalPlant.load(path)
    t0 = time.perf_counter()
    log, _ = synthesize(SynthConfig(seed=seed), plant=truth)
    p = identify(log).plant
    p.meta["family_name"] = name
    p.to_json(path)
    print(f"identified {name} in {time.perf_counter() - t0:.0f} s: " +
          ", ".join(f"{m.freq_hz:.0f} Hz g {m.gain:.3g}" for m in p.modes), flush=True)
    return p


def md_table(head, rows) -> str:
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def write_section(text: str, name: str = "operating_range") -> None:
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    old = README.read_text()
    block = f"{begin}\n{text.rstrip()}\n{end}"
    if begin in old and end in old:
        new = old[:old.index(begin)] + block + old[old.index(end) + len(end):]
    else:
        new = old.rstrip() + "\n\n" + block + "\n"
    README.write_text(new)


def better_paper(plant, truth, ctrl, K) -> float:
    """Seek-settle time [s] of the better of the shortest sine and windowed sine within Imax (rigid
    reference from the design plant) played on ``truth`` (its drive's gain calibration applied)."""
    fs = ctrl.sample_rate_hz
    return min(evaluate_profile(truth, ctrl, played_on(baseline_profile(plant, fs, kind, K, IMAX, BAND), truth),
                                settle=BAND, k0_for_tbb=plant.k0).settle_time_s for kind in ("sine", "windowed_sine"))


def family_study(ks, cache: Path, options=None):
    ctrl = Controller.nss()
    truths = family_truths()
    ident = {name: identified(name, truths[name], seed, cache) for name, *_, seed in MEMBERS}
    room = ident["room"]
    # each member's drive calibrates its feedforward to its own identified gain
    members = {n: calibrated(truths[n], room.k0, ident[n].k0) for n in truths}
    nf = dict(options or {})
    designs = {"room plant, default drift": SeekProblem(room, ctrl, IMAX, BAND, robust=Drift(), **nf),
               "family (3 identified plants)": SeekProblem(room, ctrl, IMAX, BAND, robust=Drift(),
                                                           family=[ident["cold"], ident["hot"]], **nf),
               f"room plant, --drift {DRIFT}": SeekProblem(room, ctrl, IMAX, BAND, robust=Drift.from_string(DRIFT),
                                                           **nf)}
    rows, pred_rows, summary = [], [], {}
    base = {(n, K): better_paper(room, members[n], ctrl, K) for n in members for K in ks}
    for label, prob in designs.items():
        t0 = time.perf_counter()
        des = SeekDesigner(prob)
        build = time.perf_counter() - t0
        for K in ks:
            t1 = time.perf_counter()
            try:
                res = des.design(K)
            except (DesignInfeasible, RuntimeError) as exc:
                rows.append([label, f"{K:g}", f"design failed: {str(exc)[:80]}"] + [""] * 6)
                continue
            dt = time.perf_counter() - t1 + (build if K == ks[0] else 0.0)
            tbb = t_bang_bang(K, room.k0, IMAX)
            act = {n: evaluate_profile(members[n], ctrl, played_on(res.profile, members[n]), settle=BAND,
                                       k0_for_tbb=room.k0) for n in members}
            ratio = {n: act[n].settle_time_s / base[(n, K)] for n in members}
            rows.append([label, f"{K:g}"] + [f"{act[n].settle_time_s * 1e3:.3f} ({ratio[n]:.2f})" for n in members]
                        + [f"{act['room'].settle_time_s / tbb:.2f}", f"{len(des.plants)}", f"{dt:.0f}"])
            pw = res.prediction.worst_metrics.settle_time_s if res.prediction else res.metrics.settle_time_s
            aw = max(a.settle_time_s for a in act.values())
            g = res.guard
            ar = act["room"].settle_time_s
            pred_rows.append([label, f"{K:g}", f"{res.metrics.settle_time_s * 1e3:.3f}", f"{pw * 1e3:.3f}",
                              res.prediction.labels[res.prediction.binding] if res.prediction else "nominal",
                              f"{ar * 1e3:.3f} ({ar / pw:.2f})", f"{aw * 1e3:.3f} ({aw / pw:.2f})",
                              f"{g.worst_band:.2f} at {g.worst_hz:.0f} Hz" if g else "-"]
                             + ([f"{res.settle_samples}", f"{res.set_settle_samples} ({res.set_min_settle_samples})"]
                                if nf.get("worst_case_slack_s") else []))
            summary[(label, K)] = {"ratio": ratio, "tbb_room": act["room"].settle_time_s / tbb,
                                   "pred_ratio": aw / pw, "pred_ratio_room": ar / pw, "pred_worst_tbb": pw / tbb}
            print(rows[-1], pred_rows[-1], flush=True)
    ident_rows = []
    for name, *_ in MEMBERS:
        p = ident[name]
        near = [m for m in p.modes if abs(m.freq_hz - NOTCH_MODE.freq_hz * (1 + dict(
            (n, t) for n, t, *_ in MEMBERS)[name])) < 400]
        curve = plant_gain_curve(p)
        f0 = NOTCH_MODE.freq_hz * (1 + dict((n, t) for n, t, *_ in MEMBERS)[name])
        gmin = float(curve_gain(curve, [f0])[0]) if curve else float("nan")
        ident_rows.append([name, f"{f0:.0f}", ", ".join(f"{m.freq_hz:.0f} Hz g {m.gain:.3g}" for m in near) or "missed",
                           f"{gmin:.3g}", f"{p.meta.get('blind_detect', {}).get('calibration', float('nan'))}",
                           ", ".join(f"{m.freq_hz:.0f}" for m in p.modes)])
    return rows, pred_rows, ident_rows, summary


def nss_study(cache: Path, ks=(200.0, 1000.0), options=None):
    ctrl = Controller.nss()
    truth = default_truth_plant()
    path = cache / "nss_default.json"
    if path.exists():
        p = ModalPlant.load(path)
    else:
        log, truth = synthesize(SynthConfig(seed=0), plant=truth)
        p = identify(log).plant
        p.to_json(path)

    def shift(pl, s):
        return pl.copy(modes=[Mode(m.freq_hz * (1 + s) if seek_induced(m) else m.freq_hz, m.zeta, m.gain)
                              for m in pl.modes])
    truths = {"truth": truth, "seek modes -5 %": shift(truth, -0.05), "seek modes +5 %": shift(truth, 0.05)}
    variants = {"default (Drift(): ranges from the data)": Drift(), "former default RobustSpec()": RobustSpec(),
                "nominal (no robust set)": None}
    rows, out = [], {}
    for label, rob in variants.items():
        des = SeekDesigner(SeekProblem(p, ctrl, IMAX, BAND, robust=rob, **(options or {})))
        for K in ks:
            t0 = time.perf_counter()
            res = des.design(K)
            dt = time.perf_counter() - t0
            r = {n: evaluate_profile(t, ctrl, res.profile, settle=BAND, k0_for_tbb=p.k0).ratio_tbb for n, t in truths.items()}
            pw = res.prediction.worst_metrics.ratio_tbb if res.prediction else res.metrics.ratio_tbb
            rows.append([label, f"{K:g}", f"{res.metrics.ratio_tbb:.2f}", f"{pw:.2f}"] + [f"{v:.2f}" for v in r.values()]
                        + [f"{res.guard.worst_band:.2f}" if res.guard else "-", f"{len(des.plants)}", f"{dt:.0f}"])
            out[(label, K)] = dict(r, pred_worst=pw)
            print(rows[-1], flush=True)
    return rows, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="K = 10, 200 only")
    ap.add_argument("--cache", default="/tmp/seekopt_operating_range")
    ap.add_argument("--no-readme", action="store_true")
    ap.add_argument("--before-after", action="store_true",
                    help="also design as before this change (inputs end at the settle sample, every plant's band "
                         "from one sample: input_tail_s=0, nominal_first=False) and tabulate both")
    ap.add_argument("--worst-case-slack", default=None, metavar="TIME",
                    help="design with SeekProblem.worst_case_slack_s (e.g. 0.04ms); tables into the README's "
                         "operating_range_slack section")
    a = ap.parse_args(argv)
    slack = parse_duration(a.worst_case_slack, "--worst-case-slack") if a.worst_case_slack else 0.0
    opts = {"worst_case_slack_s": slack} if slack else None
    cache = Path(a.cache)
    cache.mkdir(parents=True, exist_ok=True)
    ks = (10.0, 200.0) if a.quick else KS
    t0 = time.perf_counter()
    rows, pred, ident, summary = family_study(ks, cache, opts)
    nss_rows, nss = nss_study(cache, options=opts)
    old = {"input_tail_s": 0.0, "nominal_first": False}
    before = (family_study(ks, cache, old)[3], nss_study(cache, options=old)[1]) if a.before_after else None
    names = [n for n, *_ in MEMBERS]
    fs = Controller.nss().sample_rate_hz
    slack_cols = ["nominal smp", "set smp (min)"] if slack else []
    text = [
        "### Measured (`studies/operating_range.py`)" if not slack else
        f"### Measured with a worst-case slack of {slack * 1e3:.3g} ms = {int(slack * fs * (1 + 1e-9))} sample(s) "
        f"(`studies/operating_range.py --worst-case-slack {a.worst_case_slack}`)",
        "",
        *([f"Every design lets its set's worst case settle up to {slack * 1e3:.3g} ms after the set's minimum so "
           "that the nominal plant settles earlier (`SeekProblem.worst_case_slack_s`, `seekopt design "
           "--worst-case-slack`); the prediction table gives the design samples of the nominal plant and of the "
           "set (its minimum).", ""] if slack else []),
        f"Synthetic family: the default truth plus a mode in the controller's 8.2 kHz notch (g {NOTCH_MODE.gain}, "
        f"zeta {NOTCH_MODE.zeta}); cold = every resonance x1.04, damping x0.8, gain x1.05; hot = x0.96, x1.2, "
        "x0.95; one 120-seek log per member (seeds 0/1/2), each identified on its own. Imax 0.3 A, band 0.1 track. "
        "Played on every member's truth, its feedforward scaled by its own identified gain (its drive's "
        "seek-gain calibration); the baseline is the better of the shortest sine and windowed sine within "
        "Imax played on that member.",
        "",
        "Seek-settle time [ms] on each member (in brackets: over the better paper profile on that member); "
        "T_settle / T_bb on the room member; plants in the design set; design time [s] (shared, loaded machine):",
        "",
        md_table(["design", "K"] + [f"{n} ms (/paper)" for n in names] + ["room /T_bb", "set", "s"], rows),
        "",
        "Predicted (`design`'s nominal and worst over its set, the binding plant) against the worst the members "
        "do; the guard's worst residual (fraction of the band, guarded mode gain included):",
        "",
        md_table(["design", "K", "pred nominal ms", "pred worst ms", "binding plant", "room ms (/pred worst)",
                  "members' worst ms (/pred worst)", "guard"] + slack_cols, pred),
        "",
        "Identification of each member: the notch mode (true gain 0.1) and the smallest gain the log could show "
        "there (`detectable_gain_curve`, calibrated on the identified modes' reported std):",
        "",
        md_table(["member", "notch mode at Hz", "identified near it", "g_min there", "calibration", "all modes Hz"], ident),
        "",
        "NSS-like default drive (identified from the seed-0 log): T_settle / T_bb on the truth and with its "
        "seek-induced modes shifted; predicted nominal and worst over the set:",
        "",
        md_table(["design", "K", "pred nominal", "pred worst"] + ["truth", "seek -5 %", "seek +5 %"] +
                 ["guard", "set", "s"], nss_rows),
        "",
        "Per design, over every member and K: worst ratio to the better paper profile; worst T_settle / T_bb on "
        "the room member at K >= 200; worst (members' worst / predicted worst) and (room member / predicted "
        "worst) -- the room member carries the notch mode at the design's temperature:",
        "",
        md_table(["design", "worst /paper", "room /T_bb at K >= 200", "members / pred", "room / pred"],
                 [[lab, f"{max(max(summary[(lab, K)]['ratio'].values()) for K in ks if (lab, K) in summary):.2f}",
                   f"{max((summary[(lab, K)]['tbb_room'] for K in ks if K >= 200 and (lab, K) in summary), default=float('nan')):.2f}",
                   f"{max(summary[(lab, K)]['pred_ratio'] for K in ks if (lab, K) in summary):.2f}",
                   f"{max(summary[(lab, K)]['pred_ratio_room'] for K in ks if (lab, K) in summary):.2f}"]
                  for lab in dict.fromkeys(k[0] for k in summary)]),
        "",
    ]
    if before is not None:
        text += ["Before / after (same identified plants, one run). Before: the inputs end at the settle sample and "
                 "every plant of the set holds the band from that sample (`input_tail_s=0, nominal_first=False`). "
                 "After: the feedforward and reference may go on 0.3 ms after the settle sample "
                 "(`SeekProblem.input_tail_s`) and the design is lexicographic (`nominal_first`: the set's worst "
                 "seek-settle time first, then, holding it, the nominal plant's). T_settle / T_bb on the room "
                 "member, worst over the members of (T_settle / better paper profile), predicted worst over the "
                 "set / T_bb:", "",
                 md_table(["design", "K", "room /T_bb before", "after", "worst /paper before", "after",
                           "pred worst /T_bb before", "after"],
                          [[lab, f"{K:g}"] + [f"{d[(lab, K)][key]:.2f}" if key != "ratio" else
                                              f"{max(d[(lab, K)]['ratio'].values()):.2f}"
                                              for key in ("tbb_room", "ratio", "pred_worst_tbb") for d in (before[0], summary)]
                           for (lab, K) in summary if (lab, K) in before[0]]), "",
                 "NSS-like default drive, before / after (T_settle / T_bb on the truth, on the truth with its "
                 "seek-induced modes -5 % / +5 %, predicted worst over the set):", "",
                 md_table(["design", "K", "truth before", "after", "seek -5 % before", "after", "seek +5 % before",
                           "after", "pred worst before", "after"],
                          [[lab, f"{K:g}"] + [f"{d[(lab, K)][key]:.2f}" for key in
                                              ("truth", "seek modes -5 %", "seek modes +5 %", "pred_worst")
                                              for d in (before[1], nss)]
                           for (lab, K) in nss if (lab, K) in before[1]]), ""]
    text += [f"Study wall time {time.perf_counter() - t0:.0f} s (machine shared)."]
    text = "\n".join(text)
    print(text)
    if not a.no_readme:
        write_section(text, "operating_range_slack" if slack else "operating_range")
    (cache / ("summary_slack.json" if slack else "summary.json")).write_text(json.dumps({f"{k[0]}|{k[1]:g}": v for k, v in summary.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
