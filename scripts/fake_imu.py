#!/usr/bin/env python3
"""A fake protocol-v1 IMU on a pseudo-terminal, for trying `torchtea record` without hardware.

    python scripts/fake_imu.py --seconds 60 &            # prints: PORT /dev/pts/7
    torchtea record --port /dev/pts/7 --duration 30 --out rec.csv

Sources: ``synth`` (fractional noise, default) or ``replay`` / ``replay:PATH`` (the bundled recording or
another). Faults (repeatable): --fault drop@500:20 --fault corrupt@100 --fault reset@2000 … (see
torchtea.sensors.fakeimu). With --link PATH the port is also reachable as a stable symlink; after a
``disconnect`` fault and --reconnect-after S, a new pty appears behind the same link.
"""
from __future__ import annotations

import argparse
import fcntl
import os
import select
import struct
import sys
import termios
import time

from torchtea.sensors.fakeimu import FakeIMU, open_pty, parse_fault, replay_counts, synthetic_counts


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--source", default="synth", help="synth | replay | replay:PATH")
    p.add_argument("--rate", type=float, help="samples per second (default 100, or the replayed file's)")
    p.add_argument("--seconds", type=float, default=60.0, help="how long to run (synth data are generated up front)")
    p.add_argument("--fault", action="append", default=[], help="KIND@K[:COUNT], repeatable")
    p.add_argument("--link", help="also expose the port as this symlink (kept across reconnects)")
    p.add_argument("--reconnect-after", type=float, help="after a disconnect fault, come back after S seconds")
    p.add_argument("--counter0", type=int, default=0, help="first counter value (test wrapping with 4294967000)")
    p.add_argument("--t0-us", type=int, default=0, help="first device time [µs]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--wait-for-host", action="store_true",
                   help="send nothing until the host asks for the header (H), so that no sample is sent before "
                        "the host has the port open (tests that must not depend on how fast the host starts)")
    p.add_argument("--wait-timeout", type=float, default=120.0,
                   help="give up waiting for the host (to ask, or to read what was sent) after S seconds")
    args = p.parse_args(argv)

    faults = tuple(parse_fault(f) for f in args.fault)
    if args.source == "synth":
        rate = args.rate or 100.0
        counts = synthetic_counts(max(2, min(int(rate * args.seconds), 200_000)), rate_hz=rate, seed=args.seed)
        lsb = 4096
    elif args.source.startswith("replay"):
        counts, file_rate, lsb = replay_counts(args.source.partition(":")[2] or None)
        rate = args.rate or file_rate
    else:
        p.error(f"unknown source {args.source!r}")
    replay = args.source.startswith("replay")  # the bundled recordings are an MPU-6050's
    meta = {"sensor": "MPU-6050" if replay else "MPU-9250", "rate_hz": f"{rate:g}", "accel_lsb_per_g": f"{lsb:g}",
            "gyro_lsb_per_dps": "131", "temp_lsb_per_c": "340" if replay else "333.87",
            "temp_offset_c": "36.53" if replay else "21", "dlpf_hz": "44", "firmware": "fake_imu.py"}
    dev = FakeIMU(counts, rate_hz=rate, meta=meta, faults=faults, counter0=args.counter0, t0_us=args.t0_us,
                  seed=args.seed)
    state = {}

    def expose():
        master, slave, path = open_pty()
        state.update(master=master, slave=slave)
        if args.link:
            tmp = args.link + ".tmp"
            if os.path.lexists(tmp):
                os.remove(tmp)
            os.symlink(path, tmp)
            os.replace(tmp, args.link)
        print(f"PORT {path}", flush=True)

    def write(data: bytes):
        view = memoryview(data)
        while view:
            try:
                n = os.write(state["master"], view)
            except BlockingIOError:
                time.sleep(0.001)
                continue
            view = view[n:]

    def asked(timeout: float = 0.0) -> bool:
        r, _, _ = select.select([state["master"]], [], [], timeout)
        return bool(r) and b"H" in os.read(state["master"], 1024)

    def drained() -> bool:
        """Wait until the host has read every byte sent: the slave's input queue has stayed empty for 0.2 s.
        (Linux moves bytes from the master to the slave's queue asynchronously, so an empty queue right after
        a write does not yet mean "read"; the 0.2 s cover that hand-over inside the kernel, while a host that is
        slow to read keeps the queue non-empty and is waited for, up to --wait-timeout.)"""
        end = time.monotonic() + args.wait_timeout
        empty_since = None
        while time.monotonic() < end:
            waiting = struct.unpack("i", fcntl.ioctl(state["slave"], termios.FIONREAD, b"\0\0\0\0"))[0]
            now = time.monotonic()
            if waiting:
                empty_since = None
            elif empty_since is None:
                empty_since = now
            elif now - empty_since >= 0.2:
                return True
            time.sleep(0.01)
        return False

    def gone():
        drained()  # what was sent reaches the host (a real unplug may lose the host's buffer; this fake does not)
        os.close(state["master"])
        os.close(state["slave"])
        print("DISCONNECTED", flush=True)
        if args.reconnect_after is None:
            return None
        time.sleep(args.reconnect_after)
        expose()
        return write

    expose()
    n = int(rate * args.seconds)
    try:
        if args.wait_for_host:
            end = time.monotonic() + args.wait_timeout
            while not asked(timeout=max(0.0, end - time.monotonic())):
                if time.monotonic() >= end:
                    print("TIMEOUT waiting for the host", flush=True)
                    return 1
        sent = dev.run(write, n, on_request=asked, on_disconnect=gone)
    except KeyboardInterrupt:
        return 0
    print(f"DONE {sent}", flush=True)
    if sent == n:
        drained()  # let the host read the last lines before the pty goes away
        os.close(state["master"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
