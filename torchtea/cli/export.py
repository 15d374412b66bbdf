"""``torchtea export`` and the export that ``fit --export`` and ``check --export`` make
(:mod:`torchtea.export.run`), with the datasheet verdicts (:mod:`torchtea.fitting.datasheet`); the recordings that
``--together`` reads and their pooled model's export."""
from __future__ import annotations

import sys
from pathlib import Path

from .common import (
    CLIError,
    _check_channels,
    _check_cluster_flags,
    _checkpoint,
    _cluster,
    _cluster_flags,
    _measurements,
    _model_inputs,
    _note,
    _recording_flags,
    _steps,
    _tensorboard,
)


def add_parsers(sub) -> None:
    """Add the sub-parsers of export to ``sub`` (``build_parser``'s subcommands)."""
    _add_export(sub)


def _add_export(sub) -> None:
    """``torchtea export``'s flags."""
    ex = sub.add_parser("export", help="the noise numbers in a navigation filter's format (Kalibr, VINS, ORB-SLAM3, "
                                       "OpenVINS, IEEE 952, gtsam), with intervals and a cover")
    _recording_flags(ex, columns_help="the columns to export (default: every accelerometer and gyroscope axis)",
                     temperature_help="temperature column (°C) for the temperature effects", samples_default="all",
                     samples_help="use the first N samples (default all)", several=True)
    ex.add_argument("--together", action="store_true",
                    help="several recordings of one sensor: per channel the model checked (or --model fitted) on "
                         "all of them together, its noise parameters shared, and that pooled model exported")
    ex.add_argument("--format", action="append", required=True, metavar="FORMAT",
                    help="kalibr (imu.yaml), vins, orbslam3, openvins (kalibr_imu_chain.yaml), ieee952 (CSV), gtsam (YAML), "
                         "gtsam-python (a module setting PreintegrationCombinedParams) or all; repeatable or "
                         "comma-separated")
    ex.add_argument("--model", help="fit this model SPEC to every axis (default: check each axis to the end, as "
                                    "check --auto, and export the model it ends with)")
    ex.add_argument("--strong", type=float, default=None, metavar="BIC", help="as check --strong")
    ex.add_argument("--max-steps", type=_steps, default=6, help="as check --max-steps")
    ex.add_argument("--no-simplify", action="store_true", help="as check --no-simplify")
    ex.add_argument("--exclude-start", action="store_true", help="as check --exclude-start")
    ex.add_argument("--fits", choices=("auto", "exact", "whittle"), default="auto", help="as check --fits")
    ex.add_argument("--out", help="output directory (default export-<recording name>)")
    ex.add_argument("--no-plots", action="store_true")
    ex.add_argument("--logdir", help="as check --logdir: each axis's loop as a TensorBoard run")
    _export_flags(ex, standalone=True)
    _cluster_flags(ex, "the channels' checks or fits")
    ex.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    """``torchtea export``: check each axis to the end (as ``check --auto``) or fit ``--model``, then export; each
    axis kept in ``OUT/partial`` as it finishes (a stop loses only the axis running; the same command goes on)."""
    _check_cluster_flags(args)
    if args.out:  # (before the checks: a wrong --out found after minutes of fitting loses them)
        _export_folder(args.out)
    paths = list(args.recording or [])
    if args.together or len(paths) > 1:
        return _export_together(args, paths)
    args.recording = paths[0] if paths else None
    if args.logdir and args.model:
        raise CLIError("--logdir shows the check's loop on each axis; with --model there is none: leave one out")
    m = _measurements(args, "an export", min_samples=1000)
    plan = _export_plan(args, m, args.format)
    inputs = None if args.temperature is None else {"temperature": m.temperature_input()}
    meta = m.describe()
    meta.update(command="torchtea " + " ".join(sys.argv[1:]), warnings=m.notes())
    out = Path(args.out or f"export-{Path(m.recording.path).stem}")
    checkpoint = _checkpoint(args, out / "partial", len(m.channels))
    if args.model:
        fits = _fit_channels(args, m, inputs, checkpoint)
    else:
        results = _check_channels(args, m, inputs, auto=True, intervals=True, checkpoint=checkpoint)
        fits = {a: r.fit for a, r in results.items()}
        meta["loop_end"] = {a: r.loop_end for a, r in results.items()}
        _tensorboard(args, m, results)
    _export(args, m, plan, fits, inputs, meta, out, quiet=False, plots=not args.no_plots)
    checkpoint.finish()
    return 0


