"""TensorBoard logging of a Monte Carlo study (imported only where used)."""
from __future__ import annotations

import math
from pathlib import Path

from ..core.stats import QUANTILES, over_realisations

__all__ = ["log_study", "decimated_steps"]


def decimated_steps(N: int, max_points: int):
    stride = max(1, math.ceil(N / max_points))
    return list(range(0, N, stride))


def log_study(logdir, result, summary: dict, hparams: dict, *, figures: bool = False) -> Path:
    """Write one run directory of event files for a study (a :class:`~torchtea.studies.montecarlo.StudyResult`).

    Scalars at the study's logged steps (x axis: sample index k; ≤ 1000 evenly strided steps,
    :func:`~torchtea.studies.montecarlo.logged_steps`): ``order/{truth,mean,q05…q95,rmse}``, ``param/{…}``,
    ``consistency/{nees,nis,band_lo,band_hi,order_coverage,param_coverage}`` (the coverages: the fraction of
    realisations whose truth lies within the estimate ± 2σ at that step); the fan charts as TensorBoard's own margin charts (CUSTOM SCALARS
    tab: the median with the 5–95 % and 25–75 % bands, truth against mean, NEES/NIS in their band); histograms
    ``final/order``, ``final/param``; text ``summary``; hparams (study settings → final metrics, tags
    ``metric/…``) so that several studies can be compared side by side in the HParams view.
    ``figures``: also the matplotlib fan charts (at the logged steps) as images ``figures/{order,param}_fan``
    (≈1.5 s: pyplot's import and two renderings).
    """
    from torch.utils.tensorboard import SummaryWriter
    from torch.utils.tensorboard.summary import hparams as hparams_summary

    logdir = Path(logdir)
    keep = ~result.diverged
    steps = result.steps.tolist()
    t = result.t[result.steps]
    truths = {"order": result.logged["alpha_true"], "param": result.study.truth.param_like(result.logged["alpha_true"])}
    with SummaryWriter(log_dir=str(logdir)) as w:
        series = []  # (columns, steps), written together at the end: one event per step
        for name, key, fkey in (("order", "alpha", "alpha"), ("param", "w", "w")):
            est, truth = result.logged[key], truths[name]
            st = over_realisations(est.unsqueeze(-1), truth.view(1, -1, 1), keep)
            cols = {f"{name}/truth": truth}
            if st["count"]:
                cols[f"{name}/mean"], cols[f"{name}/rmse"] = st["mean"][:, 0], st["rmse"][:, 0]
                for q, v in zip(QUANTILES, st["quantiles"][:, :, 0]):
                    cols[f"{name}/q{int(round(q * 100)):02d}"] = v
            series.append((cols, steps))
            if st["count"]:
                w.add_histogram(f"final/{name}", result.final[fkey][keep], 0)
            if st["count"] and figures:
                from ..render.plots import fan_figure

                label = "order α̂" if name == "order" else "parameter ŵ"
                w.add_figure(f"figures/{name}_fan", fan_figure(
                    None, t.numpy(), truth.numpy(), est[keep].numpy(), ylabel=label,
                    title=f"{label} over {st['count']} realisations"), 0)
        if "nees" in summary:
            kept = result.kept
            at = steps[1:] if len(steps) > 1 else steps
            lo, hi = summary["nees"]["band_95"]
            # NEES per state: with several KFx states its band is narrower than NIS's, which gets its own then
            nis_band = summary.get("nis", {}).get("band_95", [lo, hi])
            extra = {} if list(nis_band) == [lo, hi] else {"consistency/nis_band_lo": [nis_band[0]] * len(at),
                                                           "consistency/nis_band_hi": [nis_band[1]] * len(at)}
            series.append(({"consistency/nees": result.nees_sum[at] / kept, "consistency/nis": result.nis_sum[at] / kept,
                            "consistency/band_lo": [lo] * len(at), "consistency/band_hi": [hi] * len(at), **extra,
                            "consistency/order_coverage": result.covered_steps["order"][at] / kept,
                            "consistency/param_coverage": result.covered_steps["param"][at] / kept}, at))
        _scalars(w, series)
        w.add_custom_scalars(fan_layout())
        w.add_text("summary", _markdown(summary), 0)
        metrics = {"metric/order_rmse": summary["order"]["rmse"], "metric/order_bias": summary["order"]["bias"],
                   "metric/param_rmse": summary["param"]["rmse"], "metric/param_bias": summary["param"]["bias"],
                   "metric/diverged_fraction": summary["diverged_fraction"],
                   "metric/order_coverage": summary["order"]["coverage_2sigma"],
                   "metric/param_coverage": summary["param"]["coverage_2sigma"],
                   "metric/nees_mean": summary.get("nees", {}).get("mean", math.nan),
                   "metric/nis_mean": summary.get("nis", {}).get("mean", math.nan)}
        metrics = {k: (v if math.isfinite(v) else -1.0) for k, v in metrics.items()}
        for s in hparams_summary(hparams, metrics):
            w.file_writer.add_summary(s)
        for k, v in metrics.items():
            w.add_scalar(k, v, 0)
    return logdir


def fan_layout() -> dict:
    """The CUSTOM SCALARS layout of a study: margin charts (a line within a band) over the logged quantiles."""
    layout = {}
    for name in ("order", "param"):
        layout[name] = {f"{name}: median, 5–95 % of realisations": ["Margin", [f"{name}/q50", f"{name}/q05", f"{name}/q95"]],
                        f"{name}: median, 25–75 %": ["Margin", [f"{name}/q50", f"{name}/q25", f"{name}/q75"]],
                        f"{name}: truth and mean": ["Multiline", [f"{name}/truth", f"{name}/mean"]]}
    layout["consistency"] = {"NEES and NIS (means over realisations) and the 95 % band": [
        "Multiline", ["consistency/nees", "consistency/nis", "consistency/band_lo", "consistency/band_hi"]],
        "±2σ coverage of the order and the parameter (fraction of realisations; 0.95 if honest)": [
        "Multiline", ["consistency/order_coverage", "consistency/param_coverage"]]}
    return layout


def _scalars(w, series) -> None:
    """Scalar series ``[({tag: values at steps}, steps), …]`` as one event per step holding every tag logged at that
    step (what ``add_scalar`` writes, one value per tag, without an event and a Python call per value)."""
    from tensorboard.compat.proto.summary_pb2 import Summary

    at: dict = {}
    for cols, steps in series:
        for tag, vals in cols.items():
            for k, v in zip(steps, vals):
                at.setdefault(int(k), []).append(Summary.Value(tag=tag, simple_value=float(v)))
    for k in sorted(at):
        w.file_writer.add_summary(Summary(value=at[k]), k)


def _markdown(summary: dict) -> str:
    rows = ["| quantity | bias | std | RMSE | 2σ coverage | converged |", "|---|---|---|---|---|---|"]
    for name in ("order", "param"):
        s = summary[name]
        rows.append(f"| {name} | {s['bias']:.4g} | {s['std']:.4g} | {s['rmse']:.4g} | {s['coverage_2sigma']:.3f} | "
                    f"{s['converged_fraction']:.3f} |")
    rows.append("")
    rows.append(f"{summary['realisations']} realisations ({summary['diverged']} diverged, excluded from the statistics)"
                + (", interrupted" if summary["interrupted"] else ""))
    return "\n".join(rows)
