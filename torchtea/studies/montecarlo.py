"""Monte Carlo studies of the TEA: many simulated realisations as one (chunked) batch.

Realisation ``i`` of a study with seed ``s`` draws its input and noises from its own generator, seeded by
``numpy.random.SeedSequence(s, spawn_key=(i,))``, so a realisation is the same whatever the chunking (its truth
exactly; its estimates bit for bit on the compiled scalar engine, to rounding on the torch engine, whose batched
reductions are not bitwise batch-invariant — which a TEA whose KFo wanders can amplify over a long run).

The truth is the paper's scalar model (``order`` … ``r``, a known input or none) or a noise model
(``[truth] model = "fractional+white+random-walk"`` with ``[truth.values]``; :func:`simulate_model_truth`), estimated
through the TEA's view of an estimator model (``[estimator] model``, default the truth's; :func:`estimator_view`). Under
``prior = "consistent"`` its filters' starting estimates come from a second stream, ``spawn_key=(i, 1)``
(:func:`draw_prior`), so the input and noises are those of ``prior = "preset"``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..core.memory import parse_memory
from ..core.stats import chi2_band, convergence_time, coverage, nees, nis, over_realisations
from ..engines.settings import TEAConfig
from ..engines.structure import OrderSchedule, Structure, parse_order_spec
from ..engines.tea import make_params, run_tea
from ..noise.simulate import Simulation, simulate
from .results import FINALS, StudyResult, logged_steps

__all__ = ["Truth", "Study", "StudyResult", "realisation_seed", "draw_realisation", "draw_prior", "run_range", "auto_chunk", "logged_steps", "summarise", "build_study", "save_study", "STUDY_KEYS", "PRIORS"]

#: The top-level keys of a study's TOML table.
STUDY_KEYS = ("realisations", "seed", "chunk", "log_points", "prior", "truth", "estimator", "sweep")
#: Where each realisation's filters start (:attr:`Study.prior`).
PRIORS = ("preset", "consistent")
#: Command-line flags that set the truth, and the Truth field each sets.
TRUTH_FLAGS = {"n": "n_steps", "h": "h", "order": "order", "param": "param", "q": "q", "r": "r",
               "input_std": "input_std"}


@dataclass(frozen=True)
class Truth:
    """The simulated truth: the paper's scalar noise model (43)–(45) with a known Gaussian input or none.

    ``memory``: how the truth's GL sums are computed — ``"soe"`` (default: exponential sums, O(1) per step, every
    coefficient to relative 1e-8; :mod:`torchtea.core.memory`) or ``"exact"`` (the full history, O(N²) per
    realisation)."""

    h: float
    n_steps: int
    order: str  # SPEC as on the command line
    param: float
    q: float
    r: float
    input_std: float | None = None
    memory: str = "soe"
    #: A noise model as the truth (``"fractional+white+random-walk"``, :mod:`torchtea.noise`) with its parameter
    #: ``values`` (``{"fractional.order": 0.4, …}``), simulated by :func:`torchtea.noise.simulate_model`; ``order``,
    #: ``param``, ``q`` and ``r`` are then its fractional state's order, pole and drive and its measurement variance
    #: (:func:`build_study` fills them in). None: the paper's scalar model from ``order`` … ``r``.
    model: str | None = None
    values: dict | None = None

    def schedule(self) -> OrderSchedule:
        return parse_order_spec(self.order)

    def param_like(self, t: Tensor) -> Tensor:
        """The true parameter in the shape and dtype of ``t`` (a broadcast view, no copy)."""
        return torch.tensor(self.param, dtype=t.dtype).expand_as(t)


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
    log_points: int | None = None  # steps kept for TensorBoard and fan charts; None = automatic (logged_steps)
    #: where each realisation's KFx, KFo and KFw start: "preset" — the estimator's x0 for every realisation (a
    #: fixed start, however far from the truth its P0 says it may be); "consistent" — drawn per realisation from
    #: the estimator's own priors centred on the truth (:func:`draw_prior`), the condition under which a
    #: consistent filter's NEES averages 1 and its ±2σ intervals cover 95 % from the first step
    prior: str = "preset"
    #: The noise model the TEA runs (its view, :func:`torchtea.noise.tea.tea_view`, at the truth's values of its
    #: parameters); None: the truth's model (or the paper's scalar one). Only with a model truth.
    estimator_model: str | None = None

    def __post_init__(self):
        if self.prior not in PRIORS:
            raise ValueError(f"prior must be one of {', '.join(PRIORS)}, got {self.prior!r}")


def realisation_seed(seed: int, index: int, stream: int = 0) -> int:
    """A 63-bit torch seed for realisation ``index`` of a study seeded ``seed``: its input and noises
    (``stream`` 0) or its filters' starting estimates (``stream`` 1, :func:`draw_prior`)."""
    key = (index,) if stream == 0 else (index, stream)
    state = np.random.SeedSequence(seed, spawn_key=key).generate_state(2, dtype=np.uint32)
    return int((int(state[0]) << 31) ^ int(state[1])) & ((1 << 63) - 1)


