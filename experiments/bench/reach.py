"""Issue 29's targets, today's code and the new side by side in one run: every case runs in a fresh process on
either source tree, timed from inside (numba's compile excluded where the case says so) and with the child's
peak memory (GNU time's maximum resident set size).

    python experiments/bench/reach.py                 # all cases → experiments/bench/reach.json and a table
    python experiments/bench/reach.py --only check30k fit30k

"Today's code" is the commit before issue 29 (``--base``, default c39b0d9), checked out once into a git worktree
beside the working tree's temporary folder; "new" is this tree. The long recordings are simulated by ``torchtea
simulate`` (this tree) into ``--data`` (default ``$TMPDIR/torchtea-bench``) and reused.

Cases:

* ``check30k`` — ``check`` of one 30 000-sample axis (h = 0.01 s, temperature channel given, so every effect is
  screened, the model's intervals on: the CLI's default), on the hidden-effect study's data: clean data, a hidden
  3.37 Hz line, and random-walk seed 7 (where today's first exact fit is a local maximum and the check restarts).
  Target ≤ 5 s.
* ``fit`` — ``fit_series`` of ``fractional+white+random-walk`` with intervals on 30 000 and 120 000 samples (both
  trees) and on 2.16·10⁶ (new; target ≤ 60 s); ``eval2m``: one exact log-likelihood evaluation at 2.16·10⁶ samples
  on each tree (what a fit of that length costs per point on today's code).
* ``check3h`` — ``torchtea check`` of a simulated six-axis 3-hour 200 Hz recording (2.16·10⁶ samples per channel),
  end to end from the CSV (target ≤ 10 minutes, peak memory ≤ 4 GB).
* ``firstrun`` — the first ``torchtea check`` after install (an empty numba cache) and the second, on each tree.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
BASE = "c39b0d9"
SIX_UNITS = "ms2,ms2,ms2,rad/s,rad/s,rad/s"
#: The simulated IMU: MEMS-like accelerometer (torchtea.noise.default_values), a gyroscope 20× quieter in white
#: noise, both with a bias random walk.
SIM = ["--model", "fractional+white+random-walk", "--h", "0.005", "--columns", "ax,ay,az,gx,gy,gz",
       "--set", "random-walk.sigma=2e-4"] + [a for g in ("gx", "gy", "gz")
                                             for a in ("--set", f"{g}:white.r=2.5e-6", "--set", f"{g}:fractional.q=6e-5",
                                                       "--set", f"{g}:random-walk.sigma=1e-5")]


# --------------------------------------------------------------------------- what a child process runs

def _series(n: int, h: float, seed: int):
    import torch

    from torchtea.noise import default_values, parse_model, simulate_model

    m = parse_model("fractional+white+random-walk")
    v = default_values(m, h)
    v["random-walk.sigma"] = 2e-4
    return simulate_model(m, v, n_steps=n, h=h, generator=torch.Generator().manual_seed(seed))[0, 0].numpy()


def child(case: str, arg: str) -> dict:
    """Run one case in this process (on whichever torchtea is importable) and return its numbers."""
    if case == "check30k":
        from torchtea.checking import check
        from torchtea.studies.hidden import hidden_case

        effect, seed = arg.split(":")
        y, T, _ = hidden_case(effect, int(seed))
        check(y[:3000], 0.01, inputs={"temperature": T[:3000]}, intervals=False)  # compile and warm up, untimed
        t0 = time.perf_counter()
        r = check(y, 0.01, inputs={"temperature": T}, intervals=True)
        return {"seconds": time.perf_counter() - t0, "top": r.suggestions[0].effect if r.suggestions else None,
                "gain": r.suggestions[0].gain if r.suggestions else None, "adequate": r.adequate,
                "restarted": any("local maximum" in n for n in r.notes), "loglik": r.fit.loglik_exact,
                "values": r.fit.values}
    if case == "fit":
        from torchtea.fitting import fit_series

        n = int(arg)
        y = _series(n, 0.005, 3)
        fit_series("fractional+white+random-walk", [y[:2000]], 0.005)  # compile, untimed
        t0 = time.perf_counter()
        f = fit_series("fractional+white+random-walk", [y], 0.005)[0]
        return {"seconds": time.perf_counter() - t0, "loglik": f.loglik, "values": f.values, "se": f.se,
                "converged": f.converged}
    if case == "eval2m":
        import numpy as np

        from torchtea.fitting.mle import exact_loglik
        from torchtea.noise import default_values, parse_model

        y = _series(2_160_000, 0.005, 3)
        m = parse_model("fractional+white+random-walk")
        v = default_values(m, 0.005)
        exact_loglik(m, v, y[:2000] - y[:2000].mean(), 0.005)
        t0 = time.perf_counter()
        ll = exact_loglik(m, v, y - np.mean(y), 0.005)
        return {"seconds": time.perf_counter() - t0, "loglik": float(ll[0])}
    raise ValueError(case)


# --------------------------------------------------------------------------- the parent

def run_child(tree: Path, argv: list, env_extra: dict | None = None, timeout: float = 7200) -> dict:
    """Run ``argv`` with ``tree`` first on the path: its wall time, and what its last JSON line says."""
    env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg", **(env_extra or {}))
    t0 = time.perf_counter()
    p = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=str(tree), text=True)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
        return {"error": f"timed out after {timeout} s", "wall_s": time.perf_counter() - t0}
    res = {"wall_s": time.perf_counter() - t0, "returncode": p.returncode}
    if p.returncode != 0:
        res["error"] = err[-2000:]
        return res
    last = [ln for ln in out.splitlines() if ln.startswith("{")]
    if last:
        res.update(json.loads(last[-1]))
    return res


def peak_of(argv: list, tree: Path, env_extra=None, timeout: float = 7200) -> dict:
    """:func:`run_child` with the child's own peak RSS (MB), from GNU time (Debian's ``time`` package)."""
    gnu_time = Path("/usr/bin/time")
    if not gnu_time.exists():
        return run_child(tree, argv, env_extra, timeout)
    with tempfile.NamedTemporaryFile("r", suffix=".time") as tf:
        r = run_child(tree, [str(gnu_time), "-v", "-o", tf.name] + argv, env_extra, timeout)
        for line in Path(tf.name).read_text().splitlines():
            if "Maximum resident set size" in line:
                r["peak_rss_mb"] = int(line.split(":")[1]) / 1024.0
    return r


def worktree(base: str) -> Path:
    path = Path(tempfile.gettempdir()) / f"torchtea-base-{base}"
    if not path.exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), base], check=True,
                       capture_output=True)
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", default=["check30k", "fit", "eval2m", "check3h", "firstrun"])
    ap.add_argument("--base", default=BASE)
    ap.add_argument("--data", default=str(Path(tempfile.gettempdir()) / "torchtea-bench"))
    ap.add_argument("--out", default=str(HERE / "reach.json"))
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(*args.child), default=float))
        return
    trees = {"today": worktree(args.base), "new": ROOT}
    data = Path(args.data)
    data.mkdir(parents=True, exist_ok=True)
    doc = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(), "base": args.base,
           "date": time.strftime("%Y-%m-%d %H:%M"), "rows": []}
    if Path(args.out).exists():
        old = json.loads(Path(args.out).read_text())
        doc["rows"] = [r for r in old.get("rows", []) if r["case"] not in args.only]
    me = [sys.executable, str(Path(__file__).resolve()), "--child"]

    def add(row):
        doc["rows"].append(row)
        print(json.dumps(row, default=float)[:400], flush=True)
        Path(args.out).write_text(json.dumps(doc, indent=1, default=float))

    if "check30k" in args.only:
        for label, arg in (("clean", "none:0"), ("hidden line", "sinusoid:0"), ("random walk seed 7", "random-walk:7")):
            for tree in ("today", "new"):
                r = peak_of(me + ["check30k", arg], trees[tree])
                add({"case": "check30k", "data": label, "tree": tree, **r})
    if "fit" in args.only:
        for n, trees_ in ((30_000, ("today", "new")), (120_000, ("today", "new")), (2_160_000, ("new",))):
            for tree in trees_:
                r = peak_of(me + ["fit", str(n)], trees[tree])
                add({"case": "fit", "data": f"fractional+white+random-walk, {n} samples", "tree": tree, **r})
    if "eval2m" in args.only:
        for tree in ("today", "new"):
            r = peak_of(me + ["eval2m", "-"], trees[tree])
            add({"case": "eval2m", "data": "one exact log-likelihood, 2.16e6 samples", "tree": tree, **r})
    if "check3h" in args.only:
        rec = data / "imu3h.csv"
        if not rec.exists():
            subprocess.run([sys.executable, "-m", "torchtea.cli", "simulate", "--n", "2160000", *SIM, "--seed", "3",
                            "--out", str(rec)], check=True, cwd=str(ROOT), env=dict(os.environ, PYTHONPATH=str(ROOT)))
        for model in ("fractional+white+random-walk", "fractional+white"):
            out = data / f"check3h-{model}"
            r = peak_of([sys.executable, "-m", "torchtea.cli", "check", str(rec), "--units", SIX_UNITS, "--model",
                         model, "--temperature", "temp", "--no-plots", "--json", "--out", str(out)], ROOT)
            doc_ = json.loads((out / "check.json").read_text()) if (out / "check.json").exists() else {}
            if doc_:  # the whole document (screens, suggestions, their parameters) beside reach.json
                (HERE / "reach_check3h").mkdir(exist_ok=True)
                (HERE / "reach_check3h" / f"{model}.json").write_text(json.dumps(doc_, indent=1))
            summary = {a: {"adequate": d.get("adequate"), "failed": d.get("base", {}).get("failed"),
                           "parameters": d.get("base", {}).get("parameters"),
                           "top": (d.get("suggestions") or [{}])[0].get("effect")}
                       for a, d in doc_.get("axes", {}).items()}
            add({"case": "check3h", "data": f"six-axis 3-hour 200 Hz recording, --model {model}, --temperature temp",
                 "tree": "new", **{k: v for k, v in r.items() if k != "axes"}, "channels": summary,
                 "truth": json.loads(Path(str(rec) + ".truth.json").read_text())["values"]})
    if "firstrun" in args.only:
        for tree in ("today", "new"):
            cache = Path(tempfile.mkdtemp(prefix="numba-cache-"))
            for attempt in ("first", "second"):
                argv = [sys.executable, "-m", "torchtea.cli", "check", "--samples", "3000", "--no-plots",
                        "--out", str(cache / "out")]
                argv += ["--axes", "z"] if tree == "today" else ["--columns", "az"]
                r = peak_of(argv, trees[tree], env_extra={"NUMBA_CACHE_DIR": str(cache)})
                cache_state = "empty numba cache" if attempt == "first" else "the cache the first run filled"
                add({"case": "firstrun", "data": f"torchtea check --samples 3000, one axis, {attempt} run after "
                                                 f"install ({cache_state})", "tree": tree, **r})
    print()
    print("| case | data | today [s] | new [s] | new peak memory [MB] |")
    print("|---|---|---|---|---|")
    rows = doc["rows"]
    seen = []
    for r in rows:
        key = (r["case"], r["data"])
        if key in seen:
            continue
        seen.append(key)
        pair = {x["tree"]: x for x in rows if (x["case"], x["data"]) == key}

        def sec(x):
            if x is None:
                return "—"
            if "error" in x:
                return "error"
            return f"{x.get('seconds', x['wall_s']):.1f}"
        new = pair.get("new", {})
        print(f"| {r['case']} | {r['data']} | {sec(pair.get('today'))} | {sec(pair.get('new'))} | "
              f"{new.get('peak_rss_mb', float('nan')):.0f} |")


if __name__ == "__main__":
    main()
