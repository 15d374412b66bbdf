"""Randomised hidden-effect study of ``check --auto`` (issue 30): every seed draws its own base noise, temperature
profile and effect strengths (:func:`torchtea.studies.hidden.random_case`), so a rate is over a range of sensors,
not one setting.

    python experiments/check/random_study.py --sets step,gauss-markov,thermal-lag --dir /tmp/rs   # each effect alone
    python experiments/check/random_study.py --sets thermal-lag+sinusoid --seeds 20 --dir /tmp/rs  # a pair
    python experiments/check/random_study.py --sets none --n 60000 --h 0.005 --dir /tmp/rs200       # clean, 200 Hz
    python experiments/check/random_study.py --tables --dir /tmp/rs
    # two processes, one thread each
    export NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
    python experiments/check/random_study.py ... --shard 0/2 & python experiments/check/random_study.py ... --shard 1/2

A set is one effect, effects joined by ``+``, or ``none`` (clean data). Each case is checked with the default model
``fractional+white``, the temperature given, no intervals, and the loop run to its end (``CheckResult.auto``).
Recorded per case: the truth, the first check's suggestions (effect, BIC gain, fitted parameters), every step of
the loop (model, −ℓ per sample, misfits, failed diagnostics), how it ended, and the seconds. The tables: how often
the right effect comes first (one effect), how often the loop adds exactly the hidden effects, ends adequate and
lowers −ℓ at every step (sets of several), how often clean data get a suggestion; the fitted parameters against the
truth, as relative errors.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from torchtea.checking import check
from torchtea.checking.check import CLOSE_BIC
from torchtea.noise.components import COMPONENTS
from torchtea.noise.grammar import grammar_of
from torchtea.studies.hidden import BASE_MODEL, random_case

HERE = Path(__file__).resolve().parent


def run_case(effects: list, seed: int, n: int, h: float, max_steps: int) -> dict:
    y, T, truth = random_case(effects, seed, n, h)
    t0 = time.perf_counter()
    first = check(y, h, model=BASE_MODEL, inputs={"temperature": T}, intervals=False)
    last = first.auto(max_steps=max_steps, intervals=False)
    return {"effects": effects, "seed": seed, "n": n, "h": h, "truth": truth, "adequate_first": first.adequate,
            "failed_first": first.failed, "suggestions": [{"effect": s.effect, "gain": s.gain, "repairs": s.repairs,
                                                           "parameters": s.parameters}
                                                          for s in first.suggestions],
            "top": first.suggestions[0].effect if first.suggestions else None,
            "steps": last.step_rows(), "loop_end": last.loop_end, "adequate": last.adequate,
            "model": last.model.spec, "ties": [{k: t[k] for k in ("kind", "effects", "model", "bic_difference",
                                                                  "resolve_seconds", "words")} for t in last.ties],
            "final_parameters": last.fit.values, "seconds": time.perf_counter() - t0}


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / max(n, 1):.0f} %)"


def _iqr(x) -> str:
    q = np.percentile(x, [25, 50, 75])
    return f"{q[1]:+.3g} [{q[0]:+.3g}, {q[2]:+.3g}]"


def _relative_errors(rows: list) -> dict:
    """Per parameter of the hidden effects (not held references, not the base noise): (fitted − truth)/|truth| at
    the loop's end (a located time: fitted − truth in samples), for the cases whose loop added that effect."""
    out = {}
    for r in rows:
        fitted = r["final_parameters"]
        for name, true in r["truth"].items():
            comp = name.split(".", 1)[0]
            if comp not in r["effects"] or name.endswith("t_ref") or name.endswith("phase") or name not in fitted:
                continue
            if grammar_of(COMPONENTS[comp.rstrip("0123456789")]).needs_argument:  # spikes: a set of times (_spike_rows)
                continue
            if name.split(".", 1)[1] in COMPONENTS[comp.rstrip("0123456789")].located:  # a time: in samples
                out.setdefault(f"{name} (samples)", []).append((fitted[name] - true) / r["h"])
            elif true != 0:
                out.setdefault(name, []).append((fitted[name] - true) / abs(true))
    return out


