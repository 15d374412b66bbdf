r"""A recording's own faults, found before anything is fitted: they are never physics.

Five kinds, each a :class:`Fault` with the samples it covers (``ranges``, 0-based ``[first, last]``), the channels
it touches and a line that says what was seen:

* ``impossible values`` — values no sensor measured: not finite (``inf`` in the file, or a value whose conversion to
  SI units overflows), beyond the full scale of a format that states it, or beyond :data:`PHYSICAL_LIMIT` (far past
  any MEMS accelerometer's or gyroscope's range) — a damaged cell or a logger's junk; the file's line is named where
  the reader knows it (:func:`impossible`).
* ``stuck`` — a run in which **every channel of one sensor** repeats its previous value exactly (a sensor that stopped
  updating, a buffer re-sent), and ``zero rows`` — rows in which every channel, the temperature included, is exactly
  0 (a logger that zero-filled what it did not receive). A run counts when it is longer than the data's own
  repetitions allow: with ``p`` the fraction of consecutive samples that repeat in all of the sensor's channels, a run
  of L samples has probability about ``p^(L−1)`` per place, and the run is flagged when L exceeds
  :data:`STUCK_MIN_RUN` and ``N p^(L−1) < 10⁻³`` (:func:`stuck_min_run`).
* ``clipping`` — samples at the sensor's full scale (a format that knows it: 16-bit counts at −32768 or 32767), or,
  where the scale is unknown, a pile-up at a channel's extreme value: more than twice as many samples sit on it as on
  the value next to it inside, and at least :data:`PILEUP_MIN`, which a noise distribution's tail does not do (looked
  for in channels of at least :data:`PILEUP_LEVELS` distinct values).
* ``temperature step`` — a change of the temperature channel from one sample to the next by more than
  :data:`TEMPERATURE_STEP_C` °C and more than 5 × its 99.9 % quantile of changes: a die's temperature moves by
  hundredths of a degree per sample, its quantisation by about 0.1 °C (the MPU-6050's 1/340 °C … the shared
  recordings' 0.094 °C steps, up to 0.28 °C between samples); a jump of degrees is a logging fault.
* ``time jump`` — time stamps that go backwards, or an interval longer than :data:`TIME_JUMP_FACTOR` × the stamps'
  99.9 % quantile and 10 sample times: the clock jumped, or samples were lost without a trace in the counter.

What happens to them (:func:`apply_faults`): the samples a fault covers, in the channels it covers, become missing
(NaN), the missing-sample
policy of :mod:`.datacheck` then applies — a run stops with one line unless ``--allow-missing``; a temperature
step's temperature samples become missing (interpolated where a model reads the temperature); a time jump is
reported only (the samples are measurements; where the jump says that samples were lost, the rate and the
timing check say so too).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Fault", "Faults", "find_faults", "apply_faults", "impossible", "zero_tail", "stuck_min_run", "STUCK_MIN_RUN", "PILEUP_MIN",
           "TEMPERATURE_STEP_C", "TIME_JUMP_FACTOR", "KINDS"]

KINDS = ("impossible values", "zero rows", "stuck", "clipping", "temperature step", "time jump")
#: A run of repeated values is never flagged below this length.
STUCK_MIN_RUN = 8
#: The largest magnitude (SI units) a channel of each sensor is taken to measure: 10⁶ m/s² (about 10⁵ g, past the
#: range of shock accelerometers) and 10⁴ rad/s (about 5.7·10⁵ °/s, past any gyroscope's); a value beyond is a fault.
PHYSICAL_LIMIT = {"accelerometer": 1e6, "gyroscope": 1e4}
#: Fewest samples on a channel's extreme value for a pile-up (clipping of unknown full scale) …
PILEUP_MIN = 5
#: … which is looked for only in a channel of at least this many distinct values (coarser data pile up anywhere).
PILEUP_LEVELS = 20
#: Largest temperature magnitude (°C) a sensor's die is taken to report; beyond it a value is a fault.
TEMPERATURE_LIMIT_C = 1000.0
#: Smallest temperature change between consecutive samples called a fault (°C).
TEMPERATURE_STEP_C = 1.0
#: A stamp interval this many times the 99.9 % quantile of the intervals (and above 10 h) is a jump.
TIME_JUMP_FACTOR = 10.0


def _runs(mask: np.ndarray) -> list[list[int]]:
    """``[first, last]`` of every run of True in ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1
    return [[int(a), int(b)] for a, b in zip(starts, ends)]


