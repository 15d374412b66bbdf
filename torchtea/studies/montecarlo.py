"""Monte Carlo studies of the TEA: many simulated realisations as one (chunked) batch.

Realisation ``i`` of a study with seed ``s`` draws its input and noises from its own generator, seeded by
``numpy.random.SeedSequence(s, spawn_key=(i,))``, so a realisation is the same whatever the chunking.
"""
from __future__ import annotations

import math
from pathlib import Path
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ..core.memory import parse_memory
from ..engines.structure import OrderSchedule, Structure, parse_order_spec
from ..engines.simulate import simulate
from ..core.stats import chi2_band, convergence_time, coverage, nees, nis, over_realisations
from ..engines.tea import make_params, run_tea
from ..engines.settings import TEAConfig

__all__ = ["Truth", "Study", "StudyResult", "realisation_seed", "draw_realisation", "run_study", "auto_chunk",
           "build_study", "save_study", "STUDY_KEYS"]

#: The top-level keys of a study's TOML table.
STUDY_KEYS = ("realisations", "seed", "chunk", "truth", "estimator")
#: Command-line flags that set the truth, and the Truth field each sets.
TRUTH_FLAGS = {"n": "n_steps", "h": "h", "order": "order", "param": "param", "q": "q", "r": "r",
               "input_std": "input_std"}


@dataclass(frozen=True)
class Truth:
    """The simulated truth: the paper's scalar noise model (43)–(45) with a known Gaussian input or none.

    ``memory``: how the truth's GL sums are computed — ``"soe"`` (default: exponential sums, O(1) per step, every
    coefficient to relative 1e-8; :mod:`torchtea.core.memory`) or ``"exact"`` (the full history, O(N²) per
    realisation, what studies used before issue 13)."""

    h: float
    n_steps: int
    order: str  # SPEC as on the command line
    param: float
    q: float
    r: float
    input_std: float | None = None
    memory: str = "soe"

    def schedule(self) -> OrderSchedule:
        return parse_order_spec(self.order)


@dataclass(frozen=True)
class Study:
    """A Monte Carlo study: truth, estimator settings, size and seed."""

    truth: Truth
    estimator: TEAConfig = field(default_factory=TEAConfig)
    realisations: int = 100
    seed: int = 0
    chunk: int | None = None  # realisations per batch; None = automatic
    order_tolerance: float = 0.05
    param_tolerance: float = 0.2


def realisation_seed(seed: int, index: int) -> int:
    """A 63-bit torch seed for realisation ``index`` of a study seeded ``seed``."""
    state = np.random.SeedSequence(seed, spawn_key=(index,)).generate_state(2, dtype=np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1])) & ((1 << 63) - 1)


def draw_realisation(truth: Truth, seed: int, index: int, dtype=torch.float64):
    """Input ``(N, 1)`` (or None) and standard-normal ω, ν draws ``(N, 1)`` of one realisation."""
    g = torch.Generator().manual_seed(realisation_seed(seed, index))
    N = truth.n_steps
    u = None if truth.input_std is None else truth.input_std * torch.randn(N, 1, generator=g, dtype=dtype)
    z_w = torch.randn(N, 1, generator=g, dtype=dtype)
    z_v = torch.randn(N, 1, generator=g, dtype=dtype)
    return u, z_w, z_v


