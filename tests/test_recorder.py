"""The recorder against the fake device: pyserial ``loop://`` per fault, and real ptys end to end."""
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import serial

from torchtea.sensors.fakeimu import FakeIMU, parse_fault
from torchtea.sensors.io import STANDARD_GRAVITY, read_recording
from torchtea.sensors.protocol import U32
from torchtea.sensors.recorder import EXIT_DISCONNECTED, Recorder

from .procs import sigint_as_in_a_terminal

ROOT = Path(__file__).resolve().parents[1]
N = 200
COUNTS = np.stack([np.arange(N) % 97 - 48, -np.arange(N) % 89, 4096 + np.arange(N) % 13,
                   np.arange(N) % 5, np.zeros(N), -np.arange(N) % 7, np.full(N, 1500)], axis=1).astype(np.int64)


def record_loop(tmp_path, *faults, counter0=0):
    """Play the fake device into loop:// (as fast as the port takes it), then close the port."""
    ser = serial.serial_for_url("loop://", timeout=0.05)
    dev = FakeIMU(COUNTS, faults=tuple(parse_fault(f) for f in faults), counter0=counter0)

    def play():
        dev.run(ser.write, N, realtime=False)
        while ser.in_waiting:
            time.sleep(0.01)
        time.sleep(0.2)
        ser.close()

    th = threading.Thread(target=play)
    th.start()
    logs = []
    out = tmp_path / "rec.csv"
    rec = Recorder("loop://", out, open_port=lambda: ser, request_header=None, log=logs.append)
    code = rec.run()
    th.join()
    side = json.loads(out.with_suffix(".json").read_text())
    body = [ln for ln in out.read_text().splitlines()[3:] if not ln.startswith("#")]
    rows = np.array([[float(v) for v in ln.split(",")] for ln in body])
    return code, side, rows, logs


def _check_consistent(side, rows):
    assert side["rows"] == len(rows) == side["good_samples"] + side["missing_samples"]
    for seg in np.unique(rows[:, 0]):
        c = rows[rows[:, 0] == seg, 1]
        assert np.all(np.diff(c) == 1), "one row per counter value"


def test_clean_stream_is_recorded_exactly(tmp_path):
    code, side, rows, logs = record_loop(tmp_path)
    assert code == EXIT_DISCONNECTED and side["status"].startswith("disconnected")  # closing the port ends it
    assert (side["good_samples"], side["bad_lines"], side["missing_samples"]) == (N, 0, 0)
    assert side["headers"][0]["sensor"] == "MPU-9250" and side["segments"] == 1
    _check_consistent(side, rows)
    rec = read_recording(tmp_path / "rec.csv")
    np.testing.assert_array_equal(rec.accel_counts, COUNTS[:, :3])  # counts come back exactly
    np.testing.assert_allclose(rows[:, 3:6], COUNTS[:, :3] / 4096 * STANDARD_GRAVITY, rtol=1e-15)
    np.testing.assert_allclose(rows[:, 6:9], COUNTS[:, 3:6] / 131 * math.pi / 180, rtol=1e-15)
    np.testing.assert_allclose(rows[:, 9], 1500 / 333.87 + 21, rtol=1e-15)
    np.testing.assert_allclose(rows[:, 2], np.arange(N) * 0.01, atol=1e-12)
    assert rec.rate_hz == 100 and any("rec.csv" in m for m in logs)


@pytest.mark.parametrize("fault, reason", [("corrupt@50", "checksum"), ("checksum@50", "checksum"),
                                           ("fields@50", "fields"), ("range@50", "range"),
                                           ("nonnumeric@50", "not_integer")])
def test_a_bad_line_becomes_one_missing_row(tmp_path, fault, reason):
    _, side, rows, _ = record_loop(tmp_path, fault)
    assert side["bad_by_reason"] == {reason: 1} and side["bad_lines"] == 1
    assert (side["good_samples"], side["missing_samples"], len(rows)) == (N - 1, 1, N)
    assert np.isnan(rows[50, 2:]).all() and rows[50, 1] == 50 and not np.isnan(rows[[49, 51], 2:]).any()
    _check_consistent(side, rows)


