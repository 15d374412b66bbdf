"""Nothing lost on long runs: each channel kept as it finishes, a run stopped by SIGTERM (or Ctrl-C) goes on from the
channels kept and ends with the outputs of a run never stopped; a worker that dies is replaced and its channel run
again with the same result; a channel's stages come back from the workers."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from torchtea.cli import main
from torchtea.core.checkpoint import Checkpoint, CheckpointError

from .test_parallel import _recording, _without_times


def test_a_checkpoint_keeps_parts_whole_and_knows_its_run(tmp_path):
    folder = tmp_path / "partial"
    cp = Checkpoint(folder, {"flags": {"model": "white", "exclude": ((1.0, 2.0),)}})
    cp.keep("ax", {"value": np.arange(3.0)})
    cp.keep("gy/1", [1, 2])
    (folder / ".az.tmp").write_bytes(b"half a pickle")  # a part whose writing was cut: never taken
    same = Checkpoint(folder, {"flags": {"model": "white", "exclude": ((1.0, 2.0),)}}, resume=True)  # (as argparse)
    assert list(same.done) == ["ax", "gy/1"] and np.array_equal(same.done["ax"]["value"], np.arange(3.0))
    (folder / "ax.pickle").write_bytes(b"not a pickle")
    said = []
    assert list(Checkpoint(folder, {"flags": {"model": "white", "exclude": [[1.0, 2.0]]}}, say=said.append).done) \
        == ["gy/1"] and "run again" in said[0]
    with pytest.raises(CheckpointError, match="differs in flags"):
        Checkpoint(folder, {"flags": {"model": "white+random-walk"}}, resume=True)
    other = Checkpoint(folder, {"flags": {"model": "white+random-walk"}}, say=said.append)
    assert other.done == {} and "starts afresh" in said[-1]
    assert (folder / "gy_1.pickle").exists()  # (another run's parts stay until this run keeps its first)
    other.keep("az", 3)
    assert sorted(f.name for f in folder.iterdir()) == ["az.pickle", "run.json"]
    (folder / "run.json").write_text('{"identity": {"flags"')  # a run.json cut short: not a run to go on, replaced
    again = Checkpoint(folder, {"flags": {"model": "white+random-walk"}}, say=said.append)
    assert again.done == {} and "no readable run.json" in said[-1]
    again.keep("az", 4)
    assert Checkpoint(folder, {"flags": {"model": "white+random-walk"}}, resume=True).done == {"az": 4}
    with pytest.raises(CheckpointError, match="no interrupted run"):
        Checkpoint(tmp_path / "none", {}, resume=True)
    cp = Checkpoint(folder, {})
    cp.keep("ax", 1)
    cp.finish()
    assert not folder.exists()


def test_a_run_is_the_same_run_by_its_flags_recording_and_effects_code(tmp_path, capsys):
    """The identity `check`, `fit` and `export` keep: --exclude stretches (tuples from the command line, lists in
    run.json) compare equal; a users' effects module whose code changed, or another flag, makes another run."""
    from torchtea.cli import build_parser
    from torchtea.cli.common import _checkpoint

    mod = tmp_path / "mine.py"
    mod.write_text("X = 1\n")

    def args(*more):
        a = build_parser().parse_args(["--effects", str(mod), "check", "--exclude", "1:2", *more])
        a.recording = None
        return a

    _checkpoint(args(), tmp_path / "p", 6).keep("ax", 1)
    assert _checkpoint(args(), tmp_path / "p", 6).done == {"ax": 1}
    assert _checkpoint(args("--resume"), tmp_path / "p", 6).done == {"ax": 1}
    assert _checkpoint(args("--auto"), tmp_path / "p", 6).done == {}
    mod.write_text("X = 22\n")
    assert _checkpoint(args(), tmp_path / "p", 6).done == {}
    assert "not of this run" in capsys.readouterr().err


def _wait_for_parts(folder, proc, count: int, timeout: float) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        n = len(list(folder.glob("*.pickle")))
        if n >= count:
            return n
        time.sleep(0.1)
    return len(list(folder.glob("*.pickle")))


