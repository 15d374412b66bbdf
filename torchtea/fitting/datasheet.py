"""A datasheet: its file read (:func:`read_datasheet`, the units it prints to SI), the noise model its numbers make
(:func:`datasheet_model`, for a plan without a recording), and the fitted numbers held against it (:func:`compare`,
:func:`verdict_lines`) — "is it my recording or my IMU?".

For each IEEE 952 term the datasheet gives (:func:`read_datasheet`: N the noise density, B
the bias instability as IEEE 952's coefficient, K the rate random walk, in SI), the axis's fitted value with its 95 %
interval (:func:`~torchtea.export.terms.axis_terms`: N and K from the model's white noise and random walk, B from its Allan
deviation's minimum / 0.664) and a verdict:

- **within spec**: the whole interval is at or below the datasheet's value;
- **worse than spec**: the whole interval is above it — by the ratio fitted / datasheet, with its interval;
- **not determined by this record**: the interval holds the datasheet's value; for N and K, the record length at
  which the expected interval would no longer hold it (:func:`~torchtea.fitting.plan.length_for`, the fitted model
  taken as the truth);
- the **turn-on bias repeatability**, where the datasheet gives one and three or more recordings were fitted
  together: their levels' spread (:func:`~torchtea.fitting.together.bias_repeatability`) by the same rules, the
  record being the number of power-ups;
- **none in the model**: the fitted model has no such component (a random walk the loop did not add): the record
  shows none above its other noise, which is no measurement of it — not compared; **none seen**: the model has it
  but the fit puts almost none of it in the record (a walk at σ ≈ 0, an interval over more than six decades) — the same.

A datasheet's values are typical ones; "within spec" says the sensor is no worse than the typical part by this
record, not that it meets a guaranteed bound.
"""
from __future__ import annotations

import math

try:
    import tomllib
except ImportError:  # (Python 3.10)
    import tomli as tomllib
from pathlib import Path

from ..noise.model import NoiseModel, parse_model
from .plan import duration, length_for, nav_numbers

__all__ = ["read_datasheet", "read_sheets", "datasheet_model", "compare", "verdict_lines", "DATASHEET_UNITS",
           "B_CONVENTIONS", "VERDICTS", "VERDICT_MEANING"]

G = 9.80665
DEG = math.pi / 180.0
#: The units datasheets print, to SI (rad, m/s², s): term → unit → factor. N: a noise density (gyroscope
#: rad/s/√Hz, accelerometer m/s²/√Hz); B: a bias instability (rad/s, m/s²); K: a rate random walk (rad/s²/√Hz,
#: m/s³/√Hz).
DATASHEET_UNITS = {
    "gyroscope": {
        "N": {"rad/s/sqrt(Hz)": 1.0, "deg/s/sqrt(Hz)": DEG, "°/s/√Hz": DEG, "mdps/sqrt(Hz)": 1e-3 * DEG,
              "deg/sqrt(h)": DEG / 60.0, "°/√h": DEG / 60.0},
        "B": {"rad/s": 1.0, "deg/s": DEG, "°/s": DEG, "deg/h": DEG / 3600.0, "°/h": DEG / 3600.0},
        "K": {"rad/s^2/sqrt(Hz)": 1.0, "deg/h/sqrt(h)": DEG / 3600.0 / 60.0, "°/h/√h": DEG / 3600.0 / 60.0,
              "deg/s/sqrt(s)": DEG, "°/s/√s": DEG},
    },
    "accelerometer": {
        "N": {"m/s^2/sqrt(Hz)": 1.0, "ug/sqrt(Hz)": 1e-6 * G, "µg/√Hz": 1e-6 * G, "mg/sqrt(Hz)": 1e-3 * G,
              "m/s/sqrt(h)": 1.0 / 60.0},
        "B": {"m/s^2": 1.0, "ug": 1e-6 * G, "µg": 1e-6 * G, "mg": 1e-3 * G},
        "K": {"m/s^3/sqrt(Hz)": 1.0, "ug/sqrt(s)": 1e-6 * G, "µg/√s": 1e-6 * G, "m/s^2/sqrt(h)": 1.0 / 60.0},
    },
}


#: How a datasheet's bias instability B may be given, and what it is over IEEE Std 952's coefficient B: the minimum of
#: the Allan deviation (the flat floor of a flicker, 0.664 B — how data sheets quote an "in-run bias stability" and
#: Allan tools a "bias instability"), the default; or the coefficient itself.
B_CONVENTIONS = {"allan-minimum": math.sqrt(2.0 * math.log(2.0) / math.pi), "ieee952": 1.0}


