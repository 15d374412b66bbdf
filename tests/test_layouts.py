"""The text layouts people's recordings have (separators, a byte-order mark, quoted cells, CRLF, decimal commas),
units given in the file's column order, and damaged values named as the recording's faults — with no numpy warning
on the way."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from torchtea.cli import main
from torchtea.sensors.io import InputError, read_recording
from torchtea.sensors.measurements import prepare

N = 1200


def _table(seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / 100.0
    acc = rng.normal(0.0, 0.01, (N, 3)) + [0.0, 0.0, 1.0]
    gyro = rng.normal(0.0, 0.05, (N, 3))
    return t, acc, gyro


def _write(path, header, rows, *, sep=",", decimal=".", bom=False, quote=False, eol="\n"):
    def cell(x):
        return f"{x:.6f}".replace(".", decimal) if isinstance(x, float) else str(x)

    names = [f'"{h}"' if quote else h for h in header]
    text = sep.join(names) + eol + "".join(sep.join(cell(float(v)) for v in r) + eol for r in rows)
    path.write_text(("\ufeff" if bom else "") + text, encoding="utf-8", newline="")
    return path


@pytest.mark.parametrize("layout", [
    dict(sep="\t"), dict(sep=";"), dict(sep=";", decimal=","), dict(sep="  "), dict(sep=" ", eol="\r\n"),
    dict(sep=",", bom=True, quote=True, eol="\r\n"), dict(sep="\t", decimal=",", bom=True),
])
def test_every_layout_reads_the_same_numbers(tmp_path, layout):
    t, acc, _ = _table()
    rows = np.column_stack([t, acc])
    ref = read_recording(_write(tmp_path / "ref.csv", ("t", "ax", "ay", "az"), rows), units="g")
    rec = read_recording(_write(tmp_path / "x.csv", ("t", "ax", "ay", "az"), rows, **layout), units="g")
    for a, b in zip(ref.channels, rec.channels):
        assert a.label == b.label and np.array_equal(a.values, b.values)
    assert rec.rate_hz == ref.rate_hz and np.array_equal(rec.time_s, ref.time_s)
    if layout["sep"] == ",":
        assert "layout" not in rec.metadata  # (commas, the usual: nothing said)
    else:
        said = rec.metadata["layout"]
        assert {"\t": "tab", ";": "semicolon"}.get(layout["sep"], "whitespace") + "-separated" in said
        assert ("decimal commas" in said) == (layout.get("decimal") == ",")


def test_the_separator_is_said_and_a_ragged_row_is_named_in_its_layout(tmp_path, capsys):
    t, acc, _ = _table()
    f = _write(tmp_path / "semi.csv", ("t", "ax", "ay", "az"), np.column_stack([t, acc]), sep=";")
    assert main(["fit", str(f), "--units", "g", "--model", "white", "--json"]) == 0
    err = capsys.readouterr().err
    assert "read as semicolon-separated" in err and "--units read" not in err  # (one unit, the file's order: no note)
    lines = f.read_text().splitlines()
    lines[600] = lines[600] + ";1.0"
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 601: 5 fields, the header has 4 \(read as semicolon-separated\)"):
        read_recording(f, units="g")


def test_units_follow_the_files_column_order(tmp_path, capsys):
    """A log that writes the gyroscope first (t,gx,gy,gz,ax,ay,az): --units in that order is read in that order and
    the note says which unit each column got; the same units in the channels' order (ax … gz), which contradicts the
    names in the file's order, are read so (as before) and said so; --columns gives the order itself."""
    t, acc, gyro = _table()
    f = _write(tmp_path / "gfirst.csv", ("t", "gx", "gy", "gz", "ax", "ay", "az"), np.column_stack([t, gyro, acc]))
    rec = read_recording(f, units="deg/s,deg/s,deg/s,g,g,g")
    assert [c.label for c in rec.channels] == ["ax", "ay", "az", "gx", "gy", "gz"]
    assert [c.source_unit for c in rec.channels] == ["g"] * 3 + ["°/s"] * 3
    assert rec.metadata["units_read"].startswith("--units read in the order of the file's columns: gx deg/s")
    old = read_recording(f, units="g,g,g,deg/s,deg/s,deg/s")
    assert all(np.array_equal(a.values, b.values) for a, b in zip(rec.channels, old.channels))
    assert "channels' order ax … gz" in old.metadata["units_read"]
    cols = read_recording(f, columns=["gz", "ax"], units="deg/s,g")
    assert [(c.label, c.source_unit) for c in cols.channels] == [("gz", "°/s"), ("ax", "g")]
    with pytest.raises(InputError, match="looks like an accelerometer axis"):
        read_recording(f, units="deg/s,g,deg/s,g,deg/s,g")
    assert main(["fit", str(f), "--units", "deg/s,deg/s,deg/s,g,g,g", "--model", "white", "--json"]) == 0
    assert "gz deg/s, ax g" in capsys.readouterr().err


@pytest.mark.parametrize("cell, value", [("1e308", "'1e308'"), ("inf", "'inf'"), ("-inf", "'-inf'"),
                                         ("2e6", "'2e6'")])
