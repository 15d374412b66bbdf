"""The loop judged against the oracle at scale: every single effect of the hidden-effect draws, every physically
sensible pair of them and clean records, on local processes or a Dask cluster, resumable after a stop.

    python experiments/check/scale_study.py --list                                   # the sets, and those left out
    python experiments/check/scale_study.py --dir /tmp/scale --seeds 10 --workers 2  # local processes, one thread each
    python experiments/check/scale_study.py --dir /tmp/scale --scheduler tcp://host:8786   # a Dask cluster's workers
    python experiments/check/scale_study.py --dir /tmp/scale --tables                # the tables of what is there

Each case — a set and a seed — is one task: the loop (``random_study.run_case``: ``check`` from ``fractional+white``
with the temperature, the loop to its end) and then the oracle (``oracle_study.run_oracle``: the true model and the
model without each hidden effect fitted by exact likelihood, each rival in its place). Each result is written as soon
as it is done (a case that raises, its traceback in ``<dir>/errors/``, the others going on) (``<dir>/<set>_<n>_<h>_<seed>.json``, ``<dir>/oracle/…``, the formats of those two scripts), so a
stopped run resumes where it stopped: a case whose files exist is not run again. Cases run seed by seed across the
sets (seed 0 of every set first), so a run cut short covers every set evenly.

The tables (``<dir>.md`` beside the cases): per set, the cases where the oracle shows every hidden effect and of
those the ones whose loop ends with all of them; the other cases and of those the ones whose end is right by the
oracle (:func:`torchtea.studies.oracle.judge`); the cases where the oracle calls an effect a tie (with its rival,
or too weak to lower BIC by the tie window) and of those the ones whose loop names it; every rate with its 95 %
Clopper–Pearson interval; the totals over singles, pairs and clean records; and the time the cases took.
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

#: Pairs left out, and why: one physical effect seen twice, so a record cannot hold both as separate effects (each is
#: the other's rival in the oracle's singles), or a pair the library's models cannot hold.
LEFT_OUT = {("digital-filter", "low-pass"): "the sensor's one output filter, as an analogue or a digital one",
            ("temperature-bias", "thermal-lag"): "a bias per °C, seen at once or through the housing's lag",
            ("digital-filter", "temperature-order"): "the library's models do not put a time-varying order beside a "
                                                     "sensor filter",
            ("low-pass", "temperature-order"): "the library's models do not put a time-varying order beside a sensor "
                                               "filter"}


def all_sets() -> list[list[str]]:
    """Clean records, every single effect, every pair not in :data:`LEFT_OUT` (sorted names)."""
    from torchtea.studies.hidden import DRAWS

    names = sorted(DRAWS)
    pairs = [list(p) for p in itertools.combinations(names, 2) if p not in LEFT_OUT]
    return [[]] + [[e] for e in names] + pairs


def _name(effects: list) -> str:
    return "+".join(effects) or "none"


def run_one(effects: list, seed: int, n: int, h: float, max_steps: int, d: str, code: str = "") -> dict:
    """One case (the loop, then the oracle), each written as it is done; what was run and its seconds."""
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    d = Path(d)
    stem = f"{_name(effects)}_{n}_{h:g}_{seed:03d}.json"
    case_path, oracle_path = d / stem, d / "oracle" / stem
    out = {"case": stem, "loop_s": None, "oracle_s": None}
    try:
        _run_one(effects, seed, n, h, max_steps, case_path, oracle_path, out, code)
    except Exception as exc:  # (a case that fails is a finding: kept, and the others go on)
        import traceback

        (d / "errors").mkdir(exist_ok=True)
        (d / "errors" / stem.replace(".json", ".txt")).write_text(traceback.format_exc())
        out["error"] = f"{type(exc).__name__}: {exc}"
    return out


def _run_one(effects, seed, n, h, max_steps, case_path: Path, oracle_path: Path, out: dict, code: str) -> None:
    from oracle_study import run_oracle
    from random_study import run_case

    from torchtea.core.threads import engine_threads

    with engine_threads(1):
        if not case_path.exists():
            case = run_case(effects, seed, n, h, max_steps)
            case["code"] = code
            case_path.write_text(json.dumps(case, default=float))
            out["loop_s"] = case["seconds"]
        case = json.loads(case_path.read_text())
        if not oracle_path.exists():
            orc = run_oracle(case)
            orc["code"] = code
            oracle_path.write_text(json.dumps(orc, default=float))
            out["oracle_s"] = orc["seconds"]


def code_version() -> str:
    """The commit the cases are run with (``+changes`` where the package or the studies differ from it): each case
    keeps it, so that a directory filled over several runs says which code made each of its rows."""
    import subprocess

    def git(*a):
        return subprocess.run(["git", "-C", str(HERE), *a], capture_output=True, text=True).stdout.strip()

    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+changes" if git("status", "--porcelain", "--", "../../torchtea", ".") else "")


def _ci(k: int, n: int) -> str:
    if not n:
        return "—"
    from scipy.stats import binomtest

    lo, hi = binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
    return f"{k}/{n} ({100 * k / n:.0f} %, {100 * lo:.0f}–{100 * hi:.0f})"


def _tie_cases(j: dict, case: dict) -> tuple[bool, bool]:
    """Whether the oracle calls an effect of the case a tie (tie-rival, or weak: under the tie window), and whether
    the loop's ties name every such effect (or, for a tie with a rival, the rival)."""
    from oracle_study import RIVALS

    ties = [e for e, s in j["status"].items() if s in ("tie-rival", "weak")]
    named = {e for t in case.get("ties", []) for e in t["effects"]}
    return bool(ties), all(({e} | set(RIVALS.get(e, []))) & named for e in ties)