def read_datasheet(path) -> dict:
    """A datasheet file (TOML): ``sensor`` (gyroscope or accelerometer), ``rate_hz``, and the terms it gives —
    ``N``, ``B``, ``K`` — each ``{value = …, unit = "…"}`` in a unit of :data:`DATASHEET_UNITS`, optionally
    ``source``; B also ``convention`` (:data:`B_CONVENTIONS`: ``"allan-minimum"``, the default, the Allan deviation's
    floor as data sheets quote it; ``"ieee952"``, the coefficient); and ``repeatability``, the turn-on bias
    repeatability (the bias's spread from one power-up to the next, 1σ, in a bias's units). Returns ``{"sensor",
    "rate_hz", "N", "B", "K", "repeatability"}`` in SI, B as IEEE 952's coefficient (a term not given: None),
    ``source`` and ``B_convention``.
    Raises ``ValueError`` naming the file and what is wrong."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not TOML ({exc})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file (a datasheet is TOML)") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    sensor = doc.get("sensor")
    if not isinstance(sensor, str) or sensor not in DATASHEET_UNITS:
        raise ValueError(f"{path}: sensor must be one of {', '.join(DATASHEET_UNITS)}, got {sensor!r}")
    rate = doc.get("rate_hz")
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate < math.inf:
        raise ValueError(f"{path}: rate_hz (the sample rate the sensor is read at, Hz) is missing or not a positive "
                         "number")
    out = {"sensor": sensor, "rate_hz": float(rate), "source": str(doc.get("source", ""))}
    for term in ("N", "B", "K"):
        entry = doc.get(term)
        out[term] = None if entry is None else _term(path, term, entry, DATASHEET_UNITS[sensor][term])
        if entry is None:
            continue
        out.setdefault("printed", {})[term] = f"{entry['value']} {entry['unit']}"
        if term == "B":
            convention = entry.get("convention", "allan-minimum")
            if not isinstance(convention, str) or convention not in B_CONVENTIONS:
                raise ValueError(f"{path}: B's convention must be one of {', '.join(B_CONVENTIONS)}; got "
                                 f"{convention!r}")
            out[term] /= B_CONVENTIONS[convention]
            out["B_convention"] = convention
            if convention == "allan-minimum":
                out["printed"][term] += " at the Allan floor"
    entry = doc.get("repeatability")
    out["repeatability"] = None
    if entry is not None:  # (a bias's spread between power-ups: the units of a bias, B's)
        out["repeatability"] = _term(path, "repeatability", entry, DATASHEET_UNITS[sensor]["B"])
        out.setdefault("printed", {})["repeatability"] = f"{entry['value']} {entry['unit']} (1σ)"
    if out["N"] is None:
        raise ValueError(f"{path}: N (the noise density) is needed; B, K and repeatability are optional")
    return out


def _term(path: Path, term: str, entry, units: dict) -> float:
    """A term ``{value = …, unit = "…"}`` in SI: a positive finite number in one of ``units``; else a ValueError
    naming the file and the term."""
    unit = entry.get("unit") if isinstance(entry, dict) else None
    if not isinstance(entry, dict) or "value" not in entry or not isinstance(unit, str) or unit not in units:
        raise ValueError(f"{path}: {term} must be {{value = …, unit = \"…\"}} with unit one of "
                         f"{', '.join(units)}; got {entry!r}")
    value = entry["value"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < math.inf:
        raise ValueError(f"{path}: {term} must be a positive number, got {value!r}")
    return float(value) * units[unit]


#: The flicker's pole, as a fraction of its stability limit: all but 0 (a pole at 0 exactly is the logit's −∞).
FLICKER_POLE_FRACTION = 1e-9


def datasheet_model(sheet: dict) -> tuple[NoiseModel, dict, float, dict, tuple]:
    """The noise model a datasheet's numbers describe (:func:`read_datasheet`): white noise of density N, a flicker
    of bias instability B (fractional order ½, pole at 0, ``q = B²/h``) and a random walk K, those given.
    Returns ``(model, values, h, terms, fixed)``: ``terms`` N, B, K as :func:`plan` takes them, ``fixed`` the
    flicker's order and pole (its shape is given; B sets its level)."""
    h = 1.0 / sheet["rate_hz"]
    tokens, values = [], {}
    if sheet.get("B"):
        tokens.append("fractional")
        values.update({"fractional.order": 0.5, "fractional.q": sheet["B"] ** 2 / h,
                       "fractional.pole": -FLICKER_POLE_FRACTION * 2.0 ** 0.5 / h ** 0.5})
    tokens.append("white")
    values["white.r"] = sheet["N"] ** 2 / h
    if sheet.get("K"):
        tokens.append("random-walk")
        values["random-walk.sigma"] = sheet["K"]
    model = parse_model("+".join(tokens))
    terms = nav_numbers(model, values, h)
    fixed = ()
    if sheet.get("B"):
        terms["B"] = (sheet["B"], "fractional.q", 0.5)
        fixed = ("fractional.order", "fractional.pole")
    return model, values, h, terms, fixed


# --------------------------------------------------------------------------- what the command prints


#: An interval whose ends are further apart than this factor measures nothing (a walk fitted at σ ≈ 0: 10⁻⁸³ to 10⁶⁸).
UNBOUNDED = 1e6

VERDICTS = ("within spec", "worse than spec", "not determined by this record", "none in the model", "none seen")


