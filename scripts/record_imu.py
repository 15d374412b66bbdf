#!/usr/bin/env python3
"""Record an IMU running scripts/firmware/torchtea_imu (protocol v1) — the same as `torchtea record`.

    python scripts/record_imu.py --port /dev/ttyACM0 --duration 600 --out rec.csv [--live] [--reconnect]

Writes rec.csv (one row per sample, physical units, NaN rows where samples were lost) and rec.json
(header metadata, counts of good samples, bad lines, missing samples). Ctrl-C stops and finishes the
file. See docs/recording.md.
"""
import sys

from torchtea.cli import main

if __name__ == "__main__":
    sys.exit(main(["record", *sys.argv[1:]]))
