"""Benchmark of Monte Carlo studies sharded on Dask (issue 14): one study in this process against the same study as
shards on a local Dask cluster of 1 and 2 worker processes, side by side in one run, and the overhead per shard.

    python experiments/bench/dask_shards.py            # ≈ 3 min on 2 cores; --quick for a smoke run

The study: case A of ``engines.py`` — the MEMS setting (h = 0.01 s, α 0.4, f −4, Q 0.01, R 4e−4; paper §5.1 x-axis
filter settings) with ``soe`` memory, the setting of large studies — 4000 realisations × 3000 samples, seed 1. Runs:

- ``single``: :func:`run_study` in this process (torch and numba on every core).
- ``1 worker × T threads`` and ``2 workers × T/2 threads`` (T = this machine's cores), each with the default shards
  (≈ 4 per worker thread) and with shards of 50 and 1000 realisations. Both clusters are started first (their
  start is timed) and every worker process is warmed by a two-realisation run (its imports and numba's kernel load,
  timed too), so a run's wall time is the study's. All runs are interleaved over ``--rounds`` rounds (default 2),
  so that the machine's drift shows as spread rather than as a difference between layouts.
- Per sharded run, the workers' compute time from Dask's task stream, and the wall time minus that compute per
  worker: what scheduling, transfers and the merge add; and the CPU time of this process, which holds the client
  and the local cluster's scheduler (on 2 cores it competes with the workers).
- Every sharded summary is compared with the single-process one (largest relative difference of its numbers).

Overhead per shard, two ways: (a) the fixed cost of one :func:`run_range` call in this process (the intercept of
its time against the shard size, least squares over sizes 1…200); (b) Dask's round trip of a no-op task on the
warm cluster (submit → result, 200 in a row).

Prints a table and writes ``experiments/bench/dask_shards.json``.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from distributed import get_task_stream

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
from experiments.common import machine, write_json  # noqa: E402
from torchtea.core.memory import MemoryConfig  # noqa: E402
from torchtea.engines.presets import get_preset  # noqa: E402
from torchtea.studies.cluster import local_cluster, plan_shards, run_study  # noqa: E402
from torchtea.studies.montecarlo import Study, Truth, run_range, summarise  # noqa: E402

MEMS = Truth(h=0.01, n_steps=3000, order="0.4", param=-4.0, q=0.01, r=4e-4)


def flat(d, prefix=""):
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(flat(v, f"{prefix}{k}/"))
        elif isinstance(v, list):
            out.update({f"{prefix}{k}[{i}]": x for i, x in enumerate(v)})
        elif isinstance(v, float):
            out[prefix + k] = v
    return out


def max_rel_diff(a: dict, b: dict) -> float:
    fa, fb = flat(a), flat(b)
    worst = 0.0
    for k, x in fa.items():
        y = fb[k]
        if x != y and np.isfinite(x):
            worst = max(worst, abs(x - y) / max(abs(x), 1e-300))
    return worst


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="400 realisations × 1000 samples, one shard size")
    ap.add_argument("--out", default=str(HERE / "dask_shards.json"))
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds of every run (default 2)")
    args = ap.parse_args()
    truth = Truth(**{**vars(MEMS), "n_steps": 1000}) if args.quick else MEMS
    R = 400 if args.quick else 4000
    study = Study(truth, replace(get_preset("paper-mems-x"), memory=MemoryConfig("soe")), realisations=R, seed=1)
    cores = os.cpu_count() or 1
    rows = []

    def row(name, **kw):
        rows.append({"run": name, **kw})
        print(f"{name:<34} " + "  ".join(f"{k} {v}" for k, v in kw.items()), flush=True)

    # in-process reference, warmed by a small study (imports done; numba's kernels loaded)
    run_study(Study(truth, study.estimator, realisations=4, seed=99))

    # (a) the fixed cost of one run_range call
    sizes = [1, 2, 5, 10, 20, 50] if args.quick else [1, 5, 10, 20, 50, 100, 200]
    times = []
    for k in sizes:
        best = min(timed(lambda: run_range(study, 0, k))[0] for _ in range(3))
        times.append(best)
    slope, intercept = np.polyfit(sizes, times, 1)
    row("run_range fixed cost per call", intercept_ms=round(1e3 * intercept, 1),
        per_realisation_ms=round(1e3 * slope, 3), sizes=sizes, best_of_3_s=[round(t, 4) for t in times])

    # both clusters started and warmed up front, so that the runs can be interleaved
    clusters = {}
    for workers in (1, 2):
        threads = max(1, cores // workers)
        t_start, (cl, client) = timed(lambda: local_cluster(workers, threads_per_worker=threads))
        # every worker process imports torchtea and loads numba's kernels once: done here on each of them
        cold, _ = timed(lambda: client.run(run_range, Study(truth, study.estimator, realisations=2, seed=98), 0, 2))
        rtt = []
        for _ in range(200):
            t0 = time.perf_counter()
            client.submit(int, 0, pure=False).result()
            rtt.append(time.perf_counter() - t0)
        clusters[workers] = (cl, client)
        row(f"{workers} worker(s) × {threads} thread(s): start", cluster_start_s=round(t_start, 2),
            worker_warm_up_s=round(cold, 2), noop_task_round_trip_ms_median=round(1e3 * float(np.median(rtt)), 2))

    shard_sizes = [None] if args.quick else [None, 50, 1000]
    runs = [("single", None, None)] + [(f"{w} worker(s), shards {'default' if s is None else s}", w, s)
                                       for w in (1, 2) for s in shard_sizes]
    walls = {name: [] for name, _, _ in runs}
    detail = {}
    ref = None
    try:
        for rnd in range(args.rounds):
            for name, workers, shard in runs:
                if workers is None:
                    wall, res = timed(lambda: run_study(study))
                    ref = ref or summarise(res)
                    walls[name].append(wall)
                    continue
                client = clusters[workers][1]
                cpu0 = time.process_time()
                with get_task_stream(client) as ts:
                    wall, res = timed(lambda: run_study(study, client=client, shard=shard))
                client_cpu = time.process_time() - cpu0
                compute = sum(s["stop"] - s["start"] for d in ts.data for s in d["startstops"]
                              if s["action"] == "compute")
                walls[name].append(wall)
                plan = plan_shards(study, shard, workers)
                detail.setdefault(name, []).append(dict(
                    shards=len(plan), realisations_per_shard=len(plan[0]),
                    worker_compute_s=round(compute, 2),
                    wall_minus_compute_per_worker_s=round(wall - compute / workers, 2),
                    client_and_scheduler_cpu_s=round(client_cpu, 2),
                    max_rel_diff_of_summary=float(f"{max_rel_diff(ref, summarise(res)):.3g}"), finished=res.finished))
            print(f"round {rnd + 1}: " + ", ".join(f"{n} {walls[n][-1]:.2f} s" for n, _, _ in runs), flush=True)
    finally:
        for cl, client in clusters.values():
            client.close()
            cl.close()
    best_single = min(walls["single"])
    row("single process", wall_s=[round(w, 2) for w in walls["single"]], threads=cores)
    for name, _workers, _shard in runs[1:]:
        d = detail[name][int(np.argmin(walls[name]))]
        row(name, wall_s=[round(w, 2) for w in walls[name]], best_vs_best_single=round(min(walls[name]) / best_single, 3),
            **d)
    write_json(Path(args.out), {"machine": machine(), "cores": cores, "realisations": R, "n_steps": truth.n_steps,
                                "setting": "MEMS (paper-mems-x filter, soe memory; truth α 0.4, f −4, Q 0.01, R 4e-4)",
                                "rows": rows})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
