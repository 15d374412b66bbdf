"""``estimate``: the TEA on one column of a file — the workflow (:func:`estimate_file`: read, sample time, missing
samples and timing, the run, the trajectories and settings written, the summary) and its text lines
(:func:`estimate_lines`)."""
from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["estimate_file", "estimate_lines"]


def estimate_file(file, config, *, column: str = "y", h: float | None = None, out=None, source: str = "",
                  allow_missing: bool = False, device=None, compile: bool = False, progress: Callable | None = None,
                  log: Callable | None = None, exclude=()) -> dict:
    """Run the TEA with ``config`` on column ``column`` of ``file`` (and its known input ``u``, if the file has one),
    the paper's scalar model. The sample time is ``h``, else the mean interval of the file's time column ``t``
    (checked against ``h`` when both exist). Writes the per-step trajectories to ``out`` (default: the file with
    suffix ``.tea.csv``) and the settings beside it (``.toml``, with ``source``). Returns the summary (the meaning of
    each number in ``meaning``; the timing's and the estimates' warnings in ``warnings``). A run stopped by Ctrl-C
    keeps what it computed (``interrupted``). ``log(line)`` takes the notes. ``exclude``: stretches ``(from_s, to_s)``
    of the series (seconds from its first sample) whose samples are made missing
    (:func:`~torchtea.sensors.measurements.exclusion_ranges`)."""
    import torch

    from .engines.structure import Structure
    from .engines.tea import make_params, run_tea
    from .sensors.io import InputError

    say = log or (lambda line: None)
    cols, missing = _read_column(file, column, allow_missing, say)
    N = len(cols["y"])
    y = torch.as_tensor(cols["y"]).unsqueeze(-1)
    u = torch.as_tensor(cols["u"]).unsqueeze(-1) if "u" in cols else None
    if u is not None and torch.isnan(u).any():
        raise InputError(f"{file}: column 'u' has missing values; a known input cannot be missing", column="u")
    h, h_source, timing = _sample_time(file, cols, h)
    excluded = _exclude(file, y, exclude, h, N, say)
    t0 = time.perf_counter()
    res = run_tea(y.unsqueeze(0).to(device), h=h, params=make_params(config, Structure()),
                  inputs=None if u is None else u.unsqueeze(0).to(device), progress=progress, compile=compile,
                  partial=True)
    res = res.to("cpu")
    elapsed = time.perf_counter() - t0
    done = int(res.alpha.shape[-2])
    out = _write_run(file, out, cols, u is not None, res, done, h, config, source)
    run = {"h": h, "h_source": h_source, "missing_samples": missing.count, "missing": missing.to_dict(),
           "excluded": excluded, "timing": timing.to_dict() if timing is not None else None, "settings": source,
           "memory": config.memory.spec(), "out": str(out), "seconds": round(elapsed, 3)}
    return _summary(res, config, y, h, N, done, timing, run)


def _read_column(file, column: str, allow_missing: bool, say: Callable) -> tuple:
    """The file's column as ``y`` (with ``u`` and ``t`` where it has them), checked, and its missing samples."""
    from .reports.identify import MIN_SAMPLES
    from .sensors.datacheck import check_missing
    from .sensors.io import InputError, read_series

    try:
        cols = read_series(file, [column], ["u", "t"], allow_missing=True)
    except InputError as exc:
        if exc.column != "t":
            raise
        # a time column that is not in seconds is not a reason to stop: read the file again without it
        say(f"column 't' is not used as time stamps ({exc})")
        cols = read_series(file, [column], ["u"], allow_missing=True)
    cols["y"] = cols.pop(column) if column != "y" else cols["y"]
    N = len(cols["y"])
    if N < MIN_SAMPLES:
        raise InputError(f"{file}: {N} samples; estimate needs at least {MIN_SAMPLES} (its estimates are "
                         "summarised over the last third of the run)")
    missing = check_missing(file, cols["y"], [column], allow=allow_missing)
    if missing.count >= N - 1:
        raise InputError(f"{file}: column {column!r} has {N - missing.count} observed sample(s); nothing to estimate")
    return cols, missing


def _sample_time(file, cols: dict, h: float | None) -> tuple:
    """``(h, h_source, timing)``: the sample time given or from column ``t``, and the check of its stamps."""
    from .sensors.datacheck import check_timing, stamp_rate
    from .sensors.io import InputError

    h_source = "--h"
    if h is None:
        rate = stamp_rate(cols["t"]) if "t" in cols else math.nan
        if not math.isfinite(rate):
            raise InputError(f"{file}: give the sample time with --h (the file has no increasing time column 't')")
        h, h_source = 1.0 / rate, "the mean interval of column 't'"
    timing = check_timing(cols["t"], 1.0 / h, column="t", rate_source=h_source) if "t" in cols else None
    return h, h_source, timing


