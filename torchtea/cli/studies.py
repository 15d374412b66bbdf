"""``torchtea record`` (:mod:`torchtea.sensors.recorder`), ``torchtea montecarlo``
(:func:`torchtea.studies.run.run_sweep`) and ``torchtea presets`` (:mod:`torchtea.engines.presets`)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

from ..render import strictjson
from ..render.text import num as _num
from .common import (
    DEVICE_HELP,
    MEMORY_HELP,
    PRIOR_CHOICES,
    CLIError,
    _add_uncertainty_flags,
    _cluster,
    _count,
    _device,
    _device_name,
    _finite_float,
    _memory,
    _nonneg_float,
    _positive_float,
    _progress,
    _uncertainty_flags,
)


def add_parsers(sub) -> None:
    """Add the sub-parsers of record, montecarlo and presets to ``sub`` (``build_parser``'s subcommands)."""
    _add_record(sub)
    _add_montecarlo(sub)
    _add_presets(sub)


def _add_record(sub) -> None:
    """``torchtea record``'s flags."""
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


def _add_montecarlo(sub) -> None:
    """``torchtea montecarlo``'s flags."""
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


def _add_presets(sub) -> None:
    """``torchtea presets``'s flags."""
    r = sub.add_parser("presets", help="list presets, or print one as TOML")
    r.add_argument("name", nargs="?")
    r.set_defaults(func=cmd_presets)


def cmd_record(args) -> int:
    from ..sensors.recorder import Recorder

    if args.duration is not None and args.duration <= 0:
        raise CLIError("--duration must be positive")
    if args.samples is not None and args.samples < 1:
        raise CLIError("--samples must be at least 1")
    live = None
    if args.live:
        import torch

        from ..sensors.live import LiveEstimator

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


def _studies_from_args(args):
    """The studies of a run (:class:`~torchtea.studies.sweep.SubStudy`) from an optional STUDY.toml, then the
    command-line flags on top (:func:`build_study`); a study file with a ``[sweep]`` table gives one per
    combination (:func:`~torchtea.studies.sweep.build_sweep`), a plain one a single study named None."""
    from ..engines.config import read_toml
    from ..studies.montecarlo import build_study
    from ..studies.sweep import SubStudy, build_sweep

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

    from ..studies.run import run_sweep

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


def cmd_presets(args) -> int:
    from ..engines.config import dumps_toml
    from ..engines.presets import PRESET_H, PRESETS, get_preset

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
