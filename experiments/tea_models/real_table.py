"""The table of real.sh's runs: per channel, the model check ended with, the likelihood fit's order, and the TEA's
α̂ (mean over the last third, its sd there) and KFx's NIS over the last third with that model, with the paper's
fractional+white, and with that model under constant.toml's settings. Prints Markdown."""
from __future__ import annotations

import json
from pathlib import Path

HERE = Path(__file__).resolve().parent / "real"
RECORDINGS = ("bundled", "unmoved_x_forward", "unmoved_z_front_x_up")


def load(name: str) -> dict:
    text = (HERE / f"{name}.json").read_text()
    return json.loads(text[text.find("{"):])


def main() -> None:
    print("| recording | channel | check's model | α̂ fit (grown) | TEA α̂ grown [sd] | NIS grown | α̂ fit (plain) | "
          "TEA α̂ plain [sd] | NIS plain | TEA α̂ grown, constant [sd] | NIS grown, constant |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for rec in RECORDINGS:
        grown, plain, const = load(rec), load(f"{rec}_plain"), load(f"{rec}_constant")
        for a, s in grown["axes"].items():
            p, c = plain["axes"][a], const["axes"][a]
            fg = grown["fit"][a]["parameters"]["fractional.order"]["value"]
            fp = plain["fit"][a]["parameters"]["fractional.order"]["value"]
            print(f"| {rec} | {a} | {grown['models'][a]} | {fg:.3f} | {s['alpha']:.3f} [{s['alpha_std_last_third']:.3f}] | "
                  f"{s['innovation_nis_last_third']:.3f} | {fp:.3f} | {p['alpha']:.3f} [{p['alpha_std_last_third']:.3f}] | "
                  f"{p['innovation_nis_last_third']:.3f} | {c['alpha']:.3f} [{c['alpha_std_last_third']:.3f}] | "
                  f"{c['innovation_nis_last_third']:.3f} |")


if __name__ == "__main__":
    main()
