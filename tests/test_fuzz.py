"""Fuzzed readers: recordings (CSV in every layout, torchtea's own format), ROS bags cut and damaged, datasheets and
check.json files — whatever the bytes, the reader returns a recording (or document) or raises torchtea's own error
naming the input; no other exception and no numpy warning. And what a reader accepts it reads whole: a table written
in any layout reads back to the same numbers.

Each property runs on 50 inputs in the quick suite (`[quick]`) and on 3000 in the slow one (`[long]`:
``pytest -m slow tests/test_fuzz.py``), inputs hypothesis rejects as invalid not counted."""
from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from torchtea.sensors.io import InputError, read_recording
from torchtea.sensors.measurements import prepare

#: Each property runs on a bounded number of inputs in the quick suite and on many more in the slow one.
EXAMPLES = pytest.mark.parametrize("examples", [pytest.param(50, id="quick"),
                                                pytest.param(3000, id="long", marks=pytest.mark.slow)])


def _fuzz(examples: int, body, **strategies) -> None:
    """``body(**drawn)`` on ``examples`` inputs drawn from ``strategies`` (derandomised, as every property here)."""
    settings(max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.too_slow])(
        given(**strategies)(body))()


NAMES = ["t", "time", "time_ns", "ax", "ay", "az", "gx", "gy", "gz", "acc_x", "gyro_z", "temp", "x", "", "a b",
         '"ax"', "ax;ay", "Fs", "100", "#c", "é"]
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(2 ** 40), 2 ** 40).map(str),
    st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e308", "-1e400", "1e-320", "0", "0,5", '"1.5"', "x", "--",
                     "1.2.3", " 7 ", "0x10", "١٢"]),
    st.text(alphabet="0123456789.,;-+eE \t\"'#", max_size=6),
)
SEPS = [",", "\t", ";", " ", "|"]


