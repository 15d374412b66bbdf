"""Shared helpers for the experiments: simulate scenario seeds exactly as `torchtea simulate --seed K` does."""
from __future__ import annotations

import platform
import sys
from pathlib import Path

import torch

from torchtea.noise.simulate import simulate_noise_model

ROOT = Path(__file__).resolve().parent


def simulate_seed(sc, seed: int):
    """One realisation of a Scenario, as `torchtea simulate --seed seed` draws it."""
    return simulate_noise_model(n_steps=sc.n_steps, h=sc.h, order=sc.order, param=sc.param, q=sc.q, r=sc.r,
                                input_std=sc.input_std, seed=seed)


def simulate_seeds(sc, seeds):
    """Stack realisations of many seeds into one batch: y, u, x, alpha with batch dim first."""
    sims = [simulate_seed(sc, s) for s in seeds]
    stack = lambda name: torch.stack([getattr(s, name) for s in sims])  # noqa: E731
    return stack("y"), stack("u"), stack("x"), stack("alpha")


def machine() -> dict:
    return {"python": sys.version.split()[0], "torch": torch.__version__, "threads": torch.get_num_threads(),
            "cpu": platform.processor() or platform.machine()}


def write_json(path: Path, data) -> Path:
    """Strict JSON (NaN → null), as every torchtea output."""
    from torchtea.render import strictjson

    return strictjson.write(path, data)