def _fit_channels(args, m, inputs, checkpoint) -> dict:
    """``export --model``: the model fitted to each channel (here or on the cluster), each kept in ``checkpoint``."""
    from ..core.tasks import run_on_cluster, run_parts
    from ..fitting.recording import fit_channel
    from ..noise import parse_model

    model = parse_model(args.model)
    if any(c.inputs for _, c in model.components) and inputs is None:
        raise CLIError(f"model {model.spec!r} reads the temperature: give --temperature COL")
    channels = {c.label: c for c in m.channels}

    def here(label):
        print(f"torchtea: fitting {model.spec} to {label} …", file=sys.stderr)
        return fit_channel(model, channels[label].values, m.h, inputs=inputs)

    def cluster(todo, made):
        _note(f"fitting {model.spec} to {len(todo)} channels on the cluster …")
        run_on_cluster(client, fit_channel, [
            (a, (model.spec, channels[a].values, m.h), dict(inputs=inputs, effects=tuple(args.effects),
                                                            threads=args.threads_per_worker or 1))
            for a in todo], name="fit", on_result=made)

    client, close_cluster = _cluster(args)
    try:
        return run_parts(list(channels), here, done=checkpoint.done, keep=checkpoint.keep,
                         cluster=None if client is None else cluster)
    finally:
        close_cluster()


def _export_folder(out: str) -> None:
    """``--out`` is the folder an export writes its files in: a name that ends like a file (``imu.yaml``) or an
    existing file is refused with one line, not made a folder of that name."""
    path = Path(out)
    if path.is_file():
        raise CLIError(f"--out {out}: a file; --out is the folder the export writes its files in (imu.yaml, "
                       "export.md, export.json …)")
    if path.suffix.lower() in (".yaml", ".yml", ".csv", ".json", ".md", ".txt"):
        raise CLIError(f"--out {out}: --out is the folder the export writes its files in (the format's own names: "
                       f"imu.yaml, vins_imu.yaml, orbslam3_imu.yaml, ieee952.csv, export.md …), not a file name; e.g. "
                       f"--out {path.with_suffix('')}")


def _export_plan(args, m, names):
    """Check what an export asks for before any fitting (:func:`torchtea.export.run.plan_export`); None: no export
    asked for."""
    from ..export.run import plan_export

    plan = plan_export(m, names, args.horizon)
    if plan is not None and plan.horizon_note:
        _note(f"note: {plan.horizon_note}")
    sheets = _sheets(args)
    if sheets and not any(c.sensor in sheets for c in m.channels):
        raise CLIError(f"--datasheet: the datasheet(s) are for the {', '.join(sheets)}; the channels read are "
                       f"{', '.join(c.label for c in m.channels)}")
    return plan


def _sheets(args) -> dict:
    """``--datasheet`` files read (:func:`torchtea.fitting.datasheet.read_sheets`), once; a bad one is one line."""
    if not hasattr(args, "_sheets"):
        from ..fitting.datasheet import read_sheets

        try:
            args._sheets = read_sheets(getattr(args, "datasheet", None))
        except ValueError as exc:
            raise CLIError(f"--datasheet {exc}") from None
    return args._sheets


def _datasheet_verdicts(args, m, fits: dict, inputs, repeatability: dict | None = None) -> dict:
    """Each axis whose sensor has a ``--datasheet`` against it (:func:`torchtea.fitting.datasheet.compare`), its
    numbers as an export makes them (:func:`torchtea.export.run.export_axes`, no NEES study); ``repeatability``:
    label → the recordings' turn-on bias spread where several were fitted together."""
    from ..export.run import export_axes
    from ..export.terms import parse_horizon
    from ..fitting.datasheet import compare

    sheets = _sheets(args)
    held = {c.label: c.sensor for c in m.channels if c.sensor in sheets and c.label in fits}
    if not held:
        return {}
    _note(f"{', '.join(held)}: against the datasheet(s) {', '.join(sheets[s]['file'] for s in set(held.values()))} …")
    horizon, _ = parse_horizon(getattr(args, "horizon", None), m.h, m.samples)
    axes = export_axes({a: fits[a] for a in held}, m.series(), held, m.h, horizon, inputs=inputs, nees=0)
    return {a.label: compare(a, sheets[a.sensor], fits[a.label], m.h, repeatability=(repeatability or {}).get(a.label))
            for a in axes}


