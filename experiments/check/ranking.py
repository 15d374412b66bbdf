"""Ranking rules for check's suggestions, evaluated offline on a hidden-effect study's saved cases (issue 30, item 5).

    python experiments/check/ranking.py                      # the study's cases, experiments/check/hidden/ (hidden.py)
    python experiments/check/ranking.py --dir /tmp/hid
    python experiments/check/ranking.py --dir /tmp/rs        # a randomised study's cases (random_study.py)

Each case JSON keeps every suggestion with its BIC gain and the diagnostics it repairs, and the model's failed
diagnostics, so a rule can be replayed without refitting. Rules:

* ``gain`` — today's: the largest BIC gain first;
* ``explains`` — a suggestion that repairs a failed diagnostic its effect explains (each component's ``explains``:
  temperature → temperature-bias, thermal-lag, temperature-order; lines → sinusoid; spectrum → drifting-line) first, then
  by gain;
* ``explains-within-W`` — the same, only for suggestions within W of the best gain (W = 2, 6, 10, 15, 20); check
  uses ``explains-within-{EXPLAIN_WINDOW}``.

Prints, per hidden effect, how many cases have the right effect first (``none``: no suggestion).
"""
from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

from torchtea.checking.screens import screening_of
from torchtea.noise.components import COMPONENTS

HERE = Path(__file__).resolve().parent
RULES = ("gain", "explains", "explains-within-2", "explains-within-6", "explains-within-10", "explains-within-15",
         "explains-within-20")


def top(case: dict, rule: str) -> str:
    s = case["suggestions"]
    if not s:
        return "none"
    if rule == "gain":
        return max(s, key=lambda x: x["gain"])["effect"]
    window = float(rule.rsplit("-", 1)[1]) if rule.startswith("explains-within") else float("inf")
    best = max(x["gain"] for x in s)
    failed = set(case["failed"] if "failed" in case else case["failed_first"])

    def key(x):
        explains = (bool(set(screening_of(COMPONENTS[x["effect"]]).explains) & failed & set(x["repairs"]))
                    and x["gain"] >= best - window)
        return explains, x["gain"]

    return max(s, key=key)["effect"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--dir", default=str(HERE / "hidden"))
    args = ap.parse_args()
    right = collections.defaultdict(collections.Counter)
    for f in sorted(Path(args.dir).glob("*.json")):
        case = json.loads(f.read_text())
        hidden = case["effect"] if "effect" in case else "+".join(case["effects"]) or "none"
        truth = {"none"} if hidden == "none" else set(hidden.split("+"))  # a pair: either of its effects first
        for rule in RULES:
            right[rule][hidden] += top(case, rule) in truth
        right["cases"][hidden] += 1
    effects = sorted(right["cases"])
    print("| rule | " + " | ".join(effects) + " | all |")
    print("|---" * (len(effects) + 2) + "|")
    for rule in RULES:
        print(f"| {rule} | " + " | ".join(f"{right[rule][e]}/{right['cases'][e]}" for e in effects)
              + f" | {sum(right[rule].values())}/{sum(right['cases'].values())} |")


if __name__ == "__main__":
    main()