@dataclass(frozen=True)
class Fault:
    """One kind of fault on some channels: ``ranges`` of samples ``[first, last]``, ``count`` samples in them,
    ``message`` what was seen (with the first ranges)."""

    kind: str
    channels: tuple
    ranges: list
    count: int
    message: str
    #: whether the fault's samples become missing (the IMU channels), or only the temperature, or nothing
    treatment: str = "missing"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "channels": list(self.channels), "count": self.count,
                "ranges": [list(r) for r in self.ranges], "message": self.message, "treatment": self.treatment}


@dataclass(frozen=True)
class Faults:
    """Every fault found in a recording (``items``), which samples of each channel they make missing (``masks``:
    channel label → bool ``(N,)``; a zero row covers every channel, a stuck sensor its own, clipping one) and which
    temperature samples (``temperature_rows``)."""

    items: tuple = ()
    masks: dict = field(default_factory=dict)
    temperature_rows: np.ndarray | None = None
    h: float = 1.0

    def __bool__(self) -> bool:
        return bool(self.items)

    @property
    def imu_rows(self) -> np.ndarray | None:
        """Rows in which some channel is made missing, bool ``(N,)`` (None without channels)."""
        if not self.masks:
            return None
        return np.any(np.stack(list(self.masks.values())), axis=0)

    @property
    def missing_count(self) -> int:
        rows = self.imu_rows
        return 0 if rows is None else int(rows.sum())

    def lines(self) -> list[str]:
        return [f.message for f in self.items]

    def to_dict(self) -> dict:
        return {"found": [f.to_dict() for f in self.items], "imu_samples_made_missing": self.missing_count,
                "temperature_samples_made_missing": 0 if self.temperature_rows is None
                else int(self.temperature_rows.sum()),
                "meaning": "faults of the recording itself (logging, saturation, clock), found before any fit; "
                           "their samples are treated as missing, never explained by the noise model"}


def _where(ranges: list, h: float, limit: int = 3) -> str:
    parts = []
    for a, b in ranges[:limit]:
        parts.append(f"samples {a}–{b} ({a * h:.2f}–{b * h:.2f} s)" if b > a else f"sample {a} ({a * h:.2f} s)")
    more = len(ranges) - limit
    return "; ".join(parts) + (f" and {more} more" if more > 0 else "")


def stuck_min_run(p: float, n: int) -> int:
    """Shortest run of repeats flagged as stuck when a sample repeats its predecessor with probability ``p``
    (in all of a sensor's channels) in a series of ``n`` samples: ``n p^(L−1) < 10⁻³`` and at least
    :data:`STUCK_MIN_RUN`."""
    if p <= 0:
        return STUCK_MIN_RUN
    if p >= 1:
        return n + 1
    return max(STUCK_MIN_RUN, int(math.ceil(1 + math.log(1e-3 / max(n, 1)) / math.log(p))))


def _repeat_probability(same: np.ndarray) -> float:
    """The fraction of samples that repeat, from runs no longer than the shortest flagged run could be (so that a
    long fault does not raise its own threshold)."""
    runs = _runs(same)
    short = sum(b - a + 1 for a, b in runs if b - a + 1 < STUCK_MIN_RUN)
    return short / max(len(same), 1)


