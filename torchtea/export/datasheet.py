"""The fitted numbers held against a datasheet's: "is it my recording or my IMU?".

For each IEEE 952 term the datasheet gives (:func:`~torchtea.fitting.plan.read_datasheet`: N the noise density, B
the bias instability as IEEE 952's coefficient, K the rate random walk, in SI), the axis's fitted value with its 95 %
interval (:func:`~.terms.axis_terms`: N and K from the model's white noise and random walk, B from its Allan
deviation's minimum / 0.664) and a verdict:

- **within spec**: the whole interval is at or below the datasheet's value;
- **worse than spec**: the whole interval is above it — by the ratio fitted / datasheet, with its interval;
- **not determined by this record**: the interval holds the datasheet's value; for N and K, the record length at
  which the expected interval would no longer hold it (:func:`~torchtea.fitting.plan.length_for`, the fitted model
  taken as the truth);
- **none in the model**: the fitted model has no such component (a random walk the loop did not add): the record
  shows none above its other noise, which is no measurement of it — not compared; **none seen**: the model has it
  but the fit puts almost none of it in the record (a walk at σ ≈ 0, an interval over more than six decades) — the same.

A datasheet's values are typical ones; "within spec" says the sensor is no worse than the typical part by this
record, not that it meets a guaranteed bound.
"""
from __future__ import annotations

import math

from ..fitting.plan import duration, length_for, verdict_lines

__all__ = ["compare", "verdict_lines", "read_sheets", "VERDICTS", "VERDICT_MEANING"]

#: An interval whose ends are further apart than this factor measures nothing (a walk fitted at σ ≈ 0: 10⁻⁸³ to 10⁶⁸).
UNBOUNDED = 1e6

VERDICTS = ("within spec", "worse than spec", "not determined by this record", "none in the model", "none seen")


#: What the entries of a datasheet verdict (an axis's ``datasheet`` in check.json and export.json) mean.
VERDICT_MEANING = ("fitted: the axis's value (SI) with its 95 % interval; datasheet: the data sheet's typical value "
    "in SI (B as IEEE 952's coefficient); ratio: fitted / datasheet; verdict: within spec (the "
    "interval at or below), worse than spec (above), not determined by this record (it holds "
    "the datasheet's value; record_for_s: the length that would tell), none in the model")


def compare(terms, sheet: dict, fit, h: float) -> dict:
    """One axis against a datasheet: ``terms`` its :class:`~.terms.AxisTerms`, ``sheet`` a read datasheet, ``fit``
    the axis's fit (for the record length a verdict needs), ``h`` the sample time. Returns ``{"sensor", "source",
    "rows": [{"term", "fitted", "ci95", "datasheet", "datasheet_as_printed", "unit", "ratio", "ratio_ci95",
    "verdict", "words", "record_for_s"}]}``."""
    rows = []
    for term in ("N", "B", "K"):
        spec = sheet.get(term)
        if spec is None:
            continue
        num = terms.ieee.get(term)
        value = None if num is None else num.value
        ci = None if num is None else num.ci95
        unit = "" if num is None else num.unit
        row = {"term": term, "fitted": value, "ci95": None if ci is None else list(ci), "datasheet": spec,
               "datasheet_as_printed": sheet.get("printed", {}).get(term, ""), "unit": unit, "ratio": None,
               "ratio_ci95": None, "record_for_s": None}
        if value and ci is not None and (not math.isfinite(ci[1]) or ci[1] > UNBOUNDED * max(ci[0], 1e-300)):
            row["verdict"] = "none seen"
            row["words"] = ("the fit puts almost none of it in the record (its interval spans more than six decades "
                            "or has no upper end): the record does not measure it; not compared")
            rows.append(row)
            continue
        if not value:
            row["verdict"] = "none in the model"
            row["words"] = (f"the fitted model has no {'random walk' if term == 'K' else term} — the record shows "
                            "none above its other noise, which does not measure it: not compared")
            rows.append(row)
            continue
        row["ratio"] = value / spec
        if ci is not None:
            row["ratio_ci95"] = [ci[0] / spec, ci[1] / spec]
        if ci is None:
            row["verdict"] = "not determined by this record"
            row["words"] = "no interval for the fitted value (see the fit's notes): not compared"
        elif ci[1] <= spec:
            row["verdict"] = "within spec"
            row["words"] = f"{value / spec:.2g}× the datasheet's [{ci[0] / spec:.2g}, {ci[1] / spec:.2g}]"
        elif ci[0] > spec:
            row["verdict"] = "worse than spec"
            row["words"] = f"{value / spec:.3g}× the datasheet's [{ci[0] / spec:.3g}, {ci[1] / spec:.3g}]"
        else:
            row["verdict"] = "not determined by this record"
            rel = abs(value - spec) / value
            n = None
            if term in ("N", "K") and rel > 0:
                n = length_for(fit.model, fit.values, h, term, rel)
            row["record_for_s"] = None if n is None else n * h
            row["words"] = (f"its interval [{ci[0] / spec:.2g}, {ci[1] / spec:.2g}]× the datasheet's holds it; "
                            + (f"about {duration(n * h)} of recording would tell (expected, the fit as the truth)"
                               if n else "the plan gives no record length for it"))
        rows.append(row)
    return {"sensor": sheet["sensor"], "source": sheet.get("source", ""), "file": sheet.get("file", ""),
            "rows": rows,
            "meaning": VERDICT_MEANING}


def read_sheets(paths) -> dict:
    """Datasheet files (:func:`~torchtea.fitting.plan.read_datasheet`) by sensor; two of one sensor: ``ValueError``."""
    from ..fitting.plan import read_datasheet

    out = {}
    for path in paths or ():
        sheet = read_datasheet(path)
        if sheet["sensor"] in out:
            raise ValueError(f"{path}: a second datasheet for the {sheet['sensor']} (the first: "
                             f"{out[sheet['sensor']]['file']})")
        out[sheet["sensor"]] = dict(sheet, file=str(path))
    return out
