"""Recording an IMU that speaks protocol v1 (``docs/protocol.md``) from a serial port.

A reader thread moves bytes from pyserial into a queue; the recording thread parses them
(:mod:`torchtea.sensors.protocol`, pure), writes rows (flush + fsync per chunk) and keeps a sidecar JSON
up to date. Nothing malformed stops it; a vanished port finishes the file (or, with
``reconnect``, waits for the port to come back).

The recording (``REC.csv``; format documented in ``docs/recording.md``)::

    # torchtea-recording 1
    # units: t_s [s] device clock from the segment's first sample; ax,ay,az [m/s^2]; gx,gy,gz [rad/s]; temp [degC]
    segment,counter,t_s,ax,ay,az,gx,gy,gz,temp
    # segment 0: {"sensor": "MPU-9250", "rate_hz": "100", "accel_lsb_per_g": "4096", ...}
    0,17,0.0,0.0124,...
    0,18,nan,nan,...          (sample 18 missing by the counter)
"""
from __future__ import annotations

import json
import math
import os
import queue
import sys
import threading
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..render import strictjson
from .io import RECORDER_COLUMNS as FILE_COLUMNS
from .io import RECORDING_MAGIC, STANDARD_GRAVITY
from .protocol import Assembler, Parser, Row

__all__ = ["RECORDING_MAGIC", "FILE_COLUMNS", "RecordingWriter", "Recorder", "physical_row", "EXIT_DISCONNECTED"]

UNITS = ("# units: t_s [s] device clock from the segment's first sample; ax,ay,az [m/s^2]; gx,gy,gz [rad/s]; "
         "temp [degC]; nan = sample missing by the counter")
#: Exit status of a recording that ended because the port went away.
EXIT_DISCONNECTED = 3
_NAN_VALUES = ",".join(["nan"] * 8)  # t_s and the seven measured columns


def physical_row(values, scale: dict) -> list[float]:
    """Raw counts (ax, ay, az, gx, gy, gz, temp) → m/s², rad/s, °C."""
    a = STANDARD_GRAVITY / scale["accel_lsb_per_g"]
    g = math.pi / 180.0 / scale["gyro_lsb_per_dps"]
    ax, ay, az, gx, gy, gz, t = values
    return [ax * a, ay * a, az * a, gx * g, gy * g, gz * g, t / scale["temp_lsb_per_c"] + scale["temp_offset_c"]]


class RecordingWriter:
    """Appends rows to ``REC.csv`` and keeps ``REC.json`` (the sidecar) current."""

    def __init__(self, path, info: dict):
        self.path = Path(path)
        self.sidecar = self.path.with_suffix(".json")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "w", newline="")
        self.info = dict(info, format=RECORDING_MAGIC[2:], file=self.path.name,
                         started_utc=datetime.now(timezone.utc).isoformat(timespec="milliseconds"), status="recording")
        self.rows = 0
        self._segment_written = -1
        self._t0: dict = {}
        self._fh.write(f"{RECORDING_MAGIC}\n{UNITS}\n{','.join(FILE_COLUMNS)}\n")
        self._sync()

    def write(self, rows: list[Row], headers: list) -> None:
        """Write rows (from :class:`~torchtea.sensors.protocol.Assembler`); ``headers`` is its ``headers`` list."""
        out = []
        for r in rows:
            if r.segment != self._segment_written:
                hdr = dict(headers)[r.segment]
                out.append(f"# segment {r.segment}: " + json.dumps({k: v for k, v in hdr.meta.items() if k != "columns"}))
                self._segment_written = r.segment
                self._t0[r.segment] = r.t_us
                self._scale = hdr.scale
            if r.sample is None:
                out.append(f"{r.segment},{r.counter},{_NAN_VALUES}")
            else:
                t = (r.t_us - self._t0[r.segment]) / 1e6
                vals = physical_row(r.sample.values, self._scale)
                out.append(f"{r.segment},{r.counter},{t!r}," + ",".join(repr(v) for v in vals))
        if out:
            self._fh.write("\n".join(out) + "\n")
            self.rows += len(rows)
            self._sync()

    def _sync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def update(self, **stats) -> None:
        """Rewrite the sidecar atomically with the current statistics."""
        self.info.update(stats, rows=self.rows)
        strictjson.write(self.sidecar, self.info, atomic=True)

    def close(self, status: str, **stats) -> None:
        self._sync()
        self._fh.close()
        self.update(status=status, finished_utc=datetime.now(timezone.utc).isoformat(timespec="milliseconds"), **stats)


