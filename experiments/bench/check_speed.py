"""The engine at its limit, timed as users run it: the code before this work (a git worktree at ``--old``) and this
tree, one after the other, each command a child process (``python -m torchtea.cli …``; wall, CPU and peak memory
from ``os.wait4``, the Dask workers' included), on this machine with nothing else running.

Cases (``--cases``, comma-separated):

* ``bundled``, ``x_forward``, ``z_front``: ``check --auto`` of the bundled recording and of the two shared six-axis
  MPU-6050 recordings (read from ``../shared``), serial;
* ``export``: ``export --format all`` of ``x_forward``;
* ``whittle``: every Whittle fit of the bundled recording's loop timed in the process (``whittle_fit`` wrapped): their
  number, median and total;
* ``bags``: a ``sensor_msgs/Imu`` topic of 10⁶ messages (and a temperature topic) as ROS 1, ROS 2 db3 and MCAP bags,
  read by ``read_bag`` (µs a message);
* ``sim_3h``: ``check --auto --workers 2`` of a six-axis recording simulated with ``torchtea simulate`` — three hours
  at 200 Hz (2.16·10⁶ samples an axis): white+random-walk on the accelerometers, fractional+white+random-walk on the
  gyroscopes, a 2 mrad/s line at 3.37 Hz on gz, a bias of 0.004 per °C on ay and a 6 °C warm-up — new tree only (the
  old one took 45–55 minutes); the parameters of each axis's final model against the truth file ``simulate`` writes.

Usage::

    python experiments/bench/check_speed.py [--old a7b5f71] [--cases …] [--out check_speed.json] [--table]

``--append`` keeps the runs already in ``--out`` (a run cut short goes on); ``--table`` prints the tables again."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from issue44 import ROOT, SHARED, SIX, run  # noqa: E402

SIM = ["--model", "fractional+white+random-walk+temperature-bias+sinusoid", "--columns", "ax,ay,az,gx,gy,gz",
       "--temperature-profile", "25,6,600,0.3", "--set", "temperature-bias.bias_per_degC=0",
       "--set", "ay:temperature-bias.bias_per_degC=0.004", "--set", "sinusoid.amplitude=0",
       "--set", "gz:sinusoid.amplitude=0.002", "--set", "sinusoid.frequency_hz=3.37",
       "--set", "fractional.q=0", "--set", "gx:fractional.q=4e-5", "--set", "gy:fractional.q=4e-5",
       "--set", "gz:fractional.q=4e-5", "--set", "gx:white.r=2.5e-6", "--set", "gy:white.r=2.5e-6",
       "--set", "gz:white.r=2.5e-6", "--seed", "7"]


def simulate(path: Path, n: int, h: float) -> None:
    subprocess.run([sys.executable, "-m", "torchtea.cli", "simulate", *SIM, "--n", str(n), "--h", str(h),
                    "--out", str(path)], check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                   stdout=subprocess.DEVNULL)


WHITTLE_TIMER = r"""
import json, sys, time
import numpy as np
import torchtea.fitting.mle as M
import torchtea.checking.screening as SC, torchtea.checking.check as CK, torchtea.checking.simplify as SI
import torchtea.checking.refits as RF
times = []
real = M.whittle_fit
def timed(model, series, h, **kw):
    t = time.perf_counter(); r = real(model, series, h, **kw); times.append(time.perf_counter() - t); return r
for mod in (M, SC, CK, SI, RF):
    if hasattr(mod, "whittle_fit"):
        mod.whittle_fit = timed
from torchtea.cli import main
main(["check", "--auto", "--no-plots", "--out", sys.argv[2]])
json.dump({"fits": len(times), "median_ms": 1000 * float(np.median(times)), "total_s": float(np.sum(times))},
          open(sys.argv[1], "w"))
