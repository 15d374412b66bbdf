"""A simulated protocol-v1 IMU with injectable faults (``scripts/fake_imu.py`` is its command line).

It replays a recording or synthesises fractional noise, paced in real time, on a pseudo-terminal
(``open_pty``: the recorder opens the slave path like a real port) or into any writable object
(pyserial ``loop://`` in the unit tests). Faults are given per sample index ``k`` (the k-th sample the
device produces, from 0) as ``KIND@K`` or ``KIND@K:COUNT``:

==============  =============================================================================
``corrupt``     one byte of line k changed (its checksum no longer matches)
``checksum``    line k sent with a wrong checksum
``garbage:N``   N random bytes and a newline before line k (one malformed line)
``fields``      line k with a field missing (valid checksum)
``range``       line k with ax = 40000 (outside int16; valid checksum)
``nonnumeric``  line k with ax = ``1x`` (valid checksum)
``drop:N``      samples k … k+N−1 never sent (the counter moves on)
``reset``       device reset before sample k: header again, counter and clock restart at 0
``disconnect``  the port goes away before sample k (the pty is closed)
==============  =============================================================================
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from .protocol import U32, checksum, format_header, format_line

__all__ = ["Fault", "parse_fault", "FakeIMU", "synthetic_counts", "replay_counts", "open_pty", "DEFAULT_META"]

FAULT_KINDS = ("corrupt", "checksum", "garbage", "fields", "range", "nonnumeric", "drop", "reset", "disconnect")

#: What the firmware sends for an MPU-9250 at its defaults (±8 g, ±250 °/s, 100 Hz, DLPF 41 Hz).
DEFAULT_META = {"sensor": "MPU-9250", "rate_hz": "100", "accel_lsb_per_g": "4096", "gyro_lsb_per_dps": "131",
                "temp_lsb_per_c": "333.87", "temp_offset_c": "21", "dlpf_hz": "41", "firmware": "fake_imu"}


@dataclass(frozen=True)
class Fault:
    kind: str
    at: int
    count: int = 1


def parse_fault(spec: str) -> Fault:
    """``KIND@K`` or ``KIND@K:COUNT`` (see the module docstring)."""
    kind, _, rest = spec.partition("@")
    at, _, count = rest.partition(":")
    if kind not in FAULT_KINDS:
        raise ValueError(f"fault {spec!r}: unknown kind {kind!r} (one of {', '.join(FAULT_KINDS)})")
    try:
        f = Fault(kind, int(at), int(count) if count else 1)
    except ValueError:
        raise ValueError(f"fault {spec!r}: expected KIND@K or KIND@K:COUNT with whole numbers") from None
    if f.at < 0 or f.count < 1:
        raise ValueError(f"fault {spec!r}: K must be >= 0 and COUNT >= 1")
    return f


def synthetic_counts(n: int, *, rate_hz: float = 100.0, lsb_per_g: float = 4096.0, order: float = 0.3,
                     param: float = -1.0, noise_ms2: float = 0.02, seed: int = 0) -> np.ndarray:
    """``(n, 7)`` int counts of a static IMU: fractional noise (the paper's model, order ``order``) on
    each accelerometer axis scaled to ``noise_ms2`` standard deviation, 1 g on z, white gyro noise, a
    constant temperature."""
    import torch

    from ..engines.structure import ConstantOrder, Structure
    from ..noise.simulate import simulate
    from .io import STANDARD_GRAVITY

    g = torch.Generator().manual_seed(seed)
    sim = simulate(Structure(), n_steps=n, h=1.0 / rate_hz, order=ConstantOrder(order), parameters=[param],
                   process_noise=1.0, measurement_noise=0.1, batch_shape=(3,), generator=g, memory="soe")
    y = sim.y[..., 0].numpy()  # (3, n)
    y = y / y.std(axis=1, keepdims=True) * noise_ms2
    y[2] += STANDARD_GRAVITY
    rng = np.random.default_rng(seed)
    out = np.empty((n, 7), dtype=np.int64)
    out[:, :3] = np.rint(y.T / STANDARD_GRAVITY * lsb_per_g)
    out[:, 3:6] = np.rint(rng.normal(0.0, 3.0, size=(n, 3)))
    out[:, 6] = 1500
    return np.clip(out, -32768, 32767)


def replay_counts(path=None) -> tuple[np.ndarray, float, float]:
    """Counts of a recording to replay: ``(n, 7)``, its rate and accelerometer LSB per g.

    The bundled format holds accelerometer and gyroscope counts (temperature set constant)."""
    from .io import read_recording

    rec = read_recording(path)
    n = len(rec.accel_counts)
    out = np.zeros((n, 7), dtype=np.int64)
    out[:, :3] = np.nan_to_num(rec.accel_counts)
    if rec.gyro_counts is not None:
        out[:, 3:6] = np.nan_to_num(rec.gyro_counts)
    out[:, 6] = 1500
    return np.clip(out, -32768, 32767), rec.rate_hz, rec.accel_lsb_per_g


@dataclass
class FakeIMU:
    """A device producing protocol-v1 bytes from ``counts`` (``(n, 7)``; replayed cyclically)."""

    counts: np.ndarray
    rate_hz: float = 100.0
    meta: dict = field(default_factory=lambda: dict(DEFAULT_META))
    faults: tuple = ()
    counter0: int = 0
    t0_us: int = 0
    seed: int = 0

    def __post_init__(self):
        self.meta = dict(self.meta, rate_hz=f"{self.rate_hz:g}")
        self._rng = np.random.default_rng(self.seed)

    def header(self) -> bytes:
        return format_header(self.meta)

    def chunks(self, n: int):
        """Yield ``(k, bytes)`` for samples ``k = 0 … n−1`` (a fault's extra bytes come with its sample),
        and ``(k, None)`` where the device disconnects."""
        by_k: dict = {}
        for f in self.faults:
            by_k.setdefault(f.at, []).append(f)
        dropping = 0
        counter, t_us = self.counter0, self.t0_us
        yield -1, self.header()
        period = 1e6 / self.rate_hz
        base_t, base_k = self.t0_us, 0
        for k in range(n):
            pre = b""
            line_fault = None
            for f in by_k.get(k, ()):
                if f.kind == "disconnect":
                    yield k, None
                elif f.kind == "reset":
                    counter, base_t, base_k = 0, 0, k
                    pre += self.header()
                elif f.kind == "drop":
                    dropping = max(dropping, f.count)
                elif f.kind == "garbage":
                    junk = self._rng.integers(0, 256, size=f.count, dtype=np.uint8).tobytes()
                    pre += junk.replace(b"\n", b"?").replace(b"\r", b"?") + b"\n"
                else:
                    line_fault = f.kind
            t_us = int(base_t + round((k - base_k) * period))
            values = [int(v) for v in self.counts[k % len(self.counts)]]
            if dropping:
                dropping -= 1
                line = b""
            else:
                line = self._line(counter, t_us, values, line_fault)
            counter = (counter + 1) % U32
            if pre or line:
                yield k, pre + line

    def _line(self, counter: int, t_us: int, values: list, fault: str | None) -> bytes:
        if fault is None:
            return format_line(counter, t_us, values)
        fields = [str(counter % U32), str(t_us % U32)] + [str(v) for v in values]
        if fault == "fields":
            fields = fields[:-1]
        elif fault == "range":
            fields[2] = "40000"
        elif fault == "nonnumeric":
            fields[2] = "1x"
        body = ",".join(fields).encode()
        hh = checksum(body)
        if fault == "checksum":
            hh ^= 0x5A
        elif fault == "corrupt":
            i = int(self._rng.integers(0, len(body)))
            new = (body[i] + 1 + int(self._rng.integers(0, 250))) % 256
            new = new if new not in (10, 13, body[i]) else 0x7F
            body = body[:i] + bytes([new]) + body[i + 1:]
        return body + b"*%02X\r\n" % hh

    def run(self, write, n: int, *, realtime: bool = True, on_request=None, on_disconnect=None) -> int:
        """Send ``n`` samples through ``write(bytes)``, paced at ``rate_hz`` when ``realtime``.

        ``on_request()`` (optional) is polled between samples and returns True when the host asked for
        the header (``H``); the header is then sent again. At a ``disconnect`` fault, ``on_disconnect()``
        returns a new ``write`` (the port came back; the device carries on where it stopped) or None.
        Returns the number of samples produced before the run ended."""
        t0 = time.monotonic()
        for k, data in self.chunks(n):
            if data is None:
                write = None if on_disconnect is None else on_disconnect()
                if write is None:
                    return k
                t0 = time.monotonic() - k / self.rate_hz  # the device paused while the port was away
                continue
            if realtime and k >= 0:
                delay = t0 + k / self.rate_hz - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            if on_request is not None and on_request():
                write(self.header())
            write(data)
        return n


def open_pty():
    """A pseudo-terminal pair in raw mode: ``(master_fd, slave_fd, slave_path)``. Keep ``slave_fd`` open
    while the device lives (closing the master then looks like a pulled cable to the host)."""
    import pty
    import tty

    master, slave = pty.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)