def _raises_only_own(call):
    """``call()`` under warnings as errors: its result, or None where it raised torchtea's own InputError."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            return call()
        except InputError as exc:
            assert str(exc).strip(), "an error without words"
            return None


@st.composite
def csv_texts(draw):
    header = draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=8))
    width = len(header)
    rows = draw(st.lists(st.lists(CELLS, min_size=max(0, width - 1), max_size=width + 1), max_size=30))
    sep = draw(st.sampled_from(SEPS))
    eol = draw(st.sampled_from(["\n", "\r\n"]))
    lines = [sep.join(header)] + [sep.join(r) for r in rows]
    if draw(st.booleans()):
        lines.insert(0, "Fs,100")
    for _ in range(draw(st.integers(0, 3))):
        lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from(["", "# note", "   "])))
    text = ("\ufeff" if draw(st.booleans()) else "") + eol.join(lines) + eol
    data = text.encode("utf-8")
    if draw(st.booleans()):
        data = data[:draw(st.integers(0, len(data)))]
    if draw(st.integers(0, 4)) == 0:
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(max_size=8)) + data[at:]
    return data


READ_FLAGS = st.fixed_dictionaries({
    "units": st.sampled_from([None, "g", "deg/s", "ms2", "g,g,g,deg/s,deg/s,deg/s", "counts", "rad/s,g"]),
    "rate_hz": st.sampled_from([None, 100.0]),
    "columns": st.sampled_from([None, ["ax"], ["x"], ["ax", "gz"]]),
})


def _read_any_csv(tmp_path, data, flags, allow_missing):
    path = tmp_path / "fuzz.csv"
    path.write_bytes(data)
    rec = _raises_only_own(lambda: read_recording(path, **flags))
    if rec is None:
        return
    assert all(len(c.values) == rec.samples and c.values.dtype == np.float64 for c in rec.channels)
    m = _raises_only_own(lambda: prepare(rec, allow_missing=allow_missing))
    if m is None:
        return
    for c in m.channels:  # what is not a measurement is missing, never infinite
        assert not np.isinf(c.values).any()
        assert len(c.values) == m.samples
    m.describe()
    m.notes()


@EXAMPLES
def test_any_csv_reads_or_is_one_own_error(tmp_path, examples):
    _fuzz(examples, lambda data, flags, allow_missing: _read_any_csv(tmp_path, data, flags, allow_missing),
          data=csv_texts(), flags=READ_FLAGS, allow_missing=st.booleans())


@st.composite
def tables(draw):
    n = draw(st.integers(2, 25))
    k = draw(st.integers(1, 4))
    finite = st.floats(-1e5, 1e5, allow_nan=False, allow_infinity=False)
    values = np.array(draw(st.lists(st.lists(finite, min_size=k, max_size=k), min_size=n, max_size=n)))
    layout = draw(st.sampled_from([(",", "."), ("\t", "."), (";", "."), (" ", "."), ("  ", "."), (";", ","),
                                   ("\t", ",")]))
    return values, layout, draw(st.booleans()), draw(st.sampled_from(["\n", "\r\n"])), draw(st.booleans())


def _round_trip(tmp_path, case):
    values, (sep, decimal), bom, eol, quote = case
    names = ["ax", "ay", "az", "gx"][:values.shape[1]]
    head = sep.join(f'"{c}"' if quote else c for c in ["t", *names])
    rows = [sep.join(repr(float(v)).replace(".", decimal) for v in (1.0 + i / 100.0, *row)) for i, row in enumerate(values)]
    path = tmp_path / "table.csv"
    path.write_bytes((("\ufeff" if bom else "") + eol.join([head, *rows]) + eol).encode())
    rec = read_recording(path, units="ms2" if values.shape[1] < 4 else "ms2,ms2,ms2,rad/s")
    assert rec.samples == len(values)
    for j, c in enumerate(rec.channels):
        assert np.array_equal(c.values, values[:, j]), (sep, decimal)


@EXAMPLES
def test_a_table_in_any_layout_reads_back_whole(tmp_path, examples):
    _fuzz(examples, lambda case: _round_trip(tmp_path, case), case=tables())


def _recorder_file(n=400):
    rows = ["# torchtea-recording 1", "# units", "segment,counter,t_s,ax,ay,az,gx,gy,gz,temp",
            '# segment 0: {"rate_hz": "100", "accel_lsb_per_g": "4096", "gyro_lsb_per_dps": "131"}']
    rng = np.random.default_rng(3)
    for k in range(n):
        v = rng.normal(0, 1e-2, 6)
        rows.append(",".join(["0", str(k), f"{k / 100:.2f}", *(f"{x:.6f}" for x in v), "25.0"]))
    return ("\n".join(rows) + "\n").encode()


RECORDER = _recorder_file()


@st.composite
def damaged(draw, good: bytes):
    data = bytearray(good)
    for _ in range(draw(st.integers(1, 4))):
        how = draw(st.sampled_from(["cut", "junk", "flip", "drop"]))
        at = draw(st.integers(0, max(0, len(data) - 1)))
        if how == "cut":
            del data[at:]
        elif how == "junk":
            data[at:at] = draw(st.binary(min_size=1, max_size=40))
        elif how == "flip" and data:
            data[at] = draw(st.integers(0, 255))
        else:
            del data[at:at + draw(st.integers(1, 200))]
    return bytes(data)


def _read_recorder(tmp_path, data):
    path = tmp_path / "rec.csv"
    path.write_bytes(data)
    rec = _raises_only_own(lambda: read_recording(path))
    if rec is not None:
        _raises_only_own(lambda: prepare(rec, allow_missing=True))


@EXAMPLES
def test_a_damaged_torchtea_recording_reads_or_is_one_own_error(tmp_path, examples):
    _fuzz(examples, lambda data: _read_recorder(tmp_path, data), data=damaged(RECORDER))


# --------------------------------------------------------------------------- bags written with rosbags, then damaged


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    pytest.importorskip("rosbags")
    from .test_bags import _data, write_bag

    root = tmp_path_factory.mktemp("bags")
    t_ns, acc, gyr, temp = _data(300)
    out = {"ros1": write_bag(root / "imu.bag", "ros1", t_ns, acc, gyr, temp).read_bytes()}
    folder = write_bag(root / "imu_mcap", "mcap", t_ns, acc, gyr, temp)
    out["mcap"] = next(folder.glob("*.mcap")).read_bytes()
    return out


def _read_bag(tmp_path, kind, data):
    path = tmp_path / ("fuzz.bag" if kind == "ros1" else "fuzz.mcap")
    path.write_bytes(data)
    rec = _raises_only_own(lambda: read_recording(path))
    if rec is not None:
        assert all(len(c.values) == rec.samples for c in rec.channels)
        _raises_only_own(lambda: prepare(rec, allow_missing=True))


@EXAMPLES
def test_a_damaged_bag_reads_or_is_one_own_error(tmp_path, bags, examples):
    _fuzz(examples, lambda kind, data: _read_bag(tmp_path, kind, data.draw(damaged(bags[kind]))),
          kind=st.sampled_from(["ros1", "mcap"]), data=st.data())


# --------------------------------------------------------------------------- datasheets and check.json read back

TOML_VALUES = st.recursive(
    st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10 ** 6, 10 ** 6), st.booleans(),
              st.sampled_from(["gyroscope", "accelerometer", "deg/sqrt(h)", "deg/h", "m/s/sqrt(h)", "ug", "x",
                               "allan-minimum", "ieee952", ""])),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.sampled_from(["value", "unit", "convention", "source"]), inner,
                                            max_size=4)),
    max_leaves=8)
SHEET_KEYS = st.sampled_from(["sensor", "rate_hz", "N", "B", "K", "repeatability", "source", "other"])


def _toml(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return "{" + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + "}"


@st.composite
def sheets(draw):
    if draw(st.integers(0, 5)) == 0:
        return draw(st.binary(max_size=200))
    doc = draw(st.dictionaries(SHEET_KEYS, TOML_VALUES, max_size=7))
    if draw(st.booleans()):
        doc.update(sensor=draw(st.sampled_from(["gyroscope", "accelerometer"])), rate_hz=100)
    text = "\n".join(f"{k} = {_toml(v)}" for k, v in doc.items()) + "\n"
    return text.encode()


def _read_sheet(tmp_path, data):
    from torchtea.fitting.datasheet import read_datasheet

    path = tmp_path / "sheet.toml"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            sheet = read_datasheet(path)
        except ValueError as exc:  # (the datasheet reader's own error names the file)
            assert str(path) in str(exc)
            return
    assert sheet["sensor"] in ("gyroscope", "accelerometer") and sheet["rate_hz"] > 0
    for term in ("N", "B", "K", "repeatability"):
        assert sheet[term] is None or (isinstance(sheet[term], float) and math.isfinite(sheet[term])
                                       and sheet[term] > 0), (term, sheet[term])


@EXAMPLES
def test_any_datasheet_reads_or_is_one_error_naming_it(tmp_path, examples):
    _fuzz(examples, lambda data: _read_sheet(tmp_path, data), data=sheets())


@pytest.fixture(scope="module")
def check_json(tmp_path_factory):
    """A real check.json: `check` of a two-channel CSV with a random walk on one."""
    from torchtea.cli import main

    root = tmp_path_factory.mktemp("check")
    rng = np.random.default_rng(2)
    n = 1500
    t = np.arange(n) / 100.0
    ax = rng.normal(0, 0.01, n)
    gz = rng.normal(0, 0.001, n) + np.cumsum(rng.normal(0, 1e-4, n))
    path = root / "two.csv"
    path.write_text("t,ax,gz\n" + "\n".join(f"{a:.17g},{b:.17g},{c:.17g}" for a, b, c in zip(t, ax, gz)) + "\n")
    assert main(["check", str(path), "--units", "ms2,rad/s", "--model", "white+random-walk", "--no-plots",
                 "--out", str(root / "ck")]) == 0
    return json.loads((root / "ck" / "check.json").read_text())


JSON_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-5, 10 ** 6), st.floats(allow_nan=False),
                        st.text(max_size=8), st.builds(list), st.builds(dict), st.builds(lambda: [1.0, 2.0]))


@st.composite
def mutated_checks(draw, doc):
    doc = json.loads(json.dumps(doc))
    for _ in range(draw(st.integers(1, 4))):
        node, key = doc, None
        for _ in range(draw(st.integers(0, 5))):  # walk down to a random entry
            keys = list(node) if isinstance(node, dict) else list(range(len(node))) if isinstance(node, list) else []
            if not keys:
                break
            key = draw(st.sampled_from(keys))
            if not isinstance(node[key], (dict, list)):
                break
            node = node[key]
        keys = list(node) if isinstance(node, dict) else list(range(len(node))) if isinstance(node, list) else []
        if keys:
            key = draw(st.sampled_from(keys))
            if draw(st.booleans()) and isinstance(node, dict):
                del node[key]
            else:
                node[key] = draw(JSON_VALUES)
    text = json.dumps(doc).encode()
    if draw(st.integers(0, 5)) == 0:
        text = text[:draw(st.integers(0, len(text)))]
    return text


def _read_check(tmp_path, data):
    from torchtea.checking.results import read_check

    path = tmp_path / "check.json"
    path.write_bytes(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            doc, fits = read_check(path)
        except ValueError as exc:
            assert str(path) in str(exc)
            return
    assert isinstance(doc, dict) and all(hasattr(f, "values") for f in fits.values())


@EXAMPLES
def test_a_damaged_check_json_reads_or_is_one_error_naming_it(tmp_path, check_json, examples):
    _fuzz(examples, lambda data: _read_check(tmp_path, data), data=mutated_checks(check_json))


@pytest.mark.slow
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_plan_from_a_damaged_check_json_is_a_plan_or_one_line(tmp_path, check_json, data, capsys):
    """What reads a check.json further — `plan --from-check` — on a damaged one: exit 0 or one error line (2),
    never a traceback."""
    from torchtea.cli import main

    path = tmp_path / "check.json"
    path.write_bytes(data.draw(mutated_checks(check_json)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code = main(["plan", "--from-check", str(path), "--target", "K=50%", "--json"])
    err = capsys.readouterr().err
    assert code in (0, 2) and "Traceback" not in err, err
    if code == 2:
        assert err.count("torchtea: error:") == 1
