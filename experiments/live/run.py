"""Highest sample rate `torchtea record --live` sustains, measured through the whole pipeline.

For each rate: the fake device (scripts/fake_imu.py) streams synthetic fractional noise on a pty;
`torchtea record --live --duration D --json` records it and runs the TEA (3 axes, soe memory) while
samples arrive. The live estimator keeps up when the samples still waiting at the end of the recording
(`lag_at_close_samples`) stay under half a second's worth. Also measured: the estimator alone, fed
as fast as it can take samples (no device, no recorder).

    python experiments/live/run.py                 # rates 100 200 300 400 600, 20 s each (~3 min)
    python experiments/live/run.py --rates 100 150 --duration 10

Prints a table; writes experiments/live/results.json. The device, the recorder and the estimator share
this machine's cores (on a bench the device is a separate board).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from common import machine, write_json  # noqa: E402

ROOT = HERE.parents[1]


def offline(n: int = 3000) -> dict:
    """The estimator alone: n samples queued at once, time to drain them."""
    from torchtea.sensors.fakeimu import FakeIMU, synthetic_counts
    from torchtea.sensors.live import LiveEstimator
    from torchtea.sensors.protocol import Assembler, Parser

    dev = FakeIMU(synthetic_counts(n))
    p, a = Parser(), Assembler()
    rows = a.add(p.feed(b"".join(d for _, d in dev.chunks(n))))
    with tempfile.TemporaryDirectory() as tmp:
        live = LiveEstimator(Path(tmp) / "tb", warmup_s=2.0)
        t0 = time.perf_counter()
        for i in range(0, len(rows), 100):
            live.put(rows[i:i + 100], a.headers)
        s = live.close()
        dt = time.perf_counter() - t0
    return {"samples": n, "seconds": round(dt, 3), "samples_per_s": round(n / dt, 1), "steps": s["steps"]}


def through_pty(rate: float, duration: float) -> dict:
    fake = subprocess.Popen([sys.executable, str(ROOT / "scripts" / "fake_imu.py"), "--rate", str(rate),
                             "--seconds", str(duration + 15)], stdout=subprocess.PIPE, text=True)
    try:
        port = fake.stdout.readline().split()[1]
        with tempfile.TemporaryDirectory() as tmp:
            r = subprocess.run([sys.executable, "-m", "torchtea.cli", "record", "--port", port, "--duration",
                                str(duration), "--out", str(Path(tmp) / "rec.csv"), "--live", "--json"],
                               capture_output=True, text=True, timeout=duration + 600)
            side = json.loads((Path(tmp) / "rec.json").read_text())
    finally:
        fake.kill()
        fake.wait()
    live = json.loads(r.stdout.strip().splitlines()[-1])
    lag = live["lag_at_close_samples"]
    return {"rate_hz": rate, "duration_s": duration, "good_samples": side["good_samples"],
            "missing_samples": side["missing_samples"], "bad_lines": side["bad_lines"], "steps": live["steps"],
            "lag_at_close_samples": lag, "lag_at_close_s": round(lag / rate, 3), "max_lag_samples": live["max_lag_samples"],
            "keeps_up": lag <= rate / 2, "exit": r.returncode}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rates", type=float, nargs="+", default=[100, 200, 300, 400, 600])
    ap.add_argument("--duration", type=float, default=20.0)
    args = ap.parse_args()
    off = offline()
    print(f"estimator alone: {off['samples']} samples in {off['seconds']} s = {off['samples_per_s']} samples/s")
    rows = []
    print(f"{'rate [Hz]':>9} {'samples':>8} {'missing':>8} {'waiting at end':>15} {'max waiting':>12} {'keeps up':>9}")
    for rate in args.rates:
        r = through_pty(rate, args.duration)
        rows.append(r)
        print(f"{rate:9g} {r['good_samples']:8d} {r['missing_samples']:8d} {r['lag_at_close_samples']:8d} "
              f"({r['lag_at_close_s']:4.1f} s) {r['max_lag_samples']:12d} {'yes' if r['keeps_up'] else 'NO':>9}")
    best = max((r["rate_hz"] for r in rows if r["keeps_up"]), default=None)
    print(f"highest sustained rate measured: {best} Hz")
    write_json(HERE / "results.json", {"machine": machine(), "offline": off, "runs": rows,
                                       "highest_sustained_hz": best})


if __name__ == "__main__":
    main()