def _spike_rows(rows: list) -> list:
    """Per case with hidden spikes: how many there were, how many of them the loop's end has at their sample, and
    how many it has at a sample where there was none (sizes: the median |fitted − true| / |true| of those found)."""
    out = []
    for r in rows:
        if "spikes" not in r["effects"]:
            continue
        true = {round(v / r["h"]): r["truth"][k.replace(".t", ".size")] for k, v in r["truth"].items()
                if k.startswith("spikes.t")}
        fitted = {round(v / r["h"]): r["final_parameters"][k.replace(".t", ".size")]
                  for k, v in r["final_parameters"].items() if k.startswith("spikes") and ".t" in k}
        hit = set(true) & set(fitted)
        out.append({"true": len(true), "found": len(hit), "false": len(set(fitted) - set(true)),
                    "size_err": [abs(fitted[k] - true[k]) / abs(true[k]) for k in hit]})
    return out


def _close(r: dict) -> set:
    """The first suggestion and those within CLOSE_BIC of its gain or above it (check's ``close``)."""
    s = r["suggestions"]
    if not s:
        return set()
    first = next(x for x in s if x["effect"] == r["top"])
    return {x["effect"] for x in s if x["gain"] >= first["gain"] - CLOSE_BIC}


def tables(d: Path) -> str:
    rows = [json.loads(p.read_text()) for p in sorted(d.glob("*.json"))]
    if not rows:
        return "nothing saved yet"
    groups = {}
    for r in rows:
        groups.setdefault((tuple(r["effects"]), r["n"], r["h"]), []).append(r)
    out = ["| hidden | N, h | seeds | right first | right first or close to it | loop adds exactly the hidden | ends "
           "adequate | −ℓ falls at every step | suggested (clean) | seconds median [max] |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for (effects, n, h), rs in sorted(groups.items()):
        hidden = set(effects)
        added = [{s["added"] for s in r["steps"][1:]} for r in rs]
        exact = sum(a == hidden for a in added)
        right = sum(r["top"] in hidden for r in rs) if hidden else None
        close = sum(bool(hidden & _close(r)) for r in rs) if hidden else None
        falls = sum(all(b["nll_per_sample"] < a["nll_per_sample"] for a, b in zip(r["steps"], r["steps"][1:]))
                    for r in rs if len(r["steps"]) > 1)
        several = sum(len(r["steps"]) > 1 for r in rs)
        secs = [r["seconds"] for r in rs]
        out.append(f"| {'+'.join(effects) or 'none'} | {n}, {h:g} s | {len(rs)} | "
                   f"{_pct(right, len(rs)) if hidden else '—'} | {_pct(close, len(rs)) if hidden else '—'} | "
                   f"{_pct(exact, len(rs))} | "
                   f"{_pct(sum(r['adequate'] for r in rs), len(rs))} | {_pct(falls, several) if several else '—'} | "
                   f"{'—' if hidden else _pct(sum(r['top'] is not None for r in rs), len(rs))} | "
                   f"{np.median(secs):.1f} [{np.max(secs):.0f}] |")
    out += ["", "**What came first when it was not the hidden effect** (first check's top suggestion):", ""]
    for (effects, n, h), rs in sorted(groups.items()):
        wrong = [str(r["top"]) for r in rs if r["top"] not in effects]
        if wrong:
            counts = {w: wrong.count(w) for w in sorted(set(wrong))}
            out.append(f"- {'+'.join(effects) or 'none'} ({n}, {h:g} s): " +
                       ", ".join(f"{w} {c}" for w, c in counts.items()))
    out += ["", "**Right first by the effect's time constant against the record** (effects with a τ; the Gauss–Markov "
                "bias looks like a random walk when its τ is not well below the record, a short thermal lag like a "
                "bias per °C):", "", "| hidden | τ / record | seeds | right first | right first or close to it |",
            "|---|---|---|---|---|"]
    for (effects, n, h), rs in sorted(groups.items()):
        for e in effects:
            rs_tau = [r for r in rs if f"{e}.tau_s" in r["truth"]]
            for lo, hi in ((0.0, 0.02), (0.02, 0.05), (0.05, 0.2), (0.2, float("inf"))):
                sel = [r for r in rs_tau if lo <= r["truth"][f"{e}.tau_s"] / (n * h) < hi]
                if sel:
                    out.append(f"| {'+'.join(effects)} | {lo:g}–{hi:g} | {len(sel)} | "
                               f"{_pct(sum(r['top'] == e for r in sel), len(sel))} | "
                               f"{_pct(sum(e in _close(r) for r in sel), len(sel))} |")
    out += ["", "**The hidden effects' parameters at the loop's end against the truth** ((fitted − truth)/|truth|, "
                "median [quartiles], over the cases whose loop added the effect):", "",
            "| hidden | parameter | cases | relative error |", "|---|---|---|---|"]
    for (effects, _n, _h), rs in sorted(groups.items()):
        for name, errs in sorted(_relative_errors(rs).items()):
            out.append(f"| {'+'.join(effects)} | {name} | {len(errs)} | {_iqr(errs)} |")
    spikes = [(effects, n, h, _spike_rows(rs)) for (effects, n, h), rs in sorted(groups.items())]
    spikes = [x for x in spikes if x[3]]
    if spikes:
        out += ["", "**Spikes at the loop's end against the truth** (a spike found: one at its sample; false: one where "
                    "there was none):", "", "| hidden | seeds | spikes | found | false | size error median [quartiles] |",
                "|---|---|---|---|---|---|"]
        for effects, _n, _h, sr in spikes:
            errs = [e for x in sr for e in x["size_err"]]
            out.append(f"| {'+'.join(effects)} | {len(sr)} | {sum(x['true'] for x in sr)} | "
                       f"{_pct(sum(x['found'] for x in sr), sum(x['true'] for x in sr))} | {sum(x['false'] for x in sr)} "
                       f"| {_iqr(errs) if errs else '—'} |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="step,gauss-markov,thermal-lag", help="comma-separated; a set: a+b, or none")
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--n", type=int, default=30_000, help="samples per case")
    ap.add_argument("--h", type=float, default=0.01, help="sample time (s)")
    ap.add_argument("--max-steps", type=int, default=4)
    ap.add_argument("--dir", required=True, help="where the cases' JSON go (outside the repository)")
    ap.add_argument("--tables", action="store_true")
    ap.add_argument("--shard", default="0/1", help="i/k: run only the cases whose seed is i modulo k")
    args = ap.parse_args()
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    if not args.tables:
        sets = [[] if s == "none" else s.split("+") for s in args.sets.split(",")]
        i, k = (int(x) for x in args.shard.split("/"))
        for seed in range(args.seeds):
            if seed % k != i:
                continue
            for effects in sets:
                name = "+".join(effects) or "none"
                path = d / f"{name}_{args.n}_{args.h:g}_{seed:03d}.json"
                if path.exists():
                    continue
                res = run_case(effects, seed, args.n, args.h, args.max_steps)
                path.write_text(json.dumps(res))
                added = [s["added"] for s in res["steps"][1:]]
                print(f"{name} seed {seed}: top {res['top']}, added {added}, adequate {res['adequate']} "
                      f"({res['seconds']:.0f} s)", flush=True)
    text = tables(d)
    d.with_suffix(".md").write_text(text + "\n")  # beside the cases (--dir /tmp/x → /tmp/x.md)
    print(text)


if __name__ == "__main__":
    main()
