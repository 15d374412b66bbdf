"""Checks on measured series before they are estimated: missing samples and time stamps.

**Missing samples — one policy for every command.** A sample is missing when a measured value is empty or
NaN (a generic CSV with a blank field, a ``nan`` row the recorder wrote for a counter gap). Every command that
reads measurements (``estimate``, ``identify``) stops with an error naming the file, how many samples are
missing and where, unless ``--allow-missing`` is given; with it, every filter predicts through a missing
sample without an update, the sample is left out of every statistic (variances, NIS), and the outputs
state the count and the ranges (``missing_samples`` in the JSON summary, a line in the report).

**Time stamps.** When a file has a time column, its stamps are compared with the sample rate in use: the
stamps' mean rate over their whole span, the spread of the intervals between stamps, and whether they ever
go backwards. A rate that disagrees with the stamps by more than :data:`RATE_TOLERANCE`, or more than
:data:`IRREGULAR_TOLERANCE` of the intervals outside ``[0.5 h, 1.5 h]``, is warned about with the numbers.
The filters assume equally spaced samples; stamps taken on arrival at a host come in bursts and say little
about the sampling instants, so the *mean* rate over the span is the only rate they can give.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError

__all__ = ["MISSING_POLICY", "RATE_TOLERANCE", "IRREGULAR_TOLERANCE", "Missing", "find_missing",
           "missing_error", "check_missing", "Timing", "check_timing", "stamp_rate"]

MISSING_POLICY = ("missing samples (empty or NaN values, the recorder's NaN rows) stop a run unless --allow-missing; "
                  "with it the filters predict through them without an update and they are left out of every "
                  "statistic")

#: Largest relative difference between the rate in use and the time stamps' mean rate that passes silently.
#: A device's sample clock is typically good to a few tenths of a per cent (a ceramic resonator ±0.5 %); a
#: larger difference means the nominal rate is not the real one, or the stamping clock is off.
RATE_TOLERANCE = 0.005
#: Largest fraction of stamp intervals outside ``[0.5 h, 1.5 h]`` that passes silently.
IRREGULAR_TOLERANCE = 0.01


def _ranges(idx: np.ndarray) -> list[list[int]]:
    """Consecutive runs of sorted indices as ``[first, last]`` pairs."""
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) != 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    return [[int(a), int(b)] for a, b in zip(starts, ends)]


@dataclass(frozen=True)
class Missing:
    """Missing samples of a series. ``count``: samples (rows) with at least one missing value among the
    measured columns; ``per_column``: per column; ``ranges``: ``[first, last]`` sample indices (0-based) of
    each run of missing rows."""

    samples: int
    count: int
    per_column: dict
    ranges: list = field(default_factory=list)

    def where(self, limit: int = 4) -> str:
        parts = [f"{a}" if a == b else f"{a}–{b}" for a, b in self.ranges[:limit]]
        more = len(self.ranges) - limit
        return ", ".join(parts) + (f" and {more} more run(s)" if more > 0 else "")

    def describe(self) -> str:
        if not self.count:
            return f"none of {self.samples} samples missing"
        return f"{self.count} of {self.samples} samples missing (sample index {self.where()})"

    def to_dict(self) -> dict:
        return {"count": self.count, "of": self.samples, "per_column": dict(self.per_column),
                "ranges": [list(r) for r in self.ranges]}

    @classmethod
    def from_dict(cls, d: dict) -> Missing:
        """The inverse of :meth:`to_dict`."""
        return cls(samples=d["of"], count=d["count"], per_column=dict(d["per_column"]),
                   ranges=[list(r) for r in d["ranges"]])


def find_missing(values: np.ndarray, names) -> Missing:
    """``values`` ``(N, k)`` (or ``(N,)``) with NaN for missing; ``names`` the ``k`` column names."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    names = list(names)
    if v.shape[1] != len(names):
        raise ValueError(f"{v.shape[1]} columns but {len(names)} names")
    nan = np.isnan(v)
    rows = nan.any(axis=1)
    return Missing(samples=int(v.shape[0]), count=int(rows.sum()),
                   per_column={n: int(nan[:, i].sum()) for i, n in enumerate(names)},
                   ranges=_ranges(np.flatnonzero(rows)))


def missing_error(source, missing: Missing, per: str = "column") -> str:
    """The message of the error for missing samples without ``--allow-missing`` (``per``: what the names of
    ``missing.per_column`` are, e.g. ``"axis"``)."""
    cols = ", ".join(f"{n!r}: {c}" for n, c in missing.per_column.items() if c)
    return (f"{source}: {missing.count} of {missing.samples} samples are missing (sample index {missing.where()}; "
            f"per {per} {cols}); add --allow-missing to predict through them (they are then left out of "
            "every statistic)")


def _units_hint(stamp_rate_hz: float, rate_hz: float | None = None) -> str:
    """A hint when the stamps are probably not in seconds: a stamp rate ~10³, 10⁶ or 10⁹ times off the rate in
    use, or (rate taken from the stamps) a rate an IMU does not have."""
    if not math.isfinite(stamp_rate_hz) or stamp_rate_hz <= 0:
        return ""
    names = {3: "milliseconds", 6: "microseconds", 9: "nanoseconds"}
    if rate_hz is not None:
        decades = math.log10(rate_hz / stamp_rate_hz)
        p = round(decades)
        if p in names and abs(decades - p) < 0.3:
            return (f"the stamps give {stamp_rate_hz:.4g} Hz against {rate_hz:g} Hz in use, a factor of about 10^{p}: "
                    f"they look like {names[p]}, but torchtea reads time stamps as seconds (--time-column none "
                    "ignores them)")
        return ""
    if not 0.5 <= stamp_rate_hz <= 1e5:
        return (f"the stamps give a sample rate of {stamp_rate_hz:.4g} Hz, implausible for an IMU: torchtea reads time "
                "stamps as seconds; if they are in other units give the rate with --rate (and --time-column none)")
    return ""


