"""The command line, ``torchtea COMMAND`` (``torchtea.cli:main``, also ``python -m torchtea.cli``): each command
parses its flags, calls one library workflow (``estimate_file``, ``fit_recording``, ``check_measurements``,
``export_recording``, ``identify``, ``run_sweep`` …) and prints its lines.

It may import every layer of torchtea; nothing in torchtea imports it but the docs' reference pages
(:mod:`torchtea.reference` reads the parser), the top layer of tests/test_layers.py.
:mod:`~torchtea.cli.common` holds what the commands share (errors, help texts, argparse types, progress, the reading
of a recording from its flags, the cluster flags); one module per group of commands adds their sub-parsers
(``add_parsers``) and runs them (``cmd_*``): :mod:`~torchtea.cli.simulate` (simulate), :mod:`~torchtea.cli.tea`
(estimate, identify), :mod:`~torchtea.cli.checking` (fit, plan, check), :mod:`~torchtea.cli.export` (export) and
:mod:`~torchtea.cli.studies` (record, montecarlo, presets). The command modules import ``common`` (and ``checking``
imports ``export``), never this package."""
from __future__ import annotations

import argparse
import signal
import sys

from . import checking, export, simulate, studies, tea
from .common import BOOTSTRAP_LIMIT, ESTIMATE_UNCERTAINTY_CHOICES, KFX_UNCERTAINTY_CHOICES, PRIOR_CHOICES, CLIError

__all__ = ["main", "build_parser", "CLIError", "BOOTSTRAP_LIMIT", "PRIOR_CHOICES", "ESTIMATE_UNCERTAINTY_CHOICES",
           "KFX_UNCERTAINTY_CHOICES"]

#: what ``torchtea --help`` prints above the commands
DESCRIPTION = ("torchtea: noise models of inertial sensors — simulate, estimate (the TEA), identify, fit, plan, "
               "check, export,\nrecord, montecarlo, presets. torchtea COMMAND --help lists a command's flags.")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="torchtea", description=DESCRIPTION)
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.add_argument("--effects", action="append", default=[], metavar="MODULE",
                   help="import MODULE (a module name or a .py file) before the command: the effects it registers "
                        "(torchtea.effects.register) can be named in --model and --add; may be repeated")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for commands in (simulate, tea, checking, export, studies):  # the order --help lists them in
        commands.add_parsers(sub)
    return p


def main(argv=None) -> int:
    from ..core.checkpoint import CheckpointError
    from ..core.tasks import TaskFailed
    from ..effects import import_effects
    from ..sensors.io import InputError

    parser = build_parser()
    args = parser.parse_args(argv)
    previous = _stop_on_sigterm() if args.command in KEEPING else None
    try:
        for name in args.effects:
            import_effects(name)
        return args.func(args)
    except (CLIError, InputError, TaskFailed, CheckpointError) as exc:
        if args.debug:
            raise
        print(f"torchtea: error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"torchtea: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        how = "stopped (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
        kept = getattr(args, "kept", None)  # (what a command that keeps its channels kept)
        kept = kept() if kept is not None else None
        print(f"torchtea: {how}" + (f": {kept}" if kept else ""), file=sys.stderr)
        return 143 if isinstance(exc, Terminated) else 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


#: The commands that keep each channel as it finishes: SIGTERM stops them as Ctrl-C does (what finished is kept,
#: exit 143); the others end on SIGTERM as any process does.
KEEPING = ("check", "export", "fit")


class Terminated(KeyboardInterrupt):
    """SIGTERM (a time limit, a batch scheduler, ``timeout``, ``kill``): raised where the run is, so that it stops as
    on Ctrl-C — what finished is kept — and exits 143."""


def _raise_terminated(signum, frame):
    raise Terminated


def _stop_on_sigterm():
    """SIGTERM raises :class:`Terminated` while a command runs; the handler before (to put back), or None where
    signals cannot be set (not the main thread)."""
    try:
        return signal.signal(signal.SIGTERM, _raise_terminated)
    except ValueError:
        return None
