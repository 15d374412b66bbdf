"""Issue 44: the commands users run, timed with the code before the issue and the code now, in one run.

    python experiments/bench/issue44.py [--old 97a7c4c] [--cases bundled,x_forward,...] [--out issue44.json]

Every case is a ``torchtea`` command run as a user runs it — in a child process (``python -m torchtea.cli``), the
tree under test first on its ``PYTHONPATH`` — with its wall time, its CPU time (user + system, the child's own and
its children's: the Dask workers' too) and its peak memory (the largest resident set of the process and of any of
its children) read from ``os.wait4`` and the Dask workers' own accounting. The old tree is checked out from git
(``git worktree``, removed afterwards). numba's kernels are compiled once per tree before the timings (a first run
of each command on a short recording), so the times are those of a user's second and later runs. Cases:

* ``bundled``: ``check --auto`` of the bundled recording (six channels, 449 s at 100 Hz), old and new, and new with
  ``--workers 2``;
* ``x_forward``, ``z_front``: ``check --auto`` of the two shared MPU-6050 recordings (six channels + temperature,
  123 s and 132 s, read at 100 Hz), old and new;
* ``sim_1min``, ``sim_10min``: ``check --auto`` of a simulated six-axis recording with temperature at 100 Hz
  (``torchtea simulate --model fractional+white+random-walk`` with a bias per °C on the accelerometer and a line on
  one gyroscope axis), old and new (the 10-minute one new with ``--workers 2`` as well);
* ``export``: ``export --format all`` of ``x_forward`` (the loop, then the files), old and new;
* ``sim_3h``: ``check --auto --workers 2`` of a simulated six-axis 3-hour 200 Hz recording with temperature: new only
  (the old code took 704 s for a fit of the true model without ``--auto`` on one such recording, 30 minutes with the
  default model: issue 29), its fitted parameters against the truth.

Writes a JSON of every run (the per-axis models, loop ends and seconds) and prints the table.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
SHARED = ROOT.parent / "shared" / "data" / "mpu6050_sensor_fusion_temperature"
SIX = "--units", "g,g,g,deg/s,deg/s,deg/s", "--rate", "100", "--temperature", "temp"


def run(tree: Path, args: list, out: Path, env_extra: dict | None = None) -> dict:
    """One command in a child process with ``tree`` first on its path: wall, CPU, peak RSS, its check.json."""
    env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg")
    env.update(env_extra or {})
    cmd = [sys.executable, "-m", "torchtea.cli", *map(str, args)]
    t0 = time.perf_counter()
    log = open(out.with_suffix(".log"), "w")
    p = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=out.parent)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    log.close()
    code = os.waitstatus_to_exitcode(status)
    cpu = usage.ru_utime + usage.ru_stime
    res = {"command": "torchtea " + " ".join(map(str, args)), "exit": code, "wall_s": round(wall, 1),
           "cpu_s": round(cpu, 1), "peak_rss_mb": round(usage.ru_maxrss / 1024, 0)}
    doc = out / "check.json"
    if not doc.exists():
        doc = out / "export.json" if (out / "export.json").exists() else None
    if doc is not None and doc.exists():
        d = json.loads(doc.read_text())
        axes = d.get("axes", {})
        res["axes"] = {a: {"model": x.get("model"), "adequate": x.get("adequate"),
                           "loop_end": x.get("loop_end"), "seconds": x.get("seconds"),
                           "failed": x.get("base", {}).get("failed")} for a, x in axes.items()}
    if code != 0:
        res["log_tail"] = out.with_suffix(".log").read_text()[-2000:]
    return res


def simulate(tree: Path, path: Path, n: int, h: float) -> None:
    """A six-axis recording with temperature: fractional+white+random-walk on every axis, a bias per °C on ay and a
    2 mrad/s line at 3.37 Hz on gz (``torchtea simulate``, as a user would make one)."""
    subprocess.run([sys.executable, "-m", "torchtea.cli", "simulate", "--model",
                    "fractional+white+random-walk+temperature-bias+sinusoid", "--n", str(n), "--h", str(h),
                    "--columns", "ax,ay,az,gx,gy,gz", "--temperature-profile", "25,6,600,0.3",
                    "--set", "temperature-bias.bias_per_degC=0", "--set", "ay:temperature-bias.bias_per_degC=0.004",
                    "--set", "sinusoid.amplitude=0", "--set", "gz:sinusoid.amplitude=0.002",
                    "--set", "sinusoid.frequency_hz=3.37", "--set", "gx:white.r=2.5e-6", "--set", "gy:white.r=2.5e-6",
                    "--set", "gz:white.r=2.5e-6", "--seed", "7", "--out", str(path)],
                   check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.DEVNULL)


def cases(work: Path) -> dict:
    bundled = []
    x_fwd = [SHARED / "unmoved_x_forward.csv", *SIX]
    z_front = [SHARED / "unmoved_z_front_x_up.csv", *SIX]
    sim = lambda name: [work / f"{name}.csv", "--units", "ms2,ms2,ms2,rad/s,rad/s,rad/s",  # noqa: E731
                        "--temperature", "temp"]
    return {
        "bundled": (bundled, ["check", "--auto", "--no-plots"], True),
        "x_forward": (x_fwd, ["check", "--auto", "--no-plots"], False),
        "z_front": (z_front, ["check", "--auto", "--no-plots"], False),
        "sim_1min": (sim("sim_1min"), ["check", "--auto", "--no-plots"], False),
        "sim_10min": (sim("sim_10min"), ["check", "--auto", "--no-plots"], True),
        "export": (x_fwd, ["export", "--format", "all", "--no-plots", "--nees", "16"], False),
        "sim_3h": (sim("sim_3h"), ["check", "--auto", "--no-plots"], None),
    }


def table(results: dict) -> str:
    """The runs as two markdown tables: the commands' times, and each axis's model, verdict and seconds."""
    lines = ["| case | code | wall [s] | CPU [s] | peak memory [MB] | exit |", "|---|---|---|---|---|---|"]
    for r in results["runs"]:
        lines.append(f"| {r['case']} | {r['code']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | "
                     f"{r['peak_rss_mb']:.0f} | {r['exit']} |")
    lines += ["", "| case | code | axis | model | verdict | loop's end | seconds |", "|---|---|---|---|---|---|---|"]
    for r in results["runs"]:
        for axis, a in (r.get("axes") or {}).items():
            verdict = {True: "adequate", False: "not adequate"}.get(a.get("adequate"), "—")
            failed = ", ".join(a.get("failed") or [])
            if failed:
                verdict += f" (fails {failed})"
            seconds = a.get("seconds")
            lines.append(f"| {r['case']} | {r['code']} | {axis} | {a.get('model')} | {verdict} | "
                         f"{a.get('loop_end')} | {'' if seconds is None else f'{seconds:.1f}'} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default="97a7c4c", help="the commit before issue 44 (default 97a7c4c)")
    ap.add_argument("--cases", default="bundled,x_forward,z_front,sim_1min,sim_10min,export,sim_3h")
    ap.add_argument("--out", default=str(HERE / "issue44.json"))
    ap.add_argument("--no-old", action="store_true", help="time the new tree only")
    ap.add_argument("--append", action="store_true",
                    help="keep the runs already in --out and skip those cases and variants (a run cut short goes on)")
    ap.add_argument("--table", action="store_true", help="only print the tables of --out (markdown)")
    args = ap.parse_args()
    if args.table:
        print(table(json.loads(Path(args.out).read_text())))
        return 0
    work = Path(tempfile.mkdtemp(prefix="issue44-"))
    wanted = args.cases.split(",")
    old = None
    if not args.no_old:
        old = work / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old), args.old], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    results = {"old": args.old, "new": subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                                      capture_output=True, text=True).stdout.strip(),
               "machine": f"{os.cpu_count()} cores", "load_at_start": os.getloadavg()[0], "runs": []}
    if args.append and Path(args.out).exists():
        kept = json.loads(Path(args.out).read_text())
        results["runs"] = kept["runs"]
        results["earlier"] = {k: kept.get(k) for k in ("new", "load_at_start")}
    done = {(r["case"], r["code"]) for r in results["runs"]}
    try:
        for name, n, h in (("sim_1min", 6000, 0.01), ("sim_10min", 60000, 0.01), ("sim_3h", 2160000, 0.005)):
            if name in wanted:
                simulate(ROOT, work / f"{name}.csv", n, h)
        warm = work / "warm"
        for tree in [t for t in (old, ROOT) if t is not None]:  # numba's compile, once per tree
            warm.mkdir(exist_ok=True)
            run(tree, ["check", "--samples", "3000", "--columns", "ax,gx", "--auto", "--no-plots", "--out", warm],
                warm)
        for name, (inputs, command, workers) in cases(work).items():
            if name not in wanted:
                continue
            variants = [("new", ROOT, [])]
            if workers:
                variants.append(("new --workers 2", ROOT, ["--workers", "2"]))
            if workers is None:
                variants = [("new --workers 2", ROOT, ["--workers", "2"])]
            elif old is not None:
                variants.insert(0, ("old", old, []))
            for label, tree, extra in variants:
                if (name, label) in done:
                    continue
                out = work / f"{name}-{label.replace(' ', '_')}"
                if out.exists():
                    shutil.rmtree(out)
                out.mkdir()
                r = run(tree, [command[0], *inputs, *command[1:], *extra, "--out", out], out)
                r.update(case=name, code=label)
                results["runs"].append(r)
                print(f"{name:10s} {label:16s} {r['wall_s']:8.1f} s wall {r['cpu_s']:8.1f} s CPU "
                      f"{r['peak_rss_mb']:6.0f} MB  exit {r['exit']}", flush=True)
                Path(args.out).write_text(json.dumps(results, indent=1, ensure_ascii=False))
    finally:
        if old is not None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return 0


if __name__ == "__main__":
    sys.exit(main())