def _export(args, m, plan, fits: dict, inputs, meta: dict, out: Path, *, quiet: bool, plots: bool,
            repeatability: dict | None = None) -> tuple:
    """Export ``fits`` as ``plan`` says into ``out``; unless ``quiet``, print what was written and the datasheet
    verdicts (``repeatability``: label → recordings' turn-on bias spread, held against the datasheet's). Returns the
    export's JSON document and its axes' terms."""
    from ..export.run import export_lines, export_recording

    _note(f"exporting {', '.join(plan.formats)} (cover over τ {plan.horizon[0]:g}–{plan.horizon[1]:g} s; NEES "
          f"study: {args.nees} realisations) …")
    doc, axes = export_recording(m, plan, fits, out, inputs=inputs, meta=meta, nees=args.nees, seed=args.export_seed,
                                 values=args.values, plots=plots, sheets=_sheets(args), repeatability=repeatability)
    if not quiet:
        print("\n".join(export_lines(doc, axes, out)))
        _print_verdicts({a.label: a.datasheet for a in axes if a.datasheet})
    return doc, axes


def _print_verdicts(verdicts: dict) -> None:
    from ..fitting.datasheet import verdict_lines

    if verdicts:
        print("against the datasheet (fitted [95 %] against its value, SI units):")
        for label, doc in verdicts.items():
            print("\n".join(verdict_lines(label, doc)))


def _export_flags(parser, *, standalone: bool) -> None:
    """The flags of an export, the same on ``export``, ``fit --export`` and ``check --export``."""
    from_what = "" if standalone else " (with --export)"
    if not standalone:
        parser.add_argument("--export", action="append", default=[], metavar="FORMAT",
                            help="also export the models the command ends with: kalibr, vins, orbslam3, openvins, ieee952, "
                                 "gtsam, gtsam-python or all (repeatable; the files go to an export folder: "
                                 "check's OUT/export, beside fit's --out file, else export-RECORDING)")
    parser.add_argument("--horizon", metavar="LO:HI",
                        help="time scales (s) the exported white noise + random walk must cover" + from_what
                             + " (default 0.005:100, clipped to the recording: one sample to half its length)")
    parser.add_argument("--values", choices=("covered", "bare"), default="covered",
                        help="the value each format's field takes" + from_what + ": covered (default: the least "
                             "values that cover the fitted model's Allan deviation) or bare (the fitted white noise "
                             "and random walk); the other is in a comment")
    parser.add_argument("--nees", type=int, default=64, metavar="M",
                        help="realisations of the filter NEES study of the bare and covered values" + from_what
                             + " (default 64; 0: not run)")
    parser.add_argument("--export-seed", type=int, default=0, help="seed of the NEES study's simulated series")
    parser.add_argument("--datasheet", action="append", default=[], metavar="FILE",
                        help="hold each axis's N, B, K against a datasheet's (TOML, as torchtea plan --datasheet reads "
                             "it; examples/datasheets/): within spec, worse than spec, or not determined by this "
                             "record and how long would tell; one file per sensor, repeatable")


#: Why ``--exclude`` is refused with ``--together``.
_EXCLUDE_WORDS = (" (it would leave the same seconds out of every recording): leave a stretch out of the one recording "
                  "it disturbs before fitting them together")


def _together_flags(args, paths: list, verb: str, refused: tuple) -> None:
    """Several recordings need ``--together``, and ``--together`` two or more; the flags ``refused`` (attribute
    names) are not available with it: each one clear error."""
    if not args.together:
        raise CLIError(f"{len(paths)} recordings: {verb} them together with --together (one model, its noise "
                       "parameters shared), or one at a time")
    if len(paths) < 2:
        raise CLIError("--together needs two or more recordings")
    for flag in refused:
        if getattr(args, flag, None):
            raise CLIError(f"--{flag.replace('_', '-')} is not available with --together"
                           + _EXCLUDE_WORDS * (flag == "exclude"))


