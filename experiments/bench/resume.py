"""What a stop costs a `check` now that each channel is kept as it finishes: the check of a shared six-axis recording
run whole, and the same command stopped by SIGTERM once k channels are kept and then run again — each a child
process as users run it. Writes resume.json beside this file: the times, the channels kept, and whether the resumed
check.json equals the whole run's (timings aside).

    python experiments/bench/resume.py [--recording PATH] [--stops 2 4]
"""
from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SHARED = HERE.parents[2] / "shared" / "data" / "mpu6050_sensor_fusion_temperature" / "unmoved_x_forward.csv"
FLAGS = ["--units", "g,g,g,deg/s,deg/s,deg/s", "--rate", "100", "--temperature", "temp", "--no-plots"]
TIMINGS = ("seconds", "seconds_this_step", "timings", "command", "out", "figures")


def _without_times(x):
    if isinstance(x, dict):
        return {k: _without_times(v) for k, v in x.items() if k not in TIMINGS}
    if isinstance(x, list):
        return [_without_times(v) for v in x]
    return x


def _command(recording: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "torchtea.cli", "check", str(recording), *FLAGS, "--out", str(out)]


def _run(cmd) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _stopped(cmd, partial: Path, k: int) -> tuple[float, int, list[str]]:
    """The command stopped by SIGTERM once ``k`` channels are kept: its time, exit code and the channels kept."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    while proc.poll() is None and len(list(partial.glob("*.pickle"))) < k:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    proc.communicate()
    return time.perf_counter() - t0, proc.returncode, sorted(f.stem for f in partial.glob("*.pickle"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recording", type=Path, default=SHARED)
    ap.add_argument("--stops", type=int, nargs="+", default=[2, 4])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        whole_s = _run(_command(args.recording, tmp / "whole"))
        whole = json.loads((tmp / "whole" / "check.json").read_text())
        rows = []
        for k in args.stops:
            out = tmp / f"stop{k}"
            cmd = _command(args.recording, out)
            stop_s, code, kept = _stopped(cmd, out / "partial", k)
            resume_s = _run(cmd)
            again = json.loads((out / "check.json").read_text())
            rows.append({"stopped_after_channels": k, "exit_code": code, "kept": kept, "stopped_run_s": stop_s,
                         "resumed_run_s": resume_s, "same_check_json": _without_times(again["axes"])
                         == _without_times(whole["axes"])})
    doc = {"recording": args.recording.name, "flags": FLAGS, "whole_run_s": whole_s, "stops": rows,
           "meaning": "wall seconds of each child process: the whole check, a run stopped by SIGTERM once k channels "
                      "were kept, and the same command run again (it checks only the channels not kept)"}
    (HERE / "resume.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(f"whole: {whole_s:.1f} s")
    for r in rows:
        print(f"stopped after {len(r['kept'])} channels (exit {r['exit_code']}): {r['stopped_run_s']:.1f} s, resumed "
              f"{r['resumed_run_s']:.1f} s, same check.json: {r['same_check_json']}")


if __name__ == "__main__":
    main()