def test_garbage_is_one_bad_line_and_loses_no_sample(tmp_path):
    _, side, rows, _ = record_loop(tmp_path, "garbage@50:40")
    assert side["bad_lines"] == 1 and side["good_samples"] == N and side["missing_samples"] == 0
    _check_consistent(side, rows)


def test_dropped_samples_become_nan_rows_in_place(tmp_path):
    _, side, rows, _ = record_loop(tmp_path, "drop@50:7")
    assert (side["good_samples"], side["missing_samples"], side["bad_lines"]) == (N - 7, 7, 0)
    assert np.isnan(rows[50:57, 3]).all() and not np.isnan(rows[[49, 57], 3]).any()
    np.testing.assert_allclose(rows[57, 3], COUNTS[57, 0] / 4096 * STANDARD_GRAVITY)  # not shifted
    _check_consistent(side, rows)


def test_reset_starts_a_new_segment(tmp_path):
    _, side, rows, _ = record_loop(tmp_path, "reset@120")
    assert side["segments"] == 2 and side["good_samples"] == N and side["missing_samples"] == 0
    assert (rows[:, 0] == 0).sum() == 120 and (rows[:, 0] == 1).sum() == 80
    assert rows[120, 1] == 0 and rows[120, 2] == 0.0  # counter and clock restart
    _check_consistent(side, rows)
    assert read_recording(tmp_path / "rec.csv").accel_counts.shape == (120, 3)  # the longest segment
    seg1 = read_recording(tmp_path / "rec.csv", segment=1)
    np.testing.assert_array_equal(seg1.accel_counts, COUNTS[120:, :3])


def test_counter_and_clock_wrap(tmp_path):
    _, side, rows, _ = record_loop(tmp_path, counter0=U32 - 100)
    assert side["good_samples"] == N and side["missing_samples"] == 0 and side["segments"] == 1
    assert rows[0, 1] == U32 - 100 and rows[-1, 1] == U32 + 99
    _check_consistent(side, rows)


# --------------------------------------------------------------------------- real ptys, real processes

def _fake(*args):
    proc = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "fake_imu.py"), *args], stdout=subprocess.PIPE,
                            text=True)
    line = proc.stdout.readline().split()
    assert line[0] == "PORT", line
    return proc, line[1]


def _torchtea(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "torchtea.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=sigint_as_in_a_terminal, **kw)


def _stop(proc):
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=10)


@pytest.mark.slow
def test_end_to_end_pty_record_then_identify(tmp_path):
    # the fake waits for the recorder's header request, and the recorder stops after a number of samples:
    # what is recorded does not depend on how fast either process starts or runs
    fake, port = _fake("--seconds", "60", "--rate", "100", "--wait-for-host")
    try:
        rec = _torchtea("record", "--port", port, "--samples", "400", "--out", str(tmp_path / "rec.csv"))
        out, err = rec.communicate(timeout=120)
        assert rec.returncode == 0, err
    finally:
        _stop(fake)
    side = json.loads((tmp_path / "rec.json").read_text())
    assert side["status"] == "finished" and side["bad_lines"] == 0 and side["missing_samples"] == 0
    assert side["good_samples"] == side["rows"] == 400
    r = read_recording(tmp_path / "rec.csv")
    assert r.metadata["first_counter"] == 0 and len(r.accel_counts) == 400  # from the very first sample on
    assert "rec.csv" in err and "400 samples" in err
    ident = _torchtea("identify", str(tmp_path / "rec.csv"), "--samples", "all", "--memory", "soe", "--json",
                      "--out", str(tmp_path / "ident"))
    out, err = ident.communicate(timeout=300)
    assert ident.returncode == 0, err
    summary = json.loads(out)
    assert summary["samples"] == 400 and set(summary["axes"]) == {"ax", "ay", "az"}
    assert all(np.isfinite(a["alpha"]) and not a["diverged"] for a in summary["axes"].values())
    # the device clock t_s was checked against the header's rate: 10 ms steps exactly
    assert summary["timing"]["column"] == "t_s" and summary["timing"]["irregular_fraction"] == 0.0
    assert abs(summary["timing"]["rate_mismatch"]) < 1e-9 and summary["timing"]["warnings"] == []
    assert (tmp_path / "ident" / "report.md").exists()


