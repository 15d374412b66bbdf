"""Protocol v1 parser and assembler: exact behaviour on every kind of bad input, and properties."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from torchtea.sensors.fakeimu import DEFAULT_META, FakeIMU, parse_fault
from torchtea.sensors.protocol import (
    COLUMNS,
    MAGIC,
    U32,
    Assembler,
    Header,
    Parser,
    Sample,
    checksum,
    format_header,
    format_line,
)

META = {k: v for k, v in DEFAULT_META.items()}


def _samples(events):
    return [e for e in events if isinstance(e, Sample)]


def test_checksum_is_xor_and_either_case_accepted():
    body = b"1,2,3,4,5,6,7,8,9"
    hh = 0
    for b in body:
        hh ^= b
    assert checksum(body) == hh
    for text in (b"%02x" % hh, b"%02X" % hh):
        p = Parser()
        ev = p.feed(format_header(META) + body + b"*" + text + b"\n")
        assert _samples(ev) == [Sample(1, 2, (3, 4, 5, 6, 7, 8, 9))] and p.bad_lines == 0


def test_header_is_parsed_with_scales():
    ev = Parser().feed(format_header(META))
    assert len(ev) == 1 and isinstance(ev[0], Header)
    assert ev[0].scale["accel_lsb_per_g"] == 4096.0 and ev[0].meta["sensor"] == "MPU-9250"
    assert ev[0].meta["columns"] == ",".join(COLUMNS)


@pytest.mark.parametrize("line, reason", [
    (b"1,2,3,4,5,6,7,8,9*00", "checksum"),
    (b"1,2,3,4,5,6,7,8,9", "no_checksum"),
    (b"1,2,3,4,5,6,7,8*", "no_checksum"),
    (None, "fields"),  # built below with a valid checksum
    (b"#garbage", "header"),
    (b"x" * 300, "too_long"),
])
def test_each_bad_line_is_counted_by_reason(line, reason):
    if line is None:
        body = b"1,2,3,4,5,6,7,8"
        line = body + b"*%02X" % checksum(body)
    p = Parser()
    ev = p.feed(format_header(META) + line + b"\r\n" + format_line(5, 6, [1] * 7))
    assert _samples(ev) == [Sample(5, 6, (1,) * 7)]
    assert dict(p.bad) == {reason: 1}


@pytest.mark.parametrize("fields, reason", [
    ([1, 2, 3, 4, 5, 6, 7, 8, "1x"], "not_integer"),
    ([1, 2, 3, 4, 5, 6, 7, 8, ""], "not_integer"),
    ([1, 2, 3, 4, 5, 6, 7, 8, "+9"], "not_integer"),
    ([1, 2, 40000, 4, 5, 6, 7, 8, 9], "range"),
    ([1, 2, -32769, 4, 5, 6, 7, 8, 9], "range"),
    ([U32, 2, 3, 4, 5, 6, 7, 8, 9], "range"),
    ([1, -1, 3, 4, 5, 6, 7, 8, 9], "range"),
])
def test_values_checked_after_the_checksum(fields, reason):
    body = ",".join(map(str, fields)).encode()
    p = Parser()
    p.feed(format_header(META) + body + b"*%02x\n" % checksum(body))
    assert dict(p.bad) == {reason: 1}


def test_incomplete_header_block_is_bad_and_data_still_parses():
    p = Parser()
    text = (MAGIC + "\n# sensor=x\n").encode() + format_line(0, 0, [0] * 7)
    ev = p.feed(text)
    assert not any(isinstance(e, Header) for e in ev) and p.bad["header"] == 1
    assert len(_samples(ev)) == 1


def test_missing_required_key_rejects_the_header():
    meta = dict(META)
    del meta["dlpf_hz"]
    p = Parser()
    assert p.feed(format_header(meta)) == [] and p.bad["header"] == 1


def test_assembler_fills_gaps_with_missing_rows_and_wraps():
    a = Assembler()
    hdr = Parser().feed(format_header(META))
    rows = a.add(hdr + [Sample(U32 - 2, U32 - 100, (0,) * 7), Sample(1, 19_900, (1,) * 7)])
    # U32−2, U32−1 (missing), 0 (missing), 1
    assert [r.counter for r in rows] == [U32 - 2, U32 - 1, U32, U32 + 1]
    assert [r.sample is None for r in rows] == [False, True, True, False]
    assert rows[-1].t_us - rows[0].t_us == 20_000  # the clock wrapped too
    assert (a.good_samples, a.missing_samples) == (2, 2)


def test_assembler_duplicate_jump_and_reset():
    a = Assembler(max_gap=10)
    hdr = Parser().feed(format_header(META))
    s = lambda c: Sample(c, c * 10_000, (c,) * 7)  # noqa: E731
    rows = a.add(hdr + [s(5), s(5), s(6), s(100)] + hdr + [s(0), s(1)])
    assert a.duplicate == 1 and a.counter_jumps == 1
    assert [(r.segment, r.counter) for r in rows] == [(0, 5), (0, 6), (1, 100), (2, 0), (2, 1)]


def test_samples_before_the_first_header_kept_when_the_counter_runs_on():
    p = Parser()
    a = Assembler()
    rows = a.add(p.feed(format_line(7, 0, [1] * 7) + format_line(8, 10, [2] * 7) + format_header(META)
                        + format_line(10, 30, [3] * 7)))
    assert [r.counter for r in rows] == [7, 8, 9, 10] and a.before_header == 0 and a.missing_samples == 1
    b = Assembler()  # the device reset: the early samples cannot be placed
    rows = b.add(p.feed(format_line(7, 0, [1] * 7) + format_header(META) + format_line(0, 0, [3] * 7)))
    assert [r.counter for r in rows] == [0] and b.before_header == 1


def _stream(n=60, faults=()):
    counts = np.arange(n * 7).reshape(n, 7) % 2000 - 1000
    dev = FakeIMU(counts, faults=tuple(parse_fault(f) for f in faults), counter0=U32 - 20, t0_us=U32 - 150_000)
    return b"".join(d for _, d in dev.chunks(n) if d is not None)


STREAM = _stream(faults=("corrupt@3", "drop@10:3", "garbage@20:30", "reset@30", "checksum@40", "fields@41"))


def _parse_all(chunks):
    p = Parser()
    ev = []
    for c in chunks:
        ev += p.feed(c)
    return ev, dict(p.bad)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, len(STREAM)), max_size=20))
def test_any_split_parses_to_the_same_events(cuts):
    cuts = sorted(cuts)
    pieces = [STREAM[a:b] for a, b in zip([0] + cuts, cuts + [len(STREAM)])]
    assert _parse_all(pieces) == _parse_all([STREAM])


def test_the_reference_stream_has_what_was_injected():
    ev, bad = _parse_all([STREAM])
    assert sum(isinstance(e, Header) for e in ev) == 2
    assert len(_samples(ev)) == 60 - 3 - 3  # drop:3, and corrupt, checksum, fields lose one line each
    assert bad.pop("checksum") >= 2 and bad.pop("fields") == 1
    assert sum(bad.values()) <= 1  # the garbage line: whatever reason its random bytes give


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000), st.lists(st.integers(0, 2000), max_size=10))
def test_arbitrary_bytes_never_raise(data, cuts):
    p, a = Parser(), Assembler()
    cuts = sorted(c for c in cuts if c <= len(data))
    for lo, hi in zip([0] + cuts, cuts + [len(data)]):
        a.add(p.feed(data[lo:hi]))
    a.finish()
    assert p.bad_lines >= 0 and a.good_samples >= 0


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 59))
def test_garbage_inside_a_valid_stream_never_raises_nor_invents_samples(junk, at):
    good = _stream(n=60)
    cut = good.index(b"\n", len(format_header(META)) + at) + 1
    ev, _ = _parse_all([good[:cut] + junk + b"\n" + good[cut:]])
    clean, _ = _parse_all([good])
    got = _samples(ev)
    real = _samples(clean)
    # the junk is its own line(s): every real line survives, and nothing else appears unless a junk
    # line happens to be a valid data line (at most one per junk line)
    assert [s for s in got if s in real] == real
    assert len(got) - len(real) <= junk.count(b"\n") + 1
