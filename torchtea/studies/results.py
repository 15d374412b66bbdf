"""A Monte Carlo study's result as one form (:class:`StudyResult`: the realisations' final values, the running sums of
NEES and NIS, the coverage counts, the logged trajectories — the same whatever the chunking or the cluster), the steps
it logs (:func:`logged_steps`). Made by :func:`~.montecarlo.run_range`, written by :func:`~.montecarlo.save_study`."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

if TYPE_CHECKING:
    from .montecarlo import Study

__all__ = ["StudyResult", "logged_steps", "LOGGED_BYTES", "TRAJECTORIES", "FINALS"]


def logged_steps(study: Study) -> list[int]:
    """The sample indices at which a study keeps every realisation's α̂ and ŵ for its TensorBoard series and fan
    charts: ``study.log_points`` evenly strided steps, or by default at most 1000, fewer for very large studies
    so that the two kept ``(R, P)`` float64 arrays stay within :data:`LOGGED_BYTES` (10⁶ realisations keep 67
    steps)."""
    from .tblog import decimated_steps

    points = study.log_points or max(10, min(1000, int(LOGGED_BYTES // (16 * study.realisations))))
    return decimated_steps(study.truth.n_steps, points)


#: Memory budget of the logged trajectories of a whole study (bytes), see :func:`logged_steps`.
LOGGED_BYTES = 2 ** 30


#: The per-realisation trajectories that ``run_study(..., trajectories=True)`` keeps.
TRAJECTORIES = ("alpha_true", "alpha", "P_alpha", "w", "P_w", "nees", "nis")


#: The per-realisation final values (the last sample) every result keeps.
FINALS = ("alpha_true", "alpha", "P_alpha", "w", "P_w")


@dataclass
class StudyResult:
    """What a study keeps of its finished realisations: per realisation the final estimates, convergence times and
    ±2σ coverage counts; per step the NEES and NIS sums over the realisations that did not diverge; α̂ and ŵ of
    every realisation at the logged steps; and, when asked for, the full trajectories.

    It is the same whether the study ran in one process or as shards on a cluster (:meth:`concat` joins the
    parts of disjoint sets of realisations), so the summary, ``final_estimates.csv`` and the TensorBoard run are
    computed from it alone. Rows are in ascending realisation order; ``index`` names them (an interrupted
    sharded run may have finished a set that is not a prefix).
    """

    study: Study
    t: Tensor  # (N,) time of each sample
    index: Tensor  # (R,) int64 realisation numbers
    diverged: Tensor  # (R,) bool
    final: dict  # FINALS → (R,) values at the last sample
    converged_at: dict  # "order", "param" → (R,) convergence time [s], NaN where it never settles
    covered: dict  # "order", "param" → (R,) int64 number of steps whose truth lies within estimate ± 2σ
    nees_sum: Tensor  # (N,) Σ NEES over the realisations that did not diverge
    nis_sum: Tensor  # (N,) Σ NIS over the same
    covered_steps: dict  # "order", "param" → (N,) int64 count of the same realisations covered at each step
    steps: Tensor  # (P,) int64 logged sample indices
    logged: dict  # "alpha", "w" → (R, P) estimates at the logged steps; "alpha_true" → (P,)
    interrupted: bool = False
    trajectories: dict | None = None  # TRAJECTORIES → (R, N), only with run_study(..., trajectories=True)

    @property
    def finished(self) -> int:
        return int(self.index.shape[0])

    @property
    def kept(self) -> int:
        """Realisations in the statistics: the finished ones that did not diverge."""
        return int((~self.diverged).sum())

    @classmethod
    def empty(cls, study: Study, *, trajectories: bool = False, interrupted: bool = True) -> StudyResult:
        """A result with no finished realisation (of the study's shapes)."""
        N = study.truth.n_steps
        steps = torch.tensor(logged_steps(study))
        f64 = lambda *shape: torch.empty(shape, dtype=torch.float64)  # noqa: E731
        count = lambda: torch.empty(0, dtype=torch.int64)  # noqa: E731
        return cls(study=study, t=torch.arange(N, dtype=torch.float64) * study.truth.h, index=count(),
                   diverged=torch.empty(0, dtype=torch.bool), final={k: f64(0) for k in FINALS},
                   converged_at={"order": f64(0), "param": f64(0)}, covered={"order": count(), "param": count()},
                   nees_sum=torch.zeros(N, dtype=torch.float64), nis_sum=torch.zeros(N, dtype=torch.float64),
                   covered_steps={k: torch.zeros(N, dtype=torch.int64) for k in ("order", "param")}, steps=steps, logged={"alpha": f64(0, len(steps)), "w": f64(0, len(steps)),
                                        "alpha_true": torch.full((len(steps),), math.nan, dtype=torch.float64)},
                   interrupted=interrupted, trajectories={k: f64(0, N) for k in TRAJECTORIES} if trajectories else None)

    @classmethod
    def concat(cls, parts, *, interrupted: bool = False) -> StudyResult:
        """One result from parts holding disjoint realisations of the same study (in any order)."""
        parts = sorted(parts, key=lambda p: int(p.index[0]) if p.finished else -1)
        parts = [p for p in parts if p.finished] or parts[:1]
        first = parts[0]
        index = torch.cat([p.index for p in parts])
        if index.numel() != torch.unique(index).numel():
            raise ValueError("StudyResult.concat: parts share realisations")
        cat = lambda get: torch.cat([get(p) for p in parts])  # noqa: E731
        trajectories = None
        if all(p.trajectories is not None for p in parts):
            trajectories = {k: cat(lambda p, k=k: p.trajectories[k]) for k in TRAJECTORIES}
        return cls(study=first.study, t=first.t, index=index, diverged=cat(lambda p: p.diverged),
                   final={k: cat(lambda p, k=k: p.final[k]) for k in FINALS},
                   converged_at={k: cat(lambda p, k=k: p.converged_at[k]) for k in ("order", "param")},
                   covered={k: cat(lambda p, k=k: p.covered[k]) for k in ("order", "param")},
                   nees_sum=_sum(p.nees_sum for p in parts), nis_sum=_sum(p.nis_sum for p in parts),
                   covered_steps={k: _sum(p.covered_steps[k] for p in parts) for k in ("order", "param")},
                   steps=first.steps, logged={"alpha": cat(lambda p: p.logged["alpha"]),
                                              "w": cat(lambda p: p.logged["w"]),
                                              "alpha_true": first.logged["alpha_true"]},
                   interrupted=interrupted or any(p.interrupted for p in parts), trajectories=trajectories)


def _sum(tensors):
    out = None
    for t in tensors:
        out = t.clone() if out is None else out.add_(t)
    return out