@dataclass
class _Gone:
    """The reader thread lost the port."""

    reason: str


def _reader(ser, q: queue.Queue, stop: threading.Event) -> None:
    try:
        while not stop.is_set():
            data = ser.read(max(1, ser.in_waiting))
            if data:
                q.put(data)
    except Exception as exc:  # noqa: BLE001 — serial.SerialException, OSError, a closed port …
        if not stop.is_set():
            q.put(_Gone(f"{type(exc).__name__}: {exc}"))


def _drain(q: queue.Queue, first=None) -> tuple[list, _Gone | None]:
    """``first`` (if given) and everything queued now: the byte chunks in order, and the lost-port
    report if one came (it ends the drain)."""
    chunks: list = []
    item = first
    while True:
        if isinstance(item, _Gone):
            return chunks, item
        if item is not None:
            chunks.append(item)
        try:
            item = q.get_nowait()
        except queue.Empty:
            return chunks, None


class Recorder:
    """Record a protocol-v1 device to ``out``.

    Parameters
    ----------
    port : str
        A device path or a pyserial URL (``loop://``, ``socket://…``).
    out : path of the recording CSV (its sidecar is ``out`` with suffix ``.json``).
    duration : float, optional
        Stop after this many seconds (wall clock); default: until Ctrl-C or the port goes away.
    samples : int, optional
        Stop once this many rows (samples, missing ones included) are recorded; the rows of the last
        chunk beyond that are not written.
    reconnect : bool
        On a lost port, wait for it to come back instead of finishing.
    request_header : float or None
        If no header has arrived this many seconds after opening the port, send ``H\\n`` (the
        firmware answers with its header; pyserial discards input that arrived before opening).
        None: never ask.
    live : object with ``put(rows, headers)`` and ``close()``, optional
        Receives every chunk of rows (live estimation); it must not block.
    open_port : callable returning an open pyserial object, optional
        Default ``serial.serial_for_url(port, baud, timeout=0.1)``.
    """

    def __init__(self, port: str, out, *, baud: int = 115200, duration: float | None = None, reconnect: bool = False,
                 request_header: float | None = 1.0, live=None, open_port=None, sidecar_every: float = 1.0,
                 max_gap: int = 60_000, log=None, samples: int | None = None):
        self.port, self.baud, self.duration, self.reconnect = port, baud, duration, reconnect
        self.samples = samples
        self._beyond = {"good": 0, "missing": 0}
        self.request_header, self.live, self.sidecar_every = request_header, live, sidecar_every
        self.parser, self.assembler = Parser(), Assembler(max_gap=max_gap)
        self.bytes_received = 0
        self.disconnects = 0
        self.cut_lines = 0
        self.out = Path(out)
        self._open = open_port or self._default_open
        self._log = log or (lambda msg: print(f"torchtea record: {msg}", file=sys.stderr, flush=True))
        self.writer: RecordingWriter | None = None

    def _default_open(self):
        import serial

        return serial.serial_for_url(self.port, self.baud, timeout=0.1)

    def stats(self) -> dict:
        a, p = self.assembler, self.parser
        return {"good_samples": a.good_samples - self._beyond["good"], "bad_lines": p.bad_lines,
                "bad_by_reason": dict(sorted(p.bad.items())),
                "missing_samples": a.missing_samples - self._beyond["missing"], "duplicate_samples": a.duplicate,
                "counter_jumps": a.counter_jumps, "samples_before_header": a.before_header,
                "lines_cut_by_disconnect": self.cut_lines, "segments": a.segment + 1,
                "headers": [{"segment": s, **h.meta} for s, h in a.headers], "disconnects": self.disconnects,
                "bytes_received": self.bytes_received}

    def run(self) -> int:
        """Record until the duration, Ctrl-C or a lost port; returns the exit status (0, or
        :data:`EXIT_DISCONNECTED`). The file and sidecar are finished in every case."""
        try:
            ser = self._open()
        except Exception as exc:  # noqa: BLE001
            raise OSError(f"cannot open {self.port}: {exc}") from None
        self.writer = RecordingWriter(self.out, {"port": self.port, "baud": self.baud})
        self.writer.update(**self.stats())
        t_start = time.monotonic()
        deadline = None if self.duration is None else t_start + self.duration
        status, code = "finished", 0
        try:
            while True:
                gone = self._session(ser, deadline)
                if gone is None:
                    break
                self.disconnects += 1
                self._cut_line()
                self._log(f"lost {self.port} ({gone})")
                if not self.reconnect:
                    status, code = f"disconnected: {gone}", EXIT_DISCONNECTED
                    break
                ser = self._wait_for_port(deadline)
                if ser is None:
                    status = "finished while waiting for the port"
                    break
                self._log(f"{self.port} is back")
        except KeyboardInterrupt:
            status = "stopped (Ctrl-C)"
        finally:
            self._cut_line(count=False)
            self.assembler.finish()
            self.writer.close(status, **self.stats())
            if self.live is not None:
                self.live.close()
        s = self.stats()
        self._log(f"{self.writer.rows} rows in {self.out} ({s['good_samples']} samples, {s['missing_samples']} missing, "
                  f"{s['bad_lines']} bad lines, {s['segments']} segment(s)); {status}")
        return code

    def _cut_line(self, count: bool = True) -> None:
        """Drop the partial line held by the parser (the line in flight when the port went away)."""
        if self.parser.drop_pending() and count:
            self.cut_lines += 1

    def _wait_for_port(self, deadline):
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
            try:
                return self._open()
            except Exception:  # noqa: BLE001 — still gone
                continue
        return None

    def _session(self, ser, deadline) -> str | None:
        """Read one open port until the deadline (None returned) or until it is lost (the reason)."""
        q: queue.Queue = queue.Queue()
        stop = threading.Event()
        th = threading.Thread(target=_reader, args=(ser, q, stop), name="torchtea-serial-reader", daemon=True)
        th.start()
        opened = time.monotonic()
        asked = self.request_header is None
        last_sidecar = 0.0
        gone = None
        try:
            while True:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                try:
                    item = q.get(timeout=0.1 if deadline is None else max(0.0, min(0.1, deadline - now)))
                except queue.Empty:
                    item = None
                if item is not None:
                    chunks, lost = _drain(q, item)  # one write and one fsync for what is there
                    if chunks:
                        self._consume(b"".join(chunks))
                    if self._enough():
                        break
                    if lost is not None:
                        gone = lost.reason
                        break
                if not asked and self.assembler.header is None and time.monotonic() - opened > self.request_header:
                    asked = True
                    try:
                        ser.write(b"H\n")
                    except Exception:  # noqa: BLE001 — the reader thread will report a lost port
                        pass
                if time.monotonic() - last_sidecar >= self.sidecar_every:
                    self.writer.update(**self.stats())
                    last_sidecar = time.monotonic()
        finally:
            stop.set()
            try:
                ser.close()
            except Exception:  # noqa: BLE001
                pass
            th.join(timeout=1.0)
            if gone is None and not self._enough():  # bytes read before the thread stopped are still received
                chunks, _ = _drain(q)
                if chunks:
                    self._consume(b"".join(chunks))
        return gone

    def _enough(self) -> bool:
        return self.samples is not None and self.writer.rows >= self.samples

    def _consume(self, data: bytes) -> None:
        self.bytes_received += len(data)
        rows = self.assembler.add(self.parser.feed(data))
        if self.samples is not None:
            keep = max(0, self.samples - self.writer.rows)
            for r in rows[keep:]:  # past the requested count: not recorded, so not counted either
                self._beyond["missing" if r.sample is None else "good"] += 1
            rows = rows[:keep]
        if rows:
            self.writer.write(rows, self.assembler.headers)
            if self.live is not None:
                self.live.put(rows, self.assembler.headers)
