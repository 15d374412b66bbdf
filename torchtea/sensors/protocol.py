"""Serial protocol v1 of a torchtea IMU (see ``docs/protocol.md``) — a pure, incremental parser.

No I/O happens here: :class:`Parser` turns bytes into events, :class:`Assembler` turns events
into rows (one per counter value, NaN where a sample is missing). Both accept any byte stream:
malformed input is counted by reason and skipped, never raised.

The stream::

    # torchtea-imu 1
    # sensor=MPU-9250
    # rate_hz=100
    # ...                                       (key=value lines)
    # columns=counter,t_us,ax,ay,az,gx,gy,gz,temp
    0,1000000,12,-40,4100,3,-2,1,1520*5C
    1,1010000,...

``counter`` and ``t_us`` are unsigned 32-bit and wrap; ``HH`` after ``*`` is the XOR of every
byte before the ``*``, as two hex digits of either case; ``\\r\\n`` or ``\\n`` ends a line. A header
may come again at any time (the device reset): it starts a new segment.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

__all__ = ["MAGIC", "COLUMNS", "REQUIRED_KEYS", "Header", "Sample", "Parser", "Row", "Assembler",
           "checksum", "format_line", "format_header"]

MAGIC = "# torchtea-imu 1"
COLUMNS = ("counter", "t_us", "ax", "ay", "az", "gx", "gy", "gz", "temp")
VALUE_COLUMNS = COLUMNS[2:]
REQUIRED_KEYS = ("sensor", "rate_hz", "accel_lsb_per_g", "gyro_lsb_per_dps", "temp_lsb_per_c", "temp_offset_c",
                 "dlpf_hz")
NUMERIC_KEYS = REQUIRED_KEYS[1:]
U32 = 1 << 32
I16 = (-32768, 32767)
#: Longest line accepted (a v1 data line is at most 9 fields of 11 characters + checksum).
MAX_LINE = 160

_HEX = frozenset(b"0123456789abcdefABCDEF")


def checksum(body: bytes) -> int:
    """XOR of all bytes."""
    c = 0
    for b in body:
        c ^= b
    return c


def format_line(counter: int, t_us: int, values) -> bytes:
    """One v1 data line (the device side; used by the fake device and the tests)."""
    body = ",".join(str(int(v)) for v in (counter % U32, t_us % U32, *values)).encode()
    return body + b"*%02X\r\n" % checksum(body)


def format_header(meta: dict) -> bytes:
    lines = [MAGIC] + [f"# {k}={v}" for k, v in meta.items() if k != "columns"] + ["# columns=" + ",".join(COLUMNS)]
    return ("\n".join(lines) + "\n").encode()


@dataclass(frozen=True)
class Header:
    """A complete header: ``meta`` holds every ``key=value`` (strings; the numeric keys also as floats in ``scale``)."""

    meta: dict
    scale: dict


@dataclass(frozen=True)
class Sample:
    counter: int  # 0 … 2³²−1 as sent
    t_us: int  # 0 … 2³²−1 as sent
    values: tuple  # ax, ay, az, gx, gy, gz, temp (raw int16 counts)


@dataclass
class Parser:
    """Bytes in, :class:`Header` / :class:`Sample` events out.

    ``bad`` counts rejected lines by reason (``checksum``, ``no_checksum``, ``fields``, ``not_integer``,
    ``range``, ``too_long``, ``not_ascii``, ``header``); a header line outside a header block, or a
    header block that is incomplete or malformed, counts as ``header``. ``bad_lines`` is their total.
    The line still in flight (no newline yet) is held until more bytes come.
    """

    bad: Counter = field(default_factory=Counter)
    _buf: bytearray = field(default_factory=bytearray)
    _skipping: bool = False  # inside an over-long line: drop bytes until the next newline
    _block: dict | None = None  # header block being read

    @property
    def bad_lines(self) -> int:
        return sum(self.bad.values())

    @property
    def pending(self) -> bytes:
        """The partial line held back (the line in flight)."""
        return bytes(self._buf)

    def drop_pending(self) -> bool:
        """Forget the line in flight (the port went away mid-line); True if there was one."""
        had = bool(self._buf) or self._skipping
        self._buf.clear()
        self._skipping = False
        return had

    def feed(self, data: bytes) -> list:
        events: list = []
        start = 0
        n = len(data)
        while start < n:
            nl = data.find(b"\n", start)
            end = n if nl < 0 else nl
            if self._skipping:
                if nl >= 0:
                    self._skipping = False
                start = end + 1
                continue
            self._buf += data[start:end]
            if len(self._buf) > MAX_LINE:
                self._buf.clear()
                self.bad["too_long"] += 1
                self._skipping = nl < 0
                start = end + 1
                continue
            if nl < 0:
                break
            line = bytes(self._buf)
            self._buf.clear()
            self._line(line, events)
            start = nl + 1
        return events

    # -- one complete line (without its "\n")
    def _line(self, line: bytes, events: list) -> None:
        if line.endswith(b"\r"):
            line = line[:-1]
        if not line:
            return  # blank lines carry nothing
        if line[:1] == b"#":
            self._header_line(line, events)
            return
        if self._block is not None:  # data inside a header block: the block is broken
            self._block = None
            self.bad["header"] += 1
        star = line.rfind(b"*")
        if star < 0 or len(line) - star != 3:
            self.bad["no_checksum"] += 1
            return
        body, hh = line[:star], line[star + 1:]
        if not (hh[0] in _HEX and hh[1] in _HEX) or int(hh, 16) != checksum(body):
            self.bad["checksum"] += 1
            return
        if not body.isascii():
            self.bad["not_ascii"] += 1
            return
        fields = body.split(b",")
        if len(fields) != len(COLUMNS):
            self.bad["fields"] += 1
            return
        ints = []
        for f in fields:
            digits = f[1:] if f[:1] == b"-" else f
            if not digits.isdigit() or len(digits) > 11:  # bytes.isdigit: ASCII digits only, False if empty
                self.bad["not_integer"] += 1
                return
            ints.append(int(f))
        counter, t_us, *values = ints
        if not (0 <= counter < U32 and 0 <= t_us < U32 and all(I16[0] <= v <= I16[1] for v in values)):
            self.bad["range"] += 1
            return
        events.append(Sample(counter, t_us, tuple(values)))

    def _header_line(self, line: bytes, events: list) -> None:
        try:
            text = line.decode("ascii").rstrip()
        except UnicodeDecodeError:
            self._block = None
            self.bad["header"] += 1
            return
        if text == MAGIC:
            if self._block is not None:
                self.bad["header"] += 1  # the previous block never finished
            self._block = {}
            return
        if self._block is None or not text.startswith("# ") or "=" not in text:
            self.bad["header"] += 1
            return
        key, _, value = text[2:].partition("=")
        key, value = key.strip(), value.strip()
        if key != "columns":
            self._block[key] = value
            return
        block, self._block = self._block, None
        header = _validate(block, value)
        if header is None:
            self.bad["header"] += 1
        else:
            events.append(header)


def _validate(block: dict, columns: str) -> Header | None:
    if tuple(c.strip() for c in columns.split(",")) != COLUMNS:
        return None
    if any(k not in block for k in REQUIRED_KEYS):
        return None
    scale = {}
    for k in NUMERIC_KEYS:
        try:
            v = float(block[k])
        except ValueError:
            return None
        if not math.isfinite(v):
            return None
        scale[k] = v
    if scale["rate_hz"] <= 0 or scale["accel_lsb_per_g"] <= 0 or scale["gyro_lsb_per_dps"] <= 0 \
            or scale["temp_lsb_per_c"] <= 0:
        return None
    return Header(dict(block, columns=columns), scale)


@dataclass(frozen=True)
class Row:
    """One row of a recording: ``sample`` is None for a sample missing by the counter."""

    segment: int
    counter: int  # unwrapped: first counter of the segment as sent, then +1 per row
    t_us: int | None  # unwrapped device time, None when missing
    sample: Sample | None


@dataclass
class Assembler:
    """Events in, rows out: one row per counter value, NaN rows for gaps, new segments on headers.

    A counter step of 0 (a repeat) is dropped and counted as ``duplicate``; a step backwards or of
    more than ``max_gap`` samples cannot be a gap of lost samples (the counter jumped) and starts a new
    segment with the same header (``counter_jumps``). Samples before the first header (the host opened
    the port mid-stream) are held until it comes: if the counter runs on across it (the device re-sent
    its header on request) they open the first segment, otherwise they are counted (``before_header``)
    and dropped.
    """

    max_gap: int = 60_000
    max_pre_header: int = 10_000
    header: Header | None = None
    segment: int = -1
    good_samples: int = 0
    missing_samples: int = 0
    duplicate: int = 0
    counter_jumps: int = 0
    before_header: int = 0
    headers: list = field(default_factory=list)  # (segment, Header)
    _last: int | None = None  # unwrapped counter of the last row
    _last_raw: int = 0
    _t: int = 0
    _t_raw: int = 0
    _pre: list = field(default_factory=list)  # samples before the first header, kept until it comes

    def add(self, events) -> list[Row]:
        rows: list[Row] = []
        for ev in events:
            if isinstance(ev, Header):
                self.header = ev
                self._new_segment()
            elif self.header is None:
                if len(self._pre) < self.max_pre_header:
                    self._pre.append(ev)
                else:
                    self.before_header += 1
            elif self._last is None:
                if self._pre:
                    self._adopt_pre_header(ev, rows)
                if self._last is None:
                    self._start(ev, rows)
                else:
                    self._next(ev, rows)
            else:
                self._next(ev, rows)
        return rows

    def _adopt_pre_header(self, ev: Sample, rows: list) -> None:
        """Samples that came before the first header belong to its segment if ``ev`` continues their
        counter (the header was re-sent on request); otherwise (the device reset) they are dropped."""
        pre, self._pre = self._pre, []
        chain = [pre[0]]
        for s in pre[1:] + [ev]:
            if not 1 <= (s.counter - chain[-1].counter) % U32 <= self.max_gap + 1:
                self.before_header += len(pre)
                return
            chain.append(s)
        self._start(pre[0], rows)
        for s in pre[1:]:
            self._next(s, rows)

    def _next(self, ev: Sample, rows: list) -> None:
        step = (ev.counter - self._last_raw) % U32
        if step == 0:
            self.duplicate += 1
        elif step > self.max_gap + 1:
            self.counter_jumps += 1
            self._new_segment()
            self._start(ev, rows)
        else:
            for i in range(1, step):
                rows.append(Row(self.segment, self._last + i, None, None))
            self.missing_samples += step - 1
            self._last += step
            self._last_raw = ev.counter
            self._t += (ev.t_us - self._t_raw) % U32
            self._t_raw = ev.t_us
            rows.append(Row(self.segment, self._last, self._t, ev))
            self.good_samples += 1

    def finish(self) -> None:
        """End of input: samples still waiting for a header are dropped (counted in ``before_header``)."""
        self.before_header += len(self._pre)
        self._pre = []

    def _new_segment(self) -> None:
        if self._last is None and self.headers and self.headers[-1][0] == self.segment:
            self.headers[-1] = (self.segment, self.header)  # the segment has no rows yet: the newer header wins
            return
        self.segment += 1
        self._last = None
        self.headers.append((self.segment, self.header))

    def _start(self, ev: Sample, rows: list) -> None:
        self._last = self._last_raw = ev.counter
        self._t = self._t_raw = ev.t_us
        rows.append(Row(self.segment, ev.counter, ev.t_us, ev))
        self.good_samples += 1
