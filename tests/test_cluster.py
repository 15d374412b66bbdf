"""Monte Carlo studies sharded on a real local Dask cluster (worker processes on this machine)."""
import json
import math
import os
import re
import signal

import numpy as np
import pytest
import torch

from torchtea.engines.presets import get_preset
from torchtea.studies.cluster import run_study
from torchtea.studies.montecarlo import Study, StudyResult, Truth, summarise

distributed = pytest.importorskip("distributed")

TRUTH = Truth(h=1e-3, n_steps=150, order="0.35", param=-1.0, q=1e-4, r=1e-3, input_std=1.0)


def assert_same_result(a: StudyResult, b: StudyResult):
    """Per-realisation values equal (the same arithmetic on the same draws); per-step sums to 1e-12 (the order
    of summation over realisations differs between splits)."""
    assert torch.equal(a.index, b.index) and torch.equal(a.diverged, b.diverged)
    for k in a.final:
        torch.testing.assert_close(a.final[k], b.final[k], rtol=1e-12, atol=0)
    for k in ("order", "param"):
        torch.testing.assert_close(a.converged_at[k], b.converged_at[k], rtol=1e-12, atol=0, equal_nan=True)
        assert torch.equal(a.covered[k], b.covered[k])
    for k in a.logged:
        torch.testing.assert_close(a.logged[k], b.logged[k], rtol=1e-12, atol=0)
    for k in ("order", "param"):
        assert torch.equal(a.covered_steps[k], b.covered_steps[k])
    torch.testing.assert_close(a.nees_sum, b.nees_sum, rtol=1e-12, atol=0)
    torch.testing.assert_close(a.nis_sum, b.nis_sum, rtol=1e-12, atol=0)