def test_a_damaged_value_is_a_fault_named_by_line_and_column(tmp_path, capsys, cell, value):
    """A value no sensor measured (overflowing the conversion to m/s², infinite, beyond 10⁶ m/s²): a fault of the
    recording with its line, column and text; the run stops with one line (or, with --allow-missing, the sample is
    missing); no numpy warning on the way."""
    t, acc, _ = _table()
    f = _write(tmp_path / "bad.csv", ("t", "ax", "ay", "az"), np.column_stack([t, acc]))
    lines = f.read_text().splitlines()
    parts = lines[701].split(",")
    parts[2] = cell  # ay of sample 700, line 702
    lines[701] = ",".join(parts)
    f.write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(f, units="g")
        with pytest.raises(InputError) as e:
            prepare(rec)
        m = prepare(rec, allow_missing=True)
    msg = str(e.value)
    assert "sample index 700" in msg and f"line 702, column 'ay': {value}" in msg and "no sensor measured" in msg
    fault = m.faults.items[0]
    assert fault.kind == "impossible values" and fault.channels == ("ay",) and fault.ranges == [[700, 700]]
    assert np.isnan(m.channel("ay").values[700]) and np.isfinite(m.channel("ay").values[:700]).all()
    assert main(["fit", str(f), "--units", "g", "--model", "white"]) == 2
    err = capsys.readouterr().err
    assert err.count("torchtea: error:") == 1 and "Warning" not in err and "line 702" in err
    assert main(["fit", str(f), "--units", "g", "--model", "white", "--allow-missing", "--json"]) == 0
    cap = capsys.readouterr()
    assert "Warning" not in cap.err and json.loads(cap.out)["missing_samples"] == 1


def test_counts_beyond_the_formats_full_scale_are_impossible(tmp_path):
    """The bundled format's 16-bit counts: a value past −32768 … 32767 is no sample of the sensor."""
    lines = ["Fs,100", "ax,ay,az,gx,gy,gz"]
    rng = np.random.default_rng(1)
    for _ in range(1500):
        lines.append(",".join(str(int(v)) for v in rng.normal(0, 30, 6).round() + [0, 0, 16384, 0, 0, 0]))
    lines[2 + 900] = "12,40000,16390,3,4,5"
    f = tmp_path / "counts.csv"
    f.write_text("\n".join(lines) + "\n")
    m = prepare(read_recording(f), allow_missing=True)
    fault = next(x for x in m.faults.items if x.kind == "impossible values")
    assert fault.channels == ("ay",) and fault.ranges == [[900, 900]] and "line 903, column 'ay': '40000'" in \
        fault.message


def test_comments_blank_lines_a_cut_last_line_and_dates_do_not_hide_the_layout(tmp_path):
    """A logger's `#` lines and blank lines above and below the header; a short semicolon file whose last line was
    cut (a logger killed); decimal commas beside a date and a clock time written with points: read as written, the
    cut line named."""
    t, acc, _ = _table()
    rows = ["; ".join(f"{v:.6f}".replace(".", ",") for v in (t[i], *acc[i])) for i in range(30)]
    f = tmp_path / "log.csv"
    f.write_text("# logger v1\n\nt;ax;ay;az\n# started 01.02.2024 12:00:00\n" + "\n".join(rows) + "\n")
    rec = read_recording(f, units="g")
    assert rec.samples == 30 and rec.rate_hz == pytest.approx(100.0) and "decimal commas" in rec.metadata["layout"]
    assert np.allclose(rec.channels[2].values / 9.80665, np.round(acc[:30, 2], 6))
    f.write_text("date;t;ax;ay;az\n" + "\n".join(f"01.02.2024;{r}" for r in rows[:25]) + "\n01.02.2024;0,25;0,0")
    with pytest.raises(InputError, match=r"line 27: 3 fields, the header has 5 \(read as semicolon-separated, "
                                          r"decimal commas\)"):
        read_recording(f, units="g")


def test_an_impossible_temperature_is_a_fault_not_interpolated_silently(tmp_path):
    t, acc, _ = _table()
    T = np.full(N, 25.0)
    T[400] = np.inf
    T[401] = 1e6
    f = _write(tmp_path / "temp.csv", ("t", "ax", "ay", "az", "temp"), np.column_stack([t, acc, T]))
    m = prepare(read_recording(f, units="g", temperature_column="temp"))
    fault = next(x for x in m.faults.items if x.kind == "impossible values")
    assert fault.channels == ("temperature",) and fault.ranges == [[400, 401]] and fault.treatment == "temperature"
    assert np.isnan(m.temperature[400:402]).all() and m.missing.count == 0
    assert np.allclose(m.temperature_input()[400:402], 25.0)


def test_read_series_reads_the_same_layouts(tmp_path):
    from torchtea.sensors.text import read_series

    for sep in (",", ";", "\t", " "):
        f = tmp_path / "y.csv"
        f.write_text(f"t{sep}y\n" + "\n".join(f"{i / 100}{sep}{i * 0.5}" for i in range(5)) + "\n")
        assert np.array_equal(read_series(f, ["y"])["y"], np.arange(5) * 0.5)
    f.write_text("t|y\n0|1\n")
    with pytest.raises(InputError, match="separated by '|', which torchtea does not read"):
        read_series(f, ["y"])