def tables(d: Path, wall: float | None = None) -> str:
    from torchtea.studies.oracle import judge

    rows = []
    for p in sorted(d.glob("*.json")):
        o = d / "oracle" / p.name
        if p.name != "runs.json" and o.exists():
            case, orc = json.loads(p.read_text()), json.loads(o.read_text())
            rows.append((case, judge(case, orc), orc))
    if not rows:
        return "no case with its oracle yet"
    groups = {}
    for r in rows:
        groups.setdefault(_name(r[0]["effects"]), []).append(r)

    def line(name, rs):
        shown = [r for r in rs if r[1]["all_shown"]]
        other = [r for r in rs if not r[1]["all_shown"]]
        tied = [ok for c, j, _ in rs for t, ok in [_tie_cases(j, c)] if t]
        return (f"| {name} | {len(rs)} | {_ci(len(shown), len(rs))} | "
                f"{_ci(sum(j['ends_with_all'] for _, j, _ in shown), len(shown))} | {len(other)} | "
                f"{_ci(sum(j['right'] for _, j, _ in other), len(other))} | {_ci(sum(tied), len(tied))} | "
                f"{np.median([c['seconds'] for c, _, _ in rs]):.0f} [{np.max([c['seconds'] for c, _, _ in rs]):.0f}]"
                f", {np.median([o['seconds'] for _, _, o in rs]):.0f} |")

    head = ["| hidden | cases | the oracle shows every hidden effect | … the loop ends with all of them | the others "
            "| … the loop's end right by the oracle | the oracle calls one a tie: … the loop names it | seconds: "
            "loop median [max], oracle median |", "|---|---|---|---|---|---|---|---|"]
    kinds = {"all": rows, "clean": [r for r in rows if not r[0]["effects"]],
             "singles": [r for r in rows if len(r[0]["effects"]) == 1],
             "pairs": [r for r in rows if len(r[0]["effects"]) == 2]}
    out = ["Totals (rates with 95 % Clopper–Pearson intervals):", "", *head]
    out += [line(k, v) for k, v in kinds.items() if v]
    clean = kinds["clean"]
    if clean:
        base = {"fractional", "white"}
        out += ["", "Clean records that end with no effect added (the final model of fractional noise and white "
                    f"noise, or either): {_ci(sum(set(c['model'].split('+')) <= base for c, _, _ in clean), len(clean))}"]
    errors = sorted(p.stem for p in (d / "errors").glob("*.txt")) if (d / "errors").exists() else []
    if errors:
        out += ["", f"Cases that failed ({len(errors)}; the tracebacks in errors/): " + ", ".join(errors)]
    codes = Counter(c.get("code") or "not recorded" for c, _, _ in rows)
    out += ["", "Code the cases were run with: " + ", ".join(f"{k} ({v} cases)" for k, v in sorted(codes.items()))]
    cpu = sum(c["seconds"] for c, _, _ in rows) + sum(o["seconds"] for _, _, o in rows)
    out += ["", f"{len(rows)} cases, {cpu / 3600:.1f} CPU-hours in the loops and oracles"
            + (f", {wall / 3600:.1f} h of wall clock in this directory's runs" if wall else ""), "",
            "Per set:", "", *head]
    out += [line(name, rs) for name, rs in sorted(groups.items())]
    out += ["", "Misses (right by the oracle: no), by set and seed:", ""]
    for name, rs in sorted(groups.items()):
        for c, j, _ in sorted(rs, key=lambda r: r[0]["seed"]):
            if not j["right"] or (j["all_shown"] and not j["ends_with_all"]):
                per = ", ".join(f"{e} {j['lr'][e]:.1f} → {j['status'][e]}" for e in j["lr"])
                ties = "; ".join(f"{t['kind']} {' / '.join(t['effects'])}" for t in c.get("ties", [])) or "no tie"
                out.append(f"- {name} seed {c['seed']}: {per}; ended {c['model']} ({ties})")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", help="where the cases go (outside the repository)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--sets", help="comma-separated sets (a+b, or none) instead of every set")
    ap.add_argument("--n", type=int, default=30_000, help="samples per case")
    ap.add_argument("--h", type=float, default=0.01, help="sample time (s)")
    ap.add_argument("--max-steps", type=int, default=4)
    ap.add_argument("--workers", type=int, default=2, help="local processes, one thread each")
    ap.add_argument("--scheduler", help="a Dask scheduler's address: its workers run the cases")
    ap.add_argument("--tables", action="store_true", help="only the tables of what is in --dir")
    ap.add_argument("--list", action="store_true", help="the sets, and the pairs left out")
    args = ap.parse_args()
    sets = all_sets() if not args.sets else [[] if s == "none" else sorted(s.split("+")) for s in args.sets.split(",")]
    if args.list:
        print(f"{len(sets)} sets: " + ", ".join(_name(s) for s in sets))
        print("left out: " + "; ".join(f"{a}+{b}: {why}" for (a, b), why in LEFT_OUT.items() if a != b))
        return
    d = Path(args.dir)
    (d / "oracle").mkdir(parents=True, exist_ok=True)
    runs_path = d / "runs.json"
    runs = json.loads(runs_path.read_text()) if runs_path.exists() else []
    if not args.tables:
        todo = [(effects, seed) for seed in range(args.seeds) for effects in sets
                if not (d / "oracle" / f"{_name(effects)}_{args.n}_{args.h:g}_{seed:03d}.json").exists()]
        print(f"{len(todo)} cases to run", flush=True)
        t0 = time.time()
        started = time.strftime("%Y-%m-%d %H:%M")
        try:
            _run(todo, args, d)
        finally:  # (a stop keeps what was done, and the clock of this run)
            runs.append({"started": started, "wall_s": time.time() - t0, "cases": len(todo)})
            runs_path.write_text(json.dumps(runs))
    text = tables(d, sum(r["wall_s"] for r in runs) or None)
    d.with_suffix(".md").write_text(text + "\n")
    print(text)


def _run(todo: list, args, d: Path) -> None:
    code = code_version()
    print(f"code: {code}", flush=True)
    calls = [(effects, seed, args.n, args.h, args.max_steps, str(d), code) for effects, seed in todo]
    done = 0

    def report(r):
        nonlocal done
        done += 1
        print(f"[{done}/{len(calls)}] {r['case']}: " + (f"FAILED ({r['error']})" if r.get("error") else
                                                          f"loop {r['loop_s'] or 0:.0f} s, oracle {r['oracle_s'] or 0:.0f} s"),
              flush=True)

    if args.scheduler:
        from dask.distributed import Client, as_completed

        with Client(args.scheduler) as client:
            client.upload_file(str(HERE / "random_study.py"))
            client.upload_file(str(HERE / "oracle_study.py"))
            futures = [client.submit(run_one, *c, pure=False) for c in calls]
            for f in as_completed(futures):
                report(f.result())
        return
    os.environ["NUMBA_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = "1"  # (the children inherit it)
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures import as_completed as completed

    with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn")) as pool:
        for f in completed([pool.submit(run_one, *c) for c in calls]):
            report(f.result())


if __name__ == "__main__":
    main()
