"""What the commands of :mod:`torchtea.cli` share: their one-line error (:class:`CLIError`), help texts and
choices, argparse types, progress on stderr, the reading of a recording from its flags (:func:`_measurements`),
devices, GL memory, the uncertainty settings and the Dask cluster flags. It imports the library's layers and no
command module."""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from ..render import strictjson

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


def _progress(total, desc, unit="step", *, bar=True, estimate=True):
    """Progress on stderr and a callback ``(done, total)``: a tqdm bar on a terminal (when ``bar``), else a
    line every :data:`PROGRESS_EVERY_S` seconds (``torchtea TEA: 12000/44930 steps (27 %), 31 s elapsed, about
    85 s left``; ``estimate`` False: parts too unequal for a time left, which is then not given), so that logs of
    headless runs show that a long run is alive. Returns ``(step, close)``. ``total``
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
        left = ("the time left is not estimated (the parts differ in cost)" if not estimate else
                "about 0 s left" if done >= total_ else
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
    from ..core.memory import parse_memory

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
                     samples_help: str, several: bool = False) -> None:
    """The flags that say how to read a recording, the same on ``identify``, ``fit`` and ``check``
    (:func:`_measurements`); ``several``: the command takes one or more recordings (each read with the same flags)."""
    what = ("a CSV, or a ROS bag (.bag, .db3, .mcap or a ROS 2 bag's folder) (default: the bundled MPU-6050 "
            "recording)")
    if several:
        parser.add_argument("recording", nargs="*", metavar="RECORDING",
                            help=f"recording(s): each {what}; several are fitted together with --together")
    else:
        parser.add_argument("recording", nargs="?", help=f"recording: {what}")
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


def _measurements(args, command: str, *, min_samples: int = 1, sensors=None):
    """The recording named by the reading flags (:func:`_recording_flags`), prepared for ``command``
    (:func:`torchtea.sensors.measurements.prepare`): the ``--columns`` asked for — else every accelerometer and
    gyroscope axis the file names, or only the ``sensors`` given when it has them — with the faults and missing
    samples found; the notes (faults, timing) printed on stderr."""
    from ..sensors.io import read_recording
    from ..sensors.measurements import prepare

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
    for key in ("layout", "units_read", "time_column_skipped", "time_unit", "time_zero_rows"):
        if key in rec.metadata:
            print(f"torchtea: note: {rec.metadata[key]}", file=sys.stderr)
    m = prepare(rec, samples=n, allow_missing=args.allow_missing, min_samples=min_samples, command=command,
                exclude=args.exclude)
    for line in m.notes():
        print(f"torchtea: warning: {line}", file=sys.stderr)
    return m


def _whole(text, flag) -> int:
    try:
        return int(text)
    except ValueError:
        raise CLIError(f"{flag} must be a whole number or 'all', got {text!r}") from None


def _note(line: str) -> None:
    print(f"torchtea: {line}", file=sys.stderr)


def _units_of(m) -> dict:
    """``{sensor: unit}`` of the channels analysed (for the closing line of a command)."""
    out = {}
    for c in m.channels:
        out.setdefault(c.sensor if c.sensor != "signal" else f"column {c.name}", c.unit if c.sensor != "signal"
                       else c.source_unit)
    return out


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
    parser.add_argument("--resume", action="store_true",
                        help="go on with an interrupted run: each channel is kept as it finishes (check, export: "
                             "OUT/partial; fit: OUT.partial), and the same command run again takes the channels "
                             "kept, as it does without this flag; with it, a run that has none to go on is refused")


def _check_cluster_flags(args) -> None:
    if args.workers is not None and args.scheduler:
        raise CLIError("--workers and --scheduler: give one (a local cluster, or the address of a running one)")
    for flag, value in (("--workers", args.workers), ("--threads-per-worker", args.threads_per_worker)):
        if value is not None and value < 1:
            raise CLIError(f"{flag} must be at least 1, got {value}")
    if args.threads_per_worker is not None and not args.workers:
        raise CLIError("--threads-per-worker applies to the local cluster of --workers")


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

        from ..studies.cluster import local_cluster

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


#: Flags that do not change a channel's result (where its files go, how it is shown, where it runs): a run that
#: differs only in them goes on from the channels another kept.
NOT_IDENTITY = ("func", "out", "json", "workers", "threads_per_worker", "scheduler", "connect_timeout", "no_plots",
                "logdir", "debug", "resume", "export", "datasheet", "export_seed", "horizon", "nees", "values",
                "windows", "format", "kept")


def _checkpoint(args, folder, total: int):
    """The :class:`~torchtea.core.checkpoint.Checkpoint` of this command in ``folder``: its identity the flags that
    change a channel's result, the recording's file and the users' modules of effects; the channels it takes from an
    interrupted run said. A stop from here on says what is kept (``args.kept``, read by ``main``); ``total``: the
    channels of the run."""
    from ..core.checkpoint import Checkpoint, CheckpointError, file_identity

    flags = {k: v for k, v in sorted(vars(args).items()) if k not in NOT_IDENTITY and k != "recording"}
    path = args.recording
    identity = {"flags": flags, "recording": file_identity(path) if path is not None else "the bundled recording",
                "effects": [file_identity(_module_file(name)) for name in args.effects]}
    try:
        cp = Checkpoint(folder, identity, resume=True if args.resume else None, say=_note)
    except CheckpointError as exc:
        raise CLIError(str(exc)) from None
    if cp.done:
        _note(f"going on with an interrupted run: {', '.join(cp.done)} kept in {folder} (not run again)")
    args.kept = lambda: _stopped(cp, total)
    return cp


def _module_file(name: str) -> str:
    """The file of a users' module of effects (``--effects``: a .py file, or a module name), for a run's identity: its
    code changes the results."""
    if name.endswith(".py"):
        return name
    import importlib.util

    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        spec = None
    return spec.origin if spec is not None and spec.origin else name


def _stopped(checkpoint, total: int) -> str:
    """What an interrupted run kept, for its last line."""
    if not checkpoint.done:
        return "no channel had finished; nothing was kept"
    return (f"{len(checkpoint.done)} of {total} channels kept in {checkpoint.folder} ({', '.join(checkpoint.done)}); "
            "the same command run again goes on from them")


def _check_channels(args, m, inputs, *, auto: bool, intervals: bool, checkpoint) -> dict:
    """``check`` each channel of ``m`` (then ``--add``, then the loop with ``auto``) → label → result; each kept in
    ``checkpoint`` as it finishes, those it holds not checked again."""
    from ..checking.channels import check_measurements

    levels = {k: getattr(args, k) for k in ("level", "screen_level") if hasattr(args, k)}  # (else check's own)
    client, close_cluster = _cluster(args)
    step, close = _progress(len(m.channels), "check", "channel", bar=not getattr(args, "json", False),
                            estimate=False)
    step(0, len(m.channels))  # (the clock starts with the first channel, not when it is done)
    try:
        results = check_measurements(m, args.model, inputs=inputs, add=getattr(args, "add", []), auto=auto,
                                     max_steps=getattr(args, "max_steps", 6), strong=getattr(args, "strong", None),
                                     simplify=not getattr(args, "no_simplify", False),
                                     exclude_start=getattr(args, "exclude_start", False),
                                     intervals=intervals, levels=levels, progress=step, log=_note, stages=_note,
                                     client=client, fits=getattr(args, "fits", "auto"),
                                     threads=args.threads_per_worker, effects=tuple(args.effects),
                                     done=checkpoint.done, keep=checkpoint.keep)
    finally:
        close()
        close_cluster()
    return results


def _tensorboard(args, m, results: dict, windows: dict | None = None) -> None:
    """``--logdir``: the loop of each channel as a TensorBoard run (:func:`torchtea.checking.tblog.write_check_runs`)."""
    if getattr(args, "logdir", None):
        from ..checking.tblog import write_check_runs

        runs = write_check_runs(args.logdir, results, {c.label: c.unit for c in m.channels},
                                figures=not args.no_plots, windows=windows)
        _note(f"TensorBoard: {len(runs)} run(s) in {args.logdir} (tensorboard --logdir {args.logdir})")
