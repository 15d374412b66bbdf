"""Reading the text of a recording: the file as text (a clear error for a binary or missing one), the delimiter, the
numbers, the header lines, the body's columns and time stamps; one column as a series (:func:`read_series`).
:func:`~.io.read_recording` makes channels of what these return."""
from __future__ import annotations

import csv
import math
import re
import warnings
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .datacheck import stamp_rate
from .errors import InputError
from .faults import impossible

__all__ = ["read_series", "TIME_COLUMNS", "TIME_UNITS", "PLAUSIBLE_RATE_HZ", "HEAD_LINES", "Layout", "sniff_layout",
           "SEPARATORS"]

#: Column names taken as time stamps when a reader is asked to find them (``time_column="auto"``), in seconds
#: unless the name says otherwise (:data:`TIME_UNITS`) or the stamps' spacing shows ms, µs or ns.
TIME_COLUMNS = ("t", "t_s", "time", "time_s", "sec", "seconds", "timestamp", "stamp", "%time", "header.stamp",
                "field.header.stamp", "time_ns", "t_ns", "timestamp_ns", "stamp_ns", "time_us", "t_us",
                "timestamp_us", "time_ms", "t_ms", "timestamp_ms")
#: Seconds per unit of a time column whose name ends so.
TIME_UNITS = {"_ns": 1e-9, "_us": 1e-6, "_ms": 1e-3, "%time": 1e-9, "header.stamp": 1e-9}
#: The rates (Hz) time stamps may give an IMU; outside, the stamps are taken for another unit or a wrong clock.
PLAUSIBLE_RATE_HZ = (0.5, 1e5)
#: A time column's unit in words.
_UNIT_WORD = {1e-3: "milliseconds", 1e-6: "microseconds", 1e-9: "nanoseconds"}
#: Lines read to find a file's format and header row.
HEAD_LINES = 200