def assert_same_summary(a, b, path=""):
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            assert_same_summary(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_summary(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-12, abs=0, nan_ok=True), path
    else:
        assert a == b, path


@pytest.mark.parametrize("divergence_limit", [1e8, 1.5], ids=["none-diverge", "some-diverge"])
def test_sharded_equals_single_process(cluster, divergence_limit):
    """23 realisations as shards of 5 on two worker processes against one process in chunks of 4 — also with a
    divergence limit at which some realisations diverge (they are left out of the statistics in both)."""
    from dataclasses import replace

    from distributed import get_task_stream

    from torchtea.studies.cluster import plan_shards

    study = Study(TRUTH, replace(get_preset("paper-example1"), divergence_limit=divergence_limit), realisations=23,
                  seed=11, chunk=4)
    single = run_study(study)
    shards = []
    with get_task_stream(cluster) as ts:
        sharded = run_study(study, client=cluster, shard=5, progress=lambda done, total: shards.append((done, total)))
    assert [r.stop - r.start for r in plan_shards(study, 5, 2)] == [5, 5, 5, 5, 3]
    assert shards == [(i, 5) for i in range(1, 6)]
    assert sharded.finished == 23 and not sharded.interrupted
    assert_same_result(sharded, single)
    assert_same_summary(summarise(sharded), summarise(single))
    assert (int(single.diverged.sum()) > 0) == (divergence_limit < 2)
    # the five shards ran on both worker processes
    assert len({t["worker"] for t in ts.data}) == 2 and len(ts.data) == 5


def test_equal_studies_together_do_not_share_tasks(cluster):
    """The same study twice in one call (and again in a second call): separate tasks, complete equal results."""
    from torchtea.studies.cluster import run_studies

    study = Study(TRUTH, get_preset("paper-example1"), realisations=9, seed=2)
    a, b = run_studies([study, study], cluster, shard=4)
    (c,) = run_studies([study], cluster, shard=4)
    for r in (a, b, c):
        assert r.finished == 9 and not r.interrupted
        assert_same_result(r, a)


def test_default_shards_and_full_trajectories_refused(cluster):
    from torchtea.studies.cluster import plan_shards

    study = Study(TRUTH, get_preset("paper-example1"), realisations=100, seed=1)
    ranges = plan_shards(study, None, 2)
    assert len(ranges) == 8 and sum(len(r) for r in ranges) == 100  # ~4 shards per worker thread
    assert [r.start for r in ranges] == list(range(0, 100, 13))
    with pytest.raises(ValueError, match="not sent back from a cluster"):
        run_study(study, client=cluster, trajectories=True)
    with pytest.raises(ValueError, match="at least 1"):
        plan_shards(study, 0, 2)


def test_a_failing_shard_keeps_what_finished(cluster):
    """A shard that raises stops the run with one error naming the study and its realisations, with the
    worker's traceback; the finished shards come back: the study that completed is whole and not interrupted,
    the failing one holds its finished shards (equal to the one-process run there) and is interrupted."""
    from torchtea.studies.cluster import StudyFailed, run_studies

    def inject(seed, queue):  # runs in each worker process: shards of studies with this seed from realisation 4 on
        import time  # fail, once the three other shards (two of the good study, one of the bad) have finished

        from distributed import Queue

        import torchtea.studies.cluster as c

        original = getattr(c.run_range, "original", c.run_range)

        def failing(study, start, stop, **kw):
            done = Queue(queue)
            if study.seed == seed and start >= 4:
                deadline = time.monotonic() + 60
                while done.qsize() < 3 and time.monotonic() < deadline:
                    time.sleep(0.05)
                raise RuntimeError(f"injected fault in realisations {start}-{stop}")
            out = original(study, start, stop, **kw)
            done.put(start)
            return out

        failing.original = original
        c.run_range = failing

    def restore():
        import torchtea.studies.cluster as c

        c.run_range = getattr(c.run_range, "original", c.run_range)

    good = Study(TRUTH, get_preset("paper-example1"), realisations=8, seed=1)
    bad = Study(TRUTH, get_preset("paper-example1"), realisations=12, seed=77)
    cluster.run(inject, 77, "torchtea-test-finished-shards")
    try:
        with pytest.raises(StudyFailed) as info:
            run_studies([good, bad], cluster, shard=4, names=["good", "bad"])
    finally:
        cluster.run(restore)
    message = str(info.value)
    assert "a shard failed on the cluster (bad, realisations " in message and "injected fault" in message, message
    assert "worker traceback" in message and "failing" in message, message
    done_good, done_bad = info.value.partial
    assert done_good.finished == 8 and not done_good.interrupted
    assert_same_result(done_good, run_study(good))
    assert done_bad.interrupted and 4 <= done_bad.finished < 12
    assert done_bad.index[:4].tolist() == [0, 1, 2, 3]
    single = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=4, seed=77))
    torch.testing.assert_close(done_bad.final["alpha"][:4], single.final["alpha"], rtol=1e-12, atol=0)


def test_cuda_on_workers_without_it_is_one_error(cluster, tmp_path, capsys):
    """`--device cuda` on workers without CUDA: every shard fails; one error naming the study, exit 2, nothing
    summarised."""
    from torchtea.cli import main

    if torch.cuda.is_available():
        pytest.skip("the workers have CUDA")
    code = main(["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "4", "--scheduler",
                 cluster.scheduler.address, "--device", "cuda", "--logdir", str(tmp_path / "mc")])
    err = capsys.readouterr().err
    # every shard fails; the first to be reported (any of them) is named
    assert code == 2 and re.search(r"a shard failed on the cluster \(the study, realisations \d–\d\)", err), err
    assert not (tmp_path / "mc" / "summary.json").exists()