def _exclude(file, y, exclude, h: float, N: int, say: Callable) -> list:
    """The stretches ``exclude`` asks for made missing in ``y`` (in place), as the summary lists them."""
    excluded = []
    if exclude:
        from .sensors.measurements import exclusion_ranges

        excluded = exclusion_ranges(exclude, h, N, file)
        for e in excluded:
            y[e["first"]:e["last"] + 1] = float("nan")
            say(f"excluded on request (--exclude {e['from_s']:g}:{e['to_s']:g}): samples {e['first']}–{e['last']} "
                f"({e['samples']}) made missing")
    return excluded


def _write_run(file, out, cols: dict, has_u: bool, res, done: int, h: float, config, source: str) -> Path:
    """Write the run's trajectories (``out``, default the file's ``.tea.csv``) and its settings beside them."""
    import numpy as np

    from .engines.config import write_config
    from .sensors.io import write_columns

    out = Path(out) if out else Path(file).with_suffix(".tea.csv")
    cols_out = {"t": np.arange(done) * h, "y": cols["y"][:done]}
    if has_u:
        cols_out["u"] = cols["u"][:done]
    cols_out.update({
        "x_hat": res.x[0, :, 0], "P": res.P[0, :, 0, 0], "alpha_hat": res.alpha[0, :, 0],
        "P_alpha": res.P_alpha[0, :, 0, 0], "w_hat": res.w[0, :, 0], "P_w": res.P_w[0, :, 0, 0],
        "innovation": res.innovation[0, :, 0], "innovation_var": res.innovation_cov[0, :, 0, 0],
    })
    write_columns(out, cols_out)
    write_config(out.with_suffix(".toml"), config, {"h": h, "source": source})
    return out


def _summary(res, config, y, h: float, N: int, done: int, timing, run: dict) -> dict:
    """The summary of a run: its estimates, ``run``'s entries (sample time … seconds), meanings and warnings."""
    from .reports.identify import summarise

    stats = summarise(res, (config,), y=y.unsqueeze(0), h=h, names=("y",), label="column 'y'")
    s = stats["axes"]["y"]
    summary = {
        "alpha_final": s["alpha_final"],
        "alpha_mean_last_third": s["alpha"],
        "alpha_std_last_third": s["alpha_std_last_third"],
        "alpha_filter_sd_final": s["alpha_filter_sd_final"],
        "param_final": s["param_final"],
        "param_mean_last_third": s["param"],
        "param_std_last_third": s["param_std_last_third"],
        "param_filter_sd_final": s["param_filter_sd_final"],
        "innovation_nis": s["innovation_nis"],
        "innovation_nis_last_third": s["innovation_nis_last_third"],
        "diverged": bool(res.diverged[0]),
        "diverged_at_step": int(res.diverged_at[0]) if bool(res.diverged[0]) else None,
        "samples": N,
        "steps_done": done,
        "interrupted": bool(res.interrupted),
        **run,
        "last_third": stats["last_third"],
    }
    if "memory_clamped_steps" in s:
        summary["memory_clamped_steps"] = s["memory_clamped_steps"]
    meaning = dict(stats["meaning"], alpha_mean_last_third=stats["meaning"]["alpha"],
                   param_mean_last_third=stats["meaning"]["param"])
    summary["meaning"] = {k: v for k, v in meaning.items() if k in summary}
    summary["warnings"] = (list(timing.warnings) if timing is not None else []) + stats["warnings"]
    return summary


def estimate_lines(summary: dict) -> list[str]:
    """The text summary of :func:`estimate_file`'s result."""
    from .render.text import num
    from .sensors.datacheck import Missing

    missing = Missing.from_dict(summary["missing"]).describe()
    return [
        f"order α̂: final {summary['alpha_final']:.4f}, mean of last third {summary['alpha_mean_last_third']:.4f} "
        f"(sd over the last third {summary['alpha_std_last_third']:.4f}: movement, not uncertainty)",
        f"parameter ŵ: final {summary['param_final']:.4f}, mean of last third {summary['param_mean_last_third']:.4f}",
        f"NIS (1 for a consistent filter): last third {num(summary['innovation_nis_last_third'], '.3f')}, "
        f"whole run {num(summary['innovation_nis'], '.3f')}; missing samples: {missing}",
        f"trajectories: {summary['out']}",
    ]