def find_faults(channels, *, h: float, temperature: np.ndarray | None = None,
                time_s: np.ndarray | None = None, lines: dict | None = None) -> Faults:
    """The faults of a recording's ``channels`` (:class:`~torchtea.sensors.io.Channel` s), its ``temperature``
    (°C) and time stamps ``time_s`` (s); ``h`` the sample time; ``lines``: where in the file some samples are
    (``"label:sample"`` → words, the reader's ``metadata["value_lines"]``), named in the messages."""
    items = []
    N = len(channels[0].values)
    masks = {c.label: np.zeros(N, dtype=bool) for c in channels}
    temp_rows = np.zeros(N, dtype=bool)
    with np.errstate(invalid="ignore", over="ignore"):  # (an impossible value is found here, not warned of)
        _impossible(channels, h, items, masks, lines or {})
        zero = _zero_rows(channels, temperature, h, items, masks, temp_rows)
        _stuck(channels, zero, h, items, masks)
        _clipping(channels, zero | np.any(np.stack(list(masks.values())), axis=0), h, items, masks)
        if temperature is not None:
            temperature = _impossible_temperature(temperature, h, items, temp_rows)
            _temperature_steps(temperature, h, items, temp_rows)
        if time_s is not None:
            _time_jumps(time_s, h, items, N)
    return Faults(tuple(items), masks, temp_rows, h)


def impossible(c) -> np.ndarray:
    """The samples of channel ``c`` that no sensor measured, bool ``(N,)``: not finite (NaN aside: a missing
    sample), beyond the full scale its format states, or beyond :data:`PHYSICAL_LIMIT`."""
    v = np.asarray(c.values)
    with np.errstate(invalid="ignore", over="ignore"):
        bad = np.isinf(v)
        limit = PHYSICAL_LIMIT.get(c.sensor)
        if limit is not None:
            bad |= np.abs(v) > limit
        if c.full_scale is not None:
            raw = v / c.scale
            bad |= (raw < c.full_scale[0] - 0.5) | (raw > c.full_scale[1] + 0.5)
    return bad


def _impossible(channels, h: float, items: list, masks: dict, lines: dict) -> None:
    """Impossible values (:func:`impossible`), per channel, the first named with the file's line."""
    for c in channels:
        bad = impossible(c)
        if bad.any():
            runs = _runs(bad)
            count = int(bad.sum())
            said = "; ".join(lines.get(f"{c.label}:{k}", f"sample {k}: {c.values[k]:.6g} {c.unit}")
                             for k in np.flatnonzero(bad)[:3])  # (the samples the reader named, value_lines)
            limit = PHYSICAL_LIMIT.get(c.sensor)
            items.append(Fault("impossible values", (c.label,), runs, count,
                               f"channel {c.label}: {count} value(s) no sensor measured — not finite, or beyond "
                               + ("the full scale or " if c.full_scale is not None else "")
                               + (f"{limit:g} {c.unit}" if limit is not None else "any number")
                               + f" ({_where(runs, h)}; {said}): a damaged value, not a measurement"))
            masks[c.label] |= bad


def _zero_mask(channels, temperature) -> np.ndarray:
    """The rows in which every channel (and the temperature) is exactly 0, bool ``(N,)``; all False with fewer than
    two columns (where a 0 may be a measurement)."""
    cols = [c.raw for c in channels] + ([temperature] if temperature is not None else [])
    if len(cols) < 2:
        return np.zeros(len(channels[0].values), dtype=bool)
    return np.all(np.stack([np.asarray(c) == 0.0 for c in cols]), axis=0)


def _zero_rows(channels, temperature, h: float, items: list, masks: dict, temp_rows: np.ndarray) -> np.ndarray:
    """Zero rows (:func:`_zero_mask`) as a fault; their rows."""
    zero = _zero_mask(channels, temperature)
    runs = _runs(zero)
    if runs:
        count = int(zero.sum())
        items.append(Fault("zero rows", tuple(c.label for c in channels), runs, count,
                           f"{count} rows are exactly 0 in every channel"
                           + (", the temperature too" if temperature is not None else "")
                           + f" ({_where(runs, h)}): a logging fault (zero-filled rows), not a measurement"))
        for mk in masks.values():
            mk |= zero
        if temperature is not None:
            temp_rows |= zero
    return zero


