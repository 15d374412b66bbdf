"""Reading recordings and series, writing trajectories.

One reader serves every command (:func:`read_recording`): a torchtea recording, the bundled Arduino format or a
generic CSV, any number of columns, each in its own unit. Every column becomes a :class:`Channel` in SI units —
an accelerometer axis in m/s², a gyroscope axis in rad/s, any other column (a ``signal``) as the file has it —
that knows its sensor, its axis, what the file held and the sensor's full scale where the format says it.

Units (:data:`UNITS`, ``--units``): ``g``, ``ms2`` (m/s²), ``rad/s``, ``deg/s``, or counts, scaled by the
sensor's ``lsb_per_g`` / ``lsb_per_dps`` (``--lsb-per-g``, ``--lsb-per-dps``). A column's sensor comes from its
unit, else from its name (:func:`sensor_of`: ``ax``, ``acc_x``, ``accel_x``, ``linear_acceleration.x`` … and
``gx``, ``gyro_x``, ``gyr_x``, ``angular_velocity.x`` …).

Every reader raises :class:`InputError` with a message that names the file (and line or column) and says what
is wrong.
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from .datacheck import stamp_rate
from .errors import InputError
from .text import (
    PLAUSIBLE_RATE_HZ,
    TIME_COLUMNS,
    _delimiter_hint,
    _given_rate,
    _head_lines,
    _is_number,
    _numeric_column,
    _parse_body,
    _stamps_and_rate,
    _text_file,
    _time_column,
    read_series,
    sniff_layout,
    value_lines,
)

__all__ = ["RECORDER_COLUMNS", "InputError", "Channel", "Recording", "bundled_recording", "read_recording",
           "read_series", "write_columns", "STANDARD_GRAVITY", "BUNDLED", "TIME_COLUMNS", "UNITS", "SI_UNITS",
           "sensor_of", "parse_units"]

STANDARD_GRAVITY = 9.80665  # m/s² per g (CGPM 1901)
DEG = math.pi / 180.0

#: The vendored recordings (MIT, see torchtea/data/LICENSE and PROVENANCE.md).
BUNDLED = {"main": "example_data_tinit_calc.csv", "second": "imu_static_test.csv"}


#: ``--units`` names: (sensor, factor from the file's value to SI). Counts have no factor of their own.
UNITS = {"g": ("accelerometer", STANDARD_GRAVITY), "ms2": ("accelerometer", 1.0), "m/s2": ("accelerometer", 1.0),
         "m/s^2": ("accelerometer", 1.0), "rad/s": ("gyroscope", 1.0), "deg/s": ("gyroscope", DEG),
         "dps": ("gyroscope", DEG), "counts": (None, None)}
#: The SI unit of each sensor's channels, written next to every number.
SI_UNITS = {"accelerometer": "m/s²", "gyroscope": "rad/s", "signal": "units of the file"}
#: Canonical labels of IMU channels (result keys): sensor letter + axis.
_PREFIX = {"accelerometer": "a", "gyroscope": "g"}
_SENSOR_PATTERNS = (
    ("accelerometer", re.compile(r"^(?:.*[._])?(?:a|acc|accel|accl|acceleration|linear_acceleration|lin_acc)[._ ]?([xyz])"
                                 r"(?:[._ ]?(?:g|ms2|mps2|m_s2))?$")),
    ("gyroscope", re.compile(r"^(?:.*[._])?(?:g|gyr|gyro|gyroscope|w|omega|angular_velocity|ang_vel|rate)[._ ]?([xyz])"
                             r"(?:[._ ]?(?:dps|rads|rad_s|deg_s))?$")),
)


@dataclass(frozen=True)
class Channel:
    """One measured column of a recording, in SI units.

    Attributes
    ----------
    name : the column's name in the file.
    sensor : ``"accelerometer"``, ``"gyroscope"`` or ``"signal"`` (a column of no known sensor, in the file's units).
    axis : ``"x"``, ``"y"``, ``"z"`` for a sensor axis; the column's name for a signal.
    values : ``(N,)`` float64 in :attr:`unit` (NaN = missing).
    source_unit : what the file holds (``"counts (16384 LSB/g)"``, ``"g"``, ``"°/s"`` …).
    scale : file value × scale = :attr:`values`.
    full_scale : ``(low, high)`` file values at which the sensor clips (16-bit counts: −32768, 32767), or None when
        the format does not say.
    """

    name: str
    sensor: str
    axis: str
    values: np.ndarray
    source_unit: str
    scale: float = 1.0
    full_scale: tuple | None = None

    @property
    def unit(self) -> str:
        return SI_UNITS[self.sensor]

    @property
    def label(self) -> str:
        """The result key: ``ax`` … ``gz`` for a sensor axis, the column name for a signal."""
        return _PREFIX[self.sensor] + self.axis if self.sensor in _PREFIX else self.name

    @property
    def title(self) -> str:
        """``accelerometer x (m/s²)``, ``gyroscope z (rad/s)``, ``column 'y'``."""
        if self.sensor in _PREFIX:
            return f"{self.sensor} {self.axis} ({self.unit})"
        return f"column {self.name!r} ({self.source_unit})"

    @property
    def raw(self) -> np.ndarray:
        """The values as the file held them (counts come back exactly)."""
        raw = self.values / self.scale
        if "counts" not in self.source_unit:
            return raw
        rounded = np.rint(raw)
        ok = np.isfinite(raw)  # (an impossible value, a fault of its own, does not decide the rounding)
        return rounded if np.max(np.abs(raw[ok] - rounded[ok]), initial=0.0) < 1e-6 else raw

    def describe(self) -> dict:
        return {"column": self.name, "sensor": self.sensor, "axis": self.axis, "unit": self.unit,
                "file_unit": self.source_unit, "full_scale": None if self.full_scale is None else list(self.full_scale)}

    def head(self, n: int | None) -> Channel:
        """The first ``n`` samples (all for None)."""
        return Channel(self.name, self.sensor, self.axis, self.values[:n], self.source_unit, self.scale,
                       self.full_scale)

    def with_values(self, values: np.ndarray) -> Channel:
        return Channel(self.name, self.sensor, self.axis, values, self.source_unit, self.scale, self.full_scale)


@dataclass(frozen=True)
class Recording:
    """A static IMU recording: its channels in SI units, sample rate, time stamps and temperature.

    Attributes
    ----------
    path : source file.
    rate_hz : sample rate.
    channels : the :class:`Channel` s read, in the order asked for.
    metadata : whatever the file's header said.
    time_s : ``(N,)`` the file's time stamps in seconds (NaN where a sample has none), or None.
    time_column : the name of the column they came from.
    rate_source : where ``rate_hz`` came from (``"--rate"``, the file's header, the time stamps' mean).
    temperature : ``(N,)`` the sensor's temperature channel (°C; NaN where missing), or None.
    temperature_column : the column it came from.
    """

    path: Path
    rate_hz: float
    channels: tuple
    metadata: dict = field(default_factory=dict)
    time_s: np.ndarray | None = None
    time_column: str | None = None
    rate_source: str = ""
    temperature: np.ndarray | None = None
    temperature_column: str | None = None

    @property
    def h(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def samples(self) -> int:
        return len(self.channels[0].values)

    def channel(self, label: str) -> Channel:
        """The channel with this label (``ax`` … ``gz``) or column name."""
        for c in self.channels:
            if label in (c.label, c.name):
                return c
        raise KeyError(f"{self.path}: no channel {label!r} (channels: {', '.join(c.label for c in self.channels)})")

    def sensor(self, sensor: str) -> tuple:
        """The channels of one sensor (``"accelerometer"``, ``"gyroscope"``), in x, y, z order."""
        return tuple(sorted((c for c in self.channels if c.sensor == sensor), key=lambda c: c.axis))

    def _three(self, sensor: str) -> tuple:
        cs = self.sensor(sensor)
        if [c.axis for c in cs] != ["x", "y", "z"]:
            raise ValueError(f"{self.path}: the {sensor} axes x, y, z are not all among the channels read "
                             f"({', '.join(c.label for c in self.channels)})")
        return cs

    def accel_ms2(self) -> np.ndarray:
        """Acceleration in m/s², ``(N, 3)`` (the accelerometer's x, y, z channels)."""
        return np.column_stack([c.values for c in self._three("accelerometer")])

    @property
    def accel_counts(self) -> np.ndarray:
        """``(N, 3)`` the accelerometer's values as the file held them (counts where it held counts)."""
        return np.column_stack([c.raw for c in self._three("accelerometer")])

    @property
    def accel_lsb_per_g(self) -> float:
        """Counts per g of the accelerometer (1 for data in g)."""
        return STANDARD_GRAVITY / self._three("accelerometer")[0].scale

    @property
    def gyro_counts(self) -> np.ndarray | None:
        """``(N, 3)`` the gyroscope's values as the file held them, or None without a gyroscope."""
        try:
            return np.column_stack([c.raw for c in self._three("gyroscope")])
        except ValueError:
            return None

    def head(self, n: int | None) -> Recording:
        """The recording's first ``n`` samples (all for None)."""
        if n is None:
            return self
        return Recording(self.path, self.rate_hz, tuple(c.head(n) for c in self.channels), self.metadata,
                         None if self.time_s is None else self.time_s[:n], self.time_column, self.rate_source,
                         None if self.temperature is None else self.temperature[:n], self.temperature_column)


def bundled_recording(which: str = "main") -> Path:
    """Path of a vendored MPU-6050 recording (``"main"``: 449 s, ``"second"``: 100 s)."""
    return Path(str(resources.files("torchtea") / "data" / BUNDLED[which]))


def sensor_of(name: str) -> tuple[str, str] | None:
    """``(sensor, axis)`` that a column's name says (``acc_x`` → accelerometer x, ``gyro_z`` → gyroscope z), or None."""
    key = name.strip().lower()
    if key in ("t", "time", "temp", "temperature"):
        return None
    for sensor, pattern in _SENSOR_PATTERNS:
        m = pattern.match(key)
        if m:
            return sensor, m.group(1)
    return None


def parse_units(spec, columns: Sequence[str]) -> list[str | None]:
    """``--units``: one unit for every column (``"g"``) or one per column (``"g,g,g,deg/s,deg/s,deg/s"``) → a
    list with one entry per column (None where not given). Raises ``ValueError`` naming the bad unit."""
    if spec is None:
        return [None] * len(columns)
    parts = [p.strip().lower() for p in (spec.split(",") if isinstance(spec, str) else spec)]
    for p in parts:
        if p not in UNITS:
            raise ValueError(f"--units {spec!r}: unknown unit {p!r}; choose from {', '.join(UNITS)} "
                             "(one for every column, or one per column)")
    if len(parts) == 1:
        return parts * len(columns)
    if len(parts) != len(columns):
        raise ValueError(f"--units {spec!r}: {len(parts)} units for {len(columns)} columns ({', '.join(columns)}); "
                         "give one unit for all of them or one per column")
    return parts


def _counts_scale(sensor: str, lsb_per_g, lsb_per_dps):
    """SI per count of a sensor, and how the file's unit reads; None when the scale is not known."""
    if sensor == "accelerometer" and lsb_per_g is not None:
        return STANDARD_GRAVITY / lsb_per_g, f"counts ({lsb_per_g:g} LSB/g)"
    if sensor == "gyroscope" and lsb_per_dps is not None:
        return DEG / lsb_per_dps, f"counts ({lsb_per_dps:g} LSB/(°/s))"
    return None


_UNIT_NAMES = {"g": "g", "ms2": "m/s²", "m/s2": "m/s²", "m/s^2": "m/s²", "rad/s": "rad/s", "deg/s": "°/s",
               "dps": "°/s"}


def _make_channels(path: Path, names: Sequence[str], data: np.ndarray, units: list, *, default_counts: bool,
                   lsb_per_g, lsb_per_dps, full_scale=None, si: bool = False) -> tuple:
    """Channels from the columns ``data`` ``(N, k)`` named ``names``. ``units`` per column (None: by the format);
    ``default_counts``: a column of no given unit is in counts (the bundled format); ``si``: already in SI (a
    torchtea recording: m/s², rad/s)."""
    out = []
    for j, (name, unit) in enumerate(zip(names, units)):
        guess = sensor_of(name)
        col = data[:, j]
        if unit is not None and unit != "counts":
            sensor, factor = UNITS[unit]
            if guess is not None and guess[0] != sensor:
                article = "an" if guess[0][0] in "aeiou" else "a"
                raise InputError(f"{path}: column {name!r} looks like {article} {guess[0]} axis but --units says "
                                 f"{unit} ({sensor}); give its own unit (one unit per column, in the order of the "
                                 "file's columns or of --columns, e.g. --units g,g,g,deg/s,deg/s,deg/s)")
            axis = guess[1] if guess is not None else _axis_from_name(name)
            if axis is None:
                raise InputError(f"{path}: column {name!r} is a {sensor} channel (--units {unit}) but its name says no "
                                 "axis x, y or z; rename it (e.g. acc_x)")
            with np.errstate(over="ignore"):  # (a value that overflows is infinite: a fault the check names)
                out.append(Channel(name, sensor, axis, col * factor, _UNIT_NAMES[unit], factor))
            continue
        if guess is None:
            if unit == "counts":
                raise InputError(f"{path}: column {name!r} is in counts but its name says neither accelerometer nor "
                                 "gyroscope (ax, acc_x, gx, gyro_x …); rename it or give its unit (--units g, ms2, "
                                 "rad/s, deg/s)")
            out.append(Channel(name, "signal", name, col.copy(), "as in the file"))
            continue
        sensor, axis = guess
        if si and unit is None:
            scale = _counts_scale(sensor, lsb_per_g, lsb_per_dps)
            out.append(Channel(name, sensor, axis, col.copy(), SI_UNITS[sensor], 1.0,
                               None if scale is None or full_scale is None else
                               tuple(v * scale[0] for v in full_scale)))
            continue
        if unit == "counts" or default_counts or _counts_scale(sensor, lsb_per_g, lsb_per_dps) is not None:
            scale = _counts_scale(sensor, lsb_per_g, lsb_per_dps)
            if scale is None:
                flag = "--lsb-per-g" if sensor == "accelerometer" else "--lsb-per-dps"
                raise InputError(f"{path}: column {name!r} ({sensor} {axis}) is in counts, and the scale is not known: "
                                 f"give {flag} (counts per {'g' if sensor == 'accelerometer' else '°/s'}), or --units "
                                 "for data already in physical units")
            # counts / (LSB per unit) × (SI per unit): the data in g and °/s give the same bits as their counts
            lsb = lsb_per_g if sensor == "accelerometer" else lsb_per_dps
            per_unit = STANDARD_GRAVITY if sensor == "accelerometer" else DEG
            with np.errstate(over="ignore"):
                out.append(Channel(name, sensor, axis, col / lsb * per_unit, scale[1], scale[0], full_scale))
            continue
        raise InputError(f"{path}: unknown unit of column {name!r} ({sensor} {axis}): give --units (g or ms2 for an "
                         "accelerometer, rad/s or deg/s for a gyroscope; one for all columns or one per column), or "
                         f"{'--lsb-per-g' if sensor == 'accelerometer' else '--lsb-per-dps'} for counts")
    return tuple(out)


def _units_in_order(path: Path, units, wanted: list, header: list, *, given: bool, meta: dict) -> list:
    """``--units`` for the columns ``wanted`` (the channels' order), given in the order of ``--columns`` (``given``)
    or of the file's columns. Where that order contradicts the columns' names and the channels' order (ax … gz) does
    not, the units are read in the channels' order. ``meta["units_read"]`` says which unit each column got where the
    file's order is not the channels' (or the channels' order was taken)."""
    if units is None:
        return [None] * len(wanted)
    order = list(wanted) if given else sorted(wanted, key=header.index)
    try:
        by = dict(zip(order, parse_units(units, order)))
        how = "in the order of --columns" if given else "in the order of the file's columns"
        if not given and order != list(wanted) and _contradicts(by):
            canonical = dict(zip(wanted, parse_units(units, wanted)))
            if not _contradicts(canonical):
                by, how = canonical, "in the channels' order ax … gz (the file's order contradicts the names)"
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    if len(set(by.values())) > 1 and order != list(wanted) or "contradicts" in how:  # (where the order matters)
        meta["units_read"] = f"--units read {how}: " + ", ".join(f"{c} {by[c]}" for c in order)
    return [by[c] for c in wanted]


def _contradicts(units_of: dict) -> bool:
    """Whether a unit names another sensor than its column's name does."""
    return any(UNITS[u][0] is not None and sensor_of(c) is not None and sensor_of(c)[0] != UNITS[u][0]
               for c, u in units_of.items())


def _axis_from_name(name: str) -> str | None:
    m = re.search(r"([xyz])$", name.strip().lower())
    return m.group(1) if m else None


def default_columns(header: Sequence[str]) -> list[str]:
    """The IMU columns of a header (accelerometer, then gyroscope, each x, y, z as the names say), in file order
    within each sensor."""
    found = {}
    for c in header:
        g = sensor_of(c)
        if g is not None and g not in found:
            found[g] = c
    return [found[(s, a)] for s in ("accelerometer", "gyroscope") for a in "xyz" if (s, a) in found]


def read_recording(path=None, *, columns: Sequence[str] | None = None, units=None, lsb_per_g: float | None = None,
                   lsb_per_dps: float | None = None, rate_hz: float | None = None, segment: int | None = None,
                   time_column: str | None = "auto", temperature_column: str | None = None,
                   topic: str | None = None) -> Recording:
    """Read a recording: the ``columns`` asked for (default: every accelerometer and gyroscope axis its header
    names), each as a :class:`Channel` in SI units.

    Formats:

    * ``torchtea record``'s format (first line ``# torchtea-recording 1``, physical units, see
      ``docs/recording.md``): rate and scales come from the segment's header; ``segment`` picks one segment
      (default: the longest); its temperature ``temp`` is always read;
    * the bundled format (``Fs,100`` and other ``key,value`` lines, then a header ``ax,ay,az,gx,gy,gz`` and integer
      rows) — the vendored MPU-6050 files: counts, ±2 g at 16384 LSB/g and ±250 °/s at 131 LSB/(°/s) unless
      ``lsb_per_g`` / ``lsb_per_dps`` say otherwise (see PROVENANCE.md);
    * a generic CSV with a header row: every column needs its unit (``units``: one for all or one per column,
      see :func:`parse_units`; or ``lsb_per_g`` / ``lsb_per_dps`` for counts), except a column that no sensor's
      name pattern matches, which is read as a ``signal`` in the file's units.

    Time stamps: ``time_column`` names a column of time stamps; ``"auto"`` takes the first column named as in
    :data:`TIME_COLUMNS`, ``None`` ignores them. Seconds unless the name says ns, µs or ms (``_ns``, ``_us``,
    ``_ms``; ROS's ``%time`` and ``header.stamp`` are ns): then they are converted and ``metadata["time_unit"]``
    says so. Stamps in seconds whose spacing is 10³, 10⁶ or 10⁹ times off the rate look like ms, µs or ns, which
    the timing check says (:func:`~torchtea.sensors.datacheck.check_timing`). A generic CSV without ``rate_hz`` or
    an ``Fs`` line takes the stamps' mean rate. Missing values stay NaN (see
    :mod:`torchtea.sensors.datacheck` for the policy).

    Temperature: ``temperature_column`` names a column in °C (a torchtea recording's is ``temp``, read always).

    ROS bags (``.bag``, ``.db3``, ``.mcap``, a ROS 2 bag's folder): the ``sensor_msgs/Imu`` ``topic`` (default: the
    bag's only one), ``temperature_column`` a ``sensor_msgs/Temperature`` topic (default: the bag's only one) —
    :func:`torchtea.sensors.bags.read_bag`.
    """
    from .bags import is_bag, read_bag

    path = bundled_recording() if path is None else Path(path)
    if is_bag(path):
        given = [flag for flag, v in (("--units", units), ("--lsb-per-g", lsb_per_g), ("--lsb-per-dps", lsb_per_dps),
                                      ("--segment", segment)) if v is not None]
        if given:
            raise InputError(f"{path}: a ROS bag's sensor_msgs/Imu is in m/s² and rad/s, without segments: leave out "
                             f"{', '.join(given)}")
        return _bag_recording(path, read_bag(path, topic=topic, temperature_topic=temperature_column,
                                             columns=columns), rate_hz, time_column)
    if topic is not None:
        raise InputError(f"{path}: --topic is for ROS bags (.bag, .db3, .mcap); this is read as a CSV")
    lines = _head_lines(path)  # the format and the header are in the first lines; the body is streamed
    if lines and lines[0].strip() == RECORDING_MAGIC:
        if temperature_column not in (None, "temp"):
            raise InputError(f"{path}: a torchtea recording's temperature column is 'temp', not {temperature_column!r}")
        return _read_recorder_format(path, lines, segment, rate_hz, time_column, columns, units, lsb_per_g,
                                     lsb_per_dps)
    if segment is not None:
        raise InputError(f"{path}: not a torchtea recording, it has no segments")
    return _read_csv(path, lines, columns, units, lsb_per_g, lsb_per_dps, rate_hz, time_column, temperature_column)


def _header_row(path: Path, lines: list[str], columns, layout) -> tuple[dict, int]:
    """The ``key,value`` lines above a CSV's header row (the bundled format's ``Fs,100`` …) and the header's index."""
    meta: dict = {}
    for i, line in enumerate(lines):
        if not line.strip() or line.lstrip().startswith("#"):
            continue  # (a logger's comment or a blank line above the header)
        parts = layout.fields(line)
        if len(parts) == 2 and not (columns and all(c in parts for c in columns)) and not default_columns(parts) \
                and not _is_number(parts[0]):
            meta[parts[0]] = parts[1]
            continue
        return meta, i
    raise InputError(f"{path}: no header row found")


def _read_csv(path: Path, lines: list[str], columns, units, lsb_per_g, lsb_per_dps, rate_hz, time_column,
              temperature_column) -> Recording:
    """A generic CSV or the bundled format (:func:`read_recording`'s arguments; ``lines``: the file's first lines)."""
    layout = sniff_layout(lines)
    meta, start = _header_row(path, lines, columns, layout)
    header = layout.fields(lines[start])
    if layout.sep != ",":
        meta["layout"] = f"read as {layout.words} (the separator found in the file)"
    wanted = list(columns) if columns else default_columns(header)
    if not wanted:
        raise InputError(f"{path}, line {start + 1}: no accelerometer or gyroscope column recognised in the header "
                         f"({', '.join(header[:12])}{' …' if len(header) > 12 else ''}); name the columns with "
                         "--columns (e.g. --columns acc_x,acc_y,acc_z)" + _delimiter_hint(lines[start]))
    lacking = [c for c in wanted if c not in header]
    if lacking:
        raise InputError(f"{path}, line {start + 1}: the header lacks column(s) {', '.join(map(repr, lacking))} "
                         f"(it has {', '.join(header[:12])}{' …' if len(header) > 12 else ''}); name the columns with "
                         "--columns" + _delimiter_hint(lines[start]))
    bundled = "Fs" in meta
    tcol = _time_column(path, header, time_column)
    if tcol is not None and time_column == "auto" and not _numeric_column(lines, start, header.index(tcol), layout):
        meta["time_column_skipped"] = (f"column {tcol!r} is not in seconds (its first value is not a number); "
                                       "it is not used as time stamps")
        tcol = None
    if temperature_column is not None and temperature_column not in header:
        raise InputError(f"{path}: no temperature column {temperature_column!r} (the header has "
                         f"{', '.join(header[:12])}{' …' if len(header) > 12 else ''})")
    rate_hz, rate_source = _given_rate(path, meta, rate_hz, tcol, bundled)
    unit_list = _units_in_order(path, units, wanted, header, given=bool(columns), meta=meta)
    if bundled:
        lsb_per_g = 16384.0 if lsb_per_g is None else lsb_per_g  # MPU-6050 library defaults: ±2 g …
        lsb_per_dps = 131.0 if lsb_per_dps is None else lsb_per_dps  # … and ±250 °/s
    names = wanted + [c for c in (tcol, temperature_column) if c is not None and c not in wanted]
    try:
        data = _parse_body(path, start, header, names, layout)
    except InputError as exc:
        if tcol is not None and exc.column == tcol:
            raise InputError(f"{exc}; time stamps must be seconds (--time-column none ignores them)", tcol) from None
        raise
    channels = _make_channels(path, wanted, data[:, :len(wanted)], unit_list, default_counts=bundled,
                              lsb_per_g=lsb_per_g, lsb_per_dps=lsb_per_dps,
                              full_scale=(-32768.0, 32767.0) if bundled else None)
    value_lines(path, start, header, layout, channels, meta)
    t, rate_hz, rate_source = _stamps_and_rate(path, tcol, data, names, meta, rate_hz, rate_source)
    return Recording(path=path, rate_hz=float(rate_hz), channels=channels, metadata=meta, time_s=t, time_column=tcol,
                     rate_source=rate_source, temperature=None if temperature_column is None
                     else data[:, names.index(temperature_column)].copy(), temperature_column=temperature_column)


def _bag_recording(path: Path, bag: dict, rate_hz: float | None, time_column: str | None) -> Recording:
    """The :class:`Recording` of a bag's IMU topic (:func:`torchtea.sensors.bags.read_bag`): the rate from its header
    stamps unless given, the stamps left out with ``time_column=None``."""
    imu, t = bag["topic"], bag["time_s"]
    rate_source = "--rate" if rate_hz is not None else ""
    if rate_hz is None:
        if time_column is None:
            raise InputError(f"{path}: with the stamps left out (--time-column none) the rate is needed: --rate")
        rate_hz = stamp_rate(t)
        if not (math.isfinite(rate_hz) and PLAUSIBLE_RATE_HZ[0] <= rate_hz <= PLAUSIBLE_RATE_HZ[1]):
            raise InputError(f"{path}: topic {imu!r}: the header stamps give a rate of {rate_hz:.4g} Hz over "
                             f"{len(t)} messages, implausible for an IMU; give the rate with --rate")
        rate_source = f"the mean rate of topic {imu!r}'s header stamps"
    channels = tuple(Channel(name, sensor, axis, values, SI_UNITS[sensor] + " (sensor_msgs/Imu)")
                     for name, sensor, axis, values in bag["channels"])
    meta = bag["metadata"]
    return Recording(path=path, rate_hz=float(rate_hz), channels=channels, metadata=meta,
                     time_s=None if time_column is None else t,
                     time_column=None if time_column is None else f"{imu} header.stamp", rate_source=rate_source,
                     temperature=bag["temperature"], temperature_column=meta.get("temperature_topic"))


RECORDING_MAGIC = "# torchtea-recording 1"
RECORDER_COLUMNS = ("segment", "counter", "t_s", "ax", "ay", "az", "gx", "gy", "gz", "temp")


def _read_recorder_format(path: Path, lines: list[str], segment: int | None, rate_hz, time_column, columns, units,
                          lsb_per_g, lsb_per_dps) -> Recording:
    headers: dict = {}
    header_line = None
    with _text_file(path) as fh:  # the segment headers, anywhere in the file (one pass, line by line)
        for i, line in enumerate(fh, start=1):
            if i == 1:
                continue
            if line.startswith("# segment "):
                seg, _, rest = line[len("# segment "):].partition(":")
                try:
                    headers[int(seg)] = json.loads(rest)
                except ValueError:
                    raise InputError(f"{path}, line {i}: malformed segment header {line[:80]!r}") from None
            elif header_line is None and line.strip() and not line.startswith("#"):
                header_line = i - 1
                if tuple(p.strip() for p in line.split(",")) != RECORDER_COLUMNS:
                    raise InputError(f"{path}, line {i}: expected columns {','.join(RECORDER_COLUMNS)}, got "
                                     f"{line.strip()[:80]!r}")
    if header_line is None:
        raise InputError(f"{path}: no data rows")
    data = _parse_body(path, header_line, list(RECORDER_COLUMNS), list(RECORDER_COLUMNS))
    segs = data[:, 0]
    if np.isnan(segs).any() or np.any(segs != np.rint(segs)):
        bad = int(np.flatnonzero(np.isnan(segs) | (segs != np.rint(segs)))[0])
        raise InputError(f"{path}: data row {bad + 1}: the segment is not a whole number")
    for seg in np.unique(segs).astype(int):
        if seg not in headers:
            raise InputError(f"{path}: segment {seg} has no '# segment {seg}:' header line")
    sizes = {int(k): int(v) for k, v in zip(*np.unique(segs.astype(int), return_counts=True))}
    if segment is None:
        segment = max(sizes, key=lambda s: (sizes[s], -s))
    elif segment not in sizes:
        raise InputError(f"{path}: no segment {segment} (segments: {', '.join(map(str, sorted(sizes)))})")
    meta = dict(headers[segment])
    try:
        rate = float(meta["rate_hz"])
        lsb = float(meta["accel_lsb_per_g"])
        dps = float(meta["gyro_lsb_per_dps"])
    except (KeyError, ValueError):
        raise InputError(f"{path}: segment {segment}'s header lacks a numeric rate_hz, accel_lsb_per_g or "
                         "gyro_lsb_per_dps") from None
    if lsb_per_g is not None or lsb_per_dps is not None:
        raise InputError(f"{path}: a torchtea recording's scales are in its header ({lsb:g} LSB/g, {dps:g} LSB/(°/s)); "
                         "--lsb-per-g and --lsb-per-dps are for files of counts")
    if units is not None:
        raise InputError(f"{path}: a torchtea recording is in m/s², rad/s and °C already; leave out --units")
    data = data[segs == segment, 1:]  # counter, t_s, ax … temp
    counters = data[:, 0]
    if np.any(np.diff(counters) != 1):
        raise InputError(f"{path}: segment {segment}: counters are not consecutive (rows missing or reordered)")
    names = list(RECORDER_COLUMNS[3:9])
    wanted = list(columns) if columns else names
    lacking = [c for c in wanted if c not in names]
    if lacking:
        raise InputError(f"{path}: a torchtea recording's channels are {', '.join(names)} (and temp); no "
                         f"{', '.join(map(repr, lacking))}")
    idx = [RECORDER_COLUMNS.index(c) - 1 for c in wanted]
    channels = _make_channels(path, wanted, data[:, idx], [None] * len(wanted), default_counts=False,
                              lsb_per_g=lsb, lsb_per_dps=dps, full_scale=(-32768.0, 32767.0), si=True)
    # the recorder wrote counts × scale: the counts come back exactly (Channel.raw), given the scale
    channels = tuple(Channel(c.name, c.sensor, c.axis, c.values, f"{c.unit} (from counts, "
                             + (f"{lsb:g} LSB/g)" if c.sensor == "accelerometer" else f"{dps:g} LSB/(°/s))"),
                             _counts_scale(c.sensor, lsb, dps)[0], c.full_scale and (-32768.0, 32767.0))
                     for c in channels)
    meta.update(segment=segment, segments=sizes, first_counter=int(counters[0]),
                missing_samples=int(np.isnan(data[:, 2]).sum()))
    tcol = None if time_column is None else "t_s"
    if time_column not in (None, "auto", "t_s"):
        raise InputError(f"{path}: a torchtea recording's time column is 't_s' (the device clock), not {time_column!r}")
    return Recording(path=path, rate_hz=float(rate_hz) if rate_hz is not None else rate, channels=channels,
                     metadata=meta, time_s=data[:, 1] if tcol else None, time_column=tcol,
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