@pytest.mark.slow
def test_pulled_cable_finishes_the_file_and_exits_nonzero(tmp_path):
    fake, port = _fake("--seconds", "30", "--fault", "disconnect@400", "--wait-for-host")
    try:
        rec = _torchtea("record", "--port", port, "--out", str(tmp_path / "rec.csv"))
        out, err = rec.communicate(timeout=120)
    finally:
        _stop(fake)
    assert rec.returncode == EXIT_DISCONNECTED, err
    assert f"lost {port}" in err
    side = json.loads((tmp_path / "rec.json").read_text())
    assert side["status"].startswith("disconnected") and side["disconnects"] == 1
    r = read_recording(tmp_path / "rec.csv")
    # everything the device sent, from its first sample up to the last one before the cable went
    assert r.metadata["first_counter"] == 0 and len(r.accel_counts) == 400
    assert side["missing_samples"] == 0 and side["bad_lines"] == 0 and side["good_samples"] == 400


@pytest.mark.slow
def test_reconnect_waits_for_the_port_and_carries_on(tmp_path):
    link = str(tmp_path / "imu0")
    fake, _ = _fake("--seconds", "60", "--link", link, "--fault", "disconnect@300", "--reconnect-after", "1.0",
                    "--wait-for-host")
    try:
        rec = _torchtea("record", "--port", link, "--reconnect", "--samples", "450", "--out", str(tmp_path / "rec.csv"))
        out, err = rec.communicate(timeout=120)
    finally:
        _stop(fake)
    assert rec.returncode == 0, err
    assert "is back" in err
    side = json.loads((tmp_path / "rec.json").read_text())
    assert side["disconnects"] == 1 and side["status"] == "finished" and side["segments"] == 1
    r = read_recording(tmp_path / "rec.csv")
    counters = r.metadata["first_counter"] + np.arange(len(r.accel_counts))
    assert counters[0] == 0 and counters[-1] == 449  # the device paused; the counter ran on across the outage
    # samples the device sent before the port was reopened are gone (pyserial flushes input on open);
    # they are NaN rows in one block right at the outage, nowhere else, and counted as missing
    miss = side["missing_samples"]
    assert side["bad_lines"] == 0 and side["good_samples"] + miss == 450
    np.testing.assert_array_equal(counters[np.isnan(r.accel_counts[:, 0])], np.arange(300, 300 + miss))


@pytest.mark.slow
def test_recording_survives_the_recorder_being_killed(tmp_path):
    fake, port = _fake("--seconds", "30")
    try:
        rec = _torchtea("record", "--port", port, "--out", str(tmp_path / "rec.csv"))
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # wait until samples are on disk
            time.sleep(0.5)
            p = tmp_path / "rec.csv"
            if p.exists() and p.read_text().count("\n") > 150:
                break
        os.kill(rec.pid, signal.SIGKILL)
        rec.wait(timeout=10)
    finally:
        _stop(fake)
    r = read_recording(tmp_path / "rec.csv")
    assert len(r.accel_counts) > 140 and not np.isnan(r.accel_counts).any()
    side = json.loads((tmp_path / "rec.json").read_text())
    assert side["status"] == "recording"  # the sidecar as last rewritten, still valid JSON
    text = (tmp_path / "rec.csv").read_text()
    assert text.endswith("\n")  # whole lines only


