"""One way to read a recording on every command: columns, units, sensors, time columns, a torchtea recording's
six channels — and a recording's own faults found at their place before anything is fitted."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torchtea.cli import main
from torchtea.noise import default_values, parse_model, simulate_model, temperature_profile
from torchtea.sensors.faults import find_faults, stuck_min_run
from torchtea.sensors.io import InputError, parse_units, read_recording, sensor_of
from torchtea.sensors.measurements import prepare

H = 0.01
G0 = 9.80665
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "mpu6050_sensor_fusion_temperature"
SIX = ("acc_x", "acc_y", "acc_z", "gyro_x", "gyro_y", "gyro_z")


def run(*argv):
    return main([str(a) for a in argv])


def six_axis(n=1500, seed=0):
    """``(t, acc (n, 3) in m/s², gyro (n, 3) in rad/s, temperature)``: fractional+white noise on six channels,
    gravity on z, a gyroscope bias, a warming temperature."""
    m = parse_model("fractional+white")
    gen = torch.Generator().manual_seed(seed)
    T = temperature_profile(n, H, generator=gen).numpy()
    v = default_values(m, H)
    y = simulate_model(m, v, n_steps=n, h=H, realisations=6, generator=gen)[0].numpy().T  # (n, 6)
    acc = y[:, :3] + np.array([0.0, 0.0, G0])
    gyro = y[:, 3:] * 0.05 + np.array([0.01, -0.02, 0.005])
    return np.arange(n) * H, acc, gyro, T


def write_csv(path, header, columns):
    rows = "\n".join(",".join(repr(float(v)) for v in row) for row in np.column_stack(columns))
    path.write_text(",".join(header) + "\n" + rows + "\n")
    return path


def six_axis_csv(tmp_path, n=1500, *, gyro_unit="deg/s", name="imu.csv", time_name="t", time_scale=1.0):
    t, acc, gyro, T = six_axis(n)
    gy = gyro * 180 / math.pi if gyro_unit == "deg/s" else gyro
    return write_csv(tmp_path / name, (time_name,) + SIX + ("temp",), [t * time_scale, acc / G0, gy, T])


# --------------------------------------------------------------------------- names and units


@pytest.mark.parametrize("name, expect", [
    ("ax", ("accelerometer", "x")), ("acc_y", ("accelerometer", "y")), ("accel_z", ("accelerometer", "z")),
    ("field.linear_acceleration.x", ("accelerometer", "x")), ("AccX", ("accelerometer", "x")),
    ("gx", ("gyroscope", "x")), ("gyro_y", ("gyroscope", "y")), ("gyr_z", ("gyroscope", "z")),
    ("angular_velocity.z", ("gyroscope", "z")), ("wx", ("gyroscope", "x")),
    ("t", None), ("temp", None), ("y", None), ("time", None), ("counter", None)])
def test_sensor_from_a_column_name(name, expect):
    assert sensor_of(name) == expect


def test_units_one_for_all_or_one_per_column():
    assert parse_units(None, ["a", "b"]) == [None, None]
    assert parse_units("g", ["a", "b", "c"]) == ["g"] * 3
    assert parse_units("g,g,deg/s", ["a", "b", "c"]) == ["g", "g", "deg/s"]
    with pytest.raises(ValueError, match="unknown unit 'furlong'"):
        parse_units("g,furlong", ["a", "b"])
    with pytest.raises(ValueError, match="2 units for 3 columns"):
        parse_units("g,g", ["a", "b", "c"])


def test_every_format_gives_si_channels(tmp_path):
    """The bundled file in counts (±2 g, ±250 °/s), a generic CSV in g and °/s, and the same in m/s² and rad/s give
    the same channels; a torchtea recording gives its six channels and its temperature."""
    b = read_recording()
    assert [c.label for c in b.channels] == ["ax", "ay", "az", "gx", "gy", "gz"]
    assert b.channels[0].values[0] == pytest.approx(2508 / 16384 * G0, rel=1e-15)
    assert b.channels[3].values[0] == pytest.approx(-429 / 131 * math.pi / 180, rel=1e-15)
    assert b.channels[3].unit == "rad/s" and b.channels[3].full_scale == (-32768.0, 32767.0)
    f1 = six_axis_csv(tmp_path, 200)
    f2 = six_axis_csv(tmp_path, 200, gyro_unit="rad/s", name="rad.csv")
    r1 = read_recording(f1, units="g,g,g,deg/s,deg/s,deg/s", temperature_column="temp")
    r2 = read_recording(f2, units="g,g,g,rad/s,rad/s,rad/s", temperature_column="temp")
    for c1, c2 in zip(r1.channels, r2.channels):
        assert c1.label == c2.label and c1.unit == c2.unit
        np.testing.assert_allclose(c1.values, c2.values, rtol=1e-14, atol=1e-18)
    assert r1.channels[4].source_unit == "°/s" and r2.channels[4].source_unit == "rad/s"
    assert r1.temperature is not None and r1.time_column == "t"
    # a torchtea recording: m/s², rad/s and temp, whatever is asked
    rows = ["# torchtea-recording 1", "# units", "segment,counter,t_s,ax,ay,az,gx,gy,gz,temp",
            '# segment 0: {"rate_hz": "100", "accel_lsb_per_g": "4096", "gyro_lsb_per_dps": "131"}']
    for k in range(150):
        counts = np.array([k % 7 - 3, 5, 4096 + k % 3, -2, k % 5, 1])
        vals = np.concatenate([counts[:3] * G0 / 4096, counts[3:] * math.pi / 180 / 131])
        rows.append(f"0,{k},{k * 0.01!r}," + ",".join(repr(float(v)) for v in vals) + ",25.5")
    (tmp_path / "rec.csv").write_text("\n".join(rows) + "\n")
    rec = read_recording(tmp_path / "rec.csv")
    assert [c.label for c in rec.channels] == ["ax", "ay", "az", "gx", "gy", "gz"]
    assert rec.temperature_column == "temp" and float(rec.temperature[0]) == 25.5
    assert rec.gyro_counts[:3, 1].tolist() == [0.0, 1.0, 2.0]  # the counts come back exactly
    with pytest.raises(InputError, match="leave out --units"):
        read_recording(tmp_path / "rec.csv", units="g")


def test_time_columns_by_their_usual_names(tmp_path):
    """``stamp`` in seconds, ROS's ``%time`` in nanoseconds, ``timestamp_us`` in microseconds: the rate comes out
    at 100 Hz from each."""
    for name, scale in (("stamp", 1.0), ("%time", 1e9), ("timestamp_us", 1e6), ("time", 1.0)):
        f = six_axis_csv(tmp_path, 300, name=f"{name.strip('%')}.csv", time_name=name, time_scale=scale)
        rec = read_recording(f, units="g,g,g,deg/s,deg/s,deg/s")
        assert rec.time_column == name and rec.rate_hz == pytest.approx(100.0, rel=1e-9), name
        assert ("time_unit" in rec.metadata) == (scale != 1.0)


def test_bad_units_are_one_line_each(tmp_path, capsys):
    f = six_axis_csv(tmp_path, 300)
    for units, needle in (("furlong", "unknown unit 'furlong'"), ("g,g", "2 units for 6 columns"),
                          ("g", "looks like a gyroscope axis but --units says g"),
                          ("counts", "the scale is not known: give --lsb-per-g")):
        assert run("fit", f, "--units", units, "--bootstrap", 0) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1, err


# --------------------------------------------------------------------------- every command, one column and six


def test_gyro_in_degrees_and_in_radians_give_the_same_numbers(tmp_path, capsys):
    """The same gyroscope data written in °/s and in rad/s: the fits are the same, in rad/s."""
    docs = []
    for unit, name in (("deg/s", "deg.csv"), ("rad/s", "rad.csv")):
        f = six_axis_csv(tmp_path, 4000, gyro_unit=unit, name=name)
        assert run("fit", f, "--columns", "gyro_x,gyro_y", "--units", unit, "--bootstrap", 0, "--json") == 0
        docs.append(json.loads(capsys.readouterr().out))
    for a in ("gx", "gy"):
        p0, p1 = docs[0]["axes"][a], docs[1]["axes"][a]
        assert p0["unit"] == p1["unit"] == "rad/s"
        # the two files differ by the rounding of their decimal values (1e-16 relative), which moves the optimiser's
        # stopping point by far less than a standard error: ℓ to 1e-3 nats, each parameter to 1 % of its se
        assert p0["loglik"] == pytest.approx(p1["loglik"], abs=1e-3)
        for k, v in p0["parameters"].items():
            tol = 0.01 * v["se"] if v["se"] else 1e-4 * abs(v["value"])  # no se: a flat likelihood
            assert abs(v["value"] - p1["parameters"][k]["value"]) <= tol, (a, k, v, p1["parameters"][k])
    # and not in °/s: r in (rad/s)², (π/180)² of what the same data in °/s would give
    r_deg = (0.05 * 180 / math.pi) ** 2 * default_values(parse_model("fractional+white"), H)["white.r"]
    assert docs[0]["axes"]["gx"]["parameters"]["white.r"]["value"] < r_deg * (math.pi / 180) ** 2 * 3


@pytest.mark.slow
def test_one_column_and_six_on_every_command(tmp_path, capsys):
    f = six_axis_csv(tmp_path, 1500)
    units = "g,g,g,deg/s,deg/s,deg/s"
    six = ("ax", "ay", "az", "gx", "gy", "gz")
    cases = (("identify", ["--no-plots", "--samples", "all", "--r", "measured"]), ("fit", ["--bootstrap", 0]),
             ("check", ["--no-plots", "--no-intervals"]))
    for cmd, extra in cases:
        for columns, unit, labels in ((",".join(SIX), units, six), ("gyro_z", "deg/s", ("gz",))):
            assert run(cmd, f, "--columns", columns, "--units", unit, "--json", "--out", tmp_path / cmd, *extra) == 0
            out = json.loads(capsys.readouterr().out)
            assert list(out["axes"]) == list(labels), cmd
            for a in labels:
                assert out["axes"][a]["unit"] == ("m/s²" if a[0] == "a" else "rad/s"), (cmd, a)
            assert out["channels"]["gz"]["file_unit"] == "°/s"


@pytest.mark.slow
def test_check_reports_the_two_sensors_side_by_side(tmp_path, capsys):
    f = six_axis_csv(tmp_path, 1500)
    assert run("check", f, "--units", "g,g,g,deg/s,deg/s,deg/s", "--no-intervals", "--out", tmp_path / "ck") == 0
    out = capsys.readouterr().out
    report = (tmp_path / "ck" / "report.md").read_text()
    assert "## Summary, the sensors side by side" in report
    table = report.split("## Summary, the sensors side by side")[1].split("\n## ")[0]
    rows = [ln for ln in table.splitlines() if ln.startswith("| accelerometer") or ln.startswith("| gyroscope")]
    assert [r.split("|")[2].strip() for r in rows] == ["ax", "ay", "az", "gx", "gy", "gz"]
    assert all("| m/s² |" in r for r in rows[:3]) and all("| rad/s |" in r for r in rows[3:])
    assert "## gz: gyroscope z (rad/s, column `gyro_z`)" in report
    assert "Allan deviation (rad/s)" not in report  # figures carry it, not the text
    assert "gz (gyroscope z (rad/s))" in out and "units: accelerometer: m/s²; gyroscope: rad/s" in out


# --------------------------------------------------------------------------- faults of the recording


def _channels(tmp_path, n=3000, **kw):
    f = six_axis_csv(tmp_path, n, **kw)
    return read_recording(f, units="g,g,g,deg/s,deg/s,deg/s", temperature_column="temp")


def test_a_clean_recording_has_no_fault(tmp_path):
    rec = _channels(tmp_path)
    assert not find_faults(rec.channels, h=rec.h, temperature=rec.temperature, time_s=rec.time_s)
    b = read_recording()  # the bundled recording, counts at ±2 g
    assert not find_faults(b.channels, h=b.h)


@pytest.mark.skipif(not SHARED.exists(), reason="shared/data not beside the checkout")
def test_the_shared_real_recordings_have_no_fault():
    """Bursty host stamps (intervals up to 0.25 s), a temperature quantised at 0.094 °C that moves by up to
    0.28 °C between samples, MPU-6050 counts in g and °/s: all normal, none a fault."""
    for name in ("unmoved_x_forward.csv", "unmoved_z_front_x_up.csv"):
        rec = read_recording(SHARED / name, units="g,g,g,deg/s,deg/s,deg/s", rate_hz=100.0, temperature_column="temp")
        assert len(rec.channels) == 6
        faults = find_faults(rec.channels, h=rec.h, temperature=rec.temperature, time_s=rec.time_s)
        assert not faults, faults.lines()


def test_each_fault_is_found_at_its_place(tmp_path):
    f = six_axis_csv(tmp_path, 3000)
    lines = f.read_text().splitlines()
    header, rows = lines[0], [ln.split(",") for ln in lines[1:]]
    for k in range(2280, 3000):  # a zero-filled tail: every column, the time and the temperature too
        rows[k] = ["0"] * len(rows[k])
    for k in range(1000, 1040):  # the gyroscope stuck: its three channels repeat sample 999
        rows[k][4:7] = rows[999][4:7]
    rows[1500][2] = rows[1501][2] = rows[1502][2] = repr(2.0)  # a value the scale's full range would clip …
    for k in range(1700, 1720):
        rows[k][7] = repr(float(rows[k][7]) + 12.0)  # a temperature that jumps by 12 °C and back
    for k in range(600, 2280):
        rows[k][0] = repr(float(rows[k][0]) + 3.0)  # the clock jumps by 3 s at sample 600
    f.write_text("\n".join([header] + [",".join(r) for r in rows]) + "\n")
    rec = read_recording(f, units="g,g,g,deg/s,deg/s,deg/s", temperature_column="temp", rate_hz=100)
    faults = find_faults(rec.channels, h=rec.h, temperature=rec.temperature, time_s=rec.time_s)
    kinds = {x.kind: x for x in faults.items}
    assert kinds["zero rows"].ranges == [[2280, 2999]] and kinds["zero rows"].count == 720
    assert kinds["stuck"].ranges == [[999, 1039]] and kinds["stuck"].channels == ("gx", "gy", "gz")
    assert [1700, 1700] in kinds["temperature step"].ranges and [1720, 1720] in kinds["temperature step"].ranges
    # 3 s forward at 600; the zero rows' stamps are no clock (ignored as they are read, issue 44): no second jump
    assert kinds["time jump"].ranges == [[600, 600]]
    assert np.isnan(rec.time_s[2280:]).all() and "2280" not in str(kinds["time jump"].ranges)
    assert "clipping" not in kinds  # g of unknown full scale: three samples are not a pile-up
    assert faults.imu_rows[2280:].all() and faults.imu_rows[999:1040].all() and not faults.imu_rows[:999].any()
    assert faults.masks["gx"][999:1040].all() and not faults.masks["ax"][999:1040].any()
    assert faults.temperature_rows[1700] and faults.temperature_rows[2500]
    # at a known full scale (the bundled format's 16-bit counts), clipping is found where it is
    b = read_recording()
    raw = b.channels[2].raw.copy()
    raw[[100, 101, 5000]] = 32767
    clipped = (b.channels[2].with_values(raw * b.channels[2].scale),)
    c = find_faults(clipped, h=b.h)
    assert c.items[0].kind == "clipping" and c.items[0].ranges == [[100, 101], [5000, 5000]]
    # where the full scale is unknown, a pile-up at an extreme is clipping
    x = rec.channels[0].values[:2000].copy()
    top = np.quantile(x, 0.98)
    piled = rec.channels[0].with_values(np.where(x > top, top, x))  # 2 % of the samples flattened at the top
    p = find_faults((piled,), h=rec.h)
    assert p.items[0].kind == "clipping" and p.items[0].count == int(np.sum(x >= top))


def test_stuck_threshold_follows_the_repetition_rate():
    assert stuck_min_run(0.0, 10_000) == 8
    assert stuck_min_run(0.5, 10_000) == math.ceil(1 + math.log(1e-3 / 10_000) / math.log(0.5))  # 25
    assert stuck_min_run(1.0, 100) == 101


def test_a_fault_stops_the_run_or_becomes_missing_never_physics(tmp_path, capsys):
    """Zero-filled rows inside the record (every channel and the temperature, as in a real recording): the check
    stops with one line naming the fault and --allow-missing; with it, the rows are missing samples, the temperature
    there is interpolated, and no temperature effect is suggested (such rows were once explained as a temperature
    bias, ΔBIC 17 590)."""
    f = six_axis_csv(tmp_path, 3000)
    lines = f.read_text().splitlines()
    f.write_text("\n".join(lines[:2001] + [",".join(["0"] * 8)] * 280 + lines[2281:]) + "\n")
    common = ["check", f, "--columns", "acc_x", "--units", "g", "--temperature", "temp", "--rate", 100,
              "--no-plots", "--no-intervals", "--out", tmp_path / "ck"]
    assert run(*common) == 2
    err = capsys.readouterr().err
    assert err.count("torchtea: error:") == 1 and "--allow-missing" in err and "exactly 0 in every channel" in err
    assert run(*common, "--allow-missing", "--json") == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert doc["faults"]["found"][0]["kind"] == "zero rows" and doc["faults"]["found"][0]["ranges"] == [[2000, 2279]]
    assert doc["missing_samples"] == 280 and "recording fault" in cap.err and doc["zero_tail"] is None
    assert not any(s["effect"].startswith("temperature") for s in doc["suggestions"])
    report = (tmp_path / "ck" / "report.md").read_text()
    assert "Recording faults" in report and "zero rows" in report


def test_a_zero_filled_tail_is_cut_with_a_note(tmp_path, capsys):
    """The last rows 0 in every column (a logger that zero-filled what it did not receive, at the end): cut, said
    on stderr and in the JSON, the run needing no --allow-missing; the fit is the fit of the record without them."""
    f = six_axis_csv(tmp_path, 3000)
    lines = f.read_text().splitlines()
    f.write_text("\n".join(lines[:2721] + [",".join(["0"] * 8)] * 280) + "\n")
    common = ["fit", f, "--columns", "acc_x", "--units", "g", "--temperature", "temp", "--rate", 100, "--model",
              "white", "--json"]
    assert run(*common) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert doc["samples"] == 2720 and doc["samples_in_recording"] == 3000 and doc["missing_samples"] == 0
    assert doc["zero_tail"]["first"] == 2720 and doc["zero_tail"]["rows"] == 280
    assert "the last 280 rows" in cap.err and "cut" in cap.err
    f.write_text("\n".join(lines[:2721]) + "\n")
    assert run(*common) == 0
    whole = json.loads(capsys.readouterr().out)
    assert whole["zero_tail"] is None and whole["axes"]["ax"]["loglik"] == doc["axes"]["ax"]["loglik"]


def test_prepare_names_the_faults_in_its_error(tmp_path):
    rec = _channels(tmp_path, 1200)

    def stuck(c):
        v = c.values.copy()
        v[200:260] = v[199]
        return c.with_values(v)

    rec2 = type(rec)(rec.path, rec.rate_hz, tuple(stuck(c) if c.sensor == "gyroscope" else c for c in rec.channels),
                     rec.metadata)
    with pytest.raises(InputError, match="made missing by the recording's faults") as e:
        prepare(rec2)
    assert "--allow-missing" in str(e.value)
    m = prepare(rec2, allow_missing=True)
    assert m.faults.items[0].kind == "stuck" and np.isnan(m.channel("gx").values[199:260]).all()
    assert not np.isnan(m.channel("ax").values).any()  # the accelerometer is not stuck: its samples stay
    assert m.missing.count == 61 and m.missing.per_column["gz"] == 61 and m.missing.per_column["ay"] == 0


# --------------------------------------------------------------------------- stretches left out (issue 44, item 6)


def test_exclude_makes_a_stretch_missing_or_cuts_it_at_the_end(tmp_path):
    """``prepare(exclude=…)``: the samples k with FROM ≤ k h ≤ TO become missing in every channel without
    --allow-missing (they were asked for); a stretch that reaches the end is cut (the same likelihood, the series stays
    complete); both are in the JSON description and the notes; a stretch outside the series is one error naming it."""
    path = six_axis_csv(tmp_path, n=1500)
    rec = read_recording(path, units="g,g,g,deg/s,deg/s,deg/s", temperature_column="temp")
    m = prepare(rec, exclude=[(2.0, 3.005), (14.0, 20.0)])
    ax = m.channel("ax").values
    assert np.isnan(ax[200:301]).all() and np.isfinite(ax[:200]).all() and np.isfinite(ax[301:]).all()
    assert m.samples == 1400  # 14.00 s on: cut
    desc = m.describe()["excluded"]
    assert [(e["first"], e["last"], e["cut"]) for e in desc] == [(200, 300, False), (1400, 1499, True)]
    assert any("--exclude 2:3.005" in line and "made missing" in line for line in m.notes())
    assert m.missing.count == 101
    with pytest.raises(InputError, match=r"--exclude 30:40: no sample there"):
        prepare(rec, exclude=[(30.0, 40.0)])
    with pytest.raises(InputError, match="FROM < TO"):
        prepare(rec, exclude=[(5.0, 4.0)])


def test_exclude_on_every_command_that_reads_a_recording(tmp_path, capsys):
    """--exclude is a flag of fit, check, export, identify and estimate; its stretch is in each command's JSON."""
    path = six_axis_csv(tmp_path, n=3000)
    common = ("--exclude", "5:6")
    assert run("fit", path, "--columns", "acc_x", "--units", "g", *common, "--bootstrap", 0, "--out", tmp_path / "fit.json") == 0
    assert json.loads((tmp_path / "fit.json").read_text())["excluded"][0]["samples"] == 101
    assert run("check", path, "--columns", "gyro_x", "--units", "deg/s", *common, "--no-plots", "--no-intervals", "--out",
               tmp_path / "ck") == 0
    doc = json.loads((tmp_path / "ck" / "check.json").read_text())
    assert doc["excluded"][0]["first"] == 500 and doc["missing_samples"] == 101
    assert run("identify", path, "--columns", "acc_x", "--units", "g", *common, "--samples", 3000, "--no-plots", "--json", "--out",
               tmp_path / "id") == 0
    assert json.loads((tmp_path / "id" / "summary.json").read_text())["excluded"][0]["last"] == 600
    assert run("export", path, "--columns", "acc_x", "--units", "g", *common, "--model", "fractional+white", "--format", "ieee952",
               "--no-plots", "--nees", 4, "--out", tmp_path / "ex") == 0
    sim = tmp_path / "sim.csv"
    assert run("simulate", "--n", 2000, "--h", 0.01, "--order", 0.3, "--param", -1, "--q", 1e-4, "--r", 1e-3,
               "--out", sim) == 0
    capsys.readouterr()
    assert run("estimate", sim, "--exclude", "3:4", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["excluded"][0]["samples"] == 101
    assert run("check", path, "--columns", "gyro_x", "--exclude", "9:8", "--out", tmp_path / "bad") == 2


def test_zero_rows_are_found_before_the_stamps_are_read(tmp_path, capsys):
    """A recording whose last rows are 0 in every column, its time column too (a logger's zero fill): the stamps of
    those rows are ignored, so the rate comes from the rest, and the rows are the logging fault they are (a tail:
    cut) — without --rate."""
    t, acc, gyro, T = six_axis(2000)
    cols = [t, acc / G0, gyro * 180 / math.pi, T]
    data = np.column_stack(cols)
    data[-300:] = 0.0
    path = write_csv(tmp_path / "zeros.csv", ("sec",) + SIX + ("temp",), [data[:, i] for i in range(data.shape[1])])
    rec = read_recording(path, units="g,g,g,deg/s,deg/s,deg/s", temperature_column="temp")
    assert rec.rate_hz == pytest.approx(100.0, rel=1e-6)
    assert "ignored" in rec.metadata["time_zero_rows"]
    six = ("--units", "g,g,g,deg/s,deg/s,deg/s", "--temperature", "temp", "--bootstrap", 0)
    assert run("fit", path, *six) == 0  # (at the end: cut, with a note)
    assert "zero-filled tail" in capsys.readouterr().err
    assert run("fit", path, *six, "--exclude", "17:20", "--json") == 0
