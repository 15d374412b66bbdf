"""Reading recordings and series, writing trajectories.

Every reader raises :class:`InputError` with a message that names the file
(and line or column) and says what is wrong.
"""
from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np

__all__ = ["RECORDER_COLUMNS", "InputError", "Recording", "bundled_recording", "read_recording", "read_series", "write_columns",
           "STANDARD_GRAVITY", "BUNDLED", "TIME_COLUMNS"]

STANDARD_GRAVITY = 9.80665  # m/s² per g (CGPM 1901)

#: The vendored recordings (MIT, see torchtea/data/LICENSE and PROVENANCE.md).
BUNDLED = {"main": "example_data_tinit_calc.csv", "second": "imu_static_test.csv"}

#: Column names taken as time stamps in seconds when a reader is asked to find them (``time_column="auto"``).
TIME_COLUMNS = ("t", "t_s", "time", "time_s", "sec", "seconds", "timestamp")


class InputError(ValueError):
    """Bad user input: an unreadable file, a missing column, a non-numeric value …; ``column`` names the
    column of a bad value (None when the error is not about one column's values)."""

    def __init__(self, message: str, column: str | None = None):
        super().__init__(message)
        self.column = column


@dataclass(frozen=True)
class Recording:
    """A static IMU recording.

    Attributes
    ----------
    path : source file.
    rate_hz : sample rate.
    accel_counts : ``(N, 3)`` raw accelerometer counts (x, y, z); NaN = missing sample.
    accel_lsb_per_g : counts per g.
    gyro_counts : ``(N, 3)`` or None.
    metadata : whatever the file's header said.
    time_s : ``(N,)`` the file's time stamps in seconds (NaN where a sample has none), or None.
    time_column : the name of the column they came from.
    rate_source : where ``rate_hz`` came from (``"--rate"``, the file's header, the time stamps' mean).
    temperature : ``(N,)`` the sensor's temperature channel (°C; NaN where missing), or None.
    temperature_column : the column it came from.
    """

    path: Path
    rate_hz: float
    accel_counts: np.ndarray
    accel_lsb_per_g: float
    gyro_counts: np.ndarray | None = None
    metadata: dict = field(default_factory=dict)
    time_s: np.ndarray | None = None
    time_column: str | None = None
    rate_source: str = ""
    temperature: np.ndarray | None = None
    temperature_column: str | None = None

    @property
    def h(self) -> float:
        return 1.0 / self.rate_hz

    def accel_ms2(self) -> np.ndarray:
        """Acceleration in m/s², ``(N, 3)``: counts / (LSB per g) · g₀."""
        return self.accel_counts / self.accel_lsb_per_g * STANDARD_GRAVITY


def bundled_recording(which: str = "main") -> Path:
    """Path of a vendored MPU-6050 recording (``"main"``: 449 s, ``"second"``: 100 s)."""
    return Path(str(resources.files("torchtea") / "data" / BUNDLED[which]))


def _open_lines(path: Path) -> list[str]:
    try:
        with open(path, newline="") as fh:
            return fh.read().splitlines()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a CSV file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def _delimiter_hint(line: str) -> str:
    """A hint when a header line looks separated by something other than commas."""
    for sep, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "'|'")):
        if line.count(sep) >= 1 and line.count(sep) >= line.count(","):
            return (f"; the header looks separated by {name}, but torchtea reads comma-separated files "
                    f"(convert it, e.g. replace each {name[:-1] if name.endswith('s') else name} by a comma)")
    return ""


def _number(text: str, path: Path, line: int, column: str, *, allow_missing: bool) -> float:
    t = text.strip()
    if t == "" or t.lower() == "nan":
        if allow_missing:
            return math.nan
        raise InputError(f"{path}, line {line}: column {column!r} is empty or NaN "
                         "(use --allow-missing to treat such samples as missing)", column)
    try:
        v = float(t)
    except ValueError:
        raise InputError(f"{path}, line {line}: column {column!r} holds {t!r}, not a number", column) from None
    if not math.isfinite(v):
        raise InputError(f"{path}, line {line}: column {column!r} is not finite ({t})", column)
    return v


