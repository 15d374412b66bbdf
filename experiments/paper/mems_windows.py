"""Repeatability of the MEMS identification on real data: the paper's §5 procedure (30 s, 100 Hz, mean removed
per window and axis, paper's settings with R = the window's variance) on every non-overlapping 30 s window of
the bundled recordings, all windows × axes as one batch.

    python experiments/paper/mems_windows.py [--window 3000]

A static sensor's noise model should not change from one half-minute to the next, so the spread of α̂ and ŵ
across windows is a direct measure of how far one 30 s estimate can be trusted. Writes mems_windows.json.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from experiments.common import machine, write_json  # noqa: E402
from torchtea import Structure, make_params, run_tea, stack_params  # noqa: E402
from torchtea.identification import axis_configs  # noqa: E402
from torchtea.reports.identify import AXES  # noqa: E402
from torchtea.sensors.io import bundled_recording, read_recording  # noqa: E402

HERE = Path(__file__).resolve().parent


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--window", type=int, default=3000)
    ap.add_argument("--out", default=str(HERE / "mems_windows.json"))
    args = ap.parse_args()
    report = {"machine": machine(), "window_samples": args.window, "recordings": {}}
    for which in ("main", "second"):
        rec = read_recording(bundled_recording(which))
        acc = rec.accel_ms2()
        nw = acc.shape[0] // args.window
        win = acc[: nw * args.window].reshape(nw, args.window, 3)
        win = win - win.mean(axis=1, keepdims=True)
        y = torch.as_tensor(win.transpose(0, 2, 1).copy()).unsqueeze(-1)  # (nw, 3, N, 1)
        params = stack_params([
            stack_params([make_params(c, Structure()) for c in axis_configs(y[i])]) for i in range(nw)])
        t0 = time.perf_counter()
        res = run_tea(y, h=rec.h, params=params)
        el = time.perf_counter() - t0
        third = slice(args.window - args.window // 3, args.window)
        a = res.alpha[..., third, 0].mean(-1).numpy()  # (nw, 3)
        w = res.w[..., third, 0].mean(-1).numpy()
        entry = {"file": rec.path.name, "windows": nw, "seconds": round(el, 1),
                 "diverged": int(res.diverged.sum()), "axes": {}}
        for j, axis in enumerate(AXES):
            entry["axes"][axis] = {
                "alpha_per_window": [round(float(v), 4) for v in a[:, j]],
                "param_per_window": [round(float(v), 4) for v in w[:, j]],
                "alpha_mean": float(a[:, j].mean()), "alpha_sd": float(a[:, j].std(ddof=1)),
                "alpha_min": float(a[:, j].min()), "alpha_max": float(a[:, j].max()),
                "param_mean": float(w[:, j].mean()), "param_sd": float(w[:, j].std(ddof=1)),
                "param_min": float(w[:, j].min()), "param_max": float(w[:, j].max()),
            }
        report["recordings"][which] = entry
        print(f"{rec.path.name}: {nw} windows of {args.window} samples × 3 axes in one batch, {el:.1f} s, "
              f"{entry['diverged']} diverged")
        print(f"{'axis':>4} {'α̂ mean':>7} {'sd':>6} {'min':>6} {'max':>6}   {'ŵ mean':>7} {'sd':>6} {'min':>7} {'max':>7}")
        for axis, s in entry["axes"].items():
            print(f"{axis:>4} {s['alpha_mean']:7.3f} {s['alpha_sd']:6.3f} {s['alpha_min']:6.3f} {s['alpha_max']:6.3f}"
                  f"   {s['param_mean']:7.3f} {s['param_sd']:6.3f} {s['param_min']:7.3f} {s['param_max']:7.3f}")
    write_json(Path(args.out), report)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