"""


def whittle_fits(tree: Path, work: Path, tag: str) -> dict:
    """Every Whittle fit of the bundled recording's ``check --auto`` timed in the process."""
    script = work / "whittle_timer.py"
    script.write_text(WHITTLE_TIMER)
    out = work / f"whittle_{tag}.json"
    subprocess.run([sys.executable, str(script), str(out), str(work / f"whittle_{tag}")], check=True,
                   env=dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg"), stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return json.loads(out.read_text())


BAG_TIMER = r"""
import json, sys, time
from torchtea.sensors.bags import read_bag
out = {}
for kind, path in json.loads(sys.argv[1]).items():
    times = []
    for _ in range(3):  # the first read also brings the file into the page cache
        t = time.perf_counter(); d = read_bag(path); times.append(time.perf_counter() - t)
    n = d["metadata"]["messages"]
    out[kind] = {"messages": n, "us_per_message": 1e6 * min(times) / n, "us_first": 1e6 * times[0] / n}
print(json.dumps(out))
"""


def write_bags(work: Path, n: int) -> dict:
    """A 200 Hz Imu topic of ``n`` messages and a temperature topic every tenth, in each format (the tests' writer)."""
    sys.path.insert(0, str(ROOT / "tests"))
    from test_bags import KINDS, _data, write_bag

    t_ns, acc, gyr, temp = _data(n)
    return {kind: str(write_bag(work / f"bag_{name}", kind, t_ns, acc, gyr, temp)) for kind, name in KINDS.items()}


def read_bags(tree: Path, bags: dict) -> dict:
    res = subprocess.run([sys.executable, "-c", BAG_TIMER, json.dumps(bags)], check=True, capture_output=True,
                         text=True, env=dict(os.environ, PYTHONPATH=str(tree)), cwd=tree)  # -c: the cwd first
    return json.loads(res.stdout.strip().splitlines()[-1])


def truth_table(out: Path, truth_path: Path) -> dict:
    """Each axis's final model and each of its estimates that the truth file has, against the truth in its standard
    errors (a component the truth sets to zero is not there: the truth's model as simulated names it all the same)."""
    doc = json.loads((out / "check.json").read_text())
    truth = json.loads(truth_path.read_text())
    rows = {}
    for axis, x in doc["axes"].items():
        true = truth["values"].get(axis, {})
        params, se = x["base"]["parameters"], x["base"].get("se") or {}
        z = {n: (params[n] - true[n]) / se[n] for n in params if n in true and se.get(n)}
        present = [c for c in truth["model"].split("+") if not any(
            n.startswith(c + ".") and v == 0 for n, v in true.items())]
        rows[axis] = {"model": x["model"], "truth": "+".join(present), "z": z}
    return rows


def table(results: dict) -> str:
    lines = ["| case | code | wall [s] | CPU [s] | peak memory [MB] | exit |", "|---|---|---|---|---|---|"]
    for r in results["runs"]:
        if "wall_s" in r:
            lines.append(f"| {r['case']} | {r['code']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                         f"{r['peak_rss_mb']:.0f} | {r['exit']} |")
    for r in results["runs"]:
        if r["case"] == "whittle":
            lines.append(f"\nWhittle fits of the bundled loop, {r['code']}: {r['fits']} fits, median "
                         f"{r['median_ms']:.1f} ms, total {r['total_s']:.1f} s")
        if r["case"] == "bags":
            lines.append(f"\nread_bag, {r['code']}: " + "; ".join(
                f"{k} {v['us_per_message']:.2f} µs a message, best of 3 (first read {v.get('us_first', float('nan')):.2f}; "
                f"{v['messages']} messages)" for k, v in r["bags"].items()))
    lines += ["", "| case | code | axis | model | verdict | seconds |", "|---|---|---|---|---|---|"]
    for r in results["runs"]:
        for axis, a in (r.get("axes") or {}).items():
            verdict = {True: "adequate", False: "not adequate"}.get(a.get("adequate"), "—")
            seconds = a.get("seconds")
            lines.append(f"| {r['case']} | {r['code']} | {axis} | {a.get('model')} | {verdict} | "
                         f"{'' if seconds is None else f'{seconds:.1f}'} |")
    for r in results["runs"]:
        for axis, t in (r.get("truth") or {}).items():
            z = ", ".join(f"{n.split('.', 1)[1] if '.' in n else n} {v:+.2f}" for n, v in t["z"].items())
            lines.append(f"\n{r['case']} {axis}: {t['model']} (truth {t['truth']}); estimate − truth in standard "
                         f"errors: {z or '—'}")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default="a7b5f71", help="the commit before this work (default a7b5f71)")
    ap.add_argument("--cases", default="bundled,x_forward,z_front,export,whittle,bags,sim_3h")
    ap.add_argument("--out", default=str(HERE / "check_speed.json"))
    ap.add_argument("--no-old", action="store_true", help="time this tree only")
    ap.add_argument("--append", action="store_true", help="keep the runs already in --out")
    ap.add_argument("--table", action="store_true", help="only print the tables of --out (markdown)")
    args = ap.parse_args()
    if args.table:
        print(table(json.loads(Path(args.out).read_text())))
        return 0
    work = Path(tempfile.mkdtemp(prefix="check_speed-"))
    old = None
    if not args.no_old:
        old = work / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old), args.old], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    results = json.loads(Path(args.out).read_text()) if args.append and Path(args.out).exists() else \
        {"new": str(ROOT), "old": args.old, "runs": []}
    done = {(r["case"], r["code"]) for r in results["runs"]}
    trees = [("old", old), ("new", ROOT)] if old is not None else [("new", ROOT)]
    check = ["check", "--auto", "--no-plots"]
    commands = {"bundled": check, "x_forward": [*check[:1], SHARED / "unmoved_x_forward.csv", *SIX, *check[1:]],
                "z_front": [*check[:1], SHARED / "unmoved_z_front_x_up.csv", *SIX, *check[1:]],
                "export": ["export", SHARED / "unmoved_x_forward.csv", *SIX, "--format", "all", "--no-plots"]}
    for case in args.cases.split(","):
        for code, tree in trees:
            if (case, code) in done or (case == "sim_3h" and code == "old"):
                continue
            t0 = time.time()
            if case in commands:
                out = work / f"{case}-{code}"
                out.mkdir()
                r = run(tree, [*commands[case], "--out", out], out)
            elif case == "whittle":
                r = whittle_fits(tree, work, code)
            elif case == "bags":
                bags = write_bags(work, 1_000_000) if "bags" not in locals() else bags  # noqa: F821
                r = {"bags": read_bags(tree, bags)}
            elif case == "sim_3h":
                path = work / "sim_3h.csv"
                simulate(path, 2_160_000, 0.005)
                out = work / "sim_3h-new"
                out.mkdir()
                r = run(tree, ["check", path, "--units", "ms2,ms2,ms2,rad/s,rad/s,rad/s", "--temperature", "temp",
                               "--auto", "--no-plots", "--workers", "2", "--out", out], out)
                truth = Path(str(path) + ".truth.json")
                if truth.exists() and (out / "check.json").exists():
                    r["truth"] = truth_table(out, truth)
            else:
                raise SystemExit(f"unknown case {case!r}")
            r.update(case=case, code=code, started=time.strftime("%Y-%m-%d %H:%M", time.localtime(t0)))
            results["runs"].append(r)
            Path(args.out).write_text(json.dumps(results, indent=1, default=str))
            print(f"{case} {code}: {r.get('wall_s', '')}", flush=True)
    if old is not None:
        subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old)], check=False)
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
