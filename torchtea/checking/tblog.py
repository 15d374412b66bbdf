"""A check's loop in TensorBoard: ``check --logdir DIR`` (and ``export``) writes one run per
channel (``DIR/<label>``), each step of the loop a global step:

- scalars ``loop/nll_per_sample`` (the exact −ℓ per observed sample), ``loop/psd_misfit``, ``loop/adev_misfit``,
  ``loop/failed_diagnostics`` (how many), ``loop/bic``, and from the second step ``loop/gain`` (the BIC the step
  gained);
- images ``figures/<name>``: that step's figures (spectrum, Allan deviation, … as ``report.md`` shows them), so the
  slider walks the loop;
- text ``loop/step``: what the step changed and what it repaired or broke; ``verdict`` at the last step: the model the
  loop ended with, adequate or not, why it stopped, the ties.

``check A B --together --logdir DIR`` writes one run per channel too (:func:`write_pooled_runs`): each step of the
pooled loop ``pooled/bic``, ``pooled/gain``, ``pooled/failing`` (diagnostics failed, over the recordings), its change
and candidates as text, the recordings' Allan deviations with the final pooled model as an image and the verdict.

Read back with TensorBoard's own event reader in the tests."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

__all__ = ["write_check_runs", "write_pooled_runs"]


def _step_text(row: dict, k: int) -> str:
    if k == 0:
        return f"step 0: `{row['model']}` (the model checked first); failing: {', '.join(row['failed']) or 'nothing'}"
    from .check import change_words

    return (f"step {k}: {change_words(row)} → `{row['model']}`, BIC gain {row['gain']:.1f}; repaired: "
            f"{', '.join(row['repaired']) or 'nothing'}; broke: {', '.join(row['broke']) or 'nothing'}; failing: "
            f"{', '.join(row['failed']) or 'nothing'}")


def write_check_runs(logdir, results: dict, units: dict | None = None, figures: bool = True,
                     windows: dict | None = None) -> list[Path]:
    """One TensorBoard run per channel of ``results`` (label → :class:`~.check.CheckResult`, the loop's last) under
    ``logdir``; ``units``: label → unit for the figures' axes; ``windows``: label → its noise over time
    (:func:`torchtea.fitting.windows.noise_over_time`): each noise parameter per window as scalars (at the window's
    middle, in whole seconds), its figures as images. Returns the runs' folders."""
    from torch.utils.tensorboard import SummaryWriter

    logdir = Path(logdir)
    runs = []
    for label, res in results.items():
        run = logdir / label
        rows = res.step_rows()
        steps = res.steps
        with SummaryWriter(log_dir=str(run)) as w:
            for k, (row, r) in enumerate(zip(rows, steps)):
                w.add_scalar("loop/nll_per_sample", row["nll_per_sample"], k)
                for name in ("psd_misfit", "adev_misfit", "bic"):
                    if row.get(name) is not None:
                        w.add_scalar(f"loop/{name}", row[name], k)
                w.add_scalar("loop/failed_diagnostics", len(row["failed"]), k)
                if k:
                    w.add_scalar("loop/gain", row["gain"], k)
                w.add_text("loop/step", _step_text(row, k), k)
                if figures:
                    _add_figures(w, r, label, (units or {}).get(label, "units"), k)
            if windows and label in windows:
                _add_windows(w, res, label, windows[label], (units or {}).get(label, "units"), figures)
            ties = "; ".join(t["words"] for t in res.ties) or "none"
            w.add_text("verdict", f"**{label}**: `{res.model.spec}`, {'adequate' if res.adequate else 'NOT adequate'}"
                                  f" — {res.loop_end or 'one check, no loop'}. Ties: {ties}", len(rows) - 1)
        runs.append(run)
    return runs


def _add_windows(w, res, label: str, doc: dict, unit: str, figures: bool) -> None:
    """The noise over time: each parameter per window (step: the window's middle, s) and its figures."""
    from .replicates import check_residual, dynamic_allan_figure, windows_figure, windows_lines

    for row in doc["rows"]:
        for name, v in row["parameters"].items():
            w.add_scalar(f"windows/{name}", v, int(round(0.5 * (row["from_s"] + row["to_s"]))))
    w.add_text("windows", "  \n".join(windows_lines(doc)), 0)
    if figures:
        from ..render.plots import pyplot

        plt = pyplot()
        with tempfile.TemporaryDirectory() as tmp:
            for p in (windows_figure(plt, doc, Path(tmp), label, unit),
                      dynamic_allan_figure(plt, check_residual(res), res.h, doc["length_s"], Path(tmp), label, unit)):
                _add_image(w, p, f"windows/{p.stem.split('_')[0]}", 0)


def _add_image(w, path: Path, tag: str, k: int) -> None:
    import matplotlib.image as mpimg

    img = mpimg.imread(str(path))
    if img.dtype != np.uint8:
        img = (np.clip(img, 0.0, 1.0) * 255).astype(np.uint8)
    w.add_image(tag, img[..., :3], k, dataformats="HWC")


def _add_figures(w, res, label: str, unit: str, k: int) -> None:
    """The step's figures, drawn as report.md draws them, as images at global step ``k``."""
    from .report import figures as make_figures

    with tempfile.TemporaryDirectory() as tmp:
        for p in make_figures(res, Path(tmp), label, unit):
            _add_image(w, p, f"figures/{p.stem.removeprefix(label + '_')}", k)


def write_pooled_runs(logdir, results: dict, series: dict, h: float, units: dict | None = None,
                      inputs: list | None = None, figures: bool = True) -> list[Path]:
    """One TensorBoard run per channel of a check of several recordings together (``results``: label →
    :class:`~.pooled.PooledCheck`; ``series``: label → the recordings' samples) under ``logdir``. Returns the runs'
    folders."""
    from torch.utils.tensorboard import SummaryWriter

    from .replicates import pooled_lines, together_allan_figure

    logdir = Path(logdir)
    runs = []
    for label, pc in results.items():
        run = logdir / label
        unit = (units or {}).get(label, "units")
        with SummaryWriter(log_dir=str(run)) as w:
            for k, step in enumerate(pc.steps):
                d = step.as_dict()
                w.add_scalar("pooled/bic", d["bic"], k)
                w.add_scalar("pooled/failing", sum(len(f) for f in d["failing"].values()), k)
                if d["gain"] is not None:
                    w.add_scalar("pooled/gain", d["gain"], k)
                cands = ", ".join(f"{c['effect']} {c['gain']:+.1f}" for c in d["candidates"]) or "none"
                w.add_text("pooled/step", f"step {k}: `{d['model']}` ({d['change']}); candidates: {cands}", k)
            last = len(pc.steps) - 1
            if figures:
                from ..render.plots import pyplot

                with tempfile.TemporaryDirectory() as tmp:
                    p = together_allan_figure(pyplot(), pc.together, series[label], h, Path(tmp), label, unit,
                                              inputs)
                    _add_image(w, p, "pooled/allan", last)
            w.add_text("verdict", "  \n".join(pooled_lines(label, label, pc, unit)), last)
        runs.append(run)
    return runs
