"""Running a study or a sweep of sub-studies to its run directories — the workflow behind ``torchtea montecarlo``,
as a library function (:func:`run_sweep`): the command line only parses flags, calls it and prints.

Each sub-study's ``study.toml`` and ``estimator.toml`` are written before it runs (an interrupted run still says what
it was); the sub-studies run one after another in this process, or together as shards on a Dask ``client``
(:func:`~torchtea.studies.cluster.run_studies`); each finished one is summarised, judged (:func:`verdicts`) and
written (:func:`~torchtea.studies.montecarlo.save_study`), a sweep's table to ``sweep.json``."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from ..render import strictjson
from .cluster import StudyFailed, plan_studies, run_studies, run_study
from .montecarlo import save_study, summarise

__all__ = ["run_sweep", "SweepRun", "verdicts", "CONSISTENT_STEPS"]

#: A filter is called consistent when its NEES (NIS) mean over realisations lies inside the per-step 95 % band at
#: least at this fraction of the steps (about 95 % for a consistent one).
CONSISTENT_STEPS = 0.8


def verdicts(summary: dict, result, logdir) -> list[str]:
    """What a reader must know of a finished study: an interruption, diverged realisations, and NEES or NIS outside
    their bands (each line starts with ``warning:`` but the interruption's)."""
    out = []
    if result.interrupted:
        out.append(f"interrupted: kept {result.finished} of {result.study.realisations} realisations in {logdir}")
    if summary["diverged"]:
        out.append(f"warning: {summary['diverged']} realisation(s) diverged; excluded from the statistics")
    for name, what in (("nees", "NEES (state error against KFx's P)"), ("nis", "NIS (innovations against KFx's S)")):
        c = summary.get(name)
        if c is None:
            continue
        lo, hi = c["band_95"]
        inside = c["fraction_of_steps_inside_band"]
        if not lo <= c["mean"] <= hi or inside < CONSISTENT_STEPS:
            out.append(f"warning: {what}: its mean over realisations lies inside the per-step 95 % band "
                       f"[{lo:.3g}, {hi:.3g}] at {inside * 100:.0f} % of the steps (about 95 % for a consistent "
                       f"filter; warned below {CONSISTENT_STEPS * 100:.0f} %), and averages {c['mean']:.3g} over "
                       "all steps (1 when the filter's covariance matches its errors): the filter is not consistent")
    return out


@dataclass
class SweepRun:
    """What :func:`run_sweep` did: per sub-study (in order) its run directory, result (None where it did not run),
    summary and verdicts (None where nothing finished); the sweep's table (``sweep.json``'s, None for a single study),
    the wall time, and the cluster's failure message (None without one)."""

    dirs: list
    results: list
    summaries: list
    warnings: list
    table: dict | None
    seconds: float
    failure: str | None = None
    names: list = field(default_factory=list)

    @property
    def interrupted(self) -> bool:
        return any(r is not None and r.interrupted for r in self.results)


def run_sweep(studies, logdir, *, client=None, shard: int | None = None, device=None, progress=None,
              figures: bool = False, sweep_source: str | None = None) -> SweepRun:
    """Run ``studies`` (:class:`~torchtea.studies.sweep.SubStudy`, one named None for a single study) into
    ``logdir`` (a sub-directory per named sub-study). ``progress(total, unit)`` returns ``(step, close)`` for a
    progress display: called once per study here, once for all shards on a ``client``. ``sweep_source``: the sweep
    file's text, kept as ``sweep.toml``. Raises nothing for a failed cluster run: its finished shards are kept and
    the message is ``SweepRun.failure``."""
    logdir = Path(logdir)
    logdir.mkdir(parents=True, exist_ok=True)
    sweep = studies[0].name is not None
    dirs = [logdir / s.name if sweep else logdir for s in studies]
    for d, s in zip(dirs, studies):
        save_study(d, s.study, s.preset)  # before the run: an interrupted run still says what it was
    if sweep and sweep_source is not None:
        (logdir / "sweep.toml").write_text(sweep_source)
    progress = progress or (lambda total, unit: (None, lambda: None))
    failure = None
    seconds = []  # per study, where they run one after another
    t0 = time.perf_counter()
    if client is not None:
        dev = None if device is None else str(device)
        plans = plan_studies([s.study for s in studies], client, shard, dev)
        step, close = progress(sum(map(len, plans)), "shard")
        try:
            results = run_studies([s.study for s in studies], client, shard=shard, device=dev, plans=plans,
                                  progress=step, names=[f"sub-study {s.name}" if sweep else "the study" for s in studies])
        except StudyFailed as exc:
            results, failure = exc.partial, str(exc)
        close()
    else:
        results = []
        for s in studies:
            step, close = progress(s.study.realisations, "realisation")
            t1 = time.perf_counter()
            results.append(run_study(s.study, progress=step, device=device))
            seconds.append(time.perf_counter() - t1)
            close()
            if results[-1].interrupted:
                break
    elapsed = time.perf_counter() - t0
    results = list(results) + [None] * (len(studies) - len(results))
    summaries, warnings, rows = [], [], []
    for i, (d, s, result) in enumerate(zip(dirs, studies, results)):
        if result is None or not result.finished:
            summaries.append(None)
            warnings.append(None)
            continue
        summary = summarise(result)
        summary.update({"logdir": str(d), "preset": s.preset})
        if not sweep:
            summary["seconds"] = round(elapsed, 2)
        else:
            if i < len(seconds):  # sub-studies scheduled together have no time of their own, only the sweep's
                summary["seconds"] = round(seconds[i], 2)
            summary.update(sweep_seconds=round(elapsed, 2), sweep={"name": s.name, "values": s.values})
        save_study(d, s.study, s.preset, result, summary, figures=figures, hparams=s.hparams())
        said = verdicts(summary, result, d)
        words = [w.removeprefix("warning: ") for w in said]
        if sweep:  # the sweep's table keeps the numbers, each sub-study's summary.json its warnings too
            strictjson.write(d / "summary.json", {**summary, "warnings": words})
            rows.append(summary)
        else:
            summary["warnings"] = words
            strictjson.write(d / "summary.json", summary)
        summaries.append(summary)
        warnings.append(said)
    table = None
    if sweep:
        not_run = [s.name for s, r in zip(studies, results) if r is None or not r.finished]
        table = {"logdir": str(logdir), "seconds": round(elapsed, 2), "studies": rows, "not_run": not_run}
        strictjson.write(logdir / "sweep.json", table)
    return SweepRun(dirs, results, summaries, warnings, table, elapsed, failure, [s.name for s in studies])