def draw_prior(params, seed: int, rows, x_true0: Tensor, alpha_true0: Tensor, w_true: Tensor):
    """The starting estimates of realisations ``rows`` under ``prior = "consistent"``: ``x̂₀ ~ N(x₀, P₀)``,
    ``α̂₀ ~ N(α₀, P₀ᵒ)`` (then clipped into ``order_bounds``) and ``ŵ₀ ~ N(w, P₀ʷ)``: the estimator's own prior
    covariances (``params``, from :func:`~torchtea.engines.tea.make_params`) around the truth at step 0 (``x_true0``
    ``(R, n)``, ``alpha_true0`` ``(R, L)``, one row per realisation, and ``w_true`` ``(m,)``). Realisation ``i``
    draws from its second stream, so any chunking gives the same draws. Returns ``(x0, alpha0, w0)``, each with
    the leading dimension ``R = len(rows)``."""
    from ..engines.tea import sqrt_psd

    lo, hi = params.config.order_bounds
    roots = [sqrt_psd(c.to("cpu", torch.float64)) for c in (params.P0, params.P0o, params.P0w)]  # also singular P0
    out = []
    for i in rows:
        g = torch.Generator().manual_seed(realisation_seed(seed, i, stream=1))
        out.append([root @ torch.randn(root.shape[-1], generator=g, dtype=torch.float64) for root in roots])
    x0, alpha0, w0 = (torch.stack(d) for d in zip(*out))
    return x_true0 + x0, (alpha_true0 + alpha0).clamp(lo, hi), w_true + w0


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


def _digest(study: Study, rows: range, sim, res, steps: list[int], trajectories: bool) -> StudyResult:
    """What a :class:`StudyResult` keeps of one batch of realisations ``rows`` (computed where the batch ran)."""
    cpu = lambda t: t.to("cpu", torch.float64)  # noqa: E731
    tr = study.truth
    alpha_true, alpha, P_alpha = cpu(sim.alpha[..., 0]), cpu(res.alpha[..., 0]), cpu(res.P_alpha[..., 0, 0])
    w, P_w = cpu(res.w[..., 0]), cpu(res.P_w[..., 0, 0])
    # NEES per KFx state (a consistent filter's averages 1 whatever its number of states; the paper's model has one)
    e_nees, e_nis = cpu(nees(res.x, sim.x, res.P) / res.x.shape[-1]), cpu(nis(res.innovation, res.innovation_cov))
    diverged = res.diverged.to("cpu")
    keep = ~diverged
    converged_at, covered, covered_steps = {}, {}, {}
    for name, est, truth, var, tol in (("order", alpha, alpha_true, P_alpha, study.order_tolerance),
                                       ("param", w, tr.param_like(w), P_w, study.param_tolerance)):
        converged_at[name] = convergence_time(est.unsqueeze(-1), truth.unsqueeze(-1), tol, tr.h)[:, 0]
        inside = coverage(est, truth, var)
        covered[name] = inside.sum(1)
        covered_steps[name] = (inside & keep[:, None]).sum(0)
    zero = torch.zeros((), dtype=torch.float64)
    idx = torch.tensor(steps)
    full = {"alpha_true": alpha_true, "alpha": alpha, "P_alpha": P_alpha, "w": w, "P_w": P_w, "nees": e_nees,
            "nis": e_nis}
    return StudyResult(
        study=study, t=torch.arange(tr.n_steps, dtype=torch.float64) * tr.h,
        index=torch.arange(rows.start, rows.stop), diverged=diverged,
        final={k: full[k][:, -1].clone() for k in FINALS}, converged_at=converged_at, covered=covered,
        covered_steps=covered_steps,
        nees_sum=torch.where(keep[:, None], e_nees, zero).sum(0), nis_sum=torch.where(keep[:, None], e_nis, zero).sum(0),
        steps=idx, logged={"alpha": alpha[:, idx], "w": w[:, idx], "alpha_true": alpha_true[0, idx]},
        trajectories=full if trajectories else None)


