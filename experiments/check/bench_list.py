"""What the longer list of effects costs a check (issue 30): the same three 30 000-sample cases as ``bench.py``
(clean, a hidden 3.37 Hz line, the random-walk seed whose first fit is a local maximum), each checked with the seven
effects screened before issue 30 and with every registered candidate, side by side in one run, no intervals.

    python experiments/check/bench_list.py      # prints a table, writes experiments/check/bench_list.json

Run it on an otherwise idle machine: the seconds are wall-clock.
"""
from __future__ import annotations

import json
import platform
from pathlib import Path

import torch

from torchtea.checking import check
from torchtea.checking.screens import candidates
from torchtea.studies.hidden import hidden_case

HERE = Path(__file__).resolve().parent
H = 0.01
#: the candidates check screened before issue 30
BEFORE = ("random-walk", "sinusoid", "temperature-bias", "temperature-order", "low-pass", "ramp", "quantisation")


def main():
    import bench  # the cases of bench.py (this folder)

    cases = {"clean": bench.series("fractional+white"), "hidden line": bench.series("fractional+white+sinusoid")}
    y, T, _ = hidden_case("random-walk", 7)
    cases["random walk, restart"] = (y, T)
    check(cases["clean"][0], H, intervals=False)  # warm-up: numba's compile is not timed
    rows = []
    for name, (y, T) in cases.items():
        for label, effects in (("before issue 30", BEFORE), ("all", candidates())):
            r = check(y, H, inputs={"temperature": T}, intervals=False, candidates=effects)
            rows.append({"case": name, "list": label, "effects": len(effects), "seconds": r.seconds,
                         "timings": r.timings, "top": r.suggestions[0].effect if r.suggestions else None,
                         "passed": [s.effect for s in r.screens if s.passed]})
    print("| case | effects screened | seconds | fit | screens | refits | passed the screen | top |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        t = r["timings"]
        print(f"| {r['case']} | {r['effects']} ({r['list']}) | {r['seconds']:.1f} | {t['fit']:.1f} | {t['screen']:.1f} | "
              f"{t['refits']:.1f} | {', '.join(r['passed']) or '—'} | {r['top']} |")
    (HERE / "bench_list.json").write_text(json.dumps({"machine": platform.processor() or platform.machine(),
                                                       "threads": torch.get_num_threads(), "rows": rows}, indent=1))


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(HERE))
    main()
