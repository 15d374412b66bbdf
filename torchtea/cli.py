"""torchtea: noise models of inertial sensors — simulate, estimate (the TEA), identify, fit, plan, check, export,
record, montecarlo, presets. torchtea COMMAND --help lists a command's flags."""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from .render import strictjson
from .render.text import num as _num

__all__ = ["main"]


#: torchtea.fitting.recording.BOOTSTRAP_LIMIT, for fit's help without importing the fitting layer (which takes about
#: a second: the help of every command is built at start-up); tests/test_workflows.py checks that the two agree.
BOOTSTRAP_LIMIT = 200_000


class CLIError(Exception):
    """A user-facing error: one line, non-zero exit."""


MEMORY_HELP = ("GL history sums: exact (full history, O(N²) per series), soe[:TOL] (exponential sums, "
               "O(N); default TOL 1e-8) or window:L (last L lags only); default: the config's, else exact")
COMPILE_HELP = ("soe/window memory: run the filter through torch.compile (about 1-2 min to compile on first use, "
                "cached afterwards; pays off for long recordings, not for large batches)")


KFX_UNCERTAINTY_HELP = ("how KFx sees the order and parameter estimates: paper (as exact, the paper's KFx), "
                        "propagated (their covariances added to KFx's P̃, so to its gain) or paper-gain (the paper's "
                        "gain and estimates, with P and S the covariance of that filter's error, the order and "
                        "parameter uncertainty included: TEAConfig's default); see experiments/montecarlo/README.md; default: the settings'")
#: --kfx-uncertainty's choices (settings.KFX_UNCERTAINTIES, without importing torch for --help)
KFX_UNCERTAINTY_CHOICES = ("paper", "propagated", "paper-gain")
ESTIMATE_UNCERTAINTY_HELP = ("the covariance KFo and KFw report for the order and parameter: paper (their own, "
                             "that of a random-walk truth: about twice the error variance for a constant truth) or "
                             "constant-truth (the paper's estimates, bit for bit, with the covariance of their error "
                             "when the true order and parameter are constant; too small for a time-varying order); "
                             "see experiments/montecarlo/README.md; default: the settings'")
#: --estimate-uncertainty's choices (settings.ESTIMATE_UNCERTAINTIES)
ESTIMATE_UNCERTAINTY_CHOICES = ("paper", "constant-truth")
#: montecarlo --prior's choices (studies.montecarlo.PRIORS)
PRIOR_CHOICES = ("preset", "consistent")
#: TEAConfig settings that estimate, identify and montecarlo take as flags: (setting, choices, help)
UNCERTAINTY_FLAGS = (("kfx_uncertainty", KFX_UNCERTAINTY_CHOICES, KFX_UNCERTAINTY_HELP),
                     ("estimate_uncertainty", ESTIMATE_UNCERTAINTY_CHOICES, ESTIMATE_UNCERTAINTY_HELP))


def _add_uncertainty_flags(parser):
    for name, choices, text in UNCERTAINTY_FLAGS:
        parser.add_argument("--" + name.replace("_", "-"), choices=choices, help=text)


def _uncertainty_flags(args) -> dict:
    """The UNCERTAINTY_FLAGS given on the command line, as TEAConfig overrides."""
    return {name: getattr(args, name) for name, _, _ in UNCERTAINTY_FLAGS if getattr(args, name)}


ALLOW_MISSING_HELP = ("predict through missing samples (empty or NaN values, the recorder's NaN rows) instead of "
                      "stopping; they are left out of every statistic and counted in the output")



def _float_arg(accept, requirement):
    """An argparse type: a float for which ``accept(v)`` holds, else one message saying ``requirement``."""

    def parse(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(v) and accept(v)):
            raise argparse.ArgumentTypeError(f"must be {requirement}, got {text}")
        return v

    return parse


_positive_float = _float_arg(lambda v: v > 0, "a positive number")
_nonneg_float = _float_arg(lambda v: v >= 0, "a non-negative number")
_finite_float = _float_arg(lambda v: True, "finite")