def run_range(study: Study, start: int, stop: int, *, device=None, progress=None, trajectories: bool = False,
              threads: int | None = None) -> StudyResult:
    """Realisations ``start … stop − 1`` of a study, chunk by chunk: one shard of a sharded study, or all of it.

    ``progress(done, total)`` (realisations of this range) is called after each chunk; Ctrl-C between or during
    chunks returns the finished chunks, marked ``interrupted``. ``threads``: torch's and numba's thread count for
    this call (a Dask worker process runs one shard per thread). Nothing here depends on ``start``/``stop``
    beyond which realisations are drawn, so any split of a study gives the same realisations.
    """
    if threads is not None:
        import numba

        torch.set_num_threads(threads)
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    device = torch.device(device or "cpu")
    tr = study.truth
    N = tr.n_steps
    view = estimator_view(study)
    n_kfx = 1 if view is None else view.structure.n_states  # KFx's covariances grow as n²
    chunk = study.chunk or max(1, auto_chunk(N, device=device) // (n_kfx * n_kfx))
    schedule = tr.schedule()
    steps = logged_steps(study)
    structure = Structure() if view is None else view.structure
    params = make_params(study.estimator if view is None else view.config, structure, device=device)
    parts = []
    done = start
    interrupted = False
    try:
        while done < stop:
            rows = range(done, min(stop, done + chunk))
            if view is None:
                draws = [draw_realisation(tr, study.seed, i) for i in rows]
                u = None if tr.input_std is None else torch.stack([d[0] for d in draws]).to(device)
                z_w = torch.stack([d[1] for d in draws]).to(device)
                z_v = torch.stack([d[2] for d in draws]).to(device)
                sim = simulate(Structure(), n_steps=N, h=tr.h, order=schedule, parameters=[tr.param],
                               process_noise=tr.q, measurement_noise=tr.r, inputs=u, standard_draws=(z_w, z_v),
                               memory=tr.memory, device=device)
            else:
                u, sim = None, simulate_model_truth(study, view, rows, device)
            if study.estimator.kfx_filter == "exact":  # the model's exact filter as KFx (load checked the rest)
                from ..noise.tea_exact import run_tea_exact

                res = run_tea_exact(view, sim.y[..., 0].to("cpu", torch.float64), h=tr.h).to(device)
            else:
                res = run_tea(sim.y, h=tr.h, params=_prior_params(study, params, rows, sim), inputs=u,
                              structure=structure)
            parts.append(_digest(study, rows, sim, res, steps, trajectories))
            del sim, res
            done = rows.stop
            if progress is not None:
                progress(done - start, stop - start)
    except KeyboardInterrupt:
        interrupted = True
    if not parts:  # interrupted before the first chunk finished
        return StudyResult.empty(study, trajectories=trajectories, interrupted=interrupted)
    return StudyResult.concat(parts, interrupted=interrupted)


def _prior_params(study: Study, params, rows: range, sim):
    """``params`` as the study's prior says: unchanged for "preset", per-realisation starting estimates
    (:func:`draw_prior`, leading batch dimension ``len(rows)``) for "consistent"."""
    if study.prior == "preset":
        return params
    cpu = lambda t: t.to("cpu", torch.float64)  # noqa: E731
    w_true = torch.full(params.w0.shape, study.truth.param, dtype=torch.float64)
    x0, alpha0, w0 = draw_prior(params, study.seed, rows, cpu(sim.x[:, 0]), cpu(sim.alpha[:, 0, :params.alpha0.shape[-1]]),
                                w_true)
    return params._replace(x0=x0.to(params.x0), alpha0=alpha0.to(params.x0), w0=w0.to(params.x0))


def estimator_view(study: Study):
    """The TEA's view of the estimator's model (:func:`torchtea.noise.tea.tea_view`) on top of the study's estimator
    settings, at the truth's values of its parameters (a known-truth study: KFx's noise levels are the truth's, KFo and
    KFw start at the truth's order and pole); None for the paper's scalar truth."""
    tr = study.truth
    if tr.model is None:
        return None
    from ..noise import parse_model
    from ..noise.tea import tea_view

    model = parse_model(study.estimator_model or tr.model)
    missing = [n for n in model.names if n not in tr.values]
    if missing:
        raise ValueError(f"the estimator's model {model.spec!r} has parameters the truth {tr.model!r} lacks: "
                         f"{', '.join(missing)}")
    return tea_view(model, {n: tr.values[n] for n in model.names}, tr.h, study.estimator)


def simulate_model_truth(study: Study, view, rows: range, device=None) -> Simulation:
    """Realisations ``rows`` of a model truth, each from its own generator (:func:`realisation_seed`), by the noise
    simulator; as a :class:`~torchtea.noise.simulate.Simulation` for the estimator's ``view``: ``y`` without the
    estimator's means at the truth's values, ``x`` the true values of the estimator's KFx states (a state of a
    component the truth lacks is 0), ``alpha`` the fractional state's (constant) order."""
    from ..noise import parse_model, simulate_states

    tr = study.truth
    N = tr.n_steps
    truth = parse_model(tr.model)
    blocks = truth.state_space(tr.values, tr.h, N, tr.memory).blocks
    seen: dict = {}
    cols = []  # per KFx state of the estimator, its column in the truth's state (None: the truth lacks it)
    for label in view.states:  # the j-th state of a component is the j-th of its block
        j = seen[label] = seen.get(label, -1) + 1
        sl = blocks.get(label)
        cols.append(None if sl is None else sl.start + j)
    keep = sorted({c for c in cols if c is not None})  # only the states the estimator has (not the soe modes)
    ys, xs = [], []
    for i in rows:
        g = torch.Generator().manual_seed(realisation_seed(study.seed, i))
        sim = simulate_states(truth, tr.values, n_steps=N, h=tr.h, memory=tr.memory, generator=g, keep=keep)
        ys.append(sim.y[0, 0, :, 0])
        xs.append(torch.stack([sim.x[0, 0, :, keep.index(c)] if c is not None else torch.zeros(N, dtype=torch.float64)
                               for c in cols], -1))
    y, x = torch.stack(ys), torch.stack(xs)  # (R, N), (R, N, n)
    t = torch.arange(N, dtype=torch.float64) * tr.h
    y = y - view.model.mean(view.values, t)  # the estimator's means, at the truth
    alpha = torch.full((len(rows), N, view.structure.n_estimated_orders), float(tr.order), dtype=torch.float64)
    empty = torch.empty(len(rows), N, 0, dtype=torch.float64)
    dev = lambda a: a.to(device or "cpu")  # noqa: E731
    return Simulation(t=dev(t), u=dev(empty), x=dev(x), y=dev(y.unsqueeze(-1)), alpha=dev(alpha),
                      process_noise=dev(empty), measurement_noise=dev(empty))


def summarise(result: StudyResult) -> dict:
    """Final and over-time statistics of a study (diverged realisations excluded and counted)."""
    st, tr = result.study, result.study.truth
    keep = ~result.diverged
    kept = result.kept
    N = tr.n_steps
    out = {"realisations": result.finished, "requested": st.realisations, "prior": st.prior,
           "interrupted": result.interrupted,
           "diverged": int(result.diverged.sum()),
           "diverged_fraction": float(result.diverged.double().mean()) if result.finished else math.nan,
           "excluded_from_statistics": "diverged realisations"}
    for name, est, truth, tol in (
            ("order", result.final["alpha"], result.final["alpha_true"], st.order_tolerance),
            ("param", result.final["w"], tr.param_like(result.final["w"]), st.param_tolerance)):
        final = over_realisations(est[:, None, None], truth[:, None, None], keep)
        ct = result.converged_at[name][keep]
        entry = {k: float(final[k][0, 0]) for k in ("mean", "bias", "std", "rmse")}
        entry["quantiles"] = {f"{int(q * 100)}%": float(v) for q, v in zip((0.05, 0.25, 0.5, 0.75, 0.95),
                                                                           final["quantiles"][:, 0, 0])}
        entry["convergence_tolerance"] = tol
        entry["converged_fraction"] = float((~torch.isnan(ct)).double().mean()) if kept else math.nan
        entry["convergence_time_quantiles"] = (
            {f"{int(q * 100)}%": float(v) for q, v in zip((0.05, 0.5, 0.95), torch.nanquantile(
                ct, torch.tensor([0.05, 0.5, 0.95], dtype=ct.dtype)))} if kept and not torch.isnan(ct).all() else {})
        # the fraction of (realisation, step) pairs inside ±2σ: a sum of integers, the same however it was split
        entry["coverage_2sigma"] = int(result.covered[name][keep].sum()) / (kept * N) if kept else math.nan
        # the same by thirds of the run: a filter can be honest while it learns and overconfident once settled
        entry["coverage_2sigma_by_third"] = [
            int(result.covered_steps[name][part].sum()) / (kept * (part.stop - part.start))
            if kept and part.stop > part.start else math.nan for part in _thirds(N)]
        out[name] = entry
    if kept:
        view = estimator_view(st)
        n = 1 if view is None else view.structure.n_states  # NEES per state: R·n times its mean is χ² with R·n dof
        for name, total, dof in (("nees", result.nees_sum, n), ("nis", result.nis_sum, 1)):
            lo, hi = (b / dof for b in chi2_band(dof, kept))
            avg = total[1:] / kept
            out[name] = {"mean": float(avg.mean()), "band_95": [lo, hi], "dof": dof,
                         "fraction_of_steps_inside_band": float(((avg >= lo) & (avg <= hi)).double().mean()),
                         "mean_by_third": [float((total[part] / kept).mean()) if part.stop > part.start else math.nan
                                           for part in _thirds(N, first=1)]}
    return out


def _thirds(N: int, first: int = 0) -> list[slice]:
    """Steps ``first … N−1`` in three consecutive parts (the last holds the remainder; parts are empty, and their
    statistics NaN, when there are fewer than three steps)."""
    n = N - first
    return [slice(first, first + n // 3), slice(first + n // 3, first + 2 * (n // 3)), slice(first + 2 * (n // 3), N)]


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
    if "sweep" in data:
        raise ValueError(f"{source}: a [sweep] table makes several studies (torchtea.studies.sweep.build_sweep)")
    est = dict(data.get("estimator", {}))
    preset = flags.get("preset") or est.pop("preset", None) or "paper-example1"
    est.pop("preset", None)
    estimator_model = flags.get("estimator_model") or est.pop("model", None)
    est.pop("model", None)
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
    if base.get("model") is not None:
        if "input_std" not in truth and "input_std" not in flags:  # a preset's scenario input is not the model's
            base["input_std"] = None
        base.update(_model_truth_fields(base, source))
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
    try:
        study = Study(tr, estimator, realisations=int(flags.get("realisations", data.get("realisations", 100))),
                      seed=int(flags.get("seed", data.get("seed", 0))), chunk=flags.get("chunk", data.get("chunk")),
                      log_points=flags.get("log_points", data.get("log_points")),
                      prior=flags.get("prior", data.get("prior", "preset")), estimator_model=estimator_model)
    except ValueError as exc:  # the prior's check
        raise ValueError(f"{source}: {exc}") from None
    if estimator_model is not None and tr.model is None:
        raise ValueError(f"{source}: an estimator model needs a model truth ([truth] model = ...)")
    if study.estimator.kfx_filter == "exact" and (tr.model is None or study.prior != "preset"):
        raise ValueError(f"{source}: kfx_filter 'exact' runs the exact filter of a model's state space: it needs a "
                         "model truth ([truth] model = ...) and prior 'preset' (its filters start at the view's "
                         "values, one start for every realisation)")
    try:
        view = estimator_view(study)  # the estimator's model: parameters the truth has, a place in the TEA for each part
        if study.estimator.kfx_filter == "exact":
            from ..noise.tea_exact import check_exact

            check_exact(view)  # its settings and model, before any realisation runs
    except ValueError as exc:
        raise ValueError(f"{source}: {exc}") from None
    if study.realisations < 1:
        raise ValueError("--realisations must be at least 1")
    if study.log_points is not None and study.log_points < 1:
        raise ValueError(f"{source}: log_points must be at least 1")
    return study, preset


def _model_truth_fields(base: dict, source: str) -> dict:
    """``order``, ``param``, ``q``, ``r`` of a model truth, from its values (its TEA view's order, pole, fractional drive
    and measurement variance); raises ``ValueError`` for an unknown model, missing or unknown values, or an input."""
    from ..noise import parse_model
    from ..noise.tea import tea_view

    try:
        model = parse_model(base["model"])
        values = {str(k): float(v) for k, v in dict(base.get("values") or {}).items()}
        missing, extra = sorted(set(model.names) - set(values)), sorted(set(values) - set(model.names))
        if missing or extra:
            raise ValueError(f"[truth] values for {model.spec!r} need exactly {', '.join(model.names)}"
                             + (f"; missing {', '.join(missing)}" if missing else "")
                             + (f"; not in the model: {', '.join(extra)}" if extra else ""))
        if base.get("input_std") is not None:
            raise ValueError("a model truth has no known input (input_std)")
        needs = sorted({name for _, c in model.components for name in c.inputs})
        if needs:
            raise ValueError(f"model {model.spec!r} reads {', '.join(needs)}: a model truth with input channels is "
                             "not simulated by montecarlo (write the study with torchtea.noise.simulate_model)")
        if "h" not in base or "n_steps" not in base:
            raise ValueError("a model truth needs h and n")
        v = tea_view(model, values, float(base["h"]))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: bad truth: {exc}") from None
    q0 = v.config.kfx.Q0
    i = v.structure.estimated.index(True)  # the fractional state's place among KFx's states
    return {"model": model.spec, "values": values, "order": repr(float(values[f"{v.orders[0]}.order"])),
            "param": float(values[v.params[0]]), "q": float(q0 if not isinstance(q0, list) else q0[i][i]),
            "r": float(v.config.kfx.R)}


def save_study(logdir, study: Study, preset: str, result: StudyResult | None = None,
               summary: dict | None = None, *, figures: bool = False, hparams: dict | None = None) -> Path:
    """The one writer of a study's run directory. Without ``result``: ``study.toml`` (the study, reloadable by
    ``torchtea montecarlo --config``) and ``estimator.toml``, before the run, so an interrupted run still says
    what it was. With ``result`` and ``summary``: ``final_estimates.csv`` (one row per finished realisation)
    and the TensorBoard event files (:func:`~torchtea.studies.tblog.log_study`; ``figures``: with the matplotlib
    fan charts; ``hparams``: more hyperparameters for the HParams view, e.g. a sweep's settings)."""
    from ..engines.config import dumps_toml, write_config
    from ..sensors.io import write_columns
    from .tblog import log_study

    logdir = Path(logdir)
    logdir.mkdir(parents=True, exist_ok=True)
    tr = study.truth
    if result is None:
        study_dict = {"realisations": study.realisations, "seed": study.seed,
                      **({"chunk": study.chunk} if study.chunk else {}),
                      **({"log_points": study.log_points} if study.log_points else {}),
                      "prior": study.prior,
                      "truth": {k: v for k, v in vars(tr).items() if v is not None},
                      "estimator": {"preset": preset, **({"model": study.estimator_model} if study.estimator_model
                                                         else {}), **study.estimator.to_dict()}}
        (logdir / "study.toml").write_text(dumps_toml(study_dict))
        write_config(logdir / "estimator.toml", study.estimator, {"preset": preset})
        return logdir
    if summary is None:
        raise ValueError("save_study: a result needs its summary")
    f = result.final
    write_columns(logdir / "final_estimates.csv", {
        "realisation": result.index.numpy(), "diverged": result.diverged.numpy().astype(float),
        "alpha_true": f["alpha_true"], "alpha_final": f["alpha"], "P_alpha_final": f["P_alpha"],
        "param_true": np.full(result.finished, tr.param), "param_final": f["w"], "P_param_final": f["P_w"]})
    hp = {"realisations": result.finished, "seed": study.seed, "preset": preset, "order": tr.order,
          "param": tr.param, "q": tr.q, "r": tr.r, "h": tr.h, "n": tr.n_steps,
          "input_std": tr.input_std if tr.input_std is not None else 0.0, "truth_memory": tr.memory,
          "prior": study.prior, "kfx_uncertainty": study.estimator.kfx_uncertainty,
          "estimate_uncertainty": study.estimator.estimate_uncertainty, "kfx_filter": study.estimator.kfx_filter,
          "kfo_kfw": study.estimator.kfo_kfw,
          "truth_model": tr.model or "paper scalar", "estimator_model": study.estimator_model or tr.model or "paper scalar",
          **(hparams or {})}
    log_study(logdir, result, summary, hp, figures=figures)
    return logdir