def read_series(path, columns: Sequence[str], optional: Sequence[str] = (), *, allow_missing=False) -> dict:
    """Read named numeric columns of a CSV with a header row.

    Returns ``{name: (N,) float64 array}`` for the required ``columns`` and those
    ``optional`` columns that exist.
    """
    path = Path(path)
    lines = _open_lines(path)
    rows = list(csv.reader(lines))
    if not rows:
        raise InputError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in columns if c not in header]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(map(repr, missing))}; the header has {header}"
                         + _delimiter_hint(lines[0]))
    wanted = list(columns) + [c for c in optional if c in header]
    idx = {c: header.index(c) for c in wanted}
    out = {c: [] for c in wanted}
    body = rows[1:]
    while body and not any(v.strip() for v in body[-1]):
        body.pop()  # trailing blank lines are not samples
    for i, row in enumerate(body, start=2):
        if not row:
            row = [""] * len(header)  # an interior blank line is a sample with every field empty
        if len(row) != len(header):
            raise InputError(f"{path}, line {i}: {len(row)} fields, the header has {len(header)}")
        for c in wanted:
            out[c].append(_number(row[idx[c]], path, i, c, allow_missing=allow_missing))
    if columns and not out[columns[0]]:
        raise InputError(f"{path}: no data rows")
    return {c: np.asarray(v, dtype=np.float64) for c, v in out.items()}


