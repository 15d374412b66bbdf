"""What the loop's simplification (issue 45) costs and changes, timed as users run it: ``check --auto`` and
``check --auto --no-simplify`` (the loop that only adds) one after the other on this tree, on

* the bundled recording (six channels, 449 s at 100 Hz);
* the two shared six-axis MPU-6050 recordings with temperature (``x_forward``, ``z_front``; read from ``../shared``);
* ``textbook``: one simulated gyroscope axis of white noise + a bias random walk (100 s at 200 Hz, the truth
  K = 2·10⁻⁵ rad/s²/√Hz), and ``export --format ieee952`` of it (the K users put in their filters).

Usage::

    python experiments/bench/issue45.py [--cases bundled,x_forward,z_front,textbook] [--out issue45.json] [--table]

Wall time, CPU time and peak memory come from ``os.wait4`` (:func:`issue44.run`); each axis's model, verdict, loop's
end, ties and seconds from the run's ``check.json``. Nothing else should run on the machine meanwhile."""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from issue44 import ROOT, SHARED, SIX, run  # noqa: E402

K_TRUE = 2e-5
H = 0.005


def textbook(path: Path) -> None:
    """One gyroscope axis, white noise (N = 1.7·10⁻⁴ rad/s/√Hz) + a bias random walk K = 2·10⁻⁵, 20 000 samples at
    200 Hz, seed 3 (as tests/test_simplify.py)."""
    from torchtea.noise import simulate_model
    from torchtea.sensors.io import write_columns

    y = simulate_model("white+random-walk", {"white.r": (1.7e-4) ** 2 / H, "random-walk.sigma": K_TRUE},
                       n_steps=20_000, h=H, generator=torch.Generator().manual_seed(3))[0, 0].numpy()
    write_columns(path, {"t": np.arange(len(y)) * H, "gyr_x": y})


def table(results: dict) -> str:
    lines = ["| case | loop | wall [s] | CPU [s] | peak memory [MB] |", "|---|---|---|---|---|"]
    for r in results["runs"]:
        lines.append(f"| {r['case']} | {r['code']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['peak_rss_mb']:.0f} |")
    lines += ["", "| case | loop | axis | model | verdict | ties | seconds |", "|---|---|---|---|---|---|---|"]
    for r in results["runs"]:
        for axis, a in (r.get("axes") or {}).items():
            verdict = {True: "adequate", False: "not adequate"}.get(a.get("adequate"), "—")
            ties = "; ".join(a.get("ties") or []) or "—"
            extra = f" (K {a['K']})" if a.get("K") else ""
            seconds = a.get("seconds")
            lines.append(f"| {r['case']} | {r['code']} | {axis} | {a.get('model')}{extra} | {verdict} | {ties} | "
                         f"{'' if seconds is None else f'{seconds:.1f}'} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="bundled,x_forward,z_front,textbook")
    ap.add_argument("--out", default=str(HERE / "issue45.json"))
    ap.add_argument("--table", action="store_true", help="only print the tables of --out (markdown)")
    args = ap.parse_args()
    if args.table:
        print(table(json.loads(Path(args.out).read_text())))
        return 0
    work = Path(tempfile.mkdtemp(prefix="issue45-"))
    textbook(work / "textbook.csv")
    inputs = {"bundled": [], "x_forward": [SHARED / "unmoved_x_forward.csv", *SIX],
              "z_front": [SHARED / "unmoved_z_front_x_up.csv", *SIX],
              "textbook": [work / "textbook.csv", "--units", "rad/s"]}
    results = {"tree": str(ROOT), "runs": []}
    for case in args.cases.split(","):
        commands = [("new", ["check", *inputs[case], "--auto", "--no-plots"]),
                    ("only adds", ["check", *inputs[case], "--auto", "--no-simplify", "--no-plots"])]
        if case == "textbook":
            commands += [("export new", ["export", *inputs[case], "--format", "ieee952", "--no-plots"]),
                         ("export only adds", ["export", *inputs[case], "--format", "ieee952", "--no-simplify",
                                               "--no-plots"])]
        for code, command in commands:
            out = work / f"{case}-{code.replace(' ', '_')}"
            out.mkdir()
            r = run(ROOT, [*command, "--out", out], out)
            r.update(case=case, code=code)
            doc = out / "export.json"
            if doc.exists():  # the export's K and model per axis
                axes = json.loads(doc.read_text())["axes"]
                r["axes"] = {a: {"model": x["model"], "K": "{:.3g} [{}]".format(
                    x["bare"]["K"]["value"], ", ".join(f"{c:.3g}" for c in x["bare"]["K"]["ci95"] or []))}
                    for a, x in axes.items()}
            elif (out / "check.json").exists():
                for a, x in json.loads((out / "check.json").read_text())["axes"].items():
                    r["axes"][a]["ties"] = [t["words"] for t in x.get("ties", [])]
            results["runs"].append(r)
            print(f"{case} {code}: {r['wall_s']} s", flush=True)
            Path(args.out).write_text(json.dumps(results, indent=1))
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
