"""Channels in parallel (issue 44, item 4): a recording's checks and fits as tasks of a real local Dask cluster give
exactly the results of the run in this process, on the library's calls and on the command line; the engines' thread
settings are restored after a check."""
import json
import math

import numpy as np
import pytest
import torch

from torchtea.cli import main
from torchtea.noise import default_values, parse_model, simulate_model, temperature_profile

distributed = pytest.importorskip("distributed")

H = 0.01
G0 = 9.80665


def _recording(tmp_path, n=3000):
    """A six-axis CSV: fractional+white on the accelerometer, a random walk added to gx and a line to gy."""
    gen = torch.Generator().manual_seed(4)
    T = temperature_profile(n, H, generator=gen).numpy()
    m = parse_model("fractional+white")
    y = simulate_model(m, default_values(m, H), n_steps=n, h=H, realisations=6, generator=gen)[0].numpy().T
    t = np.arange(n) * H
    y[:, 3] += np.cumsum(np.random.default_rng(1).normal(0, 3e-3, n))
    y[:, 4] += 0.02 * np.sin(2 * math.pi * 3.37 * t)
    cols = [t, y[:, 0] / G0, y[:, 1] / G0, (y[:, 2] + G0) / G0, y[:, 3] * 0.05, y[:, 4] * 0.05, y[:, 5] * 0.05, T]
    path = tmp_path / "six.csv"
    rows = "\n".join(",".join(repr(float(v)) for v in row) for row in np.column_stack(cols))
    path.write_text("t,acc_x,acc_y,acc_z,gyro_x,gyro_y,gyro_z,temp\n" + rows + "\n")
    return path


def _without_times(x):
    if isinstance(x, dict):
        return {k: _without_times(v) for k, v in x.items() if k not in ("seconds", "seconds_this_step", "timings",
                                                                         "command", "out", "figures")}
    if isinstance(x, list):
        return [_without_times(v) for v in x]
    return x


@pytest.mark.slow
def test_check_on_a_cluster_is_the_check_in_this_process(cluster, tmp_path):
    """``check --auto`` of four channels with ``--scheduler`` (the module's cluster) writes the check.json of the run
    in this process, number for number (the timings aside): each channel's arithmetic is its own, torch and BLAS run
    on one thread in both, and the kernels' parallel loops run whole parameter sets per thread."""
    path = _recording(tmp_path)
    args = ("check", path, "--columns", "acc_x,acc_z,gyro_x,gyro_y", "--units", "g,g,rad/s,rad/s", "--temperature",
            "temp", "--auto", "--no-plots", "--no-intervals")
    assert main([str(a) for a in args + ("--out", tmp_path / "here")]) == 0
    address = cluster.scheduler.address
    assert main([str(a) for a in args + ("--out", tmp_path / "there", "--scheduler", address)]) == 0
    here = json.loads((tmp_path / "here" / "check.json").read_text())
    there = json.loads((tmp_path / "there" / "check.json").read_text())
    assert list(here["axes"]) == list(there["axes"]) == ["ax", "az", "gx", "gy"]
    assert _without_times(here["axes"]) == _without_times(there["axes"])
    models = {a: x["model"] for a, x in here["axes"].items()}
    assert "random-walk" in models["gx"] and "sinusoid" in models["gy"], models


@pytest.mark.slow
def test_fit_on_local_workers_is_the_fit_in_this_process(tmp_path):
    """``fit --workers 2`` starts a local cluster, fits each channel there and writes the document of the run here."""
    path = _recording(tmp_path, n=2000)
    args = ("fit", path, "--columns", "acc_x,gyro_x", "--units", "g,rad/s", "--bootstrap", 0)
    assert main([str(a) for a in args + ("--out", tmp_path / "here.json")]) == 0
    assert main([str(a) for a in args + ("--out", tmp_path / "there.json", "--workers", 2)]) == 0
    here = json.loads((tmp_path / "here.json").read_text())
    there = json.loads((tmp_path / "there.json").read_text())
    assert _without_times(here["axes"]) == _without_times(there["axes"])


def test_cluster_flags_are_checked_before_any_work(tmp_path, capsys):
    path = _recording(tmp_path, n=1500)
    assert main(["check", str(path), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert "give one" in capsys.readouterr().err
    assert main(["fit", str(path), "--threads-per-worker", "2"]) == 2
    assert "--threads-per-worker applies to the local cluster" in capsys.readouterr().err
    assert main(["export", str(path), "--format", "kalibr", "--workers", "0"]) == 2
    assert "at least 1" in capsys.readouterr().err


def test_engine_threads_are_restored():
    import numba

    from torchtea.core.threads import engine_threads

    before = torch.get_num_threads(), numba.get_num_threads()
    with engine_threads(1) as n:
        assert n == 1 and torch.get_num_threads() == 1 and numba.get_num_threads() == 1
    assert (torch.get_num_threads(), numba.get_num_threads()) == before


def test_large_channels_go_to_the_workers_as_data_not_in_the_graph(cluster):
    """A channel of hours is megabytes: run_on_cluster scatters large arguments (and keyword arguments) to the
    workers before submitting, so Dask does not warn of a large graph, and each task gets its own data back."""
    import warnings

    from torchtea.core.tasks import SCATTER_BYTES, run_on_cluster

    def _digests(y, inputs=None):  # (defined here: pickled by value for the workers)
        import hashlib
        return hashlib.sha1(y.tobytes()).hexdigest(), hashlib.sha1(inputs["temperature"].tobytes()).hexdigest()

    assert SCATTER_BYTES < 12_000_000  # (Dask warns of a graph above 10 MB: a channel of 25 min at 1 kHz)
    big = [np.random.default_rng(k).normal(size=1_500_000) for k in range(3)]
    calls = [(f"c{k}", (y,), {"inputs": {"temperature": y[::-1].copy()}}) for k, y in enumerate(big)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Dask's "Sending large graph" is a UserWarning
        out = run_on_cluster(cluster, _digests, calls, name="scatter")
    assert list(out) == ["c0", "c1", "c2"]
    for k, y in enumerate(big):
        assert out[f"c{k}"] == _digests(y, {"temperature": y[::-1].copy()})