def read_recording(path=None, *, lsb_per_g: float | None = None, rate_hz: float | None = None,
                   columns: Sequence[str] = ("ax", "ay", "az"), segment: int | None = None,
                   time_column: str | None = "auto", temperature_column: str | None = None) -> Recording:
    """Read an accelerometer recording.

    Formats:

    * ``torchtea record``'s format (first line ``# torchtea-recording 1``, physical units, see
      ``docs/recording.md``): rate and scale come from the segment's header; ``segment`` picks one
      segment (default: the longest). Counts are recovered exactly from the m/s² values;

    * the bundled format (``Fs,100`` and other ``key,value`` lines, then a header
      ``ax,ay,az,gx,gy,gz`` and integer rows) — the vendored MPU-6050 files; the
      accelerometer scale defaults to ±2 g, 16384 LSB/g (see PROVENANCE.md);
    * a generic CSV whose header names the three accelerometer ``columns``
      (``rate_hz`` and ``lsb_per_g`` then required: ``lsb_per_g = 1`` for data in g,
      ``lsb_per_g = 9.80665`` for data already in m/s²).

    Time stamps: ``time_column`` names a column of time stamps in seconds; ``"auto"`` takes the first column
    named as in :data:`TIME_COLUMNS` (the recorder's ``t_s``, the device clock), ``None`` ignores them. A
    generic CSV without ``rate_hz`` or an ``Fs`` line takes the stamps' mean rate. The stamps are kept in
    ``Recording.time_s``; :func:`torchtea.sensors.datacheck.check_timing` compares them with the rate. Missing values
    stay NaN (see :mod:`torchtea.sensors.datacheck` for the policy).

    Temperature: a torchtea recording always carries its ``temp`` column (``Recording.temperature``); a
    generic CSV's ``temperature_column`` names one (°C).
    """
    path = bundled_recording() if path is None else Path(path)
    lines = _open_lines(path)
    if lines and lines[0].strip() == RECORDING_MAGIC:
        if temperature_column not in (None, "temp"):
            raise InputError(f"{path}: a torchtea recording's temperature column is 'temp', not {temperature_column!r}")
        return _read_recorder_format(path, lines, segment, rate_hz, time_column)
    if segment is not None:
        raise InputError(f"{path}: not a torchtea recording, it has no segments")
    meta: dict = {}
    start = 0
    for i, line in enumerate(lines):
        parts = [p.strip() for p in line.split(",")]
        if all(c in parts for c in columns):
            start = i
            break
        if len(parts) == 2:
            meta[parts[0]] = parts[1]
            continue
        lacking = [c for c in columns if c not in parts]
        raise InputError(f"{path}, line {i + 1}: the header lacks column(s) {', '.join(map(repr, lacking))} "
                         f"(it has {', '.join(parts[:12])}{' …' if len(parts) > 12 else ''}); name the three "
                         "accelerometer columns with --columns X,Y,Z" + _delimiter_hint(line))
    else:
        raise InputError(f"{path}: no header with columns {', '.join(columns)} found")
    header = [h.strip() for h in lines[start].split(",")]
    tcol = _time_column(path, header, time_column)
    if tcol is not None and time_column == "auto" and not _numeric_column(lines, start, header.index(tcol)):
        meta["time_column_skipped"] = (f"column {tcol!r} is not in seconds (its first value is not a number); "
                                       "it is not used as time stamps")
        tcol = None
    rate_source = "--rate" if rate_hz is not None else ""
    if rate_hz is None and "Fs" in meta:
        try:
            rate_hz = float(meta["Fs"])
        except ValueError:
            raise InputError(f"{path}: sample rate 'Fs,{meta['Fs']}' is not a number") from None
        rate_source = "the file's Fs line"
    if rate_hz is not None and not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise InputError(f"{path}: sample rate must be positive, got {rate_hz}")
    if rate_hz is None and tcol is None:
        raise InputError(f"{path}: no sample rate in the file (an 'Fs,<Hz>' line or a time column named "
                         f"{', '.join(TIME_COLUMNS)}); give it with --rate")
    if lsb_per_g is None:
        if "Fs" not in meta:
            raise InputError(f"{path}: unknown accelerometer scale; give it with --lsb-per-g (counts per g), or "
                             "--units g / --units ms2 for data already in physical units")
        lsb_per_g = 16384.0  # bundled format: MPU-6050 library default ±2 g
    idx = [header.index(c) for c in columns]
    if temperature_column is not None and temperature_column not in header:
        raise InputError(f"{path}: no temperature column {temperature_column!r} (the header has "
                         f"{', '.join(header[:12])}{' …' if len(header) > 12 else ''})")
    temp_idx = None if temperature_column is None else header.index(temperature_column)
    temps = []
    gyro_idx = [header.index(c) for c in ("gx", "gy", "gz")] if all(c in header for c in ("gx", "gy", "gz")) else None
    acc, gyr, stamps = [], [], []
    for i in range(start + 1, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        parts = line.split(",")
        if len(parts) != len(header):
            raise InputError(f"{path}, line {i + 1}: {len(parts)} fields, the header has {len(header)}")
        acc.append([_number(parts[j], path, i + 1, header[j], allow_missing=True) for j in idx])
        if gyro_idx:
            gyr.append([_number(parts[j], path, i + 1, header[j], allow_missing=True) for j in gyro_idx])
        if temp_idx is not None:
            temps.append(_number(parts[temp_idx], path, i + 1, temperature_column, allow_missing=True))
        if tcol is not None:
            try:
                stamps.append(_number(parts[header.index(tcol)], path, i + 1, tcol, allow_missing=True))
            except InputError as exc:
                raise InputError(f"{exc}; time stamps must be seconds (--time-column none ignores them)") from None
    if not acc:
        raise InputError(f"{path}: no data rows")
    t = np.asarray(stamps, dtype=np.float64) if tcol is not None else None
    if rate_hz is None:
        from .datacheck import stamp_rate

        rate_hz = stamp_rate(t) if t is not None else math.nan
        if not math.isfinite(rate_hz):
            raise InputError(f"{path}: no sample rate in the file: no 'Fs,<Hz>' line, and time column {tcol!r} "
                             "has fewer than two stamps or does not increase; give the rate with --rate")
        if not 0.5 <= rate_hz <= 1e5:
            raise InputError(f"{path}: time column {tcol!r} gives a sample rate of {rate_hz:.4g} Hz, implausible for an "
                             "IMU: time stamps are read as seconds; give the rate with --rate (and --time-column none "
                             "if the stamps are in other units)")
        rate_source = f"the mean rate of time column {tcol!r} over the whole file"
    return Recording(path=path, rate_hz=float(rate_hz), accel_counts=np.asarray(acc, dtype=np.float64),
                     accel_lsb_per_g=float(lsb_per_g),
                     gyro_counts=np.asarray(gyr, dtype=np.float64) if gyro_idx else None, metadata=meta,
                     time_s=t, time_column=tcol, rate_source=rate_source,
                     temperature=np.asarray(temps, dtype=np.float64) if temp_idx is not None else None,
                     temperature_column=temperature_column)


def _numeric_column(lines: list, start: int, j: int) -> bool:
    """Whether column ``j`` of the first data row after line ``start`` holds a number (or is empty)."""
    for line in lines[start + 1:]:
        if line.strip():
            parts = line.split(",")
            if j >= len(parts):
                return True  # the row's own error comes later
            t = parts[j].strip()
            if t == "" or t.lower() == "nan":
                continue
            try:
                float(t)
            except ValueError:
                return False
            return True
    return True


def _time_column(path: Path, header: list, wanted) -> str | None:
    """The time column: ``wanted`` by name, the first of :data:`TIME_COLUMNS` in ``header`` for ``"auto"``,
    none for ``None``."""
    if wanted is None:
        return None
    if wanted == "auto":
        return next((c for c in header if c.lower() in TIME_COLUMNS), None)
    if wanted not in header:
        raise InputError(f"{path}: no time column {wanted!r}; the header has {', '.join(header[:12])}")
    return wanted


RECORDING_MAGIC = "# torchtea-recording 1"
RECORDER_COLUMNS = ("segment", "counter", "t_s", "ax", "ay", "az", "gx", "gy", "gz", "temp")


def _read_recorder_format(path: Path, lines: list[str], segment: int | None, rate_hz, time_column) -> Recording:
    headers: dict = {}
    rows: dict = {}
    columns = None
    for i, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        if line.startswith("#"):
            if line.startswith("# segment "):
                seg, _, rest = line[len("# segment "):].partition(":")
                try:
                    headers[int(seg)] = json.loads(rest)
                except ValueError:
                    raise InputError(f"{path}, line {i}: malformed segment header {line[:80]!r}") from None
            continue
        parts = line.split(",")
        if columns is None:
            columns = tuple(p.strip() for p in parts)
            if columns != RECORDER_COLUMNS:
                raise InputError(f"{path}, line {i}: expected columns {','.join(RECORDER_COLUMNS)}, got {line[:80]!r}")
            continue
        if len(parts) != len(columns):
            raise InputError(f"{path}, line {i}: {len(parts)} fields, the header has {len(columns)}")
        try:
            seg = int(parts[0])
        except ValueError:
            raise InputError(f"{path}, line {i}: segment {parts[0]!r} is not a whole number") from None
        if seg not in headers:
            raise InputError(f"{path}, line {i}: segment {seg} has no '# segment {seg}:' header line")
        rows.setdefault(seg, []).append(
            [_number(v, path, i, c, allow_missing=True) for v, c in zip(parts[1:], columns[1:])])
    if not rows:
        raise InputError(f"{path}: no data rows")
    sizes = {s: len(r) for s, r in rows.items()}
    if segment is None:
        segment = max(sizes, key=lambda s: (sizes[s], -s))
    elif segment not in rows:
        raise InputError(f"{path}: no segment {segment} (segments: {', '.join(map(str, sorted(rows)))})")
    meta = dict(headers[segment])
    try:
        rate = float(meta["rate_hz"])
        lsb = float(meta["accel_lsb_per_g"])
        dps = float(meta["gyro_lsb_per_dps"])
    except (KeyError, ValueError):
        raise InputError(f"{path}: segment {segment}'s header lacks a numeric rate_hz, accel_lsb_per_g or "
                         "gyro_lsb_per_dps") from None
    data = np.asarray(rows[segment], dtype=np.float64)  # counter, t_s, ax … temp
    counters = data[:, 0]
    if np.any(np.diff(counters) != 1):
        raise InputError(f"{path}: segment {segment}: counters are not consecutive (rows missing or reordered)")
    acc = data[:, 2:5] / STANDARD_GRAVITY * lsb
    rounded = np.rint(acc)
    if np.nanmax(np.abs(acc - rounded), initial=0.0) < 1e-6:
        acc = rounded  # values written by the recorder: the counts come back exactly
    gyr = data[:, 5:8] / (math.pi / 180.0) * dps
    meta.update(segment=segment, segments=sizes, first_counter=int(counters[0]),
                missing_samples=int(np.isnan(data[:, 2]).sum()))
    tcol = None if time_column is None else "t_s"
    if time_column not in (None, "auto", "t_s"):
        raise InputError(f"{path}: a torchtea recording's time column is 't_s' (the device clock), not {time_column!r}")
    return Recording(path=path, rate_hz=float(rate_hz) if rate_hz is not None else rate, accel_counts=acc,
                     accel_lsb_per_g=lsb, gyro_counts=gyr, metadata=meta,
                     time_s=data[:, 1] if tcol else None, time_column=tcol,
                     rate_source="--rate" if rate_hz is not None else "the device's header (rate_hz)",
                     temperature=data[:, RECORDER_COLUMNS.index("temp") - 1], temperature_column="temp")


def write_columns(path, columns: dict) -> Path:
    """Write equal-length 1-D arrays as CSV columns (full float64 precision)."""
    path = Path(path)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=np.float64) for n in names])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.17g")
    return path
