"""The studies' oracle (issue 45): the exact likelihood ratio of the true model against the model without each
hidden effect, at the check's screen level, and the BIC of a rival that could stand in for an effect."""
import math

import numpy as np
import pytest
import torch
from scipy import stats

from torchtea.checking.check import CANDIDATES
from torchtea.checking.oracle import effect_df, oracle
from torchtea.noise import simulate_model
from torchtea.noise.model import parse_model

H, N = 0.01, 3000


def _series(spec, values, seed):
    return simulate_model(spec, {k: torch.tensor([v]) for k, v in values.items()}, n_steps=N, h=H,
                          generator=torch.Generator().manual_seed(seed))[0, 0].numpy()


@pytest.mark.parametrize("size, resolved", [(0.05, True), (1e-4, False)])
def test_a_step_is_resolved_when_it_shows_and_not_when_it_is_buried(size, resolved):
    """A step of 5 σ_w is resolved (LR in the thousands); one of 0.01 σ_w is not (LR ≈ 0, p ≈ 1). The p-value is the
    χ² tail with the step's two parameters (its size and its located time), against 0.05 over the candidates
    screened; the true model's maximum is never below the reduced one's (LR ≥ 0, not short)."""
    v = {"white.r": 1e-4, "step.size": size, "step.t_step": 12.0}
    y = _series("white+step", v, 1)
    o = oracle(y, H, v, "white+step", base="white")
    e = o["effects"]["step"]
    assert o["threshold"] == pytest.approx(0.05 / len(CANDIDATES))
    assert e["df"] == 2 == effect_df(parse_model("white+step"), "step")
    assert e["p"] == pytest.approx(stats.chi2.sf(e["lr"], 2))
    assert e["resolved"] is resolved and not e["short"] and e["lr"] >= 0.0
    assert e["bic_gain"] == pytest.approx(e["lr"] - 2 * math.log(N))
    assert (e["lr"] > 1000.0) if resolved else (e["lr"] < 5.0)


def test_a_gauss_markov_bias_is_told_from_a_random_walk_only_when_its_tau_is_short():
    """A Gauss–Markov bias of τ = 1 % of the record is told apart from a random walk in its place (the rival's BIC
    ≥ 6 above the truth's); at τ = half the record the random walk does as well or better (the record cannot show
    the difference) — though the bias is resolved against white noise alone in both."""
    out = {}
    for tau in (0.3, 15.0):
        v = {"white.r": 1e-4, "gauss-markov.sigma": 0.02, "gauss-markov.tau_s": tau}
        y = _series("white+gauss-markov", v, 2)
        o = oracle(y, H, v, "white+gauss-markov", base="white", rivals={"gauss-markov": ["random-walk"]})
        assert o["effects"]["gauss-markov"]["resolved"]
        out[tau] = o["rivals"]["gauss-markov"]["random-walk"]["bic_difference"]
    assert out[0.3] >= 6.0 > out[15.0]