#: What the entries of a datasheet verdict (an axis's ``datasheet`` in check.json and export.json) mean.
VERDICT_MEANING = ("fitted: the axis's value (SI) with its 95 % interval; datasheet: the data sheet's typical value "
    "in SI (B as IEEE 952's coefficient); ratio: fitted / datasheet; verdict: within spec (the "
    "interval at or below), worse than spec (above), not determined by this record (it holds "
    "the datasheet's value; record_for_s: the length that would tell), none in the model")


def compare(terms, sheet: dict, fit, h: float, repeatability: dict | None = None) -> dict:
    """One axis against a datasheet: ``terms`` its :class:`~.terms.AxisTerms`, ``sheet`` a read datasheet, ``fit``
    the axis's fit (for the record length a verdict needs), ``h`` the sample time; ``repeatability`` the turn-on
    bias repeatability of several recordings fitted together
    (:func:`~torchtea.fitting.together.bias_repeatability`), held against the datasheet's where it gives one.
    Returns ``{"sensor", "source", "rows": [{"term", "fitted", "ci95", "datasheet", "datasheet_as_printed", "unit",
    "ratio", "ratio_ci95", "verdict", "words", "record_for_s"}]}``."""
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
    if sheet.get("repeatability") and repeatability is not None:
        rows.append(_repeatability_row(sheet, repeatability, terms.ieee["B"].unit if "B" in terms.ieee else ""))
    return {"sensor": sheet["sensor"], "source": sheet.get("source", ""), "file": sheet.get("file", ""),
            "rows": rows,
            "meaning": VERDICT_MEANING}


def _repeatability_row(sheet: dict, bias: dict, unit: str) -> dict:
    """The recordings' turn-on bias spread (its REML value and profile interval) against the datasheet's."""
    spec, value = sheet["repeatability"], bias["spread"]
    R = len(bias["levels"])
    row = {"term": "repeatability", "fitted": value, "ci95": None, "datasheet": spec,
           "datasheet_as_printed": sheet.get("printed", {}).get("repeatability", ""), "unit": unit,
           "ratio": None, "ratio_ci95": None, "record_for_s": None}
    if value is None:
        row["verdict"] = "not determined by this record"
        row["words"] = f"{R} recordings give no spread of the bias: three or more, each from a power-up, would"
        return row
    ci = list(bias["ci95"])
    row.update(ci95=ci, ratio=value / spec, ratio_ci95=[ci[0] / spec, ci[1] / spec])
    if ci[1] <= spec:
        row["verdict"], row["words"] = "within spec", (f"{value / spec:.2g}× the datasheet's [{ci[0] / spec:.2g}, "
                                                       f"{ci[1] / spec:.2g}] over {R} power-ups")
    elif ci[0] > spec:
        row["verdict"], row["words"] = "worse than spec", (f"{value / spec:.3g}× the datasheet's [{ci[0] / spec:.3g},"
                                                           f" {ci[1] / spec:.3g}] over {R} power-ups")
    else:
        row["verdict"] = "not determined by this record"
        row["words"] = (f"its interval [{ci[0] / spec:.2g}, {_g(ci[1] / spec)}]× the datasheet's holds it: {R} "
                        "power-ups do not tell; more recordings, each from a power-up, would")
    if sheet["sensor"] == "accelerometer":
        row["words"] += " (an accelerometer's level holds gravity's projection: only recordings in one mounting)"
    else:
        row["words"] += (" (a gyroscope's level holds the Earth's rate projected on its axis, up to 7.3·10⁻⁵ rad/s: "
                         "only recordings in one mounting)")
    return row


def read_sheets(paths) -> dict:
    """Datasheet files (:func:`read_datasheet`) by sensor; two of one sensor: ``ValueError``."""
    out = {}
    for path in paths or ():
        sheet = read_datasheet(path)
        if sheet["sensor"] in out:
            raise ValueError(f"{path}: a second datasheet for the {sheet['sensor']} (the first: "
                             f"{out[sheet['sensor']]['file']})")
        out[sheet["sensor"]] = dict(sheet, file=str(path))
    return out


def _g(x) -> str:
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.3g}"


def verdict_lines(label: str, doc: dict, markdown: bool = False) -> list[str]:
    """One axis held against a datasheet (:func:`compare`'s document) as lines: a row per
    term; ``markdown``: a markdown table."""
    out = []
    if markdown:
        out += ["| term | fitted [95 %] | datasheet | fitted / datasheet | verdict |", "|---|---|---|---|---|"]
    for r in doc["rows"]:
        ci = "" if r["ci95"] is None else f" [{_g(r['ci95'][0])}, {_g(r['ci95'][1])}]"
        sheet = f"{_g(r['datasheet'])} {r['unit']}" + (f" ({r['datasheet_as_printed']})"
                                                      if r["datasheet_as_printed"] else "")
        if markdown:
            out.append(f"| {r['term']} | {_g(r['fitted'])}{ci} {r['unit']} | {sheet} | {r['words']} | "
                       f"**{r['verdict']}** |")
        else:
            out.append(f"  {label} {r['term']}: {_g(r['fitted'])}{ci} against {sheet}: {r['verdict']} — {r['words']}")
    return out
