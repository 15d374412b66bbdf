"""``torchtea simulate``: the fractional noise model (43)–(45), or any ``--model``, to a CSV
(:mod:`torchtea.noise.simulate`)."""
from __future__ import annotations

import sys

from .common import MEMORY_HELP, CLIError, _count, _device, _finite_float, _memory, _nonneg_float, _positive_float


def add_parsers(sub) -> None:
    """Add the sub-parsers of simulate to ``sub`` (``build_parser``'s subcommands)."""
    _add_simulate(sub)


def _add_simulate(sub) -> None:
    """``torchtea simulate``'s flags."""
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

    from ..engines.structure import parse_order_spec
    from ..noise.simulate import simulate_noise_model
    from ..sensors.io import write_columns

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
    from ..noise.simulate import simulate_recording

    columns = (args.columns or "y").split(",")
    out, truth, model = simulate_recording(args.model, args.out, n_steps=args.n, h=args.h, columns=columns,
                                           sets=args.set, seed=args.seed, temperature_profile=args.temperature_profile,
                                           memory=_memory(args.memory) or "soe")
    print(f"wrote {args.n} samples of {model.spec} in {len(columns)} column(s) to {out} (values in {truth.name})",
          file=sys.stderr)
    return 0
