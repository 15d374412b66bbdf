"""What every analysing command reads of a recording, prepared once: the channels asked for, in SI units, with the
recording's faults found and made missing, the missing-sample policy applied, the time stamps checked and the
temperature ready for the models that read it.

``fit``, ``check`` and ``identify`` all start here (:func:`prepare`), so they read one column or six, in any units,
from any of the formats, the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .datacheck import Missing, Timing, check_timing, find_missing, missing_error
from .faults import Faults, apply_faults, find_faults, zero_tail
from .io import Channel, InputError, Recording

__all__ = ["Measurements", "prepare", "fill_temperature", "RECORDING_MEANING", "DOCUMENT_MEANING"]


def fill_temperature(T: np.ndarray, source) -> np.ndarray:
    """The temperature with its missing samples (NaN) interpolated linearly in time (held at the ends) — a model
    input must be complete; ``source`` names the file in the error when there is no value at all."""
    T = np.asarray(T, dtype=np.float64).copy()
    seen = np.isfinite(T)
    if not seen.any():
        raise InputError(f"{source}: the temperature column has no values")
    if not seen.all():
        k = np.arange(len(T))
        T[~seen] = np.interp(k[~seen], k[seen], T[seen])
    return T


@dataclass(frozen=True)
class Measurements:
    """The part of a recording a command analyses.

    ``recording``: the recording as read (its first ``samples`` samples); ``channels``: the channels analysed, with
    the faults' samples made missing; ``faults`` (:class:`~.faults.Faults`), ``missing`` (:class:`~.datacheck.Missing`,
    per channel label, the faults' samples included) and ``timing`` (None without time stamps); ``temperature`` the
    temperature channel (°C) with faulty samples NaN, or None."""

    recording: Recording
    channels: tuple
    faults: Faults
    missing: Missing
    timing: Timing | None
    temperature: np.ndarray | None
    allow_missing: bool = False
    #: samples in the whole recording (the part used is the first :attr:`samples`)
    total: int = 0
    #: the stretches left out on request (``--exclude``): dicts with ``from_s``, ``to_s`` (as asked), ``first``,
    #: ``last`` (sample indices) and ``samples``; those made missing, or cut where they reach the end
    excluded: tuple = ()
    #: the zero-filled tail cut (rows at the end that are 0 in every column): ``first`` (its first sample), ``rows``
    #: and ``words``; None when the part used ends in a measurement
    zero_tail: dict | None = None

    @property
    def h(self) -> float:
        return self.recording.h

    @property
    def samples(self) -> int:
        return len(self.channels[0].values)

    @property
    def labels(self) -> list[str]:
        return [c.label for c in self.channels]

    def series(self) -> dict:
        """``{label: (N,) values}`` in SI units, NaN where missing."""
        return {c.label: c.values for c in self.channels}

    def channel(self, label: str) -> Channel:
        return next(c for c in self.channels if c.label == label)

    def temperature_input(self) -> np.ndarray:
        """The temperature as a model input: complete, its missing samples interpolated (:func:`fill_temperature`):
        those a fault made missing, those where every channel is missing, and — with ``allow_missing`` — any other.
        Without it, a temperature missing in the file where a channel is observed is an :class:`~.io.InputError`."""
        rec = self.recording
        if self.temperature is None:
            raise InputError(f"{rec.path}: no temperature channel (--temperature COLUMN)")
        observed = np.isfinite(np.column_stack([c.values for c in self.channels])).any(axis=1)
        bad = int(np.sum(observed & np.isnan(rec.temperature)))
        if bad and not self.allow_missing:
            raise InputError(f"{rec.path}: temperature column {rec.temperature_column!r} has {bad} missing value(s) "
                             "where a channel is observed; the temperature input cannot be missing there (add "
                             "--allow-missing to interpolate it)")
        return fill_temperature(self.temperature, rec.path)

    def sensors(self) -> dict:
        """``{sensor: [labels]}`` in channel order (accelerometer, gyroscope, signals)."""
        out: dict = {}
        for c in self.channels:
            out.setdefault(c.sensor, []).append(c.label)
        return out

    def describe(self) -> dict:
        """The JSON entry: the recording, its channels with units, the faults, missing samples and timing (each key
        described in :data:`RECORDING_MEANING`)."""
        rec = self.recording
        return {"recording": str(rec.path), "topic": rec.metadata.get("topic"), "rate_hz": rec.rate_hz, "rate_source": rec.rate_source,
                "samples": self.samples, "samples_in_recording": self.total, "channels": {c.label: c.describe() for c in self.channels},
                "temperature_column": rec.temperature_column, "faults": self.faults.to_dict(),
                "missing_samples": self.missing.count, "missing": self.missing.to_dict(),
                "timing": None if self.timing is None else self.timing.to_dict(),
                "excluded": [dict(e) for e in self.excluded], "zero_tail": self.zero_tail}

    def notes(self) -> list[str]:
        """Lines for stderr and the reports: the faults, then the timing warnings."""
        out = [f"recording fault: {line}" for line in
               ([self.zero_tail["words"]] if self.zero_tail else []) + self.faults.lines()]
        for e in self.excluded:
            out.append(f"excluded on request (--exclude {e['from_s']:g}:{e['to_s']:g}): samples {e['first']}–"
                       f"{e['last']} ({e['samples']}), " + ("cut: the stretch reaches the end of the part used"
                                                          if e["cut"] else "made missing"))
        if self.timing is not None:
            out += list(self.timing.warnings)
        return out


#: What each entry of :meth:`Measurements.describe` means: the recording's part of every JSON output that reads one
#: (``check.json``, ``fit --json``, ``export.json``, ``summary.json``).
RECORDING_MEANING = {
    "recording": "the file (or bag) read",
    "topic": "a ROS bag's sensor_msgs/Imu topic read (null: a file that is not a bag)",
    "rate_hz": "the sample rate in use, Hz",
    "rate_source": "where rate_hz came from (--rate, the file's time column, its header)",
    "samples": "the samples used (the first --samples of the recording, less a cut at the end by --exclude)",
    "samples_in_recording": "the samples the recording holds",
    "channels": "each channel by label: its column, sensor, axis, unit (SI) and what the file held",
    "temperature_column": "the column (or topic) read as the temperature input; null: none",
    "faults": "the recording's own faults, found before any fit (their samples are missing samples, never physics)",
    "missing_samples": "samples missing in the part used (empty, NaN, a fault's or an excluded stretch's)",
    "missing": "the missing samples by cause and their longest run",
    "timing": "the file's time stamps against the rate in use (null: the file has no time column)",
    "excluded": "stretches left out on request (--exclude): their samples missing, or cut at the end",
    "zero_tail": "rows at the end of the part used that were 0 in every column (a logger's zero-filled tail): cut, "
                 "not analysed; null: none",
}
#: The entries every JSON document of a command that reads a recording has beside the recording's part.
DOCUMENT_MEANING = {
    "command": "the command line that made the file",
    "warnings": "where a number should not be trusted, and why (the recording's faults and timing first)",
    "meaning": "this table: what each entry means",
}


def exclusion_ranges(exclude, h: float, N: int, source) -> list[dict]:
    """The stretches ``exclude`` (``[(from_s, to_s), …]``, seconds from the first sample, as the reports give times)
    as sample ranges of a series of ``N`` samples at sample time ``h``: the samples k with from ≤ k h ≤ to. An
    :class:`~.io.InputError` naming ``source`` and the flag for a stretch that is empty, backwards or outside the
    series."""
    out = []
    end = (N - 1) * h
    for a, b in exclude:
        flag = f"--exclude {a:g}:{b:g}"
        if not (math.isfinite(a) and math.isfinite(b)) or b <= a:
            raise InputError(f"{source}: {flag}: give FROM:TO in seconds with FROM < TO")
        first, last = max(0, math.ceil(a / h - 1e-9)), min(N - 1, math.floor(b / h + 1e-9))
        if a > end or b < 0 or last < first:
            raise InputError(f"{source}: {flag}: no sample there (the part used spans 0–{end:g} s)")
        out.append({"from_s": float(a), "to_s": float(b), "first": int(first), "last": int(last),
                    "samples": int(last - first + 1), "cut": False})
    return out


def prepare(recording: Recording, *, samples: int | None = None, allow_missing: bool = False,
            min_samples: int = 1, command: str = "this command", exclude=()) -> Measurements:
    """The recording's first ``samples`` samples (all for None), its faults found (:func:`~.faults.find_faults`) and
    made missing, and the missing-sample policy applied: an :class:`~.io.InputError` naming the file, the faults, the
    missing samples and ``--allow-missing`` when any sample is missing and ``allow_missing`` is False; one when fewer
    than ``min_samples`` samples are there. ``exclude``: stretches ``(from_s, to_s)`` to leave out
    (:func:`exclusion_ranges`): their samples are made missing in every channel — asked for, so the policy does not
    refuse them — and a stretch that reaches the end of the part used is cut instead (the same likelihood: a missing
    sample at the end adds nothing), which keeps the series complete for the fast paths."""
    total = recording.samples
    rec = recording.head(samples)
    N = rec.samples
    excluded = exclusion_ranges(exclude, rec.h, N, rec.path) if exclude else []
    drop = np.zeros(N, dtype=bool)
    for e in excluded:
        drop[e["first"]:e["last"] + 1] = True
    if drop.any() and drop[-1]:  # the excluded stretch at the end is cut
        keep = N - int(np.argmin(drop[::-1])) if not drop.all() else 0
        for e in excluded:
            if e["last"] >= keep:
                e["cut"] = True
        rec = rec.head(keep)
        drop = drop[:keep]
        N = keep
    tail = zero_tail(rec.channels, rec.temperature)
    if tail:
        rec, drop, N = rec.head(N - tail), drop[:N - tail], N - tail
        for e in excluded:
            e["cut"] = e["cut"] or e["last"] >= N  # (a stretch that reaches into the cut tail is cut with it)
        tail = {"first": N, "rows": tail,
                "words": f"the last {tail} rows (samples {N}–{N + tail - 1}, from {N * rec.h:.2f} s) are 0 in every "
                         f"column{', the temperature too' if rec.temperature is not None else ''}: a logger's "
                         "zero-filled tail, not measurements; cut"}
    if N < min_samples:
        raise InputError(f"{rec.path}: {N} samples; {command} needs at least {min_samples}")
    faults = find_faults(rec.channels, h=rec.h, temperature=rec.temperature, time_s=rec.time_s,
                         lines=rec.metadata.get("value_lines"))
    channels, temperature = apply_faults(rec.channels, rec.temperature, faults)
    values = np.column_stack([c.values for c in channels])
    unasked = find_missing(np.where(drop[:, None], 0.0, values), [c.label for c in channels])
    if drop.any():
        from dataclasses import replace

        channels = tuple(replace(c, values=np.where(drop, np.nan, c.values)) for c in channels)
        values = np.column_stack([c.values for c in channels])
    missing = find_missing(values, [c.label for c in channels])
    if unasked.count and not allow_missing:
        missing = unasked
        why = ""
        if faults.missing_count:
            why = (f" — {faults.missing_count} of them made missing by the recording's faults: "
                   + "; ".join(f.message for f in faults.items if f.treatment == "missing"))
        raise InputError(missing_error(rec.path, missing, per="channel") + why)
    empty = [c.label for c in channels if int(np.isnan(c.values).sum()) >= N - 1]
    if empty:
        raise InputError(f"{rec.path}: channel {', '.join(empty)} has no samples in the part used")
    timing = None
    if rec.time_s is not None:
        timing = check_timing(rec.time_s, rec.rate_hz, column=rec.time_column, rate_source=rec.rate_source)
    return Measurements(rec, channels, faults, missing, timing, temperature, allow_missing, total, tuple(excluded),
                        tail or None)
