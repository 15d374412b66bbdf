"""Does the loop end with the simplest adequate model (issue 45, item 4, in part)? ``check --auto`` (the API's
``check(...).auto()``) on simulated textbook noise, seeded:

* ``white+random-walk``: white noise (N = 1.7·10⁻⁴ per √Hz) and a bias random walk K = 2·10⁻⁵, 100 s at 200 Hz;
* ``fractional+white+random-walk``: the same with a fractional part (order 0.3, the Monte Carlo studies' values
  scaled to the white noise) that the record may or may not resolve.

For each seed: the model the loop ends with, whether it is adequate, its ties, and whether the truth's components
are all there; and the oracle (:func:`torchtea.studies.oracle.oracle`): whether the record resolves the walk (the
likelihood ratio of the truth against it without the walk at the check's screen level). Usage::

    python experiments/check/simplest.py [--seeds 5] [--truths white+random-walk] [--out simplest.json] [--table]
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from torchtea.checking.check import CANDIDATES, CLOSE_BIC, check
from torchtea.noise.simulate import default_values, simulate_model
from torchtea.studies.oracle import oracle

HERE = Path(__file__).resolve().parent
H = 0.005
N = 20_000
WHITE_R = (1.7e-4) ** 2 / H
K = 2e-5


def truth(spec: str) -> dict:
    v = {"white.r": WHITE_R, "random-walk.sigma": K}
    if spec.startswith("fractional"):
        d = default_values("fractional+white", H)
        scale = WHITE_R / float(d["white.r"])
        v.update({"fractional.order": float(d["fractional.order"]), "fractional.pole": float(d["fractional.pole"]),
                  "fractional.q": float(d["fractional.q"]) * scale})
    return v


def _resolved(o: dict, n: int) -> bool:
    """The oracle's rule (:mod:`torchtea.studies.oracle`): p under the screen level and a BIC gain (LR − ln n for
    the walk's one parameter) of at least CLOSE_BIC — recomputed from the stored LR and p."""
    return o["p"] < 0.05 / len(CANDIDATES) and o["lr"] - math.log(n) >= CLOSE_BIC


def table(doc: dict) -> str:
    lines = ["| truth | seed | the oracle: walk's LR, BIC gain (resolved) | model at the loop's end | adequate | ties | s |",
             "|---|---|---|---|---|---|---|"]
    for r in doc["runs"]:
        o = r.get("oracle")
        if o is not None:
            o["resolved"] = _resolved(o, doc["samples"])
        lr = "—" if o is None else (f"{o['lr']:.1f}, {o['lr'] - math.log(doc['samples']):+.1f} "
                                    f"({'yes' if o['resolved'] else 'no'})")
        lines.append(f"| {r['truth']} | {r['seed']} | {lr} | {r['model']} | {r['adequate']} | "
                     f"{'; '.join(r['ties']) or '—'} | {r['seconds']:.0f} |")
    runs = [r for r in doc["runs"] if r.get("oracle")]
    for spec in sorted({r["truth"] for r in runs}):
        rs = [r for r in runs if r["truth"] == spec]
        shown = [r for r in rs if r["oracle"]["resolved"]]
        other = [r for r in rs if not r["oracle"]["resolved"]]
        ends = sum("random-walk" in r["model"].split("+") for r in shown)
        named = sum(bool(r["ties"]) or "random-walk" not in r["model"].split("+") for r in other)
        lines += ["", f"{spec}: the oracle resolves the walk in {len(shown)} of {len(rs)}; of those the loop ends with "
                      f"it in {ends}; of the {len(other)} others, {named} end without it or name a tie, "
                      f"{len(other) - named} keep it without a tie"]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--truths", default="white+random-walk,fractional+white+random-walk")
    ap.add_argument("--out", default=str(HERE / "simplest.json"))
    ap.add_argument("--table", action="store_true")
    args = ap.parse_args()
    if args.table:
        print(table(json.loads(Path(args.out).read_text())))
        return 0
    doc = {"samples": N, "h": H, "runs": []}
    for spec in args.truths.split(","):
        v = truth(spec)
        for seed in range(args.seeds):
            y = simulate_model(spec, {k: torch.tensor([x]) for k, x in v.items()}, n_steps=N, h=H,
                               generator=torch.Generator().manual_seed(1000 + seed))[0, 0].numpy()
            t0 = time.perf_counter()
            res = check(y, H, intervals=False).auto(intervals=False)
            seconds = time.perf_counter() - t0
            o = oracle(y, H, v, spec, base=spec.replace("+random-walk", ""))["effects"]["random-walk"]
            doc["runs"].append({"truth": spec, "seed": 1000 + seed, "model": res.model.spec, "adequate": res.adequate,
                                "ties": [t["words"] for t in res.ties], "seconds": seconds,
                                "loop_end": res.loop_end, "oracle": {k: o[k] for k in ("lr", "p", "resolved")}})
            print(spec, seed, res.model.spec, flush=True)
            Path(args.out).write_text(json.dumps(doc, indent=1))
    print(table(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
