"""The studies' oracle (issue 45): the exact likelihood ratio of the true model against the model without each
hidden effect, at the check's screen level, and the BIC of a rival that could stand in for an effect."""
import math

import pytest
import torch
from scipy import stats

from torchtea.checking.check import CANDIDATES
from torchtea.noise import simulate_model
from torchtea.noise.model import parse_model
from torchtea.studies.oracle import effect_df, oracle

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


def test_two_lines_each_judged_by_its_own_values_after_the_other_is_dropped():
    """Two lines, a strong one first and a buried one second: without the first the second is labelled
    ``sinusoid`` and must keep its own frequency (held at the truth) — then the strong line is resolved and the
    buried one is not (taking the first line's values for the second would refit the strong line in its place and
    call it unresolved)."""
    v = {"white.r": 1e-4, "sinusoid.frequency_hz": 7.0, "sinusoid.amplitude": 0.01, "sinusoid.phase": 0.3,
         "sinusoid2.frequency_hz": 19.0, "sinusoid2.amplitude": 1e-5, "sinusoid2.phase": -1.0}
    y = _series("white+sinusoid+sinusoid", v, 5)
    o = oracle(y, H, v, "white+sinusoid+sinusoid", base="white")
    assert o["effects"]["sinusoid"]["resolved"] and o["effects"]["sinusoid"]["lr"] > 100.0
    assert not o["effects"]["sinusoid2"]["resolved"] and not o["effects"]["sinusoid2"]["screen"]


def _orc(lr, gain, screen=True, rivals=None):
    e = {"name": "gauss-markov", "lr": lr, "bic_gain": gain, "screen": screen,
         "resolved": screen and gain >= 6.0}
    return {"effects": {"gauss-markov": e}, "rivals": {"gauss-markov": rivals or {}}}


@pytest.mark.parametrize("orc, model, ties, status, right", [
    (_orc(300, 280, rivals={"random-walk": {"bic_difference": 40.0}}), "fractional+white+gauss-markov", [],
     "shown", True),
    (_orc(300, 280, rivals={"random-walk": {"bic_difference": 40.0}}), "fractional+white+random-walk", [],
     "shown", False),
    # resolved but within the tie window of its rival: either, with the tie named
    (_orc(300, 280, rivals={"random-walk": {"bic_difference": 2.4}}), "fractional+white+gauss-markov",
     [{"effects": ["gauss-markov", "random-walk"]}], "tie-rival", True),
    (_orc(300, 280, rivals={"random-walk": {"bic_difference": 2.4}}), "fractional+white+random-walk", [],
     "tie-rival", False),
    # the rival does better by more than the window: the record shows the rival
    (_orc(300, 280, rivals={"random-walk": {"bic_difference": -8.0}}), "fractional+white+random-walk", [],
     "rival", True),
    # passes the screen's level, under the tie window: kept, or named as a tie
    (_orc(11.0, 0.7), "fractional+white", [{"effects": ["gauss-markov"]}], "weak", True),
    (_orc(11.0, 0.7), "fractional+white", [], "weak", False),
    # not visible at all: right when not kept
    (_orc(2.0, -18.0, screen=False), "fractional+white", [], "hidden", True),
    (_orc(2.0, -18.0, screen=False), "fractional+white+gauss-markov", [], "hidden", False),
])
def test_the_judge_scores_the_loops_end_by_what_the_record_shows(orc, model, ties, status, right):
    """oracle.judge: each status of a hidden effect and what end of the loop is right for it."""
    from torchtea.studies.oracle import judge

    j = judge({"effects": ["gauss-markov"], "model": model, "ties": ties}, orc)
    assert j["status"] == {"gauss-markov": status} and j["right"] is right
    assert j["all_shown"] is (status == "shown")