def _several(args, paths: list, model, what: str, min_samples: int, *, checked: bool = False
             ) -> tuple[list, list, list]:
    """The recordings of ``--together``, each read with the same flags: their measurements, model inputs and names;
    refused unless they share their rate and channels. ``checked``: the model is checked, not only fitted — the
    temperature is read wherever ``--temperature`` is given (its diagnostic and effects need it), as a check of
    one recording reads it."""
    ms, inputs = [], []
    for path in paths:
        args.recording = path
        m = _measurements(args, what, min_samples=min_samples)
        ms.append(m)
        if checked and args.temperature is not None:
            inputs.append({"temperature": m.temperature_input()})
        else:
            inputs.append(_model_inputs(args, [model], m, note=len(ms) == 1))
    first = ms[0]
    for m in ms[1:]:
        if abs(m.h - first.h) > 1e-9 * first.h:
            raise CLIError(f"{m.recording.path}: {m.recording.rate_hz:g} Hz, {first.recording.path}: "
                           f"{first.recording.rate_hz:g} Hz: recordings fitted together share their rate")
        if set(m.labels) != set(first.labels):
            raise CLIError(f"{m.recording.path}: channels {', '.join(m.labels)}, {first.recording.path}: "
                           f"{', '.join(first.labels)}: the recordings fitted together need the same channels")
    names = [Path(p).name for p in paths]
    if len(set(names)) < len(names):
        names = [str(p) for p in paths]
    return ms, inputs, names


def _pooled_fits(togethers: dict, h: float) -> tuple[dict, dict]:
    """Each channel's pooled model as the first recording's fit (:meth:`~torchtea.fitting.together.Together.as_fit`)
    and the recordings' turn-on bias spread (:meth:`~torchtea.fitting.together.Together.repeatability`), by label."""
    return ({a: tg.as_fit(0, h) for a, tg in togethers.items()},
            {a: tg.repeatability() for a, tg in togethers.items()})


def _pooled_export(args, ms: list, names: list, plan, togethers: dict, inputs: list, out: Path, *, quiet: bool):
    """The export of each channel's pooled model (``togethers``: label → its
    :class:`~torchtea.fitting.together.Together`): its noise terms from all recordings, the cover's data and mean
    terms the first's, said in the export's document, with the parameters in which the recordings differ and their
    turn-on bias spread held against a datasheet's. Returns what :func:`_export` returns."""
    first = ms[0]
    fits, repeatability = _pooled_fits(togethers, first.h)
    differs = {a: tg.differs for a, tg in togethers.items()}
    meta = first.describe()
    words = (f"the model fitted to {len(ms)} recordings together ({', '.join(names)}): its noise parameters from all "
             f"of them, with the pooled intervals; the mean terms, the cover's data and the figure's {names[0]}'s")
    meta.update(command="torchtea " + " ".join(sys.argv[1:]), warnings=[w for m in ms for w in m.notes()],
                pooled={"recordings": names, "words": words, "differs": differs})
    _note(f"note: exporting {words}")
    for label, d in differs.items():
        if d:
            _note(f"note: {label}: the recordings differ in {', '.join(d)}: the exported number is their compromise")
    return _export(args, first, plan, fits, inputs[0], meta, out, quiet=quiet, plots=not getattr(args, "no_plots", False),
                   repeatability=repeatability)


def _export_together(args, paths: list) -> int:
    """``torchtea export A B … --together``: each channel's model checked on the recordings together (as ``check
    --together --auto``) or ``--model`` fitted to them together, and the pooled models exported."""
    from ..checking.pooled import check_together
    from ..fitting.together import fit_together
    from ..noise import parse_model

    _together_flags(args, paths, "export", ("workers", "scheduler", "logdir", "exclude", "exclude_start", "resume"))
    model = parse_model(args.model or "fractional+white")
    ms, inputs, names = _several(args, paths, model, "an export", 1000, checked=not args.model)
    first = ms[0]
    plan = _export_plan(args, first, args.format)
    inp = None if inputs[0] is None else inputs
    togethers = {}
    for label in first.labels:
        series = [m.channel(label).values for m in ms]
        def say(line, label=label):
            _note(f"{label}: {line}")

        if args.model:
            tg = fit_together(model, series, first.h, inputs=inp, recordings=names, progress=say)
            end = ""
        else:
            pc = check_together(model, series, first.h, inputs=inp, recordings=names, max_steps=args.max_steps,
                                strong=args.strong, simplify=not args.no_simplify, fits=args.fits, progress=say)
            tg, end = pc.together, f"; {pc.loop_end}"
        togethers[label] = tg
        print(f"{label}: {tg.model.spec}: {tg.verdict}{end}")
    out = Path(args.out or f"export-{Path(paths[0]).stem}")
    _pooled_export(args, ms, names, plan, togethers, inputs, out, quiet=False)
    return 0
