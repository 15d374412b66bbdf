"""The Arduino sketch, compiled for the host against stand-ins for the Arduino core (tests/firmware_host/):
what it sends must be protocol v1 exactly as torchtea's parser reads it."""
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from torchtea.sensors.protocol import Assembler, Header, Parser, Sample, format_line

HOST = Path(__file__).parent / "firmware_host"
pytestmark = pytest.mark.skipif(shutil.which("g++") is None, reason="needs g++ to build the sketch for the host")


@pytest.fixture(scope="module")
def firmware(tmp_path_factory):
    out = {}
    for name, flags in (("9250", ["-DWHO=0x71"]), ("6050", ["-DWHO=0x68", "-DTT_MPU6050"]),
                        ("absent", ["-DWHO=0xFF"])):
        exe = tmp_path_factory.mktemp("fw") / name
        subprocess.run(["g++", "-std=c++17", "-Wall", "-Wextra", "-Werror", *flags, f"-I{HOST}", "-o", str(exe),
                        str(HOST / "host_main.cpp")], check=True, capture_output=True, text=True)
        out[name] = exe
    return out


def _run(exe, commands):
    r = subprocess.run([str(exe)], input=("\n".join(commands) + "\n").encode(), capture_output=True, timeout=30)
    regs = dict(kv.split("=") for kv in r.stderr.decode().split()[1:])
    return r.stdout, {int(k, 16): int(v) for k, v in regs.items()}


def test_sketch_speaks_protocol_v1(firmware):
    rng = np.random.default_rng(7)
    values = rng.integers(-32768, 32768, size=(50, 7))
    values[0] = [-32768, 32767, 0, -1, 1, -32768, 32767]
    cmds, expected = [], []
    t = 4294967295 - 120_000  # micros() wraps during the run
    for k, v in enumerate(values):
        regs = [v[0], v[1], v[2], v[6], v[3], v[4], v[5]]  # register order: temperature 4th
        t = (t + 10_000) % 2**32
        cmds += ["S " + " ".join(map(str, regs)), f"I {t}", "L"]
        expected.append(format_line(k, t, v.tolist()))
    out, regs = _run(firmware["9250"], cmds)
    assert out.endswith(b"".join(expected))  # byte for byte what torchtea's own formatter writes
    p = Parser()
    ev = p.feed(out)
    assert p.bad_lines == 0 and isinstance(ev[0], Header)
    hdr = ev[0]
    assert hdr.meta["sensor"] == "MPU-9250" and hdr.scale["accel_lsb_per_g"] == 4096 and hdr.scale["rate_hz"] == 100
    assert hdr.scale["temp_lsb_per_c"] == 333.87 and hdr.scale["temp_offset_c"] == 21 and hdr.scale["dlpf_hz"] == 44.8
    samples = [e for e in ev if isinstance(e, Sample)]
    assert [s.values for s in samples] == [tuple(v) for v in values.tolist()]
    # 100 Hz from a 1 kHz internal rate, DLPF 3 on gyro and accel, ±8 g, ±250 °/s, data-ready interrupt
    assert regs == {0x19: 9, 0x1A: 3, 0x1B: 0, 0x1C: 0x10, 0x1D: 3, 0x37: 0x10, 0x38: 1, 0x6B: 1}


def test_missed_interrupts_and_failed_reads_are_counter_gaps(firmware):
    cmds = ["S 1 2 3 4 5 6 7", "I 10000", "L", "I 20000", "I 30000", "L", "F", "I 40000", "L", "I 50000", "L"]
    out, _ = _run(firmware["9250"], cmds)
    a = Assembler()
    rows = a.add(Parser().feed(out))
    assert [r.counter for r in rows] == [0, 1, 2, 3, 4]
    assert [r.sample is None for r in rows] == [False, True, False, True, False]
    assert a.missing_samples == 2 and a.good_samples == 3


def test_header_on_request_and_mpu6050_define(firmware):
    out, regs = _run(firmware["6050"], ["S 1 2 3 4 5 6 7", "I 5", "L", "R H", "L", "I 10005", "L"])
    p = Parser()
    ev = p.feed(out)
    headers = [e for e in ev if isinstance(e, Header)]
    assert len(headers) == 2 and p.bad_lines == 0
    assert headers[0].meta["sensor"] == "MPU-6050" and headers[0].scale["temp_lsb_per_c"] == 340
    assert headers[0].scale["dlpf_hz"] == 44 and regs[0x1D] == 0  # a 6050 has no ACCEL_CONFIG2: left alone
    assert [e.counter for e in ev if isinstance(e, Sample)] == [0, 1]


def test_no_sensor_says_so_and_sends_no_samples(firmware):
    out, _ = _run(firmware["absent"], ["I 5", "L", "I 10", "L"])
    assert b"# error=no MPU at the I2C address (WHO_AM_I 0xFF)" in out
    assert not [e for e in Parser().feed(out) if isinstance(e, Sample)]