def auto_chunk(n_steps: int, budget_bytes: float | None = None, device=None) -> int:
    """Realisations per batch so that one chunk's tensors stay within ``budget_bytes``.

    Per realisation and step the TEA keeps ~16 float64 values (outputs and histories) and builds ~6 lag
    coefficients per step transiently; the study keeps ~8 trajectories: ~30·N·8 bytes of N-length data.
    Default budget: on the CPU 256 MB — the chunks' memory is reused, where fresh pages cost their first touch
    (12 µs per 4 kB page in this project's sandboxed machines: a 1000 × 3000 study in one chunk spent ~1 s
    there); on a GPU half its memory, since there the step's cost hardly grows with the batch.
    """
    if budget_bytes is None:
        dev = torch.device(device or "cpu")
        budget_bytes = (0.5 * torch.cuda.get_device_properties(dev).total_memory if dev.type == "cuda"
                        else 2.56e8)
    per = 30 * n_steps * 8 + 6 * n_steps * 8
    return max(1, int(budget_bytes // per))


@dataclass
class StudyResult:
    """Per-realisation trajectories of the finished realisations (time at dim 1)."""

    study: Study
    t: Tensor  # (N,)
    alpha_true: Tensor  # (R, N)
    alpha: Tensor  # (R, N)
    P_alpha: Tensor  # (R, N)
    w: Tensor  # (R, N)
    P_w: Tensor  # (R, N)
    nees: Tensor  # (R, N)
    nis: Tensor  # (R, N)
    diverged: Tensor  # (R,)
    finished: int
    interrupted: bool = False

    @property
    def w_true(self) -> Tensor:
        """The true parameter as a trajectory of ``w``'s shape (a broadcast view, no copy)."""
        return torch.tensor(self.study.truth.param, dtype=self.w.dtype).expand_as(self.w)


def run_study(study: Study, *, progress=None, device=None) -> StudyResult:
    """Run a study chunk by chunk; Ctrl-C between or during chunks keeps the finished chunks.

    ``progress(done, total)`` is called after each chunk. ``device``: where the truths are simulated and the TEA
    runs (default the CPU, where the TEA is the compiled engine); each realisation's draws come from its own CPU
    generator whatever the device, and the results come back to the CPU.
    """
    device = torch.device(device or "cpu")
    tr = study.truth
    R, N = study.realisations, tr.n_steps
    chunk = study.chunk or auto_chunk(N, device=device)
    schedule = tr.schedule()
    params = make_params(study.estimator, Structure(), device=device)
    # the trajectories, allocated once and filled chunk by chunk: a chunk's TEA outputs are freed (and their
    # memory reused) as soon as its rows are copied, and no final concatenation copies everything again
    traj = {k: torch.empty(R, N, dtype=torch.float64) for k in ("alpha_true", "alpha", "P_alpha", "w", "P_w", "nees", "nis")}
    diverged = torch.zeros(R, dtype=torch.bool)
    done = 0
    interrupted = False
    try:
        while done < R:
            idx = range(done, min(R, done + chunk))
            draws = [draw_realisation(tr, study.seed, i) for i in idx]
            u = None if tr.input_std is None else torch.stack([d[0] for d in draws]).to(device)
            z_w = torch.stack([d[1] for d in draws]).to(device)
            z_v = torch.stack([d[2] for d in draws]).to(device)
            sim = simulate(Structure(), n_steps=N, h=tr.h, order=schedule, parameters=[tr.param],
                           process_noise=tr.q, measurement_noise=tr.r, inputs=u, standard_draws=(z_w, z_v),
                           memory=tr.memory, device=device)
            res = run_tea(sim.y, h=tr.h, params=params, inputs=u)
            rows = slice(idx.start, idx.stop)
            for name, value in (("alpha_true", sim.alpha[..., 0]), ("alpha", res.alpha[..., 0]),
                                ("P_alpha", res.P_alpha[..., 0, 0]), ("w", res.w[..., 0]), ("P_w", res.P_w[..., 0, 0]),
                                ("nees", nees(res.x, sim.x, res.P)), ("nis", nis(res.innovation, res.innovation_cov))):
                traj[name][rows] = value  # copied to the CPU
            diverged[rows] = res.diverged
            del sim, res
            done = idx.stop
            if progress is not None:
                progress(done, R)
    except KeyboardInterrupt:
        interrupted = True
    cat = {k: v[:done] for k, v in traj.items()}
    cat["diverged"] = diverged[:done]
    t = torch.arange(N, dtype=torch.float64) * tr.h
    return StudyResult(study=study, t=t, finished=done, interrupted=interrupted, **cat)


def summarise(result: StudyResult) -> dict:
    """Final and over-time statistics of a study (diverged realisations excluded and counted)."""
    st, tr = result.study, result.study.truth
    keep = ~result.diverged
    kept = int(keep.sum())
    out = {"realisations": result.finished, "requested": st.realisations, "interrupted": result.interrupted,
           "diverged": int(result.diverged.sum()),
           "diverged_fraction": float(result.diverged.double().mean()) if result.finished else math.nan,
           "excluded_from_statistics": "diverged realisations"}
    # the kept realisations: views when none diverged (a boolean index would copy every trajectory)
    kept_rows = (lambda t: t) if bool(keep.all()) else (lambda t: t[keep])  # noqa: E731
    for name, est, truth, var, tol in (("order", result.alpha, result.alpha_true, result.P_alpha, st.order_tolerance),
                                       ("param", result.w, result.w_true, result.P_w, st.param_tolerance)):
        final = over_realisations(est[:, -1:, None], truth[:, -1:, None], keep)
        ct = convergence_time(kept_rows(est).unsqueeze(-1), kept_rows(truth).unsqueeze(-1), tol, tr.h)[:, 0]
        cov = coverage(kept_rows(est), kept_rows(truth), kept_rows(var))
        entry = {k: float(final[k][0, 0]) for k in ("mean", "bias", "std", "rmse")}
        entry["quantiles"] = {f"{int(q * 100)}%": float(v) for q, v in zip((0.05, 0.25, 0.5, 0.75, 0.95),
                                                                           final["quantiles"][:, 0, 0])}
        entry["convergence_tolerance"] = tol
        entry["converged_fraction"] = float((~torch.isnan(ct)).double().mean()) if kept else math.nan
        entry["convergence_time_quantiles"] = (
            {f"{int(q * 100)}%": float(v) for q, v in zip((0.05, 0.5, 0.95), torch.nanquantile(
                ct, torch.tensor([0.05, 0.5, 0.95], dtype=ct.dtype)))} if kept and not torch.isnan(ct).all() else {})
        entry["coverage_2sigma"] = float(cov.double().mean()) if kept else math.nan
        out[name] = entry
    if kept:
        lo, hi = chi2_band(1, kept)
        for name, series in (("nees", kept_rows(result.nees)), ("nis", kept_rows(result.nis))):
            avg = series[:, 1:].mean(0)
            out[name] = {"mean": float(avg.mean()), "band_95": [lo, hi],
                         "fraction_of_steps_inside_band": float(((avg >= lo) & (avg <= hi)).double().mean())}
    return out


def build_study(data: dict, flags: dict | None = None, *, memory=None, source: str = "study") -> tuple[Study, str]:
    """A :class:`Study` from a study table ``data`` (as parsed from STUDY.toml: ``realisations``, ``seed``,
    ``chunk``, ``[truth]``, ``[estimator]`` with an optional ``preset``), with ``flags`` on top (``preset``,
    ``realisations``, ``seed``, ``chunk`` and the truth's ``n h order param q r input_std``; None = not given)
    and ``memory`` (a :class:`~torchtea.core.memory.MemoryConfig`) replacing the estimator's. Returns the study
    and the name of the estimator's preset. A bad setting raises ``ValueError`` naming ``source``."""
    from dataclasses import replace

    from ..engines.presets import SCENARIOS, get_preset

    flags = {k: v for k, v in (flags or {}).items() if v is not None}
    unknown = set(data) - set(STUDY_KEYS)
    if unknown:
        raise ValueError(f"{source}: unknown study settings {sorted(unknown)}")
    est = dict(data.get("estimator", {}))
    preset = flags.get("preset") or est.pop("preset", None) or "paper-example1"
    est.pop("preset", None)
    try:
        estimator = TEAConfig.from_dict(est, get_preset(preset))
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None
    if memory is not None:
        estimator = replace(estimator, memory=memory)
    truth = dict(data.get("truth", {}))
    if "n" in truth:
        truth["n_steps"] = truth.pop("n")
    sc = SCENARIOS.get(preset)
    base = {}
    if sc is not None:
        base = dict(h=sc.h, n_steps=sc.n_steps, order=sc.order.spec(), param=sc.param, q=sc.q, r=sc.r,
                    input_std=sc.input_std)
    base.update(truth)
    base.update({key: flags[flag] for flag, key in TRUTH_FLAGS.items() if flag in flags})
    missing = [k for k in ("h", "n_steps", "order", "param", "q", "r") if k not in base]
    if missing:
        raise ValueError(f"the truth needs {', '.join(missing)} (flags --n --h --order --param --q --r, a [truth] "
                         "table, or a paper-example preset)")
    try:
        tr = Truth(**base)
        tr.schedule()
        if not isinstance(tr.memory, str):
            raise ValueError(f"memory must be a SPEC string such as 'soe' or 'exact', got {tr.memory!r}")
        parse_memory(tr.memory)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"bad truth: {exc}") from None
    study = Study(tr, estimator, realisations=int(flags.get("realisations", data.get("realisations", 100))),
                  seed=int(flags.get("seed", data.get("seed", 0))), chunk=flags.get("chunk", data.get("chunk")))
    if study.realisations < 1:
        raise ValueError("--realisations must be at least 1")
    return study, preset


def save_study(logdir, study: Study, preset: str, result: StudyResult | None = None,
               summary: dict | None = None, *, figures: bool = False) -> Path:
    """The one writer of a study's run directory. Without ``result``: ``study.toml`` (the study, reloadable by
    ``torchtea montecarlo --config``) and ``estimator.toml``, before the run, so an interrupted run still says
    what it was. With ``result`` and ``summary``: ``final_estimates.csv`` (one row per finished realisation)
    and the TensorBoard event files (:func:`~torchtea.studies.tblog.log_study`; ``figures``: with the matplotlib
    fan charts)."""
    from ..engines.config import dumps_toml, write_config
    from ..sensors.io import write_columns
    from .tblog import log_study

    logdir = Path(logdir)
    logdir.mkdir(parents=True, exist_ok=True)
    tr = study.truth
    if result is None:
        study_dict = {"realisations": study.realisations, "seed": study.seed,
                      **({"chunk": study.chunk} if study.chunk else {}),
                      "truth": {k: v for k, v in vars(tr).items() if v is not None},
                      "estimator": {"preset": preset, **study.estimator.to_dict()}}
        (logdir / "study.toml").write_text(dumps_toml(study_dict))
        write_config(logdir / "estimator.toml", study.estimator, {"preset": preset})
        return logdir
    if summary is None:
        raise ValueError("save_study: a result needs its summary")
    idx = np.arange(result.finished)
    write_columns(logdir / "final_estimates.csv", {
        "realisation": idx, "diverged": result.diverged.numpy().astype(float),
        "alpha_true": result.alpha_true[:, -1], "alpha_final": result.alpha[:, -1],
        "P_alpha_final": result.P_alpha[:, -1], "param_true": np.full(result.finished, tr.param),
        "param_final": result.w[:, -1], "P_param_final": result.P_w[:, -1]})
    hp = {"realisations": result.finished, "seed": study.seed, "preset": preset, "order": tr.order,
          "param": tr.param, "q": tr.q, "r": tr.r, "h": tr.h, "n": tr.n_steps,
          "input_std": tr.input_std if tr.input_std is not None else 0.0, "truth_memory": tr.memory}
    log_study(logdir, result, summary, hp, figures=figures)
    return logdir
