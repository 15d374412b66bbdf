"""``fit`` on every channel of a recording: the fits, the fractional-presence test and the document ``torchtea
fit`` writes (:func:`fit_recording`), and its text summary (:func:`fit_lines`)."""
from __future__ import annotations

import math
import time
from collections.abc import Callable

from ..core.tasks import run_parts
from ..noise.grammar import token
from ..render.text import num
from ..sensors.measurements import DOCUMENT_MEANING, RECORDING_MEANING
from .mle import Fit, fit_series
from .summary import MEANING, axis_summary, fit_nis

__all__ = ["FIT_MEANING", "fit_recording", "fit_channel", "fit_lines", "BOOTSTRAP_LIMIT", "bootstrap_replicates"]

#: Records up to this many samples get the fractional-presence bootstrap by default (99 replicates).
BOOTSTRAP_LIMIT = 200_000


#: What each entry of ``torchtea fit --json`` (:func:`fit_recording`'s document) means; the file carries it.
FIT_MEANING = dict(
    RECORDING_MEANING, **DOCUMENT_MEANING, **MEANING,
    model="the model fitted to every channel, as a spec (components joined by +)",
    method="the likelihood maximised: exact (Kalman filter) or whittle (spectral)",
    bootstrap="parametric-bootstrap replicates of the fractional-presence test (0: not run)",
    axes="one document per channel, by label",
    parameters="each parameter by name (component.parameter): value, se, ci95, ci95_method, unit, free",
    ci95_method="how its interval was made (Wald from the observed information, profile, or none)",
    free="false for a parameter held at a value (fixed, or a least-squares value)",
    n="the observed samples the fit saw", converged="whether the optimiser reported convergence",
    notes="what the fit did that its numbers alone do not say (restarts, a parameter at a bound)",
    fractional_test="the bootstrap test's statistic, replicates and p-value",
    order_profile="the Whittle profile likelihood's 95 % interval of the fractional order, its pieces, and whether it "
                  "reaches an edge of the order's range",
    sensor="accelerometer, gyroscope or signal",
    column="the recording's column (or bag field) the channel came from",
    unit="the channel's unit: every parameter's 'units' is this unit (variances unit²)",
    white_noise_density="√(r h): the white noise's density in unit/√Hz (the value σ/√(sample rate) converts back to a "
                        "per-sample σ)",
    seconds="wall-clock seconds of the whole fit")


def bootstrap_replicates(samples: int, asked: int | None) -> int:
    """The bootstrap's replicates: ``asked`` where given, else 99 up to :data:`BOOTSTRAP_LIMIT` samples, 0 beyond."""
    return asked if asked is not None else (99 if samples <= BOOTSTRAP_LIMIT else 0)