@pytest.mark.slow
def test_live_mode_estimates_every_row_and_logs_to_tensorboard(tmp_path):
    """The whole chain on a pty. Whether the estimator keeps up with a rate is a property of the machine:
    measured in experiments/live, not asserted here."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    fake, port = _fake("--seconds", "60", "--rate", "100", "--wait-for-host")
    try:
        rec = _torchtea("record", "--port", port, "--samples", "500", "--out", str(tmp_path / "rec.csv"), "--live",
                        "--warmup", "1", "--json", "--logdir", str(tmp_path / "tb"))
        out, err = rec.communicate(timeout=240)
    finally:
        _stop(fake)
    assert rec.returncode == 0, err
    live = json.loads(out.strip().splitlines()[-1])
    side = json.loads((tmp_path / "rec.json").read_text())
    assert side["rows"] == 500 and live["steps"] == 500  # every row estimated
    assert isinstance(live["lag_at_close_samples"], int)  # reported; whether it stays small: experiments/live
    assert set(live["axes"]) == {"x", "y", "z"} and not any(a["diverged"] for a in live["axes"].values())
    ea = EventAccumulator(str(tmp_path / "tb"), size_guidance={"scalars": 0})
    ea.Reload()
    ev = ea.Scalars("order/x")
    assert ev[-1].step == live["steps"] - 1 and ev[-1].value == pytest.approx(live["axes"]["x"]["alpha"], rel=1e-6)
    for tag in ("param/z", "innovation/y", "innovation_rms/x", "live/lag_samples"):
        assert tag in ea.Tags()["scalars"]


def test_live_estimator_logs_once_per_second_of_its_clock(tmp_path):
    """The logging cadence, on a clock that advances with the samples (100 Hz): one write per second of data,
    whatever the machine's speed; then the final estimate at close."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from torchtea.sensors.fakeimu import synthetic_counts
    from torchtea.sensors.live import LiveEstimator

    n = 650
    counts = synthetic_counts(n, rate_hz=100.0, seed=3)
    ser = serial.serial_for_url("loop://", timeout=0.05)
    dev = FakeIMU(counts, rate_hz=100.0)
    holder = []  # the clock counts samples: "one second" is 100 of them
    live = LiveEstimator(tmp_path / "tb", warmup_s=0.5, log_every_s=100, clock=lambda: holder[0].steps if holder else 0)
    holder.append(live)

    # the device writes all n samples and stops; the recorder closes the port once it has them
    th = threading.Thread(target=dev.run, args=(ser.write, n), kwargs={"realtime": False})
    th.start()

    rec = Recorder("loop://", tmp_path / "rec.csv", open_port=lambda: ser, request_header=None, log=lambda m: None,
                   live=live, samples=n)
    rec.run()
    th.join()
    assert live.summary["steps"] == n
    ea = EventAccumulator(str(tmp_path / "tb"), size_guidance={"scalars": 0})
    ea.Reload()
    steps = [e.step for e in ea.Scalars("order/x")]
    # a write each time the clock passes a whole second (every 100 samples), and the last step at close
    assert steps == [99, 199, 299, 399, 499, 599, n - 1], steps


@pytest.mark.slow
def test_scripts_identify_imu_and_record_imu(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "identify_imu.py"), "--seconds", "4", "--out",
                        str(tmp_path / "id")], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "x: α̂ =" in r.stdout and (tmp_path / "id" / "report.md").exists()
    assert "GL history `soe" in (tmp_path / "id" / "report.md").read_text()
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "record_imu.py"), "--port", "/dev/nonexistent-tty",
                        "--out", str(tmp_path / "r.csv")], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "cannot open /dev/nonexistent-tty" in r.stderr and r.stderr.count("\n") == 1


@pytest.mark.slow
def test_ctrl_c_finishes_the_file_and_the_sidecar(tmp_path):
    fake, port = _fake("--seconds", "30")
    try:
        rec = _torchtea("record", "--port", port, "--out", str(tmp_path / "rec.csv"))
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            time.sleep(0.5)
            p = tmp_path / "rec.csv"
            if p.exists() and p.read_text().count("\n") > 100:
                break
        rec.send_signal(signal.SIGINT)
        out, err = rec.communicate(timeout=20)
    finally:
        _stop(fake)
    assert rec.returncode == 0, err
    side = json.loads((tmp_path / "rec.json").read_text())
    assert side["status"] == "stopped (Ctrl-C)" and "finished_utc" in side
    r = read_recording(tmp_path / "rec.csv")
    assert len(r.accel_counts) == side["rows"] == side["good_samples"] and side["bad_lines"] == 0
