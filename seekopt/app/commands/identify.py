"""``seekopt identify``: the modal plant of one log, or a family of plants from several logs of one drive
(:func:`identification.estimate.identify.identify`)."""
from __future__ import annotations

from pathlib import Path

from seekopt.app.commands.common import UsageError, check_output_dir, check_output_file, progress, warn
from seekopt.app.commands.inputs import read_log_cli

__all__ = ["cmd_identify"]


def _identify_outputs(logs, output):
    """Output path per log: ``-o`` as given for one log; for several logs ``-o`` is a folder (``<stem>.json``
    in it) or a pattern with ``{stem}``."""
    if not output:
        return [None] * len(logs)
    if len(logs) == 1:
        return [output]
    if "{stem}" in output:
        outs = [output.format(stem=Path(x).stem) for x in logs]
    else:
        if Path(output).suffix.lower() == ".json":
            raise UsageError(f"-o {output}: several logs need a folder or a pattern with {{stem}}, not one file")
        outs = [str(Path(output) / f"{Path(x).stem}.json") for x in logs]
    if len(set(outs)) != len(outs):
        raise UsageError(f"-o {output}: two logs would write the same plant file (same file stem)")
    return outs


def cmd_identify(args) -> int:
    """``seekopt identify LOG [LOG ...] [-o plant.json | -o DIR] [--method robust|paper] [--figures DIR]
    [--current-unit mA]``: identify the modal plant of each log (several logs of one drive --
    temperatures, heads, zones -- give a family of plants), print the modes with one-standard-deviation
    uncertainties, k0, bias, delay, the held-out fit and the bands where a mode would have escaped
    detection; a bad log raises LogError (one line, exit 2 via :func:`main`) before anything is identified."""
    logs = list(args.log) if isinstance(args.log, (list, tuple)) else [args.log]
    outs = _identify_outputs(logs, args.output)
    for out in outs:
        if out is not None and len(logs) > 1:
            check_output_dir(str(Path(out).parent), "-o")
        else:
            check_output_file(out, "-o", (".json",))
    check_output_dir(args.figures, "--figures")
    loaded = [read_log_cli(x, args.current_unit, args) for x in logs]   # every log checked before the long work
    plants = []
    for path, log, out in zip(logs, loaded, outs):
        figs = args.figures if len(logs) == 1 or not args.figures else str(Path(args.figures) / Path(path).stem)
        plants.append(_identify_one(args, path, log, out, figs))
    if len(plants) > 1:
        from seekopt.design.family import family_spread
        sp = family_spread(plants[0], plants[1:])
        print(f"family of {len(plants)} plants, relative to {Path(logs[0]).name}:")
        for path, (t, z, g, d) in zip(logs[1:], sp["members"]):
            print(f"  {Path(path).name}: frequencies x{1 + t:.4f}, damping x{1 + z:.3f}, gain (k0) x{1 + g:.4f}, "
                  f"delay {d * 1e6:+.3f} us")
    return 0


def _identify_one(args, path, log, output, figures):
    """Identify one log and print its plant (see :func:`cmd_identify`); returns the plant."""
    from identification.estimate.identify import identify
    from identification.logs.checks import k0_warning
    from identification.logs.seeklog import segment_seeks
    which = f"of {path} " if len(getattr(args, "log", [])) > 1 else ""
    with progress(args, f"identifying the plant {which}from {len(segment_seeks(log))} seeks ({args.method})"):
        res = identify(log, method=args.method)
    p, sd = res.plant, res.plant.std
    w = k0_warning(p.k0, str(path))
    if w:
        warn(args, w)

    def pm(value, key, std, fmt):
        s = (std or {}).get(key)
        return f"{value:{fmt}} ± {s:.2g}" if s is not None and s == s else f"{value:{fmt}}"
    d = res.diagnostics
    print(f"{path}: {log.n} samples at {log.sample_rate_hz:g} Hz, {d.get('n_seeks')} seeks "
          f"({d.get('n_fit_seeks')} fitted, {d.get('n_heldout_seeks')} held out); method {res.method}")
    print(f"  k0    = {pm(p.k0, 'k0', sd, '.6g')} track/(A s^2)")
    print(f"  bias  = {pm(p.bias_a * 1e3, 'bias_a', {k: v * 1e3 for k, v in sd.items()}, '.4f')} mA")
    print(f"  delay = {pm(p.delay_s * 1e6, 'delay_s', {k: v * 1e6 for k, v in sd.items()}, '.3f')} us")
    print(f"  {'#':>3}  {'freq [Hz]':<20} {'zeta [-]':<20} {'gain g [-]':<24}")
    for i, m in enumerate(p.modes, 1):
        print(f"  {i:>3}  {pm(m.freq_hz, 'freq_hz', m.std, '.2f'):<20} {pm(m.zeta, 'zeta', m.std, '.5f'):<20} "
              f"{pm(m.gain, 'gain', m.std, '.4e'):<24}")
    if not p.modes:
        print("      (no significant mode)")
    fit, rig = res.fit_percent, res.fit_percent_rigid
    if fit == fit:
        print(f"  held-out fit (settle-window PES): {fit:.1f} % (rigid body only: {rig:.1f} %)")
        if fit < 0:
            print("    (negative: the log has disturbances the current does not carry -- force noise, which the rigid\n"
                  "     body integrates twice, run-out, flutter; an open-loop simulation cannot predict them.  The\n"
                  "     mode table above is not affected; see docs/results_identification.md)")
    else:
        print("  held-out fit: n/a (too few seeks to hold any out)")
    blind = p.meta.get("blind_bands")
    if blind is not None:
        det = p.meta.get("blind_detect", {})
        txt = "; ".join(f"{b['lo_hz']:.0f}-{b['hi_hz']:.0f} Hz ({b['reason']}"
                        + (f", up to g {b['min_detectable_gain']:.2g})" if b.get("min_detectable_gain") else ")")
                        for b in blind)
        print(f"  blind (a mode of gain {det.get('gain', float('nan')):g} would escape detection): {txt or 'none'}")
    if output:
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        p.to_json(output)
        print(f"wrote {output}")
    if figures:
        from identification.estimate.figures import plot_identification
        with progress(args, "drawing the figures"):
            paths = plot_identification(log, res, figures)
        for fig in paths:
            print(f"wrote {fig}")
    return p

