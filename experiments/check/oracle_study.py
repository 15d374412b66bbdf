"""The randomised studies of ``check --auto`` judged against the oracle (issue 45): a hidden effect counts as missed
only where the record could show it.

    python experiments/check/random_study.py --sets gauss-markov,step+random-walk --seeds 10 --dir /tmp/rs45  # the loop
    python experiments/check/oracle_study.py --dir /tmp/rs45                  # the oracle for every saved case
    python experiments/check/oracle_study.py --dir /tmp/rs45 --tables         # the tables only
    # two processes, one thread each: --shard 0/2 and --shard 1/2

For every case that ``random_study.py`` saved (``<dir>/*.json``) the recording is drawn again from its seed
(:func:`torchtea.studies.hidden.random_case`) and :func:`torchtea.studies.oracle.oracle` fits the true model and
the model without each hidden effect by exact likelihood; its result goes to ``<dir>/oracle/``. An effect is
**resolved** when the likelihood ratio passes the check's screen level (0.05 over the candidates screened, χ² with
the effect's parameters). For a single effect with a rival that could stand in for it (:data:`RIVALS`: a
Gauss–Markov bias for a random walk, a thermal lag for a bias per °C, one sensor filter for the other), the oracle
also fits the rival in its place: the two are **told apart** when the rival's BIC is at least
:data:`~torchtea.checking.check.CLOSE_BIC` above the truth's (the window within which check names a tie).

The tables: per set, the cases where the oracle shows every hidden effect (resolved, told apart from its rivals),
and of those the ones whose loop ends with all of them (the issue's target ≥ 90 %); the other cases, and of those
the ones whose loop's end is right by the oracle (:func:`judge`: what the record shows kept, a tie named where it
cannot tell, nothing kept that it cannot show) and the ones that name any tie.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from torchtea.noise.components import COMPONENTS
from torchtea.noise.grammar import token_for
from torchtea.studies.hidden import BASE_MODEL, random_case
from torchtea.studies.oracle import judge, oracle

#: The effects that can stand in for a hidden one on a record of a few minutes (issue 30's and 45's findings).
RIVALS = {"gauss-markov": ["random-walk"], "thermal-lag": ["temperature-bias", "ramp"], "low-pass": ["digital-filter"],
          "digital-filter": ["low-pass"], "temperature-bias": ["ramp"]}


def run_oracle(case: dict) -> dict:
    effects, seed, n, h = case["effects"], case["seed"], case["n"], case["h"]
    y, T, truth = random_case(effects, seed, n, h)
    spec = "+".join([BASE_MODEL, *(token_for(COMPONENTS[e], e, truth) for e in effects)])
    rivals = {e: [r for r in RIVALS[e] if r not in effects] for e in effects if e in RIVALS}
    t0 = time.perf_counter()
    out = oracle(y, h, truth, spec, inputs={"temperature": T}, rivals=rivals)
    out["seconds"] = time.perf_counter() - t0
    return out


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.0f} %)" if n else "—"


def tables(d: Path) -> str:
    rows = []
    for p in sorted(d.glob("*.json")):
        o = d / "oracle" / p.name
        if o.exists():
            case = json.loads(p.read_text())
            orc = json.loads(o.read_text())
            rows.append((case, judge(case, orc), orc))
    if not rows:
        return "no case with its oracle yet"
    groups = {}
    for case, j, orc in rows:
        groups.setdefault("+".join(case["effects"]) or "none", []).append((case, j, orc))
    out = ["| hidden | seeds | the oracle shows every hidden effect | … the loop ends with all of them | the others "
           "| … the loop's end right by the oracle | … a tie named | seconds: loop median [max], oracle median |",
           "|---|---|---|---|---|---|---|---|"]
    for name, rs in sorted(groups.items()):
        shown = [r for r in rs if r[1]["all_shown"]]
        other = [r for r in rs if not r[1]["all_shown"]]
        out.append(f"| {name} | {len(rs)} | {_pct(len(shown), len(rs))} | "
                   f"{_pct(sum(j['ends_with_all'] for _, j, _ in shown), len(shown))} | {_pct(len(other), len(rs))} | "
                   f"{_pct(sum(j['right'] for _, j, _ in other), len(other))} | "
                   f"{_pct(sum(j['tie'] for _, j, _ in other), len(other))} | "
                   f"{np.median([c['seconds'] for c, _, _ in rs]):.0f} [{np.max([c['seconds'] for c, _, _ in rs]):.0f}], "
                   f"{np.median([o['seconds'] for _, _, o in rs]):.0f} |")
    out += ["", "**Case by case** (per hidden effect: the oracle's LR of the truth against the model without it, its "
                "BIC gain, and what the record shows of it — shown, tie-rival, rival, weak (under the tie window), "
                "hidden; the loop's end, its ties, right by the oracle):", "",
            "| hidden | seed | per effect: LR, gain → status | rival ΔBIC | loop's end | ties at the end | right |",
            "|---|---|---|---|---|---|---|"]
    for name, rs in sorted(groups.items()):
        for c, j, _ in sorted(rs, key=lambda r: r[0]["seed"]):
            per = ", ".join(f"{e} {j['lr'][e]:.1f}, {j['gain'][e]:+.1f} → {j['status'][e]}" for e in j["lr"])
            riv = "; ".join(f"{k} {v:+.1f}" for rv in j["rival_bic"].values() for k, v in rv.items()) or "—"
            ties = "; ".join(f"{t['kind']} {' / '.join(t['effects'])} ({t['bic_difference']:+.1f})"
                             for t in c.get("ties", [])) or "—"
            out.append(f"| {name} | {c['seed']} | {per} | {riv} | {c.get('model', '?')} | {ties} | "
                       f"{'yes' if j['right'] else '**no**'} |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", required=True, help="random_study.py's --dir")
    ap.add_argument("--tables", action="store_true")
    ap.add_argument("--shard", default="0/1", help="i/k: only the cases whose seed is i modulo k")
    args = ap.parse_args()
    d = Path(args.dir)
    (d / "oracle").mkdir(parents=True, exist_ok=True)
    if not args.tables:
        i, k = (int(x) for x in args.shard.split("/"))
        for p in sorted(d.glob("*.json")):
            o = d / "oracle" / p.name
            case = json.loads(p.read_text())
            if o.exists() or case["seed"] % k != i:
                continue
            res = run_oracle(case)
            o.write_text(json.dumps(res))
            print(f"{p.stem}: " + ", ".join(f"{e['name']} LR {e['lr']:.1f}{' resolved' if e['resolved'] else ''}"
                                            for e in res["effects"].values()) + f" ({res['seconds']:.0f} s)",
                  flush=True)
    text = tables(d)
    d.with_name(d.name + "_oracle.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