def zero_tail(channels, temperature=None) -> int:
    """How many rows at the end are zero rows (:func:`_zero_mask`): a logger's zero-filled tail, which
    :func:`~.measurements.prepare` cuts (none where every row is one: the zero-rows fault says so)."""
    measured = np.flatnonzero(~_zero_mask(channels, temperature))
    return len(channels[0].values) - 1 - int(measured[-1]) if measured.size else 0  # (all zero: a fault, not a tail)


def _stuck(channels, zero: np.ndarray, h: float, items: list, masks: dict) -> None:
    """Stuck runs: all channels of one sensor repeat their previous value."""
    groups: dict = {}
    for c in channels:
        groups.setdefault(c.sensor if c.sensor != "signal" else c.name, []).append(c)
    for name, cs in groups.items():
        vals = np.stack([c.raw for c in cs])
        same = np.concatenate([[False], np.all(vals[:, 1:] == vals[:, :-1], axis=0)])
        same &= ~zero  # rows already explained as zero rows
        L = stuck_min_run(_repeat_probability(same), len(zero))
        runs = [[a - 1, b] for a, b in _runs(same) if b - a + 2 >= L]  # a run of repeats from the sample before
        if runs:
            count = sum(b - a + 1 for a, b in runs)
            what = f"the {name}'s {len(cs)} channels" if len(cs) > 1 else f"channel {cs[0].label}"
            items.append(Fault("stuck", tuple(c.label for c in cs), runs, count,
                               f"{what} repeat the same value for {len(runs)} run(s) of ≥ {L} samples, {count} in all "
                               f"({_where(runs, h)}): a stuck sensor or a re-sent buffer (runs that long have "
                               f"probability < 10⁻³ at this recording's repetition rate)"))
            for a, b in runs:
                for c in cs:
                    masks[c.label][a:b + 1] = True