def test_a_check_stopped_by_sigterm_after_two_channels_goes_on_to_the_same_check_json(tmp_path):
    """`torchtea check` in a child process, SIGTERM once two channels are kept (as a time limit sends it): exit 143,
    the two channels in OUT/partial, the line saying so; the same command again checks only the others and writes
    the check.json of a run never stopped (timings aside), and the partial folder is gone."""
    path = _recording(tmp_path, n=3000)
    flags = ["--columns", "acc_x,acc_z,gyro_x,gyro_y", "--units", "g,g,rad/s,rad/s", "--no-plots", "--no-intervals"]
    out = tmp_path / "stopped"
    proc = subprocess.Popen([sys.executable, "-m", "torchtea.cli", "check", str(path), *flags, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kept = _wait_for_parts(out / "partial", proc, 2, timeout=300)
    assert kept >= 2, ("no two channels kept", proc.poll())
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    kept = sorted(f.stem for f in (out / "partial").glob("*.pickle"))
    if proc.returncode == 0:  # (the run ended between the two lines above: nothing to go on with)
        pytest.skip("the check finished before SIGTERM reached it")
    assert proc.returncode == 143, err
    assert f"stopped (SIGTERM): {len(kept)} of 4 channels kept" in err and not (out / "check.json").exists()
    assert 2 <= len(kept) < 4
    assert main(["check", str(path), *flags, "--out", str(out), "--resume"]) == 0
    assert not (out / "partial").exists()
    assert main(["check", str(path), *flags, "--out", str(tmp_path / "whole")]) == 0
    resumed = json.loads((out / "check.json").read_text())
    whole = json.loads((tmp_path / "whole" / "check.json").read_text())
    assert list(resumed["axes"]) == ["ax", "az", "gx", "gy"]
    assert _without_times(resumed["axes"]) == _without_times(whole["axes"])


def test_fit_and_export_keep_each_channel_and_go_on(tmp_path, monkeypatch, capsys):
    """A stop in the third channel's fit (KeyboardInterrupt, as Ctrl-C raises it): exit 130, two channels kept
    (fit: beside --out; export --model: OUT/partial); the same command again fits only what is left and writes what a
    run never stopped writes. --resume without a run kept, or with --together, is one line."""
    import torchtea.fitting.recording as recording

    path = _recording(tmp_path, n=2000)
    flags = ["--columns", "acc_x,acc_z,gyro_x", "--units", "g,g,rad/s", "--model", "white+random-walk"]
    real, calls = recording.fit_channel, []

    def stop_at_third(*a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(recording, "fit_channel", stop_at_third)
    fit = ["fit", str(path), *flags, "--bootstrap", "0", "--out"]
    assert main(fit + [str(tmp_path / "fit.json")]) == 130
    assert "interrupted: 2 of 3 channels kept" in capsys.readouterr().err
    assert sorted(f.stem for f in (tmp_path / "fit.json.partial").glob("*.pickle")) == ["ax", "az"]
    calls.clear()
    monkeypatch.setattr(recording, "fit_channel", real)
    assert main(fit + [str(tmp_path / "fit.json")]) == 0
    assert "going on with an interrupted run: ax, az" in capsys.readouterr().err
    assert main(fit + [str(tmp_path / "whole.json")]) == 0
    resumed, whole = (json.loads((tmp_path / f).read_text()) for f in ("fit.json", "whole.json"))
    assert _without_times(resumed["axes"]) == _without_times(whole["axes"])
    assert not (tmp_path / "fit.json.partial").exists()

    monkeypatch.setattr(recording, "fit_channel", stop_at_third)
    calls.clear()
    export = ["export", str(path), *flags, "--format", "ieee952", "--no-plots", "--out"]
    assert main(export + [str(tmp_path / "ex")]) == 130
    assert sorted(f.stem for f in (tmp_path / "ex" / "partial").glob("*.pickle")) == ["ax", "az"]
    monkeypatch.setattr(recording, "fit_channel", real)
    assert main(export + [str(tmp_path / "ex"), "--resume"]) == 0
    assert main(export + [str(tmp_path / "ex-whole")]) == 0
    a, b = (json.loads((tmp_path / f / "export.json").read_text()) for f in ("ex", "ex-whole"))
    assert _without_times(a["axes"]) == _without_times(b["axes"])
    capsys.readouterr()

    assert main(["fit", str(path), *flags, "--resume", "--out", str(tmp_path / "none.json")]) == 2
    assert "no interrupted run to go on" in capsys.readouterr().err
    assert main(["fit", str(path), *flags, "--resume"]) == 2
    assert "give the --out of the interrupted run" in capsys.readouterr().err
    assert main(["check", str(path), str(path), "--together", "--resume", *flags]) == 2
    assert "--resume is not available with --together" in capsys.readouterr().err


def test_a_killed_worker_is_replaced_and_the_check_is_the_same(tmp_path):
    """SIGKILL of a worker process while it checks a channel: the scheduler runs that channel again on a worker (the
    nanny restarts the dead one) and the results are those of the run in this process; each channel's stages come
    back from the workers as lines, and each channel is handed to `keep` as it finishes."""
    from torchtea.checking.channels import check_measurements
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare
    from torchtea.studies.cluster import local_cluster

    from .procs import kill_a_busy_worker

    path = _recording(tmp_path, n=2500)
    m = prepare(read_recording(path, columns=["acc_x", "acc_z", "gyro_x"], units="g,g,rad/s"))
    here = check_measurements(m, "white", auto=True, intervals=False)
    cl, client = local_cluster(2, threads_per_worker=1)
    killed, lines, kept = [], [], []
    try:
        there = check_measurements(m, "white", auto=True, intervals=False, client=client,
                                   progress=kill_a_busy_worker(client, client.run(os.getpid), killed),
                                   stages=lines.append, keep=lambda label, r: kept.append(label))
        assert killed, "no worker was busy when the first channel finished"
        story = client.story(killed[0][1][0])
        assert len([s for s in story if s[0] == "scheduler" and s[3] == "processing"]) >= 2, story
    finally:
        client.close()
        cl.close()
    assert list(there) == ["ax", "az", "gx"] and sorted(kept) == ["ax", "az", "gx"]
    from torchtea.render.strictjson import dumps

    for a in here:
        assert dumps(_without_times(there[a].as_dict())) == dumps(_without_times(here[a].as_dict())), a
    assert any(line.startswith("  gx: ") and "fitting" in line for line in lines), lines[:5]


@pytest.mark.slow
def test_ctrl_c_on_local_workers_keeps_the_channels_without_dasks_warnings(tmp_path):
    """A real SIGINT to `torchtea check --workers 2` and its worker processes (as Ctrl-C in a terminal) once a
    channel is kept: exit 130, the channels kept named, the stages streamed from the workers shown, and nothing of
    Dask's (cancelled tasks, tracebacks) on stderr."""
    from .procs import sigint_as_in_a_terminal

    path = _recording(tmp_path, n=3000)
    out = tmp_path / "ck"
    proc = subprocess.Popen([sys.executable, "-m", "torchtea.cli", "check", str(path), "--columns",
                             "acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z", "--units", "g,g,g,rad/s,rad/s,rad/s", "--auto",
                             "--no-plots", "--workers", "2", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: (sigint_as_in_a_terminal(), os.setpgrp()))
    assert _wait_for_parts(out / "partial", proc, 1, timeout=300) >= 1, proc.poll()
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    if proc.returncode == 0:
        pytest.skip("the check finished before SIGINT reached it")
    assert proc.returncode == 130, err
    assert "interrupted: " in err and "kept in" in err
    assert "  ax: fitting" in err or "  ay: fitting" in err
    for noise in ("WARNING", "Traceback", "CancelledError", "distributed."):
        assert noise not in err, err


@pytest.mark.slow
def test_a_channel_that_keeps_killing_workers_is_one_error_naming_it(tmp_path):
    """With Dask allowed no failure, a worker killed mid-channel makes that channel's task a KilledWorker: the run
    stops with TaskFailed naming the channel, the channels finished already handed to `keep` and in `done`."""
    import dask

    from torchtea.core.tasks import TaskFailed, run_on_cluster
    from torchtea.studies.cluster import local_cluster

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cl, client = local_cluster(2, threads_per_worker=1)
    kept = []
    try:
        pids = client.run(os.getpid)
        calls = [("quick", (0.1,), {}), ("slow", (60.0,), {})]

        def kill_the_slow_one(done, total):
            busy = [addr for addr, keys in client.processing().items() if keys]
            for addr in busy:
                os.kill(pids[addr], signal.SIGKILL)

        with pytest.raises(TaskFailed, match="task of slow: its task killed 1 worker") as e:
            run_on_cluster(client, time.sleep, calls, name="task", progress=kill_the_slow_one,
                           on_result=lambda label, r: kept.append(label))
    finally:
        client.close()
        cl.close()
    assert kept == ["quick"] and list(e.value.done) == ["quick"]