def fit_recording(m, model, *, inputs: dict | None = None, method: str = "exact", bootstrap: int | None = None,
                  seed: int = 0, profile: bool = False, progress: Callable | None = None,
                  log: Callable | None = None, client=None, threads: int | None = None,
                  effects: tuple = (), done: dict | None = None, keep: Callable | None = None) -> tuple[dict, list[Fit]]:
    """Fit ``model`` to each channel of ``m`` (:class:`~torchtea.sensors.measurements.Measurements`) one at a time
    (bounded memory; ``progress(done, total)`` after each), test the fractional part's presence by parametric
    bootstrap (:func:`~.presence.fractional_test`; replicates: :func:`bootstrap_replicates`; complete series only),
    and summarise each channel (:func:`~.summary.axis_summary`, with the exact filter's NIS). ``inputs``: the input
    channels the model reads (``{"temperature": (N,)}``). ``log(line)`` takes the notes. Returns the document
    (``model``, ``method``, the recording's description, ``bootstrap``, ``axes``, ``meaning``, ``seconds``,
    ``warnings``) and the fits in channel order. ``client``: a ``distributed.Client``: each channel's fit is one task
    of its cluster (:func:`fit_channel`, ``threads`` numba threads each, default 1; the users' modules of ``effects``
    imported there first), the same fits as in this process. ``done``: fits made before (label → fit: an interrupted
    run's, kept), not made again; ``keep(label, fit)`` as each channel's fit is made (to keep it at once)."""
    from ..noise import parse_model
    from .presence import fractional_test

    model = parse_model(model)
    say = log or (lambda line: None)
    series = [c.values for c in m.channels]
    n_boot = bootstrap_replicates(m.samples, bootstrap)
    if bootstrap is None and n_boot == 0 and model.order_name is not None:
        say(f"{m.samples} samples: the fractional-presence bootstrap is not run (--bootstrap 99 runs it: 99 "
            "simulated replicates, each fitted twice)")
    t0 = time.perf_counter()
    kw = dict(method=method, inputs=inputs, profile=profile)
    values = {c.label: y for c, y in zip(m.channels, series)}

    def cluster(todo, made):
        from ..core.tasks import run_on_cluster

        calls = [(a, (model.spec, values[a], m.h), dict(kw, threads=1 if threads is None else threads,
                                                           effects=effects)) for a in todo]
        run_on_cluster(client, fit_channel, calls, name="fit", on_result=made)

    made = run_parts(list(values), lambda a: fit_channel(model, values[a], m.h, threads=threads, **kw), done=done,
                     keep=keep, progress=progress, cluster=None if client is None else cluster)
    fits = list(made.values())
    tests = [None] * len(series)
    if model.order_name is not None and n_boot > 0:
        if m.missing.count:
            say("the fractional test needs complete series (Whittle): not run")
        else:
            tested, test_series = model, series
            if inputs is not None:  # the test's Whittle fits take no inputs: test what the fitted means leave,
                # with the order constant (a temperature-driven order is not part of the test)
                import torch

                tested = parse_model("+".join(token(c) for _, c in model.components if not c.inputs))
                t = torch.arange(m.samples, dtype=torch.float64) * m.h
                test_series = [y - model.mean(f.values, t, inputs).numpy()[0] for y, f in zip(series, fits)]
            tests = fractional_test(tested, test_series, m.h, n_boot=n_boot, seed=seed)
    axes = {}
    for c, f, y, test in zip(m.channels, fits, series, tests):
        a = axis_summary(f, nis=fit_nis(f, y, m.h, inputs=inputs), test=test)
        a.update(sensor=c.sensor, unit=c.unit if c.sensor != "signal" else c.source_unit, column=c.name)
        if "white.r" in f.values:
            a["white_noise_density"] = math.sqrt(f.values["white.r"] * m.h)
        axes[c.label] = a
    doc = {"model": model.spec, "method": method, **m.describe(), "bootstrap": n_boot, "axes": axes,
           "meaning": FIT_MEANING, "seconds": time.perf_counter() - t0, "warnings": m.notes()}
    return doc, fits


def fit_channel(model, y, h: float, *, method: str = "exact", inputs: dict | None = None, profile: bool = False,
                threads: int | None = None, effects: tuple = ()) -> Fit:
    """One channel's fit (:func:`~.mle.fit_series`), with numba on ``threads`` threads and torch on one
    (:func:`~torchtea.core.threads.engine_threads`), after importing the users' modules of ``effects``."""
    from ..core.threads import engine_threads
    from ..effects import import_effects

    for name in effects:
        import_effects(name)
    with engine_threads(threads):
        return fit_series(model, [y], h, method=method, inputs=None if inputs is None else [inputs],
                          profile=True if profile else None)[0]


def fit_lines(doc: dict, titles: dict, units: dict, recording: str, rate_hz: float) -> list[str]:
    """The text summary of :func:`fit_recording`'s document: per channel (``titles``: label → title) the likelihood,
    criteria, NIS, the presence test's p and each parameter with its standard error and interval; what the columns
    mean and the channels' ``units`` (sensor → unit) last."""
    lines = [f"{recording}: {doc['samples']} samples at {rate_hz:g} Hz, model {doc['model']}, "
             f"{doc['method']} likelihood"]
    for label, a in doc["axes"].items():
        lines.append(f"{label} ({titles.get(label, label)}): loglik {a['loglik']:.2f}  AIC {a['aic']:.2f}  "
                     f"BIC {a['bic']:.2f}  NIS {num(a['nis'], '.3f')}  fractional p "
                     f"{num(a['fractional_p_value'], '.3f')}"
                     + (f"  white-noise density {a['white_noise_density']:.3g} {a['unit']}/√Hz"
                        if "white_noise_density" in a else ""))
        for pname, p in a["parameters"].items():
            ci = (f"[{p['ci95'][0]:.4g}, {p['ci95'][1]:.4g}] ({p['ci95_method']})" if p["ci95"] is not None
                  else "" if p["ci95_method"] in ("fixed", None) else f"({p['ci95_method']})")
            se = "" if p["se"] is None else f"± {p['se']:.3g} (se)"
            lines.append(f"    {pname:22s} {p['value']:12.5g} {se:16s} {ci}")
        for note in a["notes"]:
            lines.append(f"    note: {note}")
    lines.append("se: standard error from the observed information; NIS: mean e²/S of the exact filter, 1 when the "
                 "fitted noise levels match the data; p: bootstrap test of 'no fractional component'; units: "
                 + "; ".join(f"{k}: {v}" for k, v in units.items()) + " ('units' in a parameter's unit)")
    return lines
