"""The model's commands: ``torchtea fit`` (:func:`torchtea.fitting.recording.fit_recording`), ``torchtea plan``
(:mod:`torchtea.fitting.plan`) and ``torchtea check`` (:func:`torchtea.checking.channels.check_measurements`)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from .common import (
    BOOTSTRAP_LIMIT,
    CLIError,
    _check_channels,
    _check_cluster_flags,
    _checkpoint,
    _cluster,
    _cluster_flags,
    _measurements,
    _model_inputs,
    _note,
    _positive_float,
    _progress,
    _recording_flags,
    _steps,
    _tensorboard,
    _units_of,
)
from .export import (
    _datasheet_verdicts,
    _export,
    _export_flags,
    _export_plan,
    _pooled_export,
    _pooled_fits,
    _print_verdicts,
    _several,
    _sheets,
    _together_flags,
)


def add_parsers(sub) -> None:
    """Add the sub-parsers of fit, plan and check to ``sub`` (``build_parser``'s subcommands)."""
    _add_fit(sub)
    _add_plan(sub)
    _add_check(sub)


def _add_fit(sub) -> None:
    """``torchtea fit``'s flags."""
    fp = sub.add_parser("fit", help="fit a noise model by maximum likelihood, with intervals")
    _recording_flags(fp, columns_help="the columns to fit, any number (default: every accelerometer and gyroscope "
                                      "axis the file names)",
                     temperature_help="temperature column (°C) for temperature-bias / temperature-order (a torchtea "
                                      "recording: temp)", samples_default="all",
                     samples_help="use the first N samples (default all)", several=True)
    fp.add_argument("--together", action="store_true",
                    help="several recordings of one sensor: one model per channel whose noise parameters all share "
                         "(each recording its own mean terms), the likelihood the sum of theirs; then per noise "
                         "parameter a test of one value in all against its own in each, and from three recordings "
                         "the turn-on bias repeatability")
    fp.add_argument("--model", default="fractional+white",
                    help="components joined by '+': fractional, white, quantisation, random-walk, gauss-markov, "
                         "resonance, low-pass, digital-filter, offset, ramp, step, spikes:K, sinusoid, drifting-line, "
                         "temperature-bias, thermal-lag, temperature-order (default fractional+white)")
    fp.add_argument("--method", choices=("whittle", "exact"), default="exact",
                    help="likelihood of the final answer (default exact; Whittle always gives the start)")
    fp.add_argument("--profile", action="store_true",
                    help="also the order's Whittle profile-likelihood interval with --method exact (always with "
                         "--method whittle, where it is the order's interval)")
    fp.add_argument("--bootstrap", type=int, default=None,
                    help="replicates of the fractional-presence test (0: do not test; default 99, 0 above "
                         f"{BOOTSTRAP_LIMIT} samples)")
    fp.add_argument("--seed", type=int, default=0, help="seed of the bootstrap")
    fp.add_argument("--out", help="write the JSON document to this file")
    fp.add_argument("--json", action="store_true", help="print the JSON document")
    _export_flags(fp, standalone=False)
    _cluster_flags(fp, "the channels' fits")
    fp.set_defaults(func=cmd_fit)


def _add_plan(sub) -> None:
    """``torchtea plan``'s flags."""
    pl = sub.add_parser("plan", help="how long to record: the expected 95 %% intervals of the noise numbers by record "
                                     "length, from a recording's fit, a check, or a datasheet")
    _recording_flags(pl, columns_help="the columns to plan for (default: every accelerometer and gyroscope axis)",
                     temperature_help="temperature column (°C), for a --model with temperature effects",
                     samples_default="all", samples_help="use the first N samples (default all)", several=True)
    pl.add_argument("--together", action="store_true",
                    help="several recordings of one sensor: plan from --model fitted to all of them together (its "
                         "noise parameters shared), the lengths those of one recording")
    pl.add_argument("--model", default="fractional+white",
                    help="fit this model SPEC to each column and plan from it (default fractional+white; --from-check "
                         "takes the model check's loop ended with)")
    pl.add_argument("--from-check", metavar="CHECK_JSON",
                    help="plan from a check's models and fits (check.json), with its ties' lengths")
    pl.add_argument("--datasheet", metavar="FILE",
                    help="plan before any recording, from a datasheet's N, B, K (TOML: sensor, rate_hz, and "
                         "N/B/K = {value, unit}; see examples/datasheets)")
    pl.add_argument("--lengths", metavar="S,S,…", help="record lengths in seconds (default: the record's own, 4× and "
                                                        "10× it, 10 min, 1 h and 3 h; a datasheet: 1 min to 10 h)")
    pl.add_argument("--target", action="append", default=[], metavar="NAME=PERCENT",
                    help="the length at which NAME (N, B, K or a parameter) is within ± PERCENT (repeatable; e.g. "
                         "K=10%%)")
    pl.add_argument("--out", help="write the JSON document to this file")
    pl.add_argument("--json", action="store_true", help="print the JSON document")
    pl.set_defaults(func=cmd_plan)


def _add_check(sub) -> None:
    """``torchtea check``'s flags."""
    ck = sub.add_parser("check", help="test a noise model against a recording and rank the effects it is missing")
    _recording_flags(ck, columns_help="the columns to check, any number (default: every accelerometer and gyroscope "
                                      "axis the file names, both sensors side by side)",
                     temperature_help="temperature column (°C): enables the temperature diagnostic and the "
                                      "temperature effects (a torchtea recording: temp)", samples_default="all",
                     samples_help="use the first N samples (default all)", several=True)
    ck.add_argument("--together", action="store_true",
                    help="several recordings of one sensor: per channel one model for all (noise parameters shared, "
                         "each recording its own mean terms), every recording checked with it and the effects that "
                         "pass a screen refitted to all together; with --auto the loop adds and takes away by the "
                         "pooled BIC; then the recordings tested parameter by parameter against the final model")
    ck.add_argument("--model", default="fractional+white", help="noise model SPEC (default fractional+white)")
    ck.add_argument("--add", action="append", default=[], metavar="EFFECT",
                    help="add an effect and check again, before/after (repeatable)")
    ck.add_argument("--auto", action="store_true",
                    help="run the loop to its end: add the best suggestion and check again until no effect passes "
                         "its screen, or the model is adequate and no suggestion gains --strong BIC (after any --add)")
    ck.add_argument("--max-steps", type=_steps, default=6, help="--auto adds at most this many effects (default 6)")
    ck.add_argument("--no-simplify", action="store_true",
                    help="--auto only adds: no component taken away, replaced by its special case (the fractional "
                         "part by a random walk) or swapped for another that passed its screen, and no ties named")
    ck.add_argument("--exclude-start", action="store_true",
                    help="--auto: where the loop ends naming a stretch that differs at the record's start (a sensor "
                         "settling: its innovations larger than the model allows over the whole stretch), leave that "
                         "stretch out and check the channel again, saying so")
    ck.add_argument("--strong", type=float, default=None, metavar="BIC",
                    help="--auto goes on past an adequate model while the best suggestion gains at least this much "
                         "BIC (default 10, checking.check.STRONG_BIC: very strong evidence; inf stops at adequacy)")
    ck.add_argument("--level", type=float, default=0.01, help="level of each diagnostic (default 0.01)")
    ck.add_argument("--screen-level", type=float, default=0.05,
                    help="family level of the effect screens (default 0.05: on data from the model, at most "
                         "5 %% of checks suggest anything)")
    ck.add_argument("--fits", choices=("auto", "exact", "whittle"), default="auto",
                    help="how the loop fits: auto (default: the exact likelihood's maximum from several starts up "
                         "to 10000 samples; above, the long-record path: the Whittle likelihood, the exact one "
                         "evaluated at each point the loop compares and, up to 100000 samples, refined from the best "
                         "of them to its maximum), exact (the exact likelihood's maximum whatever the length) or "
                         "whittle (the long-record path without the refinement, whatever the length: the Whittle "
                         "estimates as they are)")
    ck.add_argument("--windows", type=_positive_float, metavar="SECONDS",
                    help="the final model's noise parameters over time: fitted in windows of SECONDS, "
                         "half-overlapping, with a test of their constancy and where one changes (report, check.json "
                         "'windows', the parameters over time and the dynamic Allan deviation as figures)")
    ck.add_argument("--no-intervals", action="store_true", help="skip the finite-difference intervals (faster)")
    ck.add_argument("--out", help="output directory (default check-<recording name>)")
    ck.add_argument("--no-plots", action="store_true")
    ck.add_argument("--json", action="store_true", help="print the JSON document")
    ck.add_argument("--logdir", help="also write the loop of each channel as a TensorBoard run (DIR/<channel>: each "
                                     "step's −ℓ per sample, misfits, gain as scalars, its figures as images, the "
                                     "verdict as text)")
    _export_flags(ck, standalone=False)
    _cluster_flags(ck, "the channels' checks")
    ck.set_defaults(func=cmd_check)


def cmd_fit(args) -> int:
    from ..fitting.recording import fit_lines, fit_recording
    from ..noise import parse_model
    from ..render.strictjson import dumps, write

    model = parse_model(args.model)
    _check_cluster_flags(args)
    paths = list(args.recording or [])
    if args.together or len(paths) > 1:
        return _fit_together(args, model, paths)
    args.recording = paths[0] if paths else None
    m = _measurements(args, "a fit", min_samples=100)
    if args.datasheet and not args.export:
        raise CLIError("--datasheet holds the exported numbers against the datasheet: give --export FORMAT too "
                       "(or use check --datasheet)")
    plan = _export_plan(args, m, args.export)
    inputs = _model_inputs(args, [model], m)
    # (with --out, each channel's fit is kept as it is made, beside it: a stop loses only the fit running)
    checkpoint = _checkpoint(args, Path(f"{args.out}.partial"), len(m.channels)) if args.out else None
    if args.resume and checkpoint is None:
        raise CLIError("--resume: fit keeps its channels beside --out FILE; give the --out of the interrupted run")
    client, close_cluster = _cluster(args)
    step, close = _progress(len(m.channels), "fit " + model.spec, "channel", bar=not args.json, estimate=False)
    step(0, len(m.channels))  # (the clock starts with the first channel, not when it is done)
    try:
        doc, fits = fit_recording(m, model, inputs=inputs, method=args.method, bootstrap=args.bootstrap,
                                  seed=args.seed, profile=args.profile, progress=step,
                                  log=lambda line: _note(f"note: {line}"), client=client,
                                  threads=args.threads_per_worker, effects=tuple(args.effects),
                                  done=None if checkpoint is None else checkpoint.done,
                                  keep=None if checkpoint is None else checkpoint.keep)
    finally:
        close()
        close_cluster()
    doc["command"] = "torchtea " + " ".join(sys.argv[1:]) if sys.argv[1:] else ""
    if args.out:
        write(Path(args.out), doc)
        checkpoint.finish()
    if plan:  # (files beside --out, else in export-<recording>)
        out = Path(args.out).parent / "export" if args.out else Path(f"export-{Path(m.recording.path).stem}")
        _export(args, m, plan, {c.label: f for c, f in zip(m.channels, fits)}, inputs, m.describe(), out,
                quiet=args.json, plots=True)
    if args.json:
        print(dumps(doc))
        return 0
    print("\n".join(fit_lines(doc, {c.label: c.title for c in m.channels}, _units_of(m), Path(m.recording.path).name,
                              m.recording.rate_hz)))
    if args.out:
        print(f"written {args.out}")
    return 0


def _windows(args, m, results: dict, inputs) -> dict | None:
    """``check --windows``: each channel's final model's noise over time (:mod:`torchtea.fitting.windows`)."""
    from ..fitting.windows import noise_over_time

    if args.windows is None:
        return None
    out = {}
    for a, r in results.items():
        _note(f"{a}: fitting {r.model.spec}'s noise in windows of {args.windows:g} s")
        out[a] = noise_over_time(r.model, m.channel(a).values, m.h, args.windows, fit=r.fit, inputs=inputs)
    return out


def _fit_together(args, model, paths: list) -> int:
    """``torchtea fit A B … --together``: each channel's pooled fit over the recordings (:mod:`torchtea.fitting.together`)."""
    from ..checking.replicates import together_allan_figure, together_lines
    from ..fitting.together import REPLICATES_MEANING, fit_together
    from ..render.plots import pyplot
    from ..render.strictjson import dumps, write
    from ..sensors.measurements import DOCUMENT_MEANING, RECORDING_MEANING

    _together_flags(args, paths, "fit", ("workers", "scheduler", "profile", "bootstrap", "exclude", "resume"))
    if args.method != "exact":
        raise CLIError("--together fits by the exact likelihood (--method exact)")
    if args.datasheet and not args.export:
        raise CLIError("--datasheet holds the exported numbers against the datasheet: give --export FORMAT too")
    ms, inputs, names = _several(args, paths, model, "a fit", 100)
    first = ms[0]
    plan = _export_plan(args, first, args.export)
    t0 = time.perf_counter()
    axes, lines, figures, togethers = {}, [], [], {}
    step, close = _progress(len(first.labels), f"fit {model.spec} together", "channel", bar=not args.json)
    step(0, len(first.labels))
    try:
        for k, label in enumerate(first.labels):
            series = [m.channel(label).values for m in ms]
            inp = None if inputs[0] is None else inputs
            tg = fit_together(model, series, first.h, inputs=inp, recordings=names)
            axes[label] = {"unit": first.channel(label).unit, "replicates": tg.as_dict()}
            togethers[label] = tg
            lines += together_lines(label, first.channel(label).title, tg, first.channel(label).unit)
            if args.out:
                figures.append(together_allan_figure(pyplot(), tg, series, first.h, Path(args.out).parent,
                                                     f"{Path(args.out).stem}_{label}", first.channel(label).unit,
                                                     inp))
            step(k + 1, len(first.labels))
    finally:
        close()
    doc = {"model": model.spec, "method": "exact", "together": True,
           "recordings": [m.describe() for m in ms], "axes": axes,
           "meaning": {**RECORDING_MEANING, **DOCUMENT_MEANING, **REPLICATES_MEANING,
                       "recordings": "each recording as read, in the order given (in replicates: their names)",
                       "axes": "per channel: its unit and the recordings fitted together (replicates)"},
           "seconds": time.perf_counter() - t0, "warnings": [line for m in ms for line in m.notes()],
           "command": "torchtea " + " ".join(sys.argv[1:]) if sys.argv[1:] else ""}
    if args.out:
        write(Path(args.out), doc)
    if plan:  # (files beside --out, else in export-<first recording>)
        out = Path(args.out).parent / "export" if args.out else Path(f"export-{Path(first.recording.path).stem}")
        _pooled_export(args, ms, names, plan, togethers, inputs, out, quiet=args.json)
    if args.json:
        print(dumps(doc))
        return 0
    print(f"{len(ms)} recordings fitted together at {first.recording.rate_hz:g} Hz ({', '.join(names)}), "
          f"model {model.spec}: noise parameters shared, each recording its own mean terms")
    print("\n".join(lines))
    print("p: likelihood-ratio test of one value in every recording against each its own (χ², recordings − 1 "
          f"degrees of freedom), differs below the threshold (the family level {axes[first.labels[0]]['replicates']['level']:g} "
          "over the parameters tested); units: " + "; ".join(f"{k}: {v}" for k, v in _units_of(first).items()))
    if args.out:
        print(f"written {args.out}" + (f"; figures: {', '.join(p.name for p in figures)}" if figures else ""))
    return 0


def _plan_together(args, model, axes: dict, targets: list, lengths) -> str:
    """``plan A B … --together``: each channel's plan from ``model`` fitted to the recordings together (the pooled
    values as the truth, the lengths of one recording) into ``axes``; returns the source's words."""
    from ..fitting.plan import plan_document
    from ..fitting.together import fit_together

    paths = list(args.recording or [])
    if args.from_check or args.datasheet:
        raise CLIError("--together plans from a model fitted to the recordings: leave out --from-check/--datasheet")
    _together_flags(args, paths, "plan from", ("exclude",))
    ms, inputs, names = _several(args, paths, model, "a plan", 100)
    first = ms[0]
    for label in first.labels:
        _note(f"fitting {model.spec} to {label} of the {len(ms)} recordings together …")
        tg = fit_together(model, [m.channel(label).values for m in ms], first.h,
                          inputs=None if inputs[0] is None else inputs, recordings=names, tests=False)
        n = tg.separate[0].n
        axes[label] = plan_document(model, tg.values[0], first.h, lengths(first.h, n), recorded=n, targets=targets)
    return (f"{model.spec} fitted to {len(ms)} recordings together ({', '.join(names)}): the pooled values as the "
            f"truth, each length that of one recording ({names[0]}'s recorded)")


def cmd_plan(args) -> int:
    """``torchtea plan``: how long to record (:mod:`torchtea.fitting.plan`)."""
    from ..fitting.datasheet import datasheet_model, read_datasheet
    from ..fitting.mle import fit_series
    from ..fitting.plan import parse_target, plan_document, plan_lines
    from ..noise import parse_model
    from ..render.strictjson import dumps, write

    try:
        targets = [parse_target(t) for t in args.target]
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    try:
        lengths_s = None if not args.lengths else [float(x) for x in args.lengths.split(",") if x.strip()]
    except ValueError:
        raise CLIError(f"--lengths {args.lengths!r}: seconds, comma-separated") from None
    if lengths_s is not None and not all(x > 0 for x in lengths_s):
        raise CLIError(f"--lengths {args.lengths!r}: every length must be positive")
    axes, ties, source = {}, {}, ""

    def lengths(h, n0):
        base = [n0, 4 * n0, 10 * n0] if n0 else [60 / h]
        default = base + [600 / h, 3600 / h, 10800 / h] + ([] if n0 else [36000 / h])
        return sorted({max(8, int(round(x))) for x in ((x / h for x in lengths_s) if lengths_s else default)})

    try:
        if args.together or len(args.recording or []) > 1:
            source = _plan_together(args, parse_model(args.model), axes, targets, lengths)
        elif args.datasheet:
            sheet = read_datasheet(args.datasheet)
            model, values, h, terms, fixed = datasheet_model(sheet)
            source = f"datasheet {args.datasheet}" + (f" ({sheet['source']})" if sheet["source"] else "")
            if sheet.get("B_convention") == "allan-minimum":
                source += ("; its B read as the Allan deviation's minimum, IEEE 952's B = that / 0.664 (convention = "
                           "\"ieee952\" in the file if it gives the coefficient)")
            axes[sheet["sensor"]] = plan_document(model, values, h, lengths(h, None), targets=targets, fixed=fixed,
                                                  terms=terms)
        elif args.from_check:
            from ..checking.check import read_check

            doc, fits = read_check(args.from_check)
            h = 1.0 / float(doc["rate_hz"])
            source = f"check {args.from_check}"
            for label, f in fits.items():
                axes[label] = plan_document(f.model, f.values, h, lengths(h, f.n), recorded=f.n, targets=targets)
                ties[label] = doc["axes"][label].get("ties", [])
        else:
            model = parse_model(args.model)
            args.recording = (args.recording or [None])[0]
            m = _measurements(args, "a plan", min_samples=100)
            inputs = _model_inputs(args, [model], m)
            source = f"{model.spec} fitted to {Path(m.recording.path).name}"
            for c in m.channels:
                _note(f"fitting {model.spec} to {c.label} …")
                f = fit_series(model, [c.values], m.h, inputs=None if inputs is None else [inputs], profile=False,
                               intervals=False)[0]
                axes[c.label] = plan_document(model, f.values, m.h, lengths(m.h, f.n), recorded=f.n, targets=targets)
    except ValueError as exc:
        raise CLIError(str(exc)) from exc
    out = {"source": source, "axes": axes, "ties": ties,
           "command": "torchtea " + " ".join(sys.argv[1:]) if sys.argv[1:] else ""}
    if args.out:
        write(Path(args.out), out)
    if args.json:
        print(dumps(out))
        return 0
    print(f"plan from {source}")
    for label, d in axes.items():
        print("\n".join(plan_lines(label, d)))
        for t in ties.get(label, []):
            print(f"  tie: {t['words']}")
    print("(expected if the model at these values is the truth: from the Whittle likelihood's expected information)")
    if args.out:
        print(f"written {args.out}")
    return 0


def _pooled_channels(args, model, ms: list, inputs: list, names: list, out: Path) -> tuple[dict, list, list]:
    """``check --together``'s loop on each channel (:func:`torchtea.checking.pooled.check_together`): its document
    per label, ``(label, title, result, unit)`` per channel, and the Allan figures drawn."""
    from ..checking.pooled import check_together
    from ..checking.replicates import together_allan_figure
    from ..render.plots import pyplot

    first = ms[0]
    axes, lines, figures = {}, [], []
    step, close = _progress(len(first.labels), f"check {model.spec} together", "channel", bar=not args.json)
    step(0, len(first.labels))
    try:
        for k, label in enumerate(first.labels):
            series = [m.channel(label).values for m in ms]
            inp = None if inputs[0] is None else inputs
            pc = check_together(model, series, first.h, inputs=inp, recordings=names,
                                max_steps=args.max_steps if args.auto else 0, strong=args.strong,
                                simplify=args.auto and not args.no_simplify, level=args.level,
                                screen_level=args.screen_level, fits=args.fits,
                                progress=lambda line, label=label: _note(f"{label}: {line}"))
            unit, title = first.channel(label).unit, first.channel(label).title
            axes[label] = {"unit": unit, **pc.as_dict()}
            lines.append((label, title, pc, unit))
            if not args.no_plots:
                figures.append(together_allan_figure(pyplot(), pc.together, series, first.h, out, label, unit, inp))
            step(k + 1, len(first.labels))
    finally:
        close()
    return axes, lines, figures


def _check_together(args, paths: list) -> int:
    """``torchtea check A B … --together``: each channel's loop on the recordings' pooled likelihood
    (:func:`torchtea.checking.pooled.check_together`)."""
    from ..checking.pooled import POOLED_MEANING
    from ..checking.replicates import pooled_lines, pooled_report
    from ..fitting.together import REPLICATES_MEANING
    from ..noise import parse_model
    from ..render.strictjson import dumps, write
    from ..sensors.measurements import DOCUMENT_MEANING, RECORDING_MEANING

    _together_flags(args, paths, "check", ("add", "exclude_start", "workers", "scheduler", "windows", "exclude",
                                           "no_intervals", "resume"))
    model = parse_model(args.model)
    ms, inputs, names = _several(args, paths, model, "check", 1000, checked=True)
    first = ms[0]
    plan = _export_plan(args, first, args.export)
    out = Path(args.out or f"check-together-{Path(paths[0]).stem}")
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    axes, lines, figures = _pooled_channels(args, model, ms, inputs, names, out)
    togethers = {label: pc.together for label, _, pc, _ in lines}
    if plan:  # (the export holds the axes against the datasheet: its verdicts are the report's, made once)
        _, exported = _pooled_export(args, ms, names, plan, togethers, inputs, out / "export", quiet=True)
        verdicts = {a.label: a.datasheet for a in exported if a.datasheet}
    else:
        fits, spread = _pooled_fits(togethers, first.h)
        verdicts = _datasheet_verdicts(args, first, fits, inputs[0], repeatability=spread)
    for label, verdict in verdicts.items():
        axes[label]["datasheet"] = verdict
    doc = {"together": True, "auto": bool(args.auto), "rate_hz": first.recording.rate_hz,
           "recordings": [m.describe() for m in ms], "axes": axes,
           "meaning": {**RECORDING_MEANING, **DOCUMENT_MEANING, **REPLICATES_MEANING, **POOLED_MEANING,
                       "recordings": "each recording as read, in the order given (in replicates: their names)",
                       "axes": "per channel: its unit, the pooled loop (steps, loop_end, adequate) and the final "
                               "model's fit together (replicates)"},
           "seconds": time.perf_counter() - t0, "warnings": [line for m in ms for line in m.notes()],
           "command": "torchtea " + " ".join(sys.argv[1:]) if sys.argv[1:] else ""}
    write(out / "check.json", doc)
    if args.logdir:
        from ..checking.tblog import write_pooled_runs

        runs = write_pooled_runs(args.logdir, {label: pc for label, _, pc, _ in lines},
                                 {label: [m.channel(label).values for m in ms] for label, _, _, _ in lines}, first.h,
                                 {label: unit for label, _, _, unit in lines}, None if inputs[0] is None else inputs,
                                 figures=not args.no_plots)
        _note(f"TensorBoard: {len(runs)} run(s) in {args.logdir} (tensorboard --logdir {args.logdir})")
    (out / "report.md").write_text(pooled_report(lines, figures, names, first.recording.rate_hz, _units_of(first),
                                                 verdicts), encoding="utf-8")
    if args.json:
        print(dumps(doc))
        return 0
    print(f"{len(ms)} recordings checked together at {first.recording.rate_hz:g} Hz ({', '.join(names)}): noise "
          "parameters shared, each recording its own mean terms")
    for label, title, pc, unit in lines:
        print("\n".join(pooled_lines(label, title, pc, unit)))
    if plan:
        print(f"export of the pooled models: {out / 'export'} (noise terms from all recordings, the cover's data "
              f"and mean terms {names[0]}'s)")
    _print_verdicts(verdicts)
    print("gain: the fall of the pooled BIC; p: likelihood-ratio test of one value in every recording against each "
          "its own; units: " + "; ".join(f"{k}: {v}" for k, v in _units_of(first).items()))
    print(f"report: {out / 'report.md'}; JSON: {out / 'check.json'}")
    return 0


def cmd_check(args) -> int:
    from ..checking.channels import summary_lines
    from ..checking.replicates import windows_lines
    from ..checking.report import write_report
    from ..render.strictjson import dumps

    _check_cluster_flags(args)
    paths = list(args.recording or [])
    if args.together or len(paths) > 1:
        return _check_together(args, paths)
    args.recording = paths[0] if paths else None
    m = _measurements(args, "check", min_samples=1000)
    plan = _export_plan(args, m, args.export)
    if plan and args.no_intervals:
        raise CLIError("--export needs the intervals: drop --no-intervals")
    if _sheets(args) and args.no_intervals:
        raise CLIError("--datasheet compares intervals: drop --no-intervals")
    inputs = None if args.temperature is None else {"temperature": m.temperature_input()}
    if args.windows is not None:  # (refused before any work)
        from ..fitting.windows import window_samples

        try:
            window_samples(args.windows, m.h, m.samples)
        except ValueError as exc:
            raise CLIError(f"--windows: {exc}") from None
    t0 = time.perf_counter()
    out = Path(args.out or f"check-{Path(m.recording.path).stem}")
    checkpoint = _checkpoint(args, out / "partial", len(m.channels))
    results = _check_channels(args, m, inputs, auto=args.auto, intervals=not args.no_intervals, checkpoint=checkpoint)
    meta = m.describe()
    meta.update(command="torchtea " + " ".join(sys.argv[1:]), seconds=time.perf_counter() - t0,
                warnings=m.notes())
    fits = {a: r.fit for a, r in results.items()}
    if plan:  # (the export holds the axes against the datasheet: its verdicts are the report's, made once)
        exported, axes = _export(args, m, plan, fits, inputs, meta, out / "export", quiet=True,
                                 plots=not args.no_plots)
        verdicts = {a.label: a.datasheet for a in axes if a.datasheet}
    else:
        verdicts = _datasheet_verdicts(args, m, fits, inputs)
    windows = _windows(args, m, results, inputs)
    doc = write_report(out, results, meta, plots=not args.no_plots, datasheet=verdicts, windows=windows)
    _tensorboard(args, m, results, windows)
    checkpoint.finish()
    if args.json:
        print(dumps(doc))
        return 0
    if plan:
        from ..export.run import export_lines

        print("\n".join(export_lines(exported, axes, out / "export")))
    print("\n".join(summary_lines(results, {c.label: c.title for c in m.channels})))
    for a, w in (windows or {}).items():
        print(f"{a}: " + "\n".join(windows_lines(w)))
    _print_verdicts(verdicts)
    print(f"units: {'; '.join(f'{k}: {v}' for k, v in _units_of(m).items())}")
    print(f"report: {out / 'report.md'}; JSON: {out / 'check.json'}")
    return 0