def check_missing(source, values: np.ndarray, names, *, allow: bool, per: str = "column") -> Missing:
    """The missing-sample policy in one place: the :class:`Missing` of ``values`` ``(N, k)``, or an
    :class:`~torchtea.sensors.io.InputError` (:func:`missing_error`) if any is missing and ``allow`` is False."""
    missing = find_missing(values, names)
    if missing.count and not allow:
        raise InputError(missing_error(source, missing, per=per))
    return missing


def stamp_rate(t: np.ndarray) -> float:
    """Mean rate of time stamps: ``(number of stamped samples − 1) / span``; NaN stamps are skipped."""
    t = np.asarray(t, dtype=np.float64)
    k = np.flatnonzero(np.isfinite(t))
    if k.size < 2 or not t[k[-1]] > t[k[0]]:
        return math.nan
    return float((k[-1] - k[0]) / (t[k[-1]] - t[k[0]]))


@dataclass(frozen=True)
class Timing:
    """What a file's time stamps say about the rate in use (see the module docstring).

    ``span_s``: last − first stamp; ``samples_span_s``: what the rate in use makes of the same samples
    (``(N − 1) / rate``); ``stamp_rate_hz``: the stamps' mean rate; ``rate_mismatch``: rate in use /
    stamp rate − 1; ``interval_*_s``: median, 99th percentile, min and max of the intervals between
    consecutive stamps; ``irregular_fraction``: fraction of intervals outside ``[0.5 h, 1.5 h]``;
    ``backwards``: intervals ≤ 0.
    """

    column: str
    rate_hz: float
    rate_source: str
    stamped: int
    span_s: float
    samples_span_s: float
    stamp_rate_hz: float
    rate_mismatch: float
    interval_median_s: float
    interval_p99_s: float
    interval_min_s: float
    interval_max_s: float
    irregular_fraction: float
    backwards: int
    warnings: tuple = ()

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__ if k != "warnings"} | {
            "warnings": list(self.warnings)}


def check_timing(t: np.ndarray, rate_hz: float, *, column: str, rate_source: str) -> Timing:
    """Compare the time stamps ``t`` ``(N,)`` (seconds, NaN where a sample has none) with ``rate_hz``.

    ``rate_source`` says where the rate came from (for the warnings), e.g. ``"--rate"``, ``"the file's Fs
    line"``, ``"the time stamps' mean"``.
    """
    t = np.asarray(t, dtype=np.float64)
    h = 1.0 / rate_hz
    k = np.flatnonzero(np.isfinite(t))
    n = t.shape[0]
    if k.size < 2:
        return Timing(column, rate_hz, rate_source, int(k.size), math.nan, (n - 1) * h, math.nan, math.nan,
                      math.nan, math.nan, math.nan, math.nan, math.nan, 0,
                      (f"time column {column!r} has {k.size} stamp(s); the rate cannot be checked against it",))
    ts = t[k]
    dt = np.diff(ts) / np.diff(k)  # per-sample interval where a stamp is missing in between
    span = float(ts[-1] - ts[0])
    srate = stamp_rate(t)
    mismatch = rate_hz / srate - 1.0 if math.isfinite(srate) else math.nan
    irregular = float(np.mean((dt < 0.5 * h) | (dt > 1.5 * h)))
    backwards = int(np.sum(dt <= 0))
    med, p99 = (float(v) for v in np.quantile(dt, [0.5, 0.99]))
    warnings = []
    if backwards:
        first = int(k[np.flatnonzero(dt <= 0)[0] + 1])
        warnings.append(f"time column {column!r} stands still or goes backwards at {backwards} place(s) (first at "
                        f"sample {first}): it is not a clock of the samples")
    units = _units_hint(srate) if "time column" in rate_source else _units_hint(srate, rate_hz)
    if units:
        warnings.append(f"time column {column!r}: {units}")
    elif math.isfinite(mismatch) and abs(mismatch) > RATE_TOLERANCE:
        warnings.append(
            f"time column {column!r}: {k.size} stamped samples span {span:.1f} s, a mean rate of {srate:.4g} Hz, "
            f"but the rate in use is {rate_hz:g} Hz ({rate_source}), {mismatch * 100:+.2f} % from the stamps: either "
            "the sensor does not sample at its nominal rate or the stamping clock is off; at the rate in use the "
            f"series lasts {(n - 1) * h:.1f} s"
            + (" (the rate in use is the whole file's mean; this part of it runs at another)"
               if "time column" in rate_source else ""))
    if irregular > IRREGULAR_TOLERANCE:
        warnings.append(
            f"time column {column!r}: the stamps are irregular: {irregular * 100:.1f} % of the intervals lie outside "
            f"0.5–1.5 × h = {h * 1e3:.3g} ms (median {med * 1e3:.3g} ms, 99th percentile {p99 * 1e3:.3g} ms, "
            f"max {float(dt.max()) * 1e3:.3g} ms); the filters assume equal steps of h = 1/({rate_hz:g} Hz, "
            f"{rate_source}). Short intervals mean stamps taken on arrival at a host, in bursts, not at the "
            "sampling instants: then only their long-run mean rate means anything, and --rate with the sensor's "
            "configured rate is better. Long gaps in a device clock mean lost samples")
    return Timing(column, float(rate_hz), rate_source, int(k.size), span, (n - 1) * h, srate, mismatch, med, p99,
                  float(dt.min()), float(dt.max()), irregular, backwards, tuple(warnings))