def test_cli_on_a_scheduler_writes_the_single_process_run(cluster, tmp_path, capsys):
    """`torchtea montecarlo --scheduler ADDRESS`: the same summary.json (to 1e-12), final_estimates.csv and
    TensorBoard scalars as the run in one process."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from torchtea.cli import main

    argv = ["montecarlo", "--preset", "paper-example1", "--n", "120", "--realisations", "13", "--seed", "4", "--json"]
    assert main(argv + ["--logdir", str(tmp_path / "one")]) == 0
    one = json.loads(capsys.readouterr().out)
    address = cluster.scheduler.address
    assert main(argv + ["--logdir", str(tmp_path / "many"), "--scheduler", address, "--shard", "4",
                        "--progress-file", str(tmp_path / "progress")]) == 0
    many = json.loads(capsys.readouterr().out)
    for k in ("logdir", "seconds"):
        one.pop(k), many.pop(k)
    assert_same_summary(many, one)
    assert (tmp_path / "progress").read_text().split() == ["4", "4", "shards"]
    a = np.genfromtxt(tmp_path / "one" / "final_estimates.csv", delimiter=",", names=True)
    b = np.genfromtxt(tmp_path / "many" / "final_estimates.csv", delimiter=",", names=True)
    assert list(b["realisation"]) == list(range(13))
    for name in a.dtype.names:
        np.testing.assert_allclose(b[name], a[name], rtol=1e-12, atol=0)
    runs = []
    for d in ("one", "many"):
        ea = EventAccumulator(str(tmp_path / d), size_guidance={"scalars": 0})
        ea.Reload()
        runs.append({tag: [(e.step, e.value) for e in ea.Scalars(tag)] for tag in ea.Tags()["scalars"]})
    assert runs[0].keys() == runs[1].keys() and len(runs[0]["order/q50"]) == 120
    for tag in runs[0]:
        np.testing.assert_allclose(np.array(runs[1][tag]), np.array(runs[0][tag]), rtol=1e-6, err_msg=tag)


SWEEP = """
realisations = 6
seed = 3
[truth]
n = 100
[estimator]
preset = "paper-example1"
[sweep.truth]
order = ["0.2", "0.6"]
[sweep.estimator.kfo]
Q0 = [0.1, 0.01]
"""


def test_sweep_of_2x2_settings_writes_four_runs_with_hparams(cluster, tmp_path, capsys):
    """A study file with a [sweep] table: four sub-studies scheduled together on the cluster, each its own
    TensorBoard run with its settings as hparams; each equals the plain study of its combination."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import metadata as hp_metadata
    from tensorboard.plugins.hparams import plugin_data_pb2

    from torchtea.cli import main

    cfg = tmp_path / "sweep.toml"
    cfg.write_text(SWEEP)
    assert main(["montecarlo", "--config", str(cfg), "--logdir", str(tmp_path / "sw"), "--scheduler",
                 cluster.scheduler.address, "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    names = sorted(s["sweep"]["name"] for s in table["studies"])
    assert names == ["order=0.2,kfo.Q0=0.01", "order=0.2,kfo.Q0=0.1", "order=0.6,kfo.Q0=0.01", "order=0.6,kfo.Q0=0.1"]
    assert json.loads((tmp_path / "sw" / "sweep.json").read_text())["studies"] == table["studies"]
    assert not table["not_run"]
    for s in table["studies"]:
        run = tmp_path / "sw" / s["sweep"]["name"]
        ea = EventAccumulator(str(run), size_guidance={"scalars": 0, "tensors": 0})
        ea.Reload()
        assert ea.Scalars("order/truth")[0].value == pytest.approx(float(s["sweep"]["values"]["truth.order"]))
        assert ea.Scalars("metric/order_rmse")[0].value == pytest.approx(s["order"]["rmse"], rel=1e-6)
        content = ea.PluginTagToContent(hp_metadata.PLUGIN_NAME)
        start = plugin_data_pb2.HParamsPluginData.FromString(content[hp_metadata.SESSION_START_INFO_TAG])
        hp = {k: v.string_value or v.number_value for k, v in start.session_start_info.hparams.items()}
        assert hp["sweep.truth.order"] == s["sweep"]["values"]["truth.order"]
        assert hp["sweep.estimator.kfo.Q0"] == pytest.approx(s["sweep"]["values"]["estimator.kfo.Q0"])
        assert hp["realisations"] == 6 and hp["kfx_uncertainty"] == "paper-gain"
        assert hp["estimate_uncertainty"] == "paper"
        # the sub-study's own study.toml reruns it in one process to the same numbers
        assert main(["montecarlo", "--config", str(run / "study.toml"), "--logdir", str(tmp_path / "again"),
                     "--json"]) == 0
        again = json.loads(capsys.readouterr().out)
        assert again["order"]["rmse"] == pytest.approx(s["order"]["rmse"], rel=1e-12)
        assert again["nees"]["mean"] == pytest.approx(s["nees"]["mean"], rel=1e-12)


def test_sweep_definition_errors(tmp_path):
    from torchtea.studies.sweep import build_sweep

    base = {"realisations": 2, "estimator": {"preset": "paper-example1"}}
    subs = build_sweep({**base, "sweep": {"truth": {"param": [-0.5, -2.0]}, "estimator": {"order_bounds": [[0, 1], [0, 2]]}}})
    assert [s.name for s in subs] == ["param=-0.5,order_bounds=0,1", "param=-0.5,order_bounds=0,2",
                                      "param=-2.0,order_bounds=0,1", "param=-2.0,order_bounds=0,2"]
    assert subs[1].study.estimator.order_bounds == (0, 2) and subs[2].study.truth.param == -2.0
    assert all(s.study.seed == 0 for s in subs)  # one seed: common random numbers across sub-studies
    assert subs[1].hparams() == {"sweep.truth.param": -0.5, "sweep.estimator.order_bounds": "[0, 2]"}
    for table, message in (({"truth": {"order": "0.2"}}, "must be a list"),
                           ({"truth": {"order": []}}, "lists no values"),
                           ({"seed": [1, 2]}, "not \\['seed'\\]"),
                           ({}, "lists no settings"),
                           ({"truth": {"order": ["0.2", "0.2"]}}, "twice"),
                           ({"estimator": {"kfo": {"Q1": [1, 2]}}}, "unknown settings in \\[kfo\\]")):
        with pytest.raises(ValueError, match=message):
            build_sweep({**base, "sweep": table}, source="s.toml")
    with pytest.raises(ValueError, match="truth.order is swept; leave out its command-line flag"):
        build_sweep({**base, "sweep": {"truth": {"order": ["0.2", "0.3"]}}}, {"order": "0.4"}, source="s.toml")


def test_cli_cluster_option_errors(tmp_path, capsys):
    from torchtea.cli import main

    base = ["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "2"]
    assert main(base + ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "give one" in capsys.readouterr().err
    assert main(base + ["--shard", "3"]) == 2
    assert "--shard sets the realisations per Dask task: it needs --workers or --scheduler" in capsys.readouterr().err
    assert main(base + ["--threads-per-worker", "1"]) == 2
    assert "--threads-per-worker applies" in capsys.readouterr().err
    assert main(base + ["--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "1", "--logdir",
                        str(tmp_path / "x")]) == 2
    assert "--scheduler tcp://127.0.0.1:9: cannot connect" in capsys.readouterr().err
    for flag in ("--workers", "--shard", "--threads-per-worker"):
        extra = ["--workers", "1"] if flag == "--threads-per-worker" else []
        assert main(base + extra + [flag, "0", "--logdir", str(tmp_path / "y")]) == 2
        assert f"{flag} must be at least 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "y").exists()  # refused before anything is written


def test_scheduler_without_workers_waits_then_says_so(tmp_path, capsys):
    from distributed import LocalCluster

    from torchtea.cli import main

    with LocalCluster(n_workers=0, processes=False, dashboard_address=":0") as empty:
        code = main(["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "2", "--scheduler",
                     empty.scheduler_address, "--connect-timeout", "1", "--logdir", str(tmp_path / "z")])
    assert code == 2
    assert "no worker joined within 1 s (--connect-timeout)" in capsys.readouterr().err


def test_worker_killed_mid_run_gives_the_complete_identical_result():
    """SIGKILL of a worker process while it runs a shard: the scheduler recomputes that shard on a worker (the
    nanny restarts the dead one), and the merged study is complete and equal to the single-process run — no
    realisation lost or counted twice."""
    from torchtea.studies.cluster import local_cluster

    from .procs import kill_a_busy_worker

    study = Study(Truth(h=1e-3, n_steps=600, order="0.35", param=-1.0, q=1e-4, r=1e-3, input_std=1.0),
                  get_preset("paper-example1"), realisations=48, seed=21)
    single = run_study(study)
    cl, client = local_cluster(2, threads_per_worker=1)
    killed = []
    try:
        sharded = run_study(study, client=client, shard=4,
                            progress=kill_a_busy_worker(client, client.run(os.getpid), killed))
        assert killed, "no worker was busy when the first shard finished"
        lost_keys = killed[0][1]
        # the scheduler's story of a shard held by the killed worker: sent out for processing a second time
        story = client.story(lost_keys[0])
        processing = [s for s in story if s[0] == "scheduler" and s[3] == "processing"]
        assert len(processing) >= 2, story
    finally:
        client.close()
        cl.close()
    assert sharded.finished == 48 and torch.equal(sharded.index, torch.arange(48))
    assert_same_result(sharded, single)
    assert_same_summary(summarise(sharded), summarise(single))


@pytest.mark.slow
def test_ctrl_c_with_local_workers_keeps_finished_shards(tmp_path):
    """A real SIGINT to `torchtea montecarlo --workers 2` (and, as in a terminal, to its worker processes):
    exit 130, and the run directory holds the finished shards' realisations, by their numbers."""
    import subprocess
    import sys

    from .procs import sigint_as_in_a_terminal, wait_for_progress

    logdir, progress = tmp_path / "mc", tmp_path / "progress"
    proc = subprocess.Popen([sys.executable, "-m", "torchtea.cli", "montecarlo", "--preset", "paper-example1",
                             "--n", "400", "--realisations", "4000", "--shard", "10", "--workers", "2",
                             "--logdir", str(logdir), "--progress-file", str(progress), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: (sigint_as_in_a_terminal(), os.setpgrp()))
    done = wait_for_progress(progress, proc, 3, timeout=180, poll=0.1)
    assert done >= 3, ("no progress within 180 s", proc.poll())
    os.killpg(proc.pid, signal.SIGINT)  # the whole process group, as Ctrl-C in a terminal
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, (proc.returncode, out, err)
    summary = json.loads((logdir / "summary.json").read_text())
    assert summary["interrupted"] and 30 <= summary["realisations"] < 4000, (summary, err)
    fin = np.genfromtxt(logdir / "final_estimates.csv", delimiter=",", names=True)
    numbers = fin["realisation"].astype(int)
    assert len(numbers) == summary["realisations"] and len(set(numbers)) == len(numbers)
    # whole shards of 10 consecutive realisations
    assert all(np.array_equal(np.unique(numbers[numbers // 10 == s]), np.arange(10 * s, 10 * s + 10))
               for s in np.unique(numbers // 10))
    assert math.isfinite(summary["order"]["rmse"])


@pytest.mark.slow
def test_documented_scheduler_and_worker_commands(tmp_path, capsys):
    """The README's multi-machine recipe on one machine: `dask scheduler` and two `dask worker` processes started
    from the command line, then `torchtea montecarlo --scheduler`; the result equals the one-process run."""
    import subprocess
    import sys
    import time

    from torchtea.cli import main

    sched_file = tmp_path / "scheduler.json"
    bin_dir = os.path.dirname(sys.executable)
    dask = os.path.join(bin_dir, "dask")
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "2", "--nthreads", "1",
                                       "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with distributed.Client(address, timeout=30) as c:
            c.wait_for_workers(2, timeout=60)
        argv = ["montecarlo", "--preset", "paper-example1", "--n", "100", "--realisations", "9", "--seed", "2",
                "--json"]
        assert main(argv + ["--logdir", str(tmp_path / "one")]) == 0
        one = json.loads(capsys.readouterr().out)
        assert main(argv + ["--logdir", str(tmp_path / "many"), "--scheduler", address]) == 0
        many = json.loads(capsys.readouterr().out)
    finally:
        for p in reversed(procs):
            p.send_signal(signal.SIGINT)  # the dask commands close cleanly on SIGINT
        for p in procs:
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
    for k in ("logdir", "seconds"):
        one.pop(k), many.pop(k)
    assert_same_summary(many, one)
