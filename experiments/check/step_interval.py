"""Coverage of a step's time interval (issue 30): on the step cases of a randomised study (random_study.py), the
interval :meth:`torchtea.fitting.starts.levels.StepStarts.located_intervals` makes at the loop's final fit, against the true time.

    python experiments/check/step_interval.py --dir /tmp/rs      # after random_study.py --sets step --dir /tmp/rs

The recording of each case is drawn again from its seed (random_case is deterministic). Prints one line per case and
the coverage (nominal 95 %) with the median width, and writes them beside --dir (DIR.step_interval.md).
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from torchtea.fitting.mle import located_intervals
from torchtea.studies.hidden import random_case


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dir", required=True)
    args = ap.parse_args()
    d = Path(args.dir)
    hits, widths, lines = 0, [], []
    for f in sorted(d.glob("step_*.json")):
        r = json.loads(f.read_text())
        v = r["final_parameters"]
        if "step.t_step" not in v:  # the loop did not add the step
            continue
        y, T, truth = random_case(["step"], r["seed"], r["n"], r["h"])
        (lo, hi), _ = located_intervals(r["steps"][-1]["model"], v, y, r["h"], {"temperature": T})["step.t_step"]
        ok = lo - 1e-9 <= truth["step.t_step"] <= hi + 1e-9
        hits += ok
        widths.append((hi - lo) / r["h"])
        lines.append(f"seed {r['seed']}: [{lo:.2f}, {hi:.2f}] s, truth {truth['step.t_step']:.2f} s, "
                     f"{'covered' if ok else 'MISSED'}")
        print(lines[-1], flush=True)
    n = len(widths)
    se = math.sqrt(0.95 * 0.05 / max(n, 1))
    text = (f"step time's 95 % interval: covers the truth in {hits}/{n} cases ({100 * hits / max(n, 1):.0f} %, nominal "
            f"95 % ± {100 * se:.0f} binomial se); width median {np.median(widths):.0f} samples, quartiles "
            f"{np.percentile(widths, 25):.0f}–{np.percentile(widths, 75):.0f}")
    d.with_suffix(".step_interval.md").write_text("\n".join(lines + ["", text]) + "\n")
    print(text)


if __name__ == "__main__":
    main()
