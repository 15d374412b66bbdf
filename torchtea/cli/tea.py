"""The TEA's commands: ``torchtea estimate`` (one column, :func:`torchtea.estimation.estimate_file`) and
``torchtea identify`` (an IMU recording's channels, :func:`torchtea.identification.identify`)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from ..render import strictjson
from .common import (
    ALLOW_MISSING_HELP,
    COMPILE_HELP,
    DEVICE_HELP,
    EXCLUDE_HELP,
    MEMORY_HELP,
    CLIError,
    _add_uncertainty_flags,
    _device,
    _measurements,
    _memory,
    _model_inputs,
    _note,
    _positive_float,
    _progress,
    _recording_flags,
    _report,
    _stretch,
    _uncertainty_flags,
    _with_memory,
)


def add_parsers(sub) -> None:
    """Add the sub-parsers of estimate and identify to ``sub`` (``build_parser``'s subcommands)."""
    _add_estimate(sub)
    _add_identify(sub)


def _add_estimate(sub) -> None:
    """``torchtea estimate``'s flags."""
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


def _add_identify(sub) -> None:
    """``torchtea identify``'s flags."""
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


def _tea_config(args):
    from ..engines.config import load_config
    from ..engines.presets import get_preset

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
    from ..estimation import estimate_file, estimate_lines

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


def _identify_overrides(args):
    """The settings table of ``--config`` (partial, merged onto each axis's MEMS preset) and ``--memory``;
    returns ``(overrides or None, where they came from or None, the memory kind they give)``."""
    from ..engines.config import read_toml
    from ..identification import axis_configs

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
    from ..checking.check import read_check

    if args.model != "fractional+white":
        raise CLIError("--from-check takes each channel's model from the check; leave out --model")
    try:
        doc, fits = read_check(args.from_check)
    except ValueError as exc:
        raise CLIError(str(exc)) from None
    columns = {label: doc.get("channels", {}).get(label, {}).get("column", label) for label in fits}
    if not args.columns:
        args.columns = ",".join(columns.values())
    asked = {c.strip() for c in args.columns.split(",")}
    plain = [lb for lb, f in fits.items() if f.model.order_name is None and columns[lb] in asked]
    if plain:  # (check --auto drops the fractional part where BIC prefers the model without it)
        raise CLIError(f"--from-check {args.from_check}: the check ended without a fractional part on "
                       f"{', '.join(f'{lb} ({fits[lb].model.spec})' for lb in plain)} — BIC preferred the model "
                       "without it — and the TEA estimates a fractional order: leave those channels out (--columns), "
                       "or identify with --model, or check with --auto --no-simplify")
    if args.temperature is None and isinstance(doc.get("temperature_column"), str):
        args.temperature = doc["temperature_column"]
    return doc, fits


def _match_check(args, doc: dict, fits: dict, m) -> list:
    from ..identification import fits_for

    try:
        return fits_for(doc, fits, m)
    except ValueError as exc:
        raise CLIError(f"--from-check {args.from_check}: {exc}") from None


def cmd_identify(args) -> int:
    from ..identification import LONG_INPUT, identify, memory_note
    from ..noise import parse_model
    from ..reports.identify import MIN_SAMPLES, identify_lines
    from ..reports.report import save_identification

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