def _pileup(raw: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """The samples piled up at a channel's extreme value (none for coarse data of few levels)."""
    at = np.zeros(len(ok), dtype=bool)
    if len(np.unique(raw[ok])) >= PILEUP_LEVELS:  # coarse data (a few levels) pile up at any value
        top, bottom = np.max(raw[ok]), np.min(raw[ok])
        for ext in (top, bottom):
            on = ok & (raw == ext)
            inner = raw[ok & (raw != ext)]
            nxt = inner.max() if ext == top else inner.min()
            if on.sum() >= PILEUP_MIN and on.sum() > 2 * np.sum(ok & (raw == nxt)):
                at |= on
    return at


def _clipping(channels, zero: np.ndarray, h: float, items: list, masks: dict) -> None:
    """Clipping: at the full scale, or a pile-up at an extreme."""
    for c in channels:
        raw = c.raw
        ok = np.isfinite(raw) & ~zero  # zero rows are a fault of their own, not a pile-up
        if not ok.any():
            continue
        if c.full_scale is not None:
            lo, hi = c.full_scale
            at = ok & ((raw <= lo) | (raw >= hi))
            how = f"at the sensor's full scale ({lo:g} / {hi:g} in the file's {c.source_unit})"
        else:
            at = _pileup(raw, ok)
            how = ("piled up at the channel's extreme value (more than twice as many samples on it as on the value "
                   "next to it: clipping at a full scale the file does not state)")
        if at.any():
            runs = _runs(at)
            count = int(at.sum())
            items.append(Fault("clipping", (c.label,), runs, count,
                               f"channel {c.label}: {count} samples {how} ({_where(runs, h)}): the sensor saturated "
                               "there, the values are not measurements"))
            masks[c.label] |= at


def _impossible_temperature(temperature, h: float, items: list, temp_rows: np.ndarray) -> np.ndarray:
    """Temperatures no die has (infinite, or beyond ±:data:`TEMPERATURE_LIMIT_C`): a fault, those samples missing
    (interpolated where a model reads the temperature). Returns the temperature with them NaN."""
    T = np.asarray(temperature, dtype=np.float64)
    bad = np.isinf(T) | (np.abs(np.nan_to_num(T)) > TEMPERATURE_LIMIT_C)
    if not bad.any():
        return T
    runs = _runs(bad)
    count = int(bad.sum())
    first = T[runs[0][0]]
    items.append(Fault("impossible values", ("temperature",), runs, count,
                       f"the temperature: {count} value(s) no die has — infinite, or beyond ±{TEMPERATURE_LIMIT_C:g} °C "
                       f"({_where(runs, h)}; the first {first:g} °C): a damaged value; those temperature samples are "
                       "treated as missing", treatment="temperature"))
    temp_rows |= bad
    return np.where(bad, np.nan, T)


def _temperature_steps(temperature: np.ndarray, h: float, items: list, temp_rows: np.ndarray) -> None:
    """Temperature steps: a jump from one sample to the next that no die's temperature makes."""
    T = np.asarray(temperature, dtype=np.float64)
    k = np.flatnonzero(np.isfinite(T))
    if k.size > 2:
        d = np.abs(np.diff(T[k]))
        q = float(np.quantile(d, 0.999))
        big = d > max(TEMPERATURE_STEP_C, 5.0 * q)
        if big.any():
            at = np.zeros(len(temp_rows), dtype=bool)
            at[k[1:][big]] = True
            # the samples between a step and the step back are faulty as well, when the temperature returns
            runs = _runs(at)
            count = int(at.sum())
            items.append(Fault("temperature step", ("temperature",), runs, count,
                               f"the temperature jumps by up to {float(d[big].max()):.3g} °C from one sample to the "
                               f"next at {count} place(s) ({_where(runs, h)}), more than a die's temperature "
                               f"moves (threshold {max(TEMPERATURE_STEP_C, 5.0 * q):.3g} °C): a logging fault; "
                               "those temperature samples are treated as missing", treatment="temperature"))
            temp_rows |= at


def _time_jumps(time_s: np.ndarray, h: float, items: list, N: int) -> None:
    """Time jumps: stamps that go backwards or leap far beyond their usual interval (reported only)."""
    t = np.asarray(time_s, dtype=np.float64)
    k = np.flatnonzero(np.isfinite(t))
    if k.size > 2:
        dt = np.diff(t[k]) / np.diff(k)
        q = float(np.quantile(dt, 0.999))
        jump = (dt <= 0) | (dt > max(TIME_JUMP_FACTOR * q, 10.0 * h))
        if jump.any():
            at = np.zeros(N, dtype=bool)
            at[k[1:][jump]] = True
            runs = _runs(at)
            back = int((dt <= 0).sum())
            items.append(Fault("time jump", ("time",), runs, int(jump.sum()),
                               f"the time stamps jump at {int(jump.sum())} place(s) ({_where(runs, h)}; {back} "
                               f"backwards, largest step {float(np.max(np.abs(dt))):.3g} s against a 99.9 % "
                               f"quantile of {q:.3g} s): a clock fault or samples lost without a trace; reported "
                               "only", treatment="reported"))


def apply_faults(channels, temperature, faults: Faults):
    """The channels with the samples the faults cover made missing (NaN) and the temperature with its faulty
    samples made missing: ``(channels, temperature)``."""
    if not faults:
        return channels, temperature
    out = []
    for c in channels:
        mask = faults.masks.get(c.label)
        if mask is None or not mask.any():
            out.append(c)
            continue
        v = c.values.copy()
        v[mask] = np.nan
        out.append(c.with_values(v))
    if temperature is not None and faults.temperature_rows is not None:
        temperature = np.where(faults.temperature_rows, np.nan, temperature)
    return tuple(out), temperature