def _int_at_least(low: int):
    """An argparse type: a whole number of at least ``low``, else one message saying so."""

    def parse(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {v}")
        return v

    return parse


_count = _int_at_least(2)
_steps = _int_at_least(1)


#: Off a terminal, progress is a line on stderr at most this often (and none for runs shorter than that).
PROGRESS_EVERY_S = 10.0


def _progress(total, desc, unit="step", *, bar=True):
    """Progress on stderr and a callback ``(done, total)``: a tqdm bar on a terminal (when ``bar``), else a
    line every :data:`PROGRESS_EVERY_S` seconds (``torchtea TEA: 12000/44930 steps (27 %), 31 s elapsed, about
    85 s left``), so that logs of headless runs show that a long run is alive. Returns ``(step, close)``. ``total``
    None: the callback's own ``total`` (a library workflow that knows it only once it has read its input)."""
    if bar and sys.stderr.isatty():
        from tqdm import tqdm

        bars = []  # opened at the first report: notes and errors before the work starts print without a bar

        def step(done, _total):
            if not bars:
                bars.append(tqdm(total=total if total is not None else _total, desc=desc, unit=unit, file=sys.stderr,
                                 leave=False, mininterval=0.5))
            bars[0].update(done - bars[0].n)

        return step, lambda: bars and bars[0].close()
    start = []  # (time, done) of the first report and of the last line: the clock starts with the work

    def line(done, _total):
        total_ = total if total is not None else _total
        now = time.monotonic()
        if not start:
            start.extend([now, done, now, done])
            return
        t0, d0, last, d_last = start
        if now - last < PROGRESS_EVERY_S or done <= d0:
            return
        # the time left at the pace since the last line: the first window holds one-time costs (numba's compile
        # made a first line say 'about 5953 s left' of a run of minutes), so the first line gives none
        left = ("about 0 s left" if done >= total_ else
                f"about {(now - last) * (total_ - done) / (done - d_last):.0f} s left" if d_last > d0 and done > d_last
                else "the time left follows at the next line")
        start[2], start[3] = now, done
        print(f"torchtea {desc}: {done}/{total_} {unit}s ({100 * done / total_:.0f} %), {now - t0:.0f} s elapsed, "
              f"{left}", file=sys.stderr, flush=True)

    return line, lambda: None


def _report(out_dir: Path, summary: dict, warnings, as_json: bool) -> bool:
    """Write ``summary.json`` (strict JSON: null for a missing number), print the warnings on stderr and,
    with ``--json``, the summary on stdout. Returns True when the JSON was printed (the caller then prints
    no table)."""
    summary["warnings"] = [w.removeprefix("warning: ") for w in warnings]
    strictjson.write(out_dir / "summary.json", summary)
    for w in warnings:
        print(f"torchtea: {w}", file=sys.stderr)
    if as_json:
        print(strictjson.dumps(summary))
    return as_json


# --------------------------------------------------------------------------- simulate


DEVICE_HELP = ("torch device of the computation: cpu (default; the TEA of the scalar model is then the compiled "
               "engine), cuda or cuda:N (the batched torch engine, float64)")


def _device_name(spec):
    """Parse --device NAME into a torch.device of a kind torchtea runs on (cpu, cuda, cuda:N), whether or not this
    machine has it (a cluster's workers may)."""
    import torch

    try:
        dev = torch.device(spec or "cpu")
    except RuntimeError as exc:
        raise CLIError(f"--device {spec!r}: {exc}") from None
    if dev.type == "mps":
        raise CLIError(f"--device {spec}: torchtea computes in float64, which the MPS backend does not have")
    if dev.type not in ("cpu", "cuda"):
        raise CLIError(f"--device {spec}: use cpu, cuda or cuda:N")
    return dev


def _device(spec):
    """Parse --device NAME into a torch.device that this machine has (one clear error naming it otherwise)."""
    import torch

    dev = _device_name(spec)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise CLIError(f"--device {spec}: no CUDA device is available to this torch {torch.__version__}")
    if dev.type == "cuda" and (dev.index or 0) >= torch.cuda.device_count():
        raise CLIError(f"--device {spec}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return dev


def _memory(spec):
    """Parse --memory SPEC (None keeps the config's)."""
    from .core.memory import parse_memory

    if spec is None:
        return None
    try:
        return parse_memory(spec)
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def _with_memory(cfg, spec):
    from dataclasses import replace

    mem = _memory(spec)
    return cfg if mem is None else replace(cfg, memory=mem)


def cmd_simulate(args) -> int:
    import torch

    if args.model is not None:
        if args.device not in (None, "cpu"):
            raise CLIError(f"--device {args.device}: --model simulations run on the CPU (the state space's compiled "
                           "loop); the paper's model runs on any device")
        return _simulate_model(args)
    absent = [f"--{n}" for n in ("order", "param", "q", "r") if getattr(args, n) is None]
    if absent:
        raise CLIError(f"simulate needs {', '.join(absent)} (the paper's model), or --model SPEC")

    from .sensors.io import write_columns
    from .engines.structure import parse_order_spec
    from .noise.simulate import simulate_noise_model

    try:
        order = parse_order_spec(args.order)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    dev = _device(args.device)  # before any work
    sim = simulate_noise_model(n_steps=args.n, h=args.h, order=order, param=args.param, q=args.q, r=args.r,
                               input_std=args.input_std, seed=args.seed, memory=_memory(args.memory) or "exact",
                               device=dev)
    if dev.type != "cpu":
        from dataclasses import fields, replace

        sim = replace(sim, **{f.name: getattr(sim, f.name).cpu() for f in fields(sim)})
    out = write_columns(args.out, {"t": sim.t, "u": sim.u[:, 0], "x": sim.x[:, 0], "y": sim.y[:, 0],
                                   "alpha": sim.alpha[:, 0]})
    if not bool(torch.isfinite(sim.x).all()):
        print(f"torchtea: warning: the simulated state is not finite (unstable settings?); written to {out}",
              file=sys.stderr)
    print(f"wrote {args.n} samples to {out}", file=sys.stderr)
    return 0


def _simulate_model(args) -> int:
    from .noise.simulate import simulate_recording

    columns = (args.columns or "y").split(",")
    out, truth, model = simulate_recording(args.model, args.out, n_steps=args.n, h=args.h, columns=columns,
                                           sets=args.set, seed=args.seed, temperature_profile=args.temperature_profile,
                                           memory=_memory(args.memory) or "soe")
    print(f"wrote {args.n} samples of {model.spec} in {len(columns)} column(s) to {out} (values in {truth.name})",
          file=sys.stderr)
    return 0


# --------------------------------------------------------------------------- check


def _measurements(args, command: str, *, min_samples: int = 1, sensors=None):
    """The recording named by the reading flags (:func:`_recording_flags`), prepared for ``command``
    (:func:`torchtea.sensors.measurements.prepare`): the ``--columns`` asked for — else every accelerometer and
    gyroscope axis the file names, or only the ``sensors`` given when it has them — with the faults and missing
    samples found; the notes (faults, timing) printed on stderr."""
    from .sensors.io import read_recording
    from .sensors.measurements import prepare

    columns = None
    if args.columns:
        columns = [c.strip() for c in args.columns.split(",")]
        if not all(columns):
            raise CLIError(f"--columns {args.columns!r}: an empty name")
        if len(set(columns)) != len(columns):
            raise CLIError(f"--columns {args.columns!r}: a column named twice")
    n = None if args.samples == "all" else _whole(args.samples, "--samples")
    if n is not None and n < 1:
        raise CLIError(f"--samples must be positive or 'all', got {n}")
    time_column = None if args.time_column == "none" else args.time_column
    rec = read_recording(args.recording, columns=columns, units=args.units, lsb_per_g=args.lsb_per_g,
                         lsb_per_dps=args.lsb_per_dps, rate_hz=args.rate, segment=args.segment,
                         time_column=time_column, temperature_column=getattr(args, "temperature", None),
                         topic=getattr(args, "topic", None))
    if getattr(args, "temperature", "") is None and rec.metadata.get("temperature_topic"):
        args.temperature = rec.metadata["temperature_topic"]  # (a bag's own temperature topic is the input)
        _note(f"temperature: topic {args.temperature!r} of the bag (--temperature names another)")
    if columns is None and sensors:
        chosen = tuple(c for c in rec.channels if c.sensor in sensors)
        if chosen:
            from dataclasses import replace

            rec = replace(rec, channels=chosen)
    if rec.metadata.get("segments") and len(rec.metadata["segments"]) > 1 and args.segment is None:
        print(f"torchtea: note: {Path(rec.path).name} has {len(rec.metadata['segments'])} segments (device resets); "
              f"using the longest, segment {rec.metadata['segment']} (choose with --segment)", file=sys.stderr)
    for key in ("time_column_skipped", "time_unit", "time_zero_rows"):
        if key in rec.metadata:
            print(f"torchtea: note: {rec.metadata[key]}", file=sys.stderr)
    m = prepare(rec, samples=n, allow_missing=args.allow_missing, min_samples=min_samples, command=command,
                exclude=args.exclude)
    for line in m.notes():
        print(f"torchtea: warning: {line}", file=sys.stderr)
    return m


def _check_channels(args, m, inputs, *, auto: bool, intervals: bool) -> dict:
    """``check`` each channel of ``m`` (then ``--add``, then the loop with ``auto``) → label → result."""
    from .checking.channels import check_measurements

    levels = {k: getattr(args, k) for k in ("level", "screen_level") if hasattr(args, k)}  # (else check's own)
    client, close_cluster = _cluster(args)
    step, close = _progress(len(m.channels), "check", "channel", bar=not getattr(args, "json", False))
    step(0, len(m.channels))  # (the clock starts with the first channel, not when it is done)
    try:
        results = check_measurements(m, args.model, inputs=inputs, add=getattr(args, "add", []), auto=auto,
                                     max_steps=getattr(args, "max_steps", 6), strong=getattr(args, "strong", None),
                                     simplify=not getattr(args, "no_simplify", False),
                                     intervals=intervals, levels=levels, progress=step, log=_note, stages=_note,
                                     client=client,
                                     threads=args.threads_per_worker, effects=tuple(args.effects))
    finally:
        close()
        close_cluster()
    return results


def _note(line: str) -> None:
    print(f"torchtea: {line}", file=sys.stderr)


def cmd_check(args) -> int:
    from .checking.channels import summary_lines
    from .checking.report import write_report
    from .render.strictjson import dumps

    _check_cluster_flags(args)
    m = _measurements(args, "check", min_samples=1000)
    plan = _export_plan(args, m, args.export)
    if plan and args.no_intervals:
        raise CLIError("--export needs the intervals: drop --no-intervals")
    if _sheets(args) and args.no_intervals:
        raise CLIError("--datasheet compares intervals: drop --no-intervals")
    inputs = None if args.temperature is None else {"temperature": m.temperature_input()}
    t0 = time.perf_counter()
    results = _check_channels(args, m, inputs, auto=args.auto, intervals=not args.no_intervals)
    name = Path(m.recording.path).stem
    out = Path(args.out or f"check-{name}")
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
    doc = write_report(out, results, meta, plots=not args.no_plots, datasheet=verdicts)
    _tensorboard(args, m, results)
    if args.json:
        print(dumps(doc))
        return 0
    if plan:
        from .export.run import export_lines

        print("\n".join(export_lines(exported, axes, out / "export")))
    print("\n".join(summary_lines(results, {c.label: c.title for c in m.channels})))
    _print_verdicts(verdicts)
    print(f"units: {'; '.join(f'{k}: {v}' for k, v in _units_of(m).items())}")
    print(f"report: {out / 'report.md'}; JSON: {out / 'check.json'}")
    return 0


def _export_plan(args, m, names):
    """Check what an export asks for before any fitting (:func:`torchtea.export.run.plan_export`); None: no export
    asked for."""
    from .export.run import plan_export

    plan = plan_export(m, names, args.horizon)
    if plan is not None and plan.horizon_note:
        _note(f"note: {plan.horizon_note}")
    sheets = _sheets(args)
    if sheets and not any(c.sensor in sheets for c in m.channels):
        raise CLIError(f"--datasheet: the datasheet(s) are for the {', '.join(sheets)}; the channels read are "
                       f"{', '.join(c.label for c in m.channels)}")
    return plan


def _sheets(args) -> dict:
    """``--datasheet`` files read (:func:`torchtea.export.datasheet.read_sheets`), once; a bad one is one line."""
    if not hasattr(args, "_sheets"):
        from .export.datasheet import read_sheets

        try:
            args._sheets = read_sheets(getattr(args, "datasheet", None))
        except ValueError as exc:
            raise CLIError(f"--datasheet {exc}") from None
    return args._sheets


def _datasheet_verdicts(args, m, fits: dict, inputs) -> dict:
    """Each axis whose sensor has a ``--datasheet`` against it (:func:`torchtea.export.datasheet.compare`), its
    numbers as an export makes them (:func:`torchtea.export.run.export_axes`, no NEES study)."""
    from .export.datasheet import compare
    from .export.run import export_axes
    from .export.terms import parse_horizon

    sheets = _sheets(args)
    held = {c.label: c.sensor for c in m.channels if c.sensor in sheets and c.label in fits}
    if not held:
        return {}
    _note(f"{', '.join(held)}: against the datasheet(s) {', '.join(sheets[s]['file'] for s in set(held.values()))} …")
    horizon, _ = parse_horizon(getattr(args, "horizon", None), m.h, m.samples)
    axes = export_axes({a: fits[a] for a in held}, m.series(), held, m.h, horizon, inputs=inputs, nees=0)
    return {a.label: compare(a, sheets[a.sensor], fits[a.label], m.h) for a in axes}


def _export(args, m, plan, fits: dict, inputs, meta: dict, out: Path, *, quiet: bool, plots: bool) -> tuple:
    """Export ``fits`` as ``plan`` says into ``out``; unless ``quiet``, print what was written and the datasheet
    verdicts. Returns the export's JSON document and its axes' terms."""
    from .export.run import export_lines, export_recording

    _note(f"exporting {', '.join(plan.formats)} (cover over τ {plan.horizon[0]:g}–{plan.horizon[1]:g} s; NEES "
          f"study: {args.nees} realisations) …")
    doc, axes = export_recording(m, plan, fits, out, inputs=inputs, meta=meta, nees=args.nees, seed=args.export_seed,
                                 values=args.values, plots=plots, sheets=_sheets(args))
    if not quiet:
        print("\n".join(export_lines(doc, axes, out)))
        _print_verdicts({a.label: a.datasheet for a in axes if a.datasheet})
    return doc, axes


def _tensorboard(args, m, results: dict) -> None:
    """``--logdir``: the loop of each channel as a TensorBoard run (:func:`torchtea.checking.tblog.write_check_runs`)."""
    if getattr(args, "logdir", None):
        from .checking.tblog import write_check_runs

        runs = write_check_runs(args.logdir, results, {c.label: c.unit for c in m.channels},
                                figures=not args.no_plots)
        _note(f"TensorBoard: {len(runs)} run(s) in {args.logdir} (tensorboard --logdir {args.logdir})")


def _print_verdicts(verdicts: dict) -> None:
    from .fitting.plan import verdict_lines

    if verdicts:
        print("against the datasheet (fitted [95 %] against its value, SI units):")
        for label, doc in verdicts.items():
            print("\n".join(verdict_lines(label, doc)))


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


def cmd_export(args) -> int:
    """``torchtea export``: check each axis to the end (as ``check --auto``) or fit ``--model``, then export."""
    from .fitting.recording import fit_channel

    _check_cluster_flags(args)
    if args.out:  # (before the checks: a wrong --out found after minutes of fitting loses them)
        _export_folder(args.out)
    if args.logdir and args.model:
        raise CLIError("--logdir shows the check's loop on each axis; with --model there is none: leave one out")
    m = _measurements(args, "an export", min_samples=1000)
    plan = _export_plan(args, m, args.format)
    inputs = None if args.temperature is None else {"temperature": m.temperature_input()}
    meta = m.describe()
    meta.update(command="torchtea " + " ".join(sys.argv[1:]), warnings=m.notes())
    if args.model:
        from .noise import parse_model

        model = parse_model(args.model)
        if any(c.inputs for _, c in model.components) and inputs is None:
            raise CLIError(f"model {model.spec!r} reads the temperature: give --temperature COL")
        client, close_cluster = _cluster(args)
        try:
            if client is None:
                fits = {}
                for c in m.channels:
                    print(f"torchtea: fitting {model.spec} to {c.label} …", file=sys.stderr)
                    fits[c.label] = fit_channel(model, c.values, m.h, inputs=inputs)
            else:
                from .core.tasks import run_on_cluster

                _note(f"fitting {model.spec} to {len(m.channels)} channels on the cluster …")
                fits = run_on_cluster(client, fit_channel, [
                    (c.label, (model.spec, c.values, m.h), dict(inputs=inputs, effects=tuple(args.effects),
                                                                threads=args.threads_per_worker or 1))
                    for c in m.channels], name="fit")
        finally:
            close_cluster()
    else:
        results = _check_channels(args, m, inputs, auto=True, intervals=True)
        fits = {a: r.fit for a, r in results.items()}
        meta["loop_end"] = {a: r.loop_end for a, r in results.items()}
        _tensorboard(args, m, results)
    out = Path(args.out or f"export-{Path(m.recording.path).stem}")
    _export(args, m, plan, fits, inputs, meta, out, quiet=False, plots=not args.no_plots)
    return 0


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


def _units_of(m) -> dict:
    """``{sensor: unit}`` of the channels analysed (for the closing line of a command)."""
    out = {}
    for c in m.channels:
        out.setdefault(c.sensor if c.sensor != "signal" else f"column {c.name}", c.unit if c.sensor != "signal"
                       else c.source_unit)
    return out


# --------------------------------------------------------------------------- estimate


def _tea_config(args):
    from .engines.config import load_config
    from .engines.presets import get_preset

    if args.config and args.preset:
        raise CLIError("give either --preset or --config, not both")
    if args.config:
        return load_config(args.config), str(args.config)
    name = args.preset or "paper-example1"
    try:
        return get_preset(name), name
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def cmd_estimate(args) -> int:
    from .estimation import estimate_file, estimate_lines

    dev = _device(args.device)  # before any work
    cfg, source = _tea_config(args)
    cfg = _with_memory(cfg, args.memory)
    if _uncertainty_flags(args):
        from dataclasses import replace

        cfg = replace(cfg, **_uncertainty_flags(args))
    name = (args.columns or "y").strip()
    if "," in name:
        raise CLIError(f"--columns {args.columns!r}: estimate runs the TEA on one column")
    step, close = _progress(None, "TEA", bar=not args.json)
    try:  # the run reports (k, N) for steps k = 1 … N − 1: N − 1 steps
        summary = estimate_file(args.file, cfg, column=name, h=args.h, out=args.out, source=source,
                                allow_missing=args.allow_missing, device=dev, compile=args.compile, exclude=args.exclude,
                                progress=lambda done, total: step(done, total - 1),
                                log=lambda line: _note(f"note: {line}"))
    finally:
        close()
    for w in summary["warnings"]:
        print(f"torchtea: warning: {w}", file=sys.stderr)
    if args.json:
        print(strictjson.dumps(summary))
    else:
        print("\n".join(estimate_lines(summary)))
    return 130 if summary["interrupted"] else 0


# --------------------------------------------------------------------------- identify


def _identify_overrides(args):
    """The settings table of ``--config`` (partial, merged onto each axis's MEMS preset) and ``--memory``;
    returns ``(overrides or None, where they came from or None, the memory kind they give)``."""
    from .engines.config import read_toml
    from .identification import axis_configs

    overrides, where = {}, []
    if args.config:
        overrides = read_toml(args.config)
        where.append(f"--config {args.config}")
    mem = _memory(args.memory)
    if mem is not None:
        overrides = dict(overrides, memory=mem.to_dict())
        where.append(f"--memory {args.memory}")
    for name, value in _uncertainty_flags(args).items():
        overrides = dict(overrides, **{name: value})
        where.append(f"--{name.replace('_', '-')} {value}")
    if not overrides:
        return None, None, None  # identify picks the memory by the recording's length
    import torch

    try:  # check the file once, before any work, so its errors name it
        mode = "measured" if args.r == "fitted" else args.r  # the file is checked, not the noise levels
        cfg = axis_configs(torch.zeros(3, 2, 1, dtype=torch.float64), mode, overrides)[0]
    except (TypeError, ValueError) as exc:
        raise CLIError(f"{args.config or '--memory'}: {exc}") from None
    return overrides, " and ".join(where), cfg.memory.kind if "memory" in overrides else None


def _checked_fits(args):
    """``--from-check CHECK.json`` read (:func:`torchtea.checking.check.read_check`); with no ``--columns`` the check's
    channels are identified, with no ``--temperature`` the check's temperature column is read."""
    from .checking.check import read_check

    if args.model != "fractional+white":
        raise CLIError("--from-check takes each channel's model from the check; leave out --model")
    try:
        doc, fits = read_check(args.from_check)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    if not args.columns:
        args.columns = ",".join(doc["channels"][label]["column"] for label in fits)
    asked = {c.strip() for c in args.columns.split(",")}
    plain = [lb for lb, f in fits.items() if f.model.order_name is None and doc["channels"][lb]["column"] in asked]
    if plain:  # (check --auto drops the fractional part where BIC prefers the model without it)
        raise CLIError(f"--from-check {args.from_check}: the check ended without a fractional part on "
                       f"{', '.join(f'{lb} ({fits[lb].model.spec})' for lb in plain)} — BIC preferred the model "
                       "without it — and the TEA estimates a fractional order: leave those channels out (--columns), "
                       "or identify with --model, or check with --auto --no-simplify")
    if args.temperature is None and doc.get("temperature_column"):
        args.temperature = doc["temperature_column"]
    return doc, fits


def _match_check(args, doc: dict, fits: dict, m) -> list:
    from .identification import fits_for

    try:
        return fits_for(doc, fits, m)
    except ValueError as exc:
        raise CLIError(f"--from-check {args.from_check}: {exc}") from None


def cmd_identify(args) -> int:
    from .identification import LONG_INPUT, identify, memory_note
    from .reports.identify import MIN_SAMPLES, identify_lines
    from .reports.report import save_identification

    from .noise import parse_model

    dev = _device(args.device)  # before any work
    model = parse_model(args.model)
    checked = _checked_fits(args) if args.from_check else None
    if (checked or model.spec != "fractional+white") and args.r != "fitted":
        raise CLIError(f"{'--from-check' if checked else '--model ' + model.spec}: the noise levels come from the "
                       "fit (--r fitted)")
    m = _measurements(args, "identify", min_samples=MIN_SAMPLES, sensors=("accelerometer",))
    fits = None
    if checked is not None:
        doc, by_label = checked
        fits = _match_check(args, doc, by_label, m)
        specs = {f.model.spec for f in fits}
        model = parse_model(specs.pop()) if len(specs) == 1 else None  # None: a model per channel
    # the checked models' temperature column came with the check: no note where they do not read it
    inputs = _model_inputs(args, [model] if fits is None else [f.model for f in fits], m, note=fits is None)
    source = f"--from-check {args.from_check}" if fits is not None else f"--model {model.spec}"
    overrides, config_source, memory_kind = _identify_overrides(args)
    note = memory_note(m.samples, memory_kind, "memory" in (overrides or {}) or args.memory is not None)
    if note:
        print(f"torchtea: note: {note}", file=sys.stderr)
    step, close = _progress(None, "TEA " + ",".join(m.labels), bar=not args.json)  # identify's total: all groups
    t0 = time.perf_counter()
    try:
        ident = identify(m, model=model or args.model, r_mode=args.r, overrides=overrides, progress=step, compile=args.compile,
                         partial=True, device=dev, inputs=inputs, fits=fits)
    except ValueError as exc:  # a model the TEA cannot run (tea_view names the component)
        close()
        raise CLIError(f"{source}: {exc}") from None
    if ident.changes and config_source is None:
        config_source = f"the recording's length (soe memory from {LONG_INPUT} samples; --memory exact for the full sums)"
    elapsed = time.perf_counter() - t0
    close()
    rec = m.recording
    out_dir = Path(args.out) if args.out else Path(f"identify-{Path(rec.path).stem}")
    summary = save_identification(ident, out_dir, plots=not args.no_plots, r_mode=args.r, seconds=elapsed,
                                  command="torchtea " + " ".join(sys.argv[1:]) if sys.argv[1:] else "",
                                  config_source=config_source)
    summary["excluded"] = [dict(e) for e in m.excluded]
    summary["meaning"]["excluded"] = "stretches left out on request (--exclude): their samples missing, or cut at the end"
    res = ident.result
    warnings = [f"warning: {w}" for w in summary["warnings"]]
    if not _report(out_dir, summary, warnings, args.json):
        for line in identify_lines(ident, summary, m, model=model, fits=fits, r_mode=args.r,
                                   config_source=config_source, out_dir=out_dir, seconds=elapsed):
            print(line)
    return 130 if res.interrupted else 0


def _whole(text, flag) -> int:
    try:
        return int(text)
    except ValueError:
        raise CLIError(f"{flag} must be a whole number or 'all', got {text!r}") from None


# --------------------------------------------------------------------------- record


def cmd_record(args) -> int:
    from .sensors.recorder import Recorder

    if args.duration is not None and args.duration <= 0:
        raise CLIError("--duration must be positive")
    if args.samples is not None and args.samples < 1:
        raise CLIError("--samples must be at least 1")
    live = None
    if args.live:
        import torch

        from .sensors.live import LiveEstimator

        torch.set_num_threads(1)  # one step of 3 axes is too small to share; leave a core to the reader

        logdir = Path(args.logdir) if args.logdir else Path(args.out).with_name(Path(args.out).stem + "-live")
        live = LiveEstimator(logdir, memory=args.memory or "soe", warmup_s=args.warmup)
        print(f"torchtea record: live estimates in {logdir} (tensorboard --logdir {logdir})", file=sys.stderr)
    rec = Recorder(args.port, args.out, baud=args.baud, duration=args.duration, reconnect=args.reconnect,
                   request_header=None if args.port.startswith("loop://") else 1.0, live=live, samples=args.samples)
    code = rec.run()
    if live is not None and live.summary is not None:
        print(strictjson.dumps(live.summary) if args.json else live.describe())
    return code


# --------------------------------------------------------------------------- montecarlo


def _studies_from_args(args):
    """The studies of a run (:class:`~torchtea.studies.sweep.SubStudy`) from an optional STUDY.toml, then the
    command-line flags on top (:func:`build_study`); a study file with a ``[sweep]`` table gives one per
    combination (:func:`~torchtea.studies.sweep.build_sweep`), a plain one a single study named None."""
    from .engines.config import read_toml
    from .studies.montecarlo import build_study
    from .studies.sweep import SubStudy, build_sweep

    data = read_toml(args.config, "study") if args.config else {}
    memory = _memory(args.memory)
    for name, value in _uncertainty_flags(args).items():
        swept = data.get("sweep", {}).get("estimator", {})
        if isinstance(swept, dict) and name in swept:
            raise CLIError(f"{args.config}: estimator.{name} is swept; leave out --{name.replace('_', '-')}")
        data = dict(data, estimator={**data.get("estimator", {}), name: value})
    flags = {k: getattr(args, k) for k in ("realisations", "seed", "chunk", "log_points", "prior", "preset", "n", "h",
                                            "order", "param", "q", "r", "input_std", "estimator_model")}
    try:
        if "sweep" in data:
            return build_sweep(data, flags, memory=memory, source=args.config)
        study, preset = build_study(data, flags, memory=memory, source=args.config or "study")
        return [SubStudy(None, {}, study, preset)]
    except ValueError as exc:
        raise CLIError(str(exc)) from None


def _cluster(args):
    """``(client, close)`` for --scheduler ADDRESS or --workers N; ``(None, no-op)`` for a run in this process."""
    if args.scheduler:
        from distributed import Client

        try:
            client = Client(args.scheduler, timeout=args.connect_timeout)
        except (OSError, TimeoutError) as exc:
            raise CLIError(f"--scheduler {args.scheduler}: cannot connect ({exc})") from None
        try:  # workers may still be starting (a batch system's jobs, say)
            client.wait_for_workers(1, timeout=args.connect_timeout)
        except TimeoutError:
            client.close()
            raise CLIError(f"--scheduler {args.scheduler}: no worker joined within {args.connect_timeout:g} s "
                           "(--connect-timeout)") from None
        return client, client.close
    if args.workers:
        import signal

        from .studies.cluster import local_cluster

        # the worker processes start with SIGINT ignored: Ctrl-C in a terminal reaches the whole process group,
        # and this process, not the workers, decides what to keep (a worker that the nanny restarts after a fault
        # has the default handling again)
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            cluster, client = local_cluster(args.workers, threads_per_worker=args.threads_per_worker)
        finally:
            signal.signal(signal.SIGINT, previous)

        def close():
            client.close()
            cluster.close()

        return client, close
    return None, lambda: None


def _print_study(result, summary, elapsed) -> None:
    print(f"{result.finished} realisations, {summary['diverged']} diverged, {elapsed:.1f} s")
    for name in ("order", "param"):
        s = summary[name]
        print(f"{name:>6}: bias {s['bias']:+.4g}  std {s['std']:.4g}  RMSE {s['rmse']:.4g}  "
              f"±2σ coverage {_num(s['coverage_2sigma'], '.3f')} (fraction of realisation-steps)")
    for name in ("nees", "nis"):
        c = summary.get(name)
        if c is not None:
            print(f"{name.upper():>6}: mean {c['mean']:.4g} over steps and realisations (1 if consistent); the "
                  f"per-step mean over realisations is inside its 95 % band [{c['band_95'][0]:.3g}, "
                  f"{c['band_95'][1]:.3g}] at {c['fraction_of_steps_inside_band'] * 100:.0f} % of the steps")


def cmd_montecarlo(args) -> int:
    import datetime

    from .studies.run import run_sweep

    if args.workers is not None and args.scheduler:
        raise CLIError("--workers and --scheduler: give one (a local cluster, or the address of a running one)")
    for flag, value in (("--workers", args.workers), ("--shard", args.shard),
                        ("--threads-per-worker", args.threads_per_worker)):
        if value is not None and value < 1:
            raise CLIError(f"{flag} must be at least 1, got {value}")
    sharded = bool(args.workers or args.scheduler)
    if args.shard is not None and not sharded:
        raise CLIError("--shard sets the realisations per Dask task: it needs --workers or --scheduler")
    if args.threads_per_worker is not None and not args.workers:
        raise CLIError("--threads-per-worker applies to the local cluster of --workers")
    # with --scheduler the workers' devices are theirs: only the name is checked here
    device = _device(args.device) if not args.scheduler else _device_name(args.device)
    studies = _studies_from_args(args)
    sweep = studies[0].name is not None
    logdir = Path(args.logdir) if args.logdir else Path("runs") / datetime.datetime.now().strftime("mc-%Y%m%d-%H%M%S")

    def progress(total, unit):
        step, close_bar = _progress(total, "montecarlo", unit, bar=not args.json)
        return _progress_to_file(step, args.progress_file, unit), close_bar

    client, close = _cluster(args)
    try:
        run = run_sweep(studies, logdir, client=client, shard=args.shard,
                        device=None if client is not None and args.device is None else device, progress=progress,
                        figures=args.figures, sweep_source=Path(args.config).read_text() if sweep else None)
    finally:
        close()
    if not any(r is not None and r.finished for r in run.results):
        if run.failure:
            raise CLIError(run.failure)
        raise CLIError("interrupted before any realisation finished; nothing to summarise")
    for s, result, summary, said, d in zip(studies, run.results, run.summaries, run.warnings, run.dirs):
        if summary is None:
            continue
        if sweep:
            for w in said:
                print(f"torchtea: [{s.name}] {w}", file=sys.stderr)
            continue
        for w in said:
            print(f"torchtea: {w}", file=sys.stderr)
        if args.json:
            print(strictjson.dumps(summary))
        else:
            _print_study(result, summary, run.seconds)
            print(f"run directory: {d}   (tensorboard --logdir {d.parent})")
    if sweep:
        table, rows = run.table, run.table["studies"]
        if args.json:
            print(strictjson.dumps(table))
        else:
            not_run = table["not_run"]
            print(f"{len(rows)} sub-studies in {run.seconds:.1f} s" + (f"; not run: {', '.join(not_run)}" if not_run else ""))
            print(f"{'sub-study':<40} {'R':>6} {'order bias':>11} {'order RMSE':>11} {'param bias':>11} "
                  f"{'param RMSE':>11} {'NEES':>9}")
            for s in rows:
                print(f"{s['sweep']['name']:<40} {s['realisations']:>6} {s['order']['bias']:>+11.4g} "
                      f"{s['order']['rmse']:>11.4g} {s['param']['bias']:>+11.4g} {s['param']['rmse']:>11.4g} "
                      f"{_num(s.get('nees', {}).get('mean', math.nan), '9.4g')}")
            print(f"run directories: {logdir}/<sub-study>   (tensorboard --logdir {logdir}: the HParams tab "
                  "compares them)")
    if run.failure:
        print(f"torchtea: error: {run.failure}; the finished shards are kept in {logdir}", file=sys.stderr)
        return 1
    return 130 if run.interrupted else 0


def _progress_to_file(step, path, unit):
    """The progress callback: the bar or line ``step``, and ``done total UNITs`` rewritten in ``path``."""
    def progress(done, total):
        step(done, total)
        if path:
            Path(path).write_text(f"{done} {total} {unit}s\n")

    return progress


# --------------------------------------------------------------------------- presets


def cmd_presets(args) -> int:
    from .engines.config import dumps_toml
    from .engines.presets import PRESET_H, PRESETS, get_preset

    if args.name is None:
        for name in PRESETS:
            print(f"{name}  (h = {PRESET_H[name]:g} s)")
        return 0
    try:
        cfg = get_preset(args.name)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    print(dumps_toml({"preset": args.name, **cfg.to_dict()}), end="")
    return 0


# --------------------------------------------------------------------------- main


UNITS_HELP = ("unit of the columns: one for all (g, ms2, rad/s, deg/s, counts) or one per column "
              "(e.g. g,g,g,deg/s,deg/s,deg/s); counts take --lsb-per-g / --lsb-per-dps. A torchtea recording is in "
              "m/s² and rad/s, the bundled format in counts (±2 g, ±250 °/s); a generic CSV needs it")


EXCLUDE_HELP = ("leave out the samples from FROM to TO seconds after the first sample (as the reports give times): "
                "they become missing, or are cut where they reach the end; repeatable")


def _stretch(text: str) -> tuple:
    """``FROM:TO`` (seconds) → ``(from, to)``."""
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(a), float(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give FROM:TO in seconds, e.g. 633:655") from None


def _recording_flags(parser, *, columns_help: str, temperature_help: str | None, samples_default: str,
                     samples_help: str) -> None:
    """The flags that say how to read a recording, the same on ``identify``, ``fit`` and ``check``
    (:func:`_measurements`)."""
    parser.add_argument("recording", nargs="?", help="recording: a CSV, or a ROS bag (.bag, .db3, .mcap or a ROS 2 "
                                                     "bag's folder) (default: the bundled MPU-6050 recording)")
    parser.add_argument("--topic", help="ROS bag: its sensor_msgs/Imu topic (default: the bag's only one; the bag's "
                                        "topics are listed when it has several)")
    parser.add_argument("--columns", help=columns_help)
    parser.add_argument("--units", help=UNITS_HELP)
    parser.add_argument("--lsb-per-g", type=_positive_float, help="accelerometer counts per g (bundled format: 16384)")
    parser.add_argument("--lsb-per-dps", type=_positive_float,
                        help="gyroscope counts per °/s (bundled format: 131)")
    parser.add_argument("--rate", type=_positive_float, help="sample rate [Hz] if the file does not say")
    parser.add_argument("--segment", type=int, help="torchtea recording: which segment (default: the longest)")
    parser.add_argument("--time-column", default="auto",
                        help="column of time stamps, checked against the rate (default: the first of t, t_s, time, "
                             "sec, timestamp, stamp, %%time, …; seconds unless the name or the spacing says ns, µs "
                             "or ms; 'none' ignores them). A generic CSV without --rate takes the stamps' mean rate")
    if temperature_help is not None:
        parser.add_argument("--temperature", metavar="COL", help=temperature_help + "; ROS bag: its "
                            "sensor_msgs/Temperature topic (default: the bag's only one)")
    parser.add_argument("--samples", default=samples_default, help=samples_help)
    parser.add_argument("--allow-missing", action="store_true", help=ALLOW_MISSING_HELP)
    parser.add_argument("--exclude", action="append", default=[], type=_stretch, metavar="FROM:TO", help=EXCLUDE_HELP)


def _cluster_flags(parser, what: str) -> None:
    """--workers, --threads-per-worker, --scheduler and --connect-timeout, as ``montecarlo`` has them (:func:`_cluster`);
    ``what`` names the tasks."""
    parser.add_argument("--workers", type=int, help=f"run {what} as tasks of a local Dask cluster of N processes")
    parser.add_argument("--threads-per-worker", type=int,
                        help="--workers: torch/numba threads of each process (default: the cores shared out)")
    parser.add_argument("--scheduler", help=f"run {what} as tasks of the Dask cluster of this scheduler "
                                            "(tcp://host:8786)")
    parser.add_argument("--connect-timeout", type=float, default=30.0,
                        help="--scheduler: seconds to wait for the scheduler and its first worker (default 30)")


def _check_cluster_flags(args) -> None:
    if args.workers is not None and args.scheduler:
        raise CLIError("--workers and --scheduler: give one (a local cluster, or the address of a running one)")
    for flag, value in (("--workers", args.workers), ("--threads-per-worker", args.threads_per_worker)):
        if value is not None and value < 1:
            raise CLIError(f"{flag} must be at least 1, got {value}")
    if args.threads_per_worker is not None and not args.workers:
        raise CLIError("--threads-per-worker applies to the local cluster of --workers")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="torchtea", description=__doc__)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.add_argument("--effects", action="append", default=[], metavar="MODULE",
                   help="import MODULE (a module name or a .py file) before the command: the effects it registers "
                        "(torchtea.effects.register) can be named in --model and --add; may be repeated")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="simulate the fractional noise model (43)–(45), or any --model, to CSV")
    s.add_argument("--n", type=_count, required=True, help="number of samples")
    s.add_argument("--h", type=_positive_float, required=True, help="sample time [s]")
    s.add_argument("--order", help="SPEC: a number, linear:A0,SLOPE or parabolic:A0,C (the paper's model)")
    s.add_argument("--param", type=_finite_float, help="the parameter f (A = f) (the paper's model)")
    s.add_argument("--q", type=_nonneg_float, help="variance of the process noise ω (the paper's model)")
    s.add_argument("--r", type=_nonneg_float, help="variance of the measurement noise ν (the paper's model)")
    s.add_argument("--model", help="a noise model SPEC (e.g. fractional+white+sinusoid): writes t, y and temp; "
                                   "parameters MEMS-like unless --set")
    s.add_argument("--set", action="append", default=[], metavar="[COLUMN:]NAME=VALUE",
                   help="--model: a parameter value, e.g. sinusoid.frequency_hz=3.37, for every column or one "
                        "(gx:white.r=1e-8) (repeatable)")
    s.add_argument("--columns", help="--model: the columns to write, each its own draw of the model (default y; e.g. "
                                     "ax,ay,az,gx,gy,gz for a six-axis recording, read back with --units)")
    s.add_argument("--temperature-profile", default="25,3,60,0.2", metavar="T0,WARMUP,TAU_S,WANDER",
                   help="--model: the temperature written to 'temp' and read by temperature components: start "
                        "°C, warm-up °C, its time constant s, slow wander sd °C (default 25,3,60,0.2)")
    s.add_argument("--input-std", type=_nonneg_float, help="known input u ~ N(0, S²) (zero when absent)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--memory", help=MEMORY_HELP)
    s.add_argument("--device", help="torch device of the paper model's recursion: cpu (default), cuda or cuda:N "
                                    "(the same seeded draws; --model runs on the CPU)")
    s.add_argument("--out", required=True, help="output CSV (t,u,x,y,alpha)")
    s.set_defaults(func=cmd_simulate)

    e = sub.add_parser("estimate", help="run the TEA on a CSV with column y (and u)")
    e.add_argument("file")
    e.add_argument("--columns", help="the column to estimate (default y; with u, t read when there)")
    e.add_argument("--h", type=_positive_float,
                   help="sample time [s] (default: the mean interval of a time column 't', e.g. simulate's output)")
    e.add_argument("--preset", help="named settings (see `torchtea presets`); default paper-example1")
    e.add_argument("--config", help="TOML settings file")
    e.add_argument("--out", help="trajectory CSV (default: FILE.tea.csv next to the input)")
    e.add_argument("--allow-missing", action="store_true", help=ALLOW_MISSING_HELP)
    e.add_argument("--exclude", action="append", default=[], type=_stretch, metavar="FROM:TO", help=EXCLUDE_HELP)
    e.add_argument("--memory", help=MEMORY_HELP)
    _add_uncertainty_flags(e)
    e.add_argument("--compile", action="store_true", help=COMPILE_HELP)
    e.add_argument("--device", help=DEVICE_HELP)
    e.add_argument("--json", action="store_true", help="print a JSON summary")
    e.set_defaults(func=cmd_estimate)

    i = sub.add_parser("identify", help="identify the noise model of an IMU recording's channels with the TEA")
    _recording_flags(i, columns_help="the columns to identify, any number (default: the accelerometer's x, y, z; "
                                     "e.g. gx,gy,gz for the gyroscope)",
                     temperature_help="temperature column (°C) for a --model with temperature components",
                     samples_default="all",
                     samples_help="use the first N samples (at least 100; the paper used 3000, 30 s), or 'all' "
                                  "(default; from 20 000 samples on the TEA runs with soe memory, O(N))")
    i.add_argument("--r", choices=("fitted", "measured", "paper"), default="fitted",
                   help="R, Rᵒ, Rʷ per channel: fitted by likelihood with Q (default), the channel's measured "
                        "variance (the paper's rule) or the paper's printed values")
    i.add_argument("--model", default="fractional+white", metavar="SPEC",
                   help="the noise model the TEA runs (default the paper's fractional+white), e.g. the one check "
                        "ended with: fractional+white+random-walk+sinusoid. It is fitted to each channel first; "
                        "its other states join KFx's state, its means are removed at their fitted values; a "
                        "sensor filter (low-pass, digital-filter) is refused")
    i.add_argument("--from-check", metavar="CHECK_JSON",
                   help="run the TEA on the models a 'torchtea check' ended with, channel by channel, at their fitted "
                        "values (its check.json; the same recording and samples; by default its channels and "
                        "temperature column)")
    i.add_argument("--config", help="TOML settings applied on top of the paper's MEMS settings")
    i.add_argument("--out", help="output directory (default identify-<recording name>)")
    i.add_argument("--no-plots", action="store_true")
    i.add_argument("--memory", help=MEMORY_HELP)
    _add_uncertainty_flags(i)
    i.add_argument("--compile", action="store_true", help=COMPILE_HELP)
    i.add_argument("--device", help=DEVICE_HELP + "; the --r fitted noise-level fit runs on the CPU whatever the "
                                                  "device (its exact Kalman filter is compiled for the CPU)")
    i.add_argument("--json", action="store_true", help="print a JSON summary")
    i.set_defaults(func=cmd_identify)

    fp = sub.add_parser("fit", help="fit a noise model by maximum likelihood, with intervals")
    _recording_flags(fp, columns_help="the columns to fit, any number (default: every accelerometer and gyroscope "
                                      "axis the file names)",
                     temperature_help="temperature column (°C) for temperature-bias / temperature-order (a torchtea "
                                      "recording: temp)", samples_default="all",
                     samples_help="use the first N samples (default all)")
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

    pl = sub.add_parser("plan", help="how long to record: the expected 95 %% intervals of the noise numbers by record "
                                     "length, from a recording's fit, a check, or a datasheet")
    _recording_flags(pl, columns_help="the columns to plan for (default: every accelerometer and gyroscope axis)",
                     temperature_help="temperature column (°C), for a --model with temperature effects",
                     samples_default="all", samples_help="use the first N samples (default all)")
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

    ck = sub.add_parser("check", help="test a noise model against a recording and rank the effects it is missing")
    _recording_flags(ck, columns_help="the columns to check, any number (default: every accelerometer and gyroscope "
                                      "axis the file names, both sensors side by side)",
                     temperature_help="temperature column (°C): enables the temperature diagnostic and the "
                                      "temperature effects (a torchtea recording: temp)", samples_default="all",
                     samples_help="use the first N samples (default all)")
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
    ck.add_argument("--strong", type=float, default=None, metavar="BIC",
                    help="--auto goes on past an adequate model while the best suggestion gains at least this much "
                         "BIC (default 10, checking.check.STRONG_BIC: very strong evidence; inf stops at adequacy)")
    ck.add_argument("--level", type=float, default=0.01, help="level of each diagnostic (default 0.01)")
    ck.add_argument("--screen-level", type=float, default=0.05,
                    help="family level of the effect screens (default 0.05: on data from the model, at most "
                         "5 %% of checks suggest anything)")
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

    ex = sub.add_parser("export", help="the noise numbers in a navigation filter's format (Kalibr, VINS, ORB-SLAM3, "
                                       "OpenVINS, IEEE 952, gtsam), with intervals and a cover")
    _recording_flags(ex, columns_help="the columns to export (default: every accelerometer and gyroscope axis)",
                     temperature_help="temperature column (°C) for the temperature effects", samples_default="all",
                     samples_help="use the first N samples (default all)")
    ex.add_argument("--format", action="append", required=True, metavar="FORMAT",
                    help="kalibr (imu.yaml), vins, orbslam3, openvins (kalibr_imu_chain.yaml), ieee952 (CSV), gtsam (YAML), "
                         "gtsam-python (a module setting PreintegrationCombinedParams) or all; repeatable or "
                         "comma-separated")
    ex.add_argument("--model", help="fit this model SPEC to every axis (default: check each axis to the end, as "
                                    "check --auto, and export the model it ends with)")
    ex.add_argument("--strong", type=float, default=None, metavar="BIC", help="as check --strong")
    ex.add_argument("--max-steps", type=_steps, default=6, help="as check --max-steps")
    ex.add_argument("--no-simplify", action="store_true", help="as check --no-simplify")
    ex.add_argument("--out", help="output directory (default export-<recording name>)")
    ex.add_argument("--no-plots", action="store_true")
    ex.add_argument("--logdir", help="as check --logdir: each axis's loop as a TensorBoard run")
    _export_flags(ex, standalone=True)
    _cluster_flags(ex, "the channels' checks or fits")
    ex.set_defaults(func=cmd_export)

    rc = sub.add_parser("record", help="record a protocol-v1 IMU from a serial port (docs/protocol.md)")
    rc.add_argument("--port", required=True, help="serial device (/dev/ttyACM0, COM3) or pyserial URL")
    rc.add_argument("--baud", type=int, default=115200, help="baud rate (default 115200, as the firmware)")
    rc.add_argument("--duration", type=float, help="stop after S seconds (default: Ctrl-C or the port going away)")
    rc.add_argument("--samples", type=int, help="stop once this many samples (rows, missing ones included) are recorded")
    rc.add_argument("--reconnect", action="store_true", help="when the port goes away, wait for it to come back")
    rc.add_argument("--out", required=True, help="recording CSV; the sidecar REC.json is written beside it")
    rc.add_argument("--live", action="store_true", help="run the TEA on the three axes while recording (TensorBoard)")
    rc.add_argument("--logdir", help="live mode: TensorBoard directory (default REC-live/)")
    rc.add_argument("--warmup", type=float, default=2.0,
                    help="live mode: seconds of data that set each axis's mean and R before the TEA starts")
    rc.add_argument("--memory", help="live mode: " + MEMORY_HELP.replace("default: the config's, else exact", "default soe"))
    rc.add_argument("--json", action="store_true", help="live mode: print the final estimates as JSON")
    rc.set_defaults(func=cmd_record)

    mc = sub.add_parser("montecarlo", help="Monte Carlo study of the TEA, logged to TensorBoard")
    mc.add_argument("--config", help="STUDY.toml: realisations, seed, chunk, log_points, [truth], [estimator], and "
                                     "[sweep] (lists of truth and estimator values: one sub-study per combination)")
    mc.add_argument("--realisations", type=int)
    mc.add_argument("--seed", type=int)
    mc.add_argument("--chunk", type=int, help="realisations per batch (default: sized to memory)")
    mc.add_argument("--log-points", type=int, help="steps logged to TensorBoard and the fan charts (default ≤ 1000; "
                                                   "fewer above 67 000 realisations, to keep them within 1 GiB)")
    mc.add_argument("--workers", type=int, help="run the study as shards on a local Dask cluster of N processes")
    mc.add_argument("--threads-per-worker", type=int,
                    help="--workers: torch/numba threads of each process (default: the cores shared out)")
    mc.add_argument("--scheduler", help="run the study as shards on the Dask cluster of this scheduler "
                                        "(e.g. tcp://host:8786); --device then names each worker's device")
    mc.add_argument("--connect-timeout", type=float, default=30.0,
                    help="--scheduler: seconds to wait for the scheduler and its first worker (default 30)")
    mc.add_argument("--shard", type=int, help="realisations per Dask task (default: ~4 per worker thread, at most "
                                              "one memory chunk)")
    mc.add_argument("--logdir", help="run directory (default runs/mc-<time>)")
    mc.add_argument("--preset", help="estimator settings (default paper-example1); a paper example also sets the truth")
    mc.add_argument("--n", type=_count)
    mc.add_argument("--h", type=_positive_float)
    mc.add_argument("--order")
    mc.add_argument("--param", type=_finite_float)
    mc.add_argument("--q", type=_nonneg_float)
    mc.add_argument("--r", type=_nonneg_float)
    mc.add_argument("--input-std", type=_nonneg_float)
    mc.add_argument("--memory", help="estimator's " + MEMORY_HELP)
    mc.add_argument("--estimator-model", metavar="SPEC",
                    help="the noise model the TEA runs, for a study whose [truth] is a model (model = SPEC with a "
                         "[truth.values] table): e.g. fractional+white on a fractional+white+random-walk truth "
                         "(default: the truth's model)")
    mc.add_argument("--prior", choices=PRIOR_CHOICES,
                    help="where each realisation's filters start: 'preset' (default), the estimator's x0 for all; "
                         "'consistent', drawn per realisation from the estimator's P0 around the truth, the condition "
                         "under which a consistent filter's NEES is 1 and its ±2σ coverage 95 %% from the start")
    _add_uncertainty_flags(mc)
    mc.add_argument("--device", help=DEVICE_HELP)
    mc.add_argument("--figures", action="store_true",
                    help="also the matplotlib fan charts as TensorBoard images (the margin charts in CUSTOM SCALARS "
                         "are always written; the images add ~1.5 s)")
    mc.add_argument("--progress-file", help="rewrite 'done total unit' in this file after each chunk or shard "
                                            "(headless runs)")
    mc.add_argument("--json", action="store_true")
    mc.set_defaults(func=cmd_montecarlo)

    r = sub.add_parser("presets", help="list presets, or print one as TOML")
    r.add_argument("name", nargs="?")
    r.set_defaults(func=cmd_presets)
    return p


# --------------------------------------------------------------------------- fit


def _model_inputs(args, models, m, *, note: bool = True):
    """The input channels ``models`` read (``{"temperature": (N,)}``) from ``--temperature``, or None; a model that
    needs one without the flag is an error, the flag without such a model a note (unless ``note`` is False)."""
    needs = sorted({name for model in models for _, c in model.components for name in c.inputs})
    unique = sorted({repr(model.spec) for model in models})
    what = f"model {unique[0]}" if len(unique) == 1 else f"the models ({', '.join(unique)})"
    if needs and args.temperature is None:
        raise CLIError(f"{what} needs the input channel(s) {', '.join(needs)}: give --temperature COL")
    if args.temperature is not None and not needs:
        if note:
            print(f"torchtea: note: {what} has no temperature component; --temperature is not used "
                  "(add temperature-bias or temperature-order)", file=sys.stderr)
        return None
    return None if args.temperature is None else {"temperature": m.temperature_input()}


def cmd_fit(args) -> int:
    from .fitting.recording import fit_lines, fit_recording
    from .noise import parse_model
    from .render.strictjson import dumps, write

    model = parse_model(args.model)
    _check_cluster_flags(args)
    m = _measurements(args, "a fit", min_samples=100)
    if args.datasheet and not args.export:
        raise CLIError("--datasheet holds the exported numbers against the datasheet: give --export FORMAT too "
                       "(or use check --datasheet)")
    plan = _export_plan(args, m, args.export)
    inputs = _model_inputs(args, [model], m)
    client, close_cluster = _cluster(args)
    step, close = _progress(len(m.channels), "fit " + model.spec, "channel", bar=not args.json)
    step(0, len(m.channels))  # (the clock starts with the first channel, not when it is done)
    try:
        doc, fits = fit_recording(m, model, inputs=inputs, method=args.method, bootstrap=args.bootstrap,
                                  seed=args.seed, profile=args.profile, progress=step,
                                  log=lambda line: _note(f"note: {line}"), client=client,
                                  threads=args.threads_per_worker, effects=tuple(args.effects))
    finally:
        close()
        close_cluster()
    doc["command"] = "torchtea " + " ".join(sys.argv[1:]) if sys.argv[1:] else ""
    if args.out:
        write(Path(args.out), doc)
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


def cmd_plan(args) -> int:
    """``torchtea plan``: how long to record (:mod:`torchtea.fitting.plan`)."""
    from .fitting.mle import fit_series
    from .fitting.plan import datasheet_model, parse_target, plan_document, plan_lines, read_datasheet
    from .noise import parse_model
    from .render.strictjson import dumps, write

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
        if args.datasheet:
            sheet = read_datasheet(args.datasheet)
            model, values, h, terms, fixed = datasheet_model(sheet)
            source = f"datasheet {args.datasheet}" + (f" ({sheet['source']})" if sheet["source"] else "")
            if sheet.get("B_convention") == "allan-minimum":
                source += ("; its B read as the Allan deviation's minimum, IEEE 952's B = that / 0.664 (convention = "
                           "\"ieee952\" in the file if it gives the coefficient)")
            axes[sheet["sensor"]] = plan_document(model, values, h, lengths(h, None), targets=targets, fixed=fixed,
                                                  terms=terms)
        elif args.from_check:
            from .checking.check import read_check

            doc, fits = read_check(args.from_check)
            h = 1.0 / float(doc["rate_hz"])
            source = f"check {args.from_check}"
            for label, f in fits.items():
                axes[label] = plan_document(f.model, f.values, h, lengths(h, f.n), recorded=f.n, targets=targets)
                ties[label] = doc["axes"][label].get("ties", [])
        else:
            model = parse_model(args.model)
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


def main(argv=None) -> int:
    from .effects import import_effects
    from .sensors.io import InputError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        for name in args.effects:
            import_effects(name)
        return args.func(args)
    except (CLIError, InputError) as exc:
        if args.debug:
            raise
        print(f"torchtea: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"torchtea: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("torchtea: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