@contextmanager
def _text_file(path: Path):
    """The file opened as text; what goes wrong while opening or reading it is one :class:`InputError` naming it."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:  # (a byte-order mark is not part of the header)
            yield fh
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a CSV file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def _read_text(path: Path) -> str:
    with _text_file(path) as fh:
        return fh.read()


def _delimiter_hint(line: str) -> str:
    """A hint when a header line looks separated by something torchtea does not read ('|')."""
    if line.count("|") >= 1 and line.count("|") >= line.count(","):
        return "; the header looks separated by '|', which torchtea does not read (comma, tab, semicolon or spaces)"
    return ""


#: The separators a recording may use, in the order they are tried (``None``: runs of spaces or tabs).
SEPARATORS = (("\t", "tab"), (";", "semicolon"), (",", "comma"), (None, "whitespace"))
#: Lines at the end of a file's head whose fields are counted to find its separator.
SNIFF_LINES = 20


@dataclass(frozen=True)
class Layout:
    """How a text recording is laid out: its separator (``None``: runs of whitespace) and whether its numbers
    write the decimal point as a comma (``1,25`` in a semicolon- or tab-separated file)."""

    sep: str | None = ","
    decimal_comma: bool = False

    @property
    def words(self) -> str:
        name = dict(SEPARATORS)[self.sep]
        return f"{name}-separated" + (", decimal commas" if self.decimal_comma else "")

    def fields(self, line: str) -> list[str]:
        """The fields of one line, stripped of spaces and of the quotes around a quoted cell."""
        if '"' in line and self.sep is not None:
            parts = next(csv.reader([line], delimiter=self.sep, skipinitialspace=True), [])
        else:
            parts = line.split(self.sep) if self.sep is not None else line.split()
        parts = [p.strip().strip('"').strip() for p in parts]
        return [p.replace(",", ".") for p in parts] if self.decimal_comma else parts


#: A number written with a decimal comma (``-0,0123``, ``1,5e-3``) and one written with a decimal point.
_COMMA_NUMBER = re.compile(r"^[+-]?\d+,\d+(?:[eE][+-]?\d+)?$")
_POINT_NUMBER = re.compile(r"^[+-]?\d*\.\d+(?:[eE][+-]?\d+)?$")


def _split(line: str, sep: str | None) -> list[str]:
    return line.split(sep) if sep is not None else line.split()


def sniff_layout(lines: list[str]) -> Layout:
    """The layout of a text recording from its first ``lines``: the first of :data:`SEPARATORS` that splits at least
    80 % of the last :data:`SNIFF_LINES` lines (blank and ``#`` lines aside) into the same number of fields, more than
    one (a last line cut short, a ragged row, does not hide the separator); commas when none does (the errors that
    follow then name the line). A decimal comma is read where the separator is not a comma and the cells that are
    numbers write them with a comma, none with a point (text cells — names, dates, clock times — aside)."""
    body = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    tail = body[-SNIFF_LINES:]
    for sep, _ in SEPARATORS:
        counts = [len(_split(ln, sep)) for ln in tail]
        if not counts:
            break
        k = max(set(counts), key=counts.count)
        if k > 1 and counts.count(k) >= 0.8 * len(counts):
            if sep == ",":
                return Layout(sep)
            cells = [c.strip().strip('"') for ln in tail for c in _split(ln, sep)]
            decimal = any(_COMMA_NUMBER.match(c) for c in cells) and not any(_POINT_NUMBER.match(c) for c in cells)
            return Layout(sep, decimal)
    return Layout(",")


def _number(text: str, path: Path, line: int, column: str, *, allow_missing: bool, infinite: bool = False) -> float:
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
    if math.isnan(v) and allow_missing:
        return math.nan
    if math.isnan(v) or (math.isinf(v) and not infinite):
        raise InputError(f"{path}, line {line}: column {column!r} is not finite ({t})", column)
    return v


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _seconds(name: str, t: np.ndarray) -> tuple[np.ndarray, str]:
    """Time stamps in seconds, by the column's name (``_ns``, ``_us``, ``_ms``, ROS's ``%time`` and ``header.stamp``
    in ns); other columns are read as seconds, and :func:`~torchtea.sensors.datacheck.check_timing` says when their
    spacing looks like ms, µs or ns. The note says what was converted."""
    low = name.lower()
    for suffix, factor in TIME_UNITS.items():
        if low.endswith(suffix):
            return t * factor, f"column {name!r} read as {_UNIT_WORD[factor]} (its name says so)"
    return t, ""


def _head_lines(path: Path, limit: int = HEAD_LINES) -> list[str]:
    """The first ``limit`` lines of a file (without their line ends)."""
    out = []
    with _text_file(path) as fh:
        for line in fh:
            out.append(line.rstrip("\r\n"))
            if len(out) >= limit:
                break
    return out


def _parse_body(path: Path, start: int, header: list, wanted: list, layout: Layout = Layout()) -> np.ndarray:
    """``(N, len(wanted))`` float64 of the rows after the header (line ``start``, 0-based); empty or ``nan`` fields
    are NaN, ``inf`` fields infinite (a fault the recording's check names); blank lines and ``#`` lines are skipped.
    The fast path streams the file through numpy's C parser (memory: the numbers only, whatever the file's size); a
    file it cannot read (an empty field, text, a row of another length) is read again line by line, which names the
    line and column at fault."""
    idx = [header.index(c) for c in wanted]
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings(), _text_file(path) as fh:
            warnings.simplefilter("ignore", UserWarning)  # (no data rows: said below, as torchtea's own error)
            rows = (ln.replace(",", ".") for ln in fh) if layout.decimal_comma else fh
            arr = np.loadtxt(rows, delimiter=layout.sep, skiprows=start + 1, ndmin=2, dtype=np.float64, comments="#",
                             quotechar='"')
        if arr.shape[0] == 0:
            raise InputError(f"{path}: no data rows")
        if arr.shape[1] != len(header):
            raise ValueError
        return np.ascontiguousarray(arr[:, idx])
    except ValueError:
        pass
    lines = _read_text(path).splitlines()
    out = np.empty((len(lines) - start - 1, len(wanted)))
    n = 0
    for i in range(start + 1, len(lines)):
        line = lines[i]
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = layout.fields(line)
        if len(parts) != len(header):
            raise InputError(f"{path}, line {i + 1}: {len(parts)} fields, the header has {len(header)}"
                             + ("" if layout.sep == "," else f" (read as {layout.words})"))
        for k, j in enumerate(idx):
            out[n, k] = _number(parts[j], path, i + 1, header[j], allow_missing=True, infinite=True)
        n += 1
    if n == 0:
        raise InputError(f"{path}: no data rows")
    return out[:n]


def data_lines(path: Path, start: int, samples) -> dict:
    """``sample → (line number, line)`` of each of the data rows ``samples`` (0-based, blank and ``#`` lines aside)
    after the header (line ``start``, 0-based; numbers 1-based): for messages that name a row."""
    want = sorted(set(int(k) for k in samples))
    out: dict = {}
    if not want:
        return out
    k = -1
    with _text_file(path) as fh:
        for i, line in enumerate(fh):
            if i <= start or not line.strip() or line.lstrip().startswith("#"):
                continue
            k += 1
            if k == want[len(out)]:
                out[k] = (i + 1, line.rstrip("\r\n"))
                if len(out) == len(want):
                    break
    return out


def value_lines(path: Path, start: int, header: list, layout: Layout, channels, meta: dict) -> None:
    """``meta["value_lines"]``: the file's line, column and text of each channel's first impossible values
    (:func:`~.faults.impossible`), which the recording's faults name."""
    flagged = [(c, np.flatnonzero(impossible(c))[:3]) for c in channels]
    if not any(len(k) for _, k in flagged):
        return
    at = data_lines(path, start, [k for _, ks in flagged for k in ks])
    meta["value_lines"] = {f"{c.label}:{k}": f"line {at[k][0]}, column {c.name!r}: "
                                             f"{layout.fields(at[k][1])[header.index(c.name)]!r}"
                           for c, ks in flagged for k in ks if k in at}


def _numeric_column(lines: list, start: int, j: int, layout: Layout = Layout()) -> bool:
    """Whether column ``j`` of the first data row after line ``start`` holds a number (or is empty)."""
    for line in lines[start + 1:]:
        if line.strip() and not line.lstrip().startswith("#"):
            parts = layout.fields(line)
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


def _given_rate(path: Path, meta: dict, rate_hz, tcol, bundled: bool) -> tuple:
    """The sample rate given or in the file's ``Fs`` line (None: from the stamps), checked, and where it came from."""
    rate_source = "--rate" if rate_hz is not None else ""
    if rate_hz is None and bundled:
        try:
            rate_hz = float(meta["Fs"])
        except ValueError:
            raise InputError(f"{path}: sample rate 'Fs,{meta['Fs']}' is not a number") from None
        rate_source = "the file's Fs line"
    if rate_hz is not None and not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise InputError(f"{path}: sample rate must be positive, got {rate_hz}")
    if rate_hz is None and tcol is None:
        raise InputError(f"{path}: no sample rate in the file (an 'Fs,<Hz>' line or a time column named "
                         f"{', '.join(TIME_COLUMNS[:8])} …); give it with --rate")
    return rate_hz, rate_source


def _stamps_and_rate(path: Path, tcol, data: np.ndarray, names: list, meta: dict, rate_hz, rate_source: str):
    """``(t, rate_hz, rate_source)``: column ``tcol``'s stamps in seconds (notes: ``meta``), their rate if not given."""
    t = None
    if tcol is not None:
        t, unit_note = _seconds(tcol, data[:, names.index(tcol)])
        if unit_note:
            meta["time_unit"] = unit_note
        # rows in which every column read is exactly 0, the time stamp too, are a logging fault (zero-filled rows,
        # found and made missing by the faults' check): their stamps are no clock, so they neither give nor
        # contradict the rate
        blank = np.all(data == 0.0, axis=1)
        if blank.any():
            t = np.where(blank, np.nan, t)
            meta["time_zero_rows"] = (f"time column {tcol!r}: the stamps of the {int(blank.sum())} row(s) that are "
                                      "0 in every column are ignored (a logging fault, not a clock)")
    if rate_hz is None:
        rate_hz = stamp_rate(t) if t is not None else math.nan
        if not math.isfinite(rate_hz):
            raise InputError(f"{path}: no sample rate in the file: no 'Fs,<Hz>' line, and time column {tcol!r} "
                             "has fewer than two stamps or does not increase; give the rate with --rate")
        if not PLAUSIBLE_RATE_HZ[0] <= rate_hz <= PLAUSIBLE_RATE_HZ[1]:
            raise InputError(f"{path}: time column {tcol!r} gives a sample rate of {rate_hz:.4g} Hz, implausible for an "
                             "IMU: time stamps are read as seconds; give the rate with --rate (and --time-column none "
                             "if the stamps are in other units)")
        rate_source = f"the mean rate of time column {tcol!r} over the whole file"
    return t, rate_hz, rate_source


def read_series(path, columns: Sequence[str], optional: Sequence[str] = (), *, allow_missing=False) -> dict:
    """Read named numeric columns of a CSV with a header row (comma-, tab-, semicolon- or space-separated, as
    :func:`sniff_layout` finds).

    Returns ``{name: (N,) float64 array}`` for the required ``columns`` and those
    ``optional`` columns that exist.
    """
    path = Path(path)
    lines = _read_text(path).splitlines()
    layout = sniff_layout(lines[:HEAD_LINES])
    rows = [layout.fields(line) if line.strip() else [] for line in lines]
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
