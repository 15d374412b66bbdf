"""Identification of a static IMU's noise with the TEA (paper §5), as one library function (:func:`identify`).

Steps (paper §5.1): the channels in SI units (m/s², rad/s); each channel's mean removed; the noise model fitted per
channel by the exact likelihood (or taken from a check, :func:`fits_for`) and read by the TEA
(:func:`torchtea.noise.tea.tea_view`); the TEA with the paper's MEMS settings on the channels (one batch per model
structure); the numbers and their trust warnings by :mod:`torchtea.reports.identify`, the report by
:mod:`torchtea.reports.report`. The paper's settings are for its accelerometer's axes (``paper-mems-x`` … ``-z``);
a gyroscope axis or another column takes ``paper-mems-x``'s, whose noise levels and starts the fit replaces.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from .engines.presets import get_preset
from .engines.settings import TEAConfig
from .engines.structure import Structure
from .engines.tea import STEP_OUTPUTS, TEAResult, make_params, run_tea, stack_params
from .noise.model import PAPER_MODEL
from .noise.tea import same_structure, tea_view
from .reports.identify import AXES, MIN_SAMPLES, summarise
from .sensors.datacheck import Missing, Timing
from .sensors.io import InputError, Recording
from .sensors.measurements import Measurements

__all__ = ["Identification", "identify", "memory_note", "EXACT_COST_SAMPLES", "axis_configs", "fits_for", "preset_for", "config_changes", "axis_changes",
           "LONG_INPUT", "R_MODES"]


#: From this many samples on, ``identify`` runs the TEA with ``soe`` memory unless the settings say otherwise: the
#: exact GL sums cost O(N²) per series (the whole 449 s bundled recording: 2.5 minutes; an hour at 200 Hz: days).
LONG_INPUT = 20000
#: Above this many samples, identify says what the exact full-history sums cost (O(N²)) when they are asked for.
EXACT_COST_SAMPLES = 20000


def memory_note(n: int, memory_kind: str | None = None, memory_set: bool = False) -> str | None:
    """What the TEA's memory costs on ``n`` samples, in a line for the terminal (None: nothing to say):
    ``memory_kind`` the memory asked for (None: :func:`identify`'s choice by the length, soe from
    :data:`LONG_INPUT` samples), ``memory_set`` whether the settings named one (then the choice is not news)."""
    kind = memory_kind or ("soe" if n >= LONG_INPUT else "exact")
    if n > EXACT_COST_SAMPLES and kind == "exact":
        return (f"{n} samples with the exact full-history GL sums cost O(N²) (the whole bundled recording takes "
                "about 2.5 minutes on 2 cores); --memory soe costs O(N)")
    if n >= LONG_INPUT and not memory_set:
        return f"{n} samples: the TEA runs with soe memory (O(N); --memory exact for the full sums, O(N²))"
    return None


def preset_for(channel) -> str:
    """The paper's §5.1 settings for a channel (a :class:`~torchtea.sensors.io.Channel`, or an axis name ``"x"``):
    its accelerometer axis's, ``paper-mems-x``'s for anything else."""
    sensor, axis = ("accelerometer", channel) if isinstance(channel, str) else (channel.sensor, channel.axis)
    return f"paper-mems-{axis}" if sensor == "accelerometer" and axis in AXES else "paper-mems-x"


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`.

    ``y`` is ``(C, N, 1)`` for C channels (mean-removed, SI units, NaN where missing); ``result`` has batch ``(C,)`` and, when
    the run was stopped early (``result.interrupted``), fewer than ``N`` steps. ``missing`` counts the
    missing samples of the part used; ``timing`` is the check of the file's time stamps (None without
    them); ``changes`` lists the settings that differ from the paper's §5.1 MEMS settings (and where the
    difference came from).
    """

    recording: Recording
    h: float
    y: torch.Tensor
    means: np.ndarray
    configs: tuple
    result: TEAResult
    missing: Missing | None = None
    timing: Timing | None = None
    changes: tuple = ()
    fits: tuple = ()
    #: The channels identified (:class:`~torchtea.sensors.io.Channel`), in batch order.
    channels: tuple = ()
    measurements: Measurements | None = None
    #: The TEA's view of each channel's fitted model (:class:`~torchtea.noise.tea.TEAView`; empty unless
    #: ``r_mode="fitted"``).
    views: tuple = ()
    #: The series the fits saw ``(C, N, 1)`` where the TEA's ``y`` differs from them (the model's means removed);
    #: None: ``y``.
    fitted_y: torch.Tensor | None = None

    @property
    def labels(self) -> tuple:
        """The channels' labels (``ax`` … ``gz``), the keys of the summary's ``axes``."""
        return tuple(c.label for c in self.channels) if self.channels else AXES

    def output(self, i: int) -> torch.Tensor:
        """Channel ``i``'s KFx estimate of the measured signal without its white noise, ``C x̂`` ``(T,)``: the
        fractional state for the paper's model, the sum of the model's state outputs for a grown one."""
        x = self.result.x[i]
        if not self.views or self.views[i].structure.n_states == 1:
            return x[:, 0]
        C = self.views[i].structure.C[0].to(x)
        k = C.shape[0]
        return (x[:, :k] * C).sum(-1)

    @property
    def steps(self) -> int:
        """Steps the TEA finished (``N`` unless interrupted)."""
        return int(self.result.alpha.shape[-2])

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.steps) * self.h

    def summary(self) -> dict:
        return summarise(self.result, self.configs, self.means, y=self.y, h=self.h, names=self.labels,
                         label="channel {}")


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def config_changes(base: TEAConfig, used: TEAConfig) -> list[str]:
    """``key: base → used`` for every setting that differs (dotted keys as in TOML)."""
    a, b = _flat(base.to_dict()), _flat(used.to_dict())
    return [f"{k}: {a.get(k)!r} → {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def axis_changes(base, used, names=AXES) -> list[str]:
    """:func:`config_changes` of every axis: a change that is the same on every axis once, the others prefixed
    with their axis (``"axis y: kfx.R: 0.00085 → 0.004"``)."""
    per = [config_changes(b, u) for b, u in zip(base, used)]
    common = [c for c in per[0] if all(c in p for p in per[1:])]
    return common + [f"channel {a}: {c}" for a, p in zip(names, per) for c in p if c not in common]


R_MODES = ("fitted", "measured", "paper")


def axis_configs(y: torch.Tensor, r_mode: str = "measured", overrides: dict | None = None, fits=(),
                 presets=None, h: float | None = None, views=None) -> tuple:
    """The paper's §5.1 settings per channel (``presets``, default ``paper-mems-x``, ``-y``, ``-z`` for three
    accelerometer axes; see :func:`preset_for`), with ``overrides`` on top.

    ``r_mode="fitted"`` (:func:`identify`'s default; this function's is ``"measured"``, which the live mode
    and the scripts use) takes the noise levels of a maximum-likelihood fit of the model to the channel (``fits``,
    :func:`torchtea.fitting.fit_series`; ``h`` its sample time) as the model's TEA view gives them
    (:func:`torchtea.noise.tea.tea_view`): KFx's R = Rᵒ = Rʷ = r̂, KFx's Q = q̂ (and the other states' drives),
    and the order and parameter filters start at α̂ and f̂ — the TEA then checks whether the
    order varies in time around a model whose noise levels match the data (NIS near 1).

    ``r_mode="paper"`` keeps the printed R, Rᵒ, Rʷ (4, 3.9, 11 ·10⁻⁴ (m/s²)²);
    ``"measured"`` sets all three to each channel's sample variance — the paper's
    rule ("adjusted according to noise measurement corresponding to each axis"),
    which its printed values follow for the MPU-9250.

    ``overrides`` is a settings table as in a TOML config (a partial nested dict): a ``preset`` key
    replaces the MEMS preset as the base of every channel, and every other key overrides that base — an
    ``R`` given there wins over the measured one. ``views``: the fits' TEA views already made on the channels'
    ``presets`` (:func:`identify` has them), reused for ``"fitted"`` unless a ``preset`` override asks another base.
    """
    presets = list(presets) if presets is not None else [f"paper-mems-{a}" for a in AXES]
    if r_mode not in R_MODES:
        raise ValueError(f"r_mode must be one of {R_MODES}, got {r_mode!r}")
    if r_mode == "fitted" and len(fits) != len(presets):
        raise ValueError("r_mode 'fitted' needs one fit per channel")
    overrides = dict(overrides or {})
    preset = overrides.pop("preset", None)
    out = []
    for i, name in enumerate(presets):
        cfg = get_preset(preset or name)
        if r_mode == "measured":
            r = float(np.nanvar(y[i, :, 0].cpu().numpy()))
            cfg = replace(cfg, kfx=replace(cfg.kfx, R=r), kfo=replace(cfg.kfo, R=r), kfw=replace(cfg.kfw, R=r))
        elif r_mode == "fitted":
            if h is None:
                raise ValueError("r_mode 'fitted' needs the sample time h")
            cfg = (views[i].config if views is not None and preset is None
                   else tea_view(fits[i].model, fits[i].values, h, cfg).config)
        if overrides:
            cfg = TEAConfig.from_dict(overrides, cfg)
        out.append(cfg)
    return tuple(out)


def identify(measurements: Measurements, *, model=PAPER_MODEL, r_mode: str = "fitted",
             overrides: dict | None = None, progress=None, compile: bool = False, partial: bool = False, device=None,
             inputs: dict | None = None, fits=None) -> Identification:
    """Run the TEA on the channels of a prepared recording (:func:`torchtea.sensors.measurements.prepare`).

    Parameters
    ----------
    measurements : Measurements
        The channels (each in SI units; its mean is removed here), their missing samples (NaN, predicted through:
        :func:`~torchtea.sensors.measurements.prepare` has applied the missing-sample policy) and time stamps. At
        least :data:`MIN_SAMPLES` samples.
    model : str or NoiseModel
        The noise model the TEA runs (:func:`torchtea.noise.tea.tea_view`): the paper's ``fractional+white`` by
        default, or the model ``check`` ended with (``fractional+white+random-walk+sinusoid`` …). It is fitted to each
        channel by the exact likelihood first; its other states join KFx's state, its means are removed from the
        series at their fitted values. A model other than ``fractional+white`` needs ``r_mode="fitted"``.
    r_mode : {"fitted", "measured", "paper"}
        See :func:`axis_configs`. ``"fitted"`` first fits the model to each channel by the exact likelihood
        (:func:`torchtea.fitting.fit_series`, kept in ``Identification.fits``).
    overrides : dict, optional
        TEA settings applied on top of the presets (as in a TOML config), e.g. ``{"memory": {"kind": "exact"}}``;
        see :func:`axis_configs`. Without a ``memory`` entry, series of :data:`LONG_INPUT` samples or more run with
        ``soe`` memory (O(N) instead of O(N²)).
    progress : callable, optional
        Called as ``progress(done, total)`` with the steps done and to do over all channels: channels of one
        structure (with ``kfx_filter = "exact"``: of one model and filters' form,
        :func:`torchtea.noise.tea_exact.batch_key`) run as one batch, the batches one after another.
    compile : bool
        Passed to :func:`torchtea.engines.tea.run_tea`.
    partial : bool
        On Ctrl-C keep the steps that finished (``result.interrupted``) instead of raising. Channels still to run
        then run those steps only (each its own run of that length), so that every channel has the same steps.
    device : torch device, optional
        Where the TEA runs (default the CPU, where the scalar model takes the compiled engine; elsewhere the torch
        engine). The noise-level fit of ``r_mode="fitted"`` runs on the CPU whatever the device (its exact
        Kalman filter is compiled for the CPU); the result comes back to the CPU.
    inputs : dict, optional
        ``{"temperature": (N,)}`` for a model with temperature components.
    fits : sequence of Fit, optional
        One fit per channel, already made (e.g. the models ``check`` ended with,
        :func:`torchtea.checking.check.read_check`): each channel runs its own fit's model, nothing is refitted
        (``model`` is not used; ``r_mode`` must be ``"fitted"``).
    """
    from .noise.model import parse_model

    model = parse_model(model)
    m = measurements
    rec = m.recording
    N = m.samples
    fits, plain = _checked_fits(m, model, r_mode, fits)
    values = np.column_stack([c.values for c in m.channels])
    means = np.array([np.nanmean(c.values) for c in m.channels])  # each on its own: the same with other channels
    y = torch.as_tensor((values - means).T.copy(), dtype=torch.float64).unsqueeze(-1)  # (C, N, 1)
    views, fitted_y = (), None
    structures = [Structure()] * len(m.channels)
    presets = [preset_for(c) for c in m.channels]
    if r_mode == "fitted":
        fits, views, structures, y, fitted_y = _fit_channels(m, model, plain, fits, presets, y, inputs)
    fits = fits or ()
    configs, changes = _channel_configs(m, y, r_mode, overrides, fits, presets, views, structures)
    exact, exact_views = _exact_views(configs, views)
    groups = _batches(structures, exact, exact_views)
    results = _run_batches(groups, y, N, rec.h, configs, structures, exact, exact_views, progress=progress,
                           compile=compile, partial=partial, device=device)
    result = results[0] if len(groups) == 1 else _in_channel_order(results, groups)
    return Identification(rec, rec.h, y, means, configs, result, m.missing, m.timing, changes, fits, m.channels, m,
                          views, fitted_y)


def _checked_fits(m: Measurements, model, r_mode: str, fits) -> tuple:
    """identify's checks of the samples, the fits given and ``r_mode``: ``(fits, plain)``."""
    N = m.samples
    if N < MIN_SAMPLES:
        raise InputError(f"{m.recording.path}: {N} samples; identify needs at least {MIN_SAMPLES} (its estimates are "
                         "summarised over the last third of the run)")
    given = fits is not None
    if given:
        fits = tuple(fits)
        if len(fits) != len(m.channels):
            raise ValueError(f"{len(fits)} fits for {len(m.channels)} channels")
    plain = all(f.model.spec == PAPER_MODEL for f in fits) if given else model.spec == PAPER_MODEL
    if (given or not plain) and r_mode != "fitted":
        what = "the given fits" if given else f"model {model.spec!r}"
        raise ValueError(f"{what}: the noise levels come from the fit; use r_mode 'fitted'")
    return fits, plain


def _fit_channels(m: Measurements, model, plain: bool, fits, presets: list, y: torch.Tensor, inputs) -> tuple:
    """``r_mode="fitted"``: the fits (made where not given), their TEA views and structures, and the series."""
    rec, N = m.recording, m.samples
    fitted_y = None
    if fits is None:
        from .fitting import fit_series

        fits = tuple(fit_series(model, [y[i, :, 0].numpy() for i in range(len(m.channels))], rec.h,
                                method="exact", profile=plain, inputs=None if inputs is None else
                                [inputs] * len(m.channels)))
    # each channel's view on its own preset, once: its structure, and the settings axis_configs starts from
    views = tuple(tea_view(f.model, f.values, rec.h, get_preset(p))  # refuses a model the TEA cannot run
                  for f, p in zip(fits, presets))
    structures = [v.structure for v in views]
    if not plain:  # the model's means (a ramp, a line …) at their fitted values; a channel of the paper's model
        fitted_y = y  # keeps its series as it is (its mean is off already), as when it is identified alone
        t = np.arange(N) * rec.h
        y = torch.stack([y[i, :, 0] if f.model.spec == PAPER_MODEL else v.residual(y[i, :, 0], t, inputs)
                         for i, (f, v) in enumerate(zip(fits, views))]).unsqueeze(-1)
    return fits, views, structures, y, fitted_y


def _channel_configs(m: Measurements, y: torch.Tensor, r_mode: str, overrides, fits, presets: list, views,
                     structures: list) -> tuple:
    """``(configs, changes)``: each channel's TEA settings (``soe`` memory for long inputs), what overrides changed."""
    rec, N = m.recording, m.samples
    overrides = dict(overrides or {})
    if "memory" not in overrides and (N >= LONG_INPUT or overrides.get("kfx_filter") == "exact"):
        overrides["memory"] = {"kind": "soe"}  # an exact KFx carries its past in its state: soe keeps it small
    configs = axis_configs(y, r_mode, overrides or None, fits, presets, h=rec.h, views=views)
    changes = tuple(axis_changes(axis_configs(y, r_mode, None, fits, presets, h=rec.h, views=views), configs,
                                 [c.label for c in m.channels]))
    for st, cfg, c in zip(structures, configs, m.channels):
        if st.n_states > 1 and cfg.noise_scaling != "scaled":  # the states' drives are h^α Q0 h^α (tea_view)
            raise ValueError(f"channel {c.label}: a model of several KFx states needs noise_scaling 'scaled' (its "
                             f"states' drives are written for it), not {cfg.noise_scaling!r}")
    return configs, changes


def _exact_views(configs: tuple, views) -> tuple:
    """Which channels run an exact KFx (``kfx_filter = "exact"``), and their views, checked: ``(exact, views)``."""
    exact = [cfg.kfx_filter == "exact" for cfg in configs]
    if any(exact) and not views:
        raise ValueError("kfx_filter 'exact' runs the exact filter of the fitted model's state space: it needs "
                         "r_mode 'fitted'")
    exact_views = {}
    if any(exact):
        from .noise.tea_exact import check_exact

        exact_views = {i: replace(views[i], config=configs[i]) for i, e in enumerate(exact) if e}
        for v in exact_views.values():  # every channel's settings and model, before any runs
            check_exact(v)
    return exact, exact_views


def _batches(structures: list, exact: list, exact_views: dict) -> list[list[int]]:
    """The channels in batches that one run of the TEA can take, in the order of their first channels."""
    if any(exact):
        from .noise.tea_exact import batch_key

    def batch_with(i: int, j: int) -> bool:
        """Whether channels i and j run as one batch: the same structure, or (an exact KFx) the same batch_key."""
        if exact[i] or exact[j]:
            return exact[i] and exact[j] and batch_key(exact_views[i]) == batch_key(exact_views[j])
        return same_structure(structures[i], structures[j])

    groups: list[list[int]] = []  # channels one batch can run
    for i in range(len(structures)):
        g = next((g for g in groups if batch_with(g[0], i)), None)
        (g.append(i) if g is not None else groups.append([i]))
    return groups


def _run_batches(groups: list, y: torch.Tensor, N: int, h: float, configs: tuple, structures: list, exact: list,
                 exact_views: dict, *, progress, compile: bool, partial: bool, device) -> list:
    """The TEA's results, batch after batch (after a Ctrl-C the later ones run the steps the interrupted one did)."""
    if any(exact):
        from .noise.tea_exact import run_tea_exact
    results = []
    steps, done = N, 0  # samples each group runs (after a Ctrl-C: those the interrupted group finished); steps done
    for g in groups:
        # progress over all groups: (steps done in every group so far, steps of all groups)
        prog = None if progress is None else (lambda k, _n, d=done: progress(d + k, len(groups) * (N - 1)))
        if exact[g[0]]:  # on the CPU, the channels of one model and filters' form as one batch
            r = run_tea_exact([exact_views[i] for i in g], y[g, :steps, 0], h=h, progress=prog, partial=partial)
        else:
            params = stack_params([make_params(configs[i], structures[i]) for i in g])
            r = run_tea(y[g, :steps].to(device or "cpu"), h=h, params=params, structure=structures[g[0]],
                        progress=prog, compile=compile, partial=partial).to("cpu")
        results.append(r)
        done += r.alpha.shape[-2] - 1
        if r.interrupted:  # Ctrl-C: the later groups run the samples this one finished, so that no channel waits
            steps = r.alpha.shape[-2]
            if steps == 0:
                raise KeyboardInterrupt
    return results


def fits_for(doc: dict, fits: dict, measurements: Measurements) -> list:
    """The fits a check made (``fits`` by channel label, from its ``check.json`` ``doc``:
    :func:`torchtea.checking.check.read_check`) for the channels of ``measurements``, in their order; raises
    ``ValueError`` when the check read another recording (by its file's name: the check's path is its own working
    directory's or clone's), another number of samples, or lacks a channel."""
    from pathlib import Path

    rec, checked = measurements.recording, Path(doc["recording"])
    if checked.name != Path(rec.path).name:
        raise ValueError(f"it checked {doc['recording']}, not {rec.path}")
    if int(doc["samples"]) != measurements.samples:
        raise ValueError(f"it checked {doc['samples']} samples, this reads {measurements.samples} (give the check's "
                         "--samples and reading flags)")
    missing = [c.label for c in measurements.channels if c.label not in fits]
    if missing:
        raise ValueError(f"no check of channel(s) {', '.join(missing)} (it has {', '.join(fits)})")
    return [fits[c.label] for c in measurements.channels]


def _in_channel_order(results: list, groups: list) -> TEAResult:
    """Results of channel groups (batch ``(len(g),)`` each) as one result in channel order; an interruption keeps
    the steps every group finished."""
    from dataclasses import fields

    steps = min(r.alpha.shape[-2] for r in results)
    order = torch.as_tensor(np.argsort(np.concatenate(groups), kind="stable"))
    out = {}
    n = max(r.x.shape[-1] for r in results)  # channels of other models may have fewer KFx states: NaN-padded
    for f in fields(TEAResult):
        vals = [getattr(r, f.name) for r in results]
        if f.name in ("x", "P"):
            vals = [_pad(v[:, :steps], n, f.name == "P") for v in vals]
        if f.name in STEP_OUTPUTS:
            out[f.name] = torch.cat([v[:, :steps] for v in vals])[order]
        elif f.name == "steps":
            out[f.name] = None if vals[0] is None else vals[0][:steps]
        elif f.name == "interrupted":
            out[f.name] = any(vals)
        else:
            out[f.name] = None if vals[0] is None else torch.cat(vals)[order]
    # a group that ran further than the others: its divergence only where it is within the steps kept (its soe clamp
    # count still covers all its steps)
    out["diverged"] = out["diverged"] & (out["diverged_at"] < steps)
    out["diverged_at"] = torch.where(out["diverged"], out["diverged_at"], -1)
    return TEAResult(**out)


def _pad(t: torch.Tensor, n: int, matrix: bool) -> torch.Tensor:
    """KFx's states ``(B, T, k)`` (or covariances ``(B, T, k, k)``) as ``n`` states, the missing ones NaN."""
    k = t.shape[-1]
    if k == n:
        return t
    shape = t.shape[:2] + ((n, n) if matrix else (n,))
    out = t.new_full(shape, math.nan)
    if matrix:
        out[..., :k, :k] = t
    else:
        out[..., :k] = t
    return out
