"""The long-record path (``torchtea.fitting.whittle_path``) against the exact one: which fits take it, its estimates
against the exact maximum on simulated records where both run, the loop's model, and what ``check.json`` says."""
import json

import numpy as np
import pytest
import torch

from torchtea.checking import check
from torchtea.cli import main
from torchtea.fitting import whittle_path as wp
from torchtea.fitting.mle import fit_series
from torchtea.noise import default_values, simulate_model

H = 0.01
N = 12_000  # (above WHITTLE_PATH_SAMPLES, below POLISH_SAMPLES)


def _series(spec: str, seed: int, n: int = N, **values) -> np.ndarray:
    v = {**default_values(spec, H), **values}
    return simulate_model(spec, v, n_steps=n, h=H, generator=torch.Generator().manual_seed(seed))[0, 0].numpy()


def test_which_fits_take_the_long_record_path():
    short, long = np.zeros(wp.WHITTLE_PATH_SAMPLES), np.zeros(wp.WHITTLE_PATH_SAMPLES + 1)
    stationary, varying = "white+random-walk", "fractional+white+temperature-order"
    assert wp.uses_exact(stationary, short) and not wp.uses_exact(stationary, long)
    assert wp.uses_exact(stationary, long, "exact") and not wp.uses_exact(stationary, short, "whittle")
    # a model without a spectrum is fitted by the exact likelihood whatever the length, optimised only up to the
    # threshold (above, evaluated at its best start)
    assert wp.uses_exact(varying, long) and wp.uses_exact(varying, long, "whittle")
    assert wp.exact_optimised(short) and not wp.exact_optimised(long) and wp.exact_optimised(long, "exact")
    varying = "fractional+white+temperature-order"  # no spectrum: optimised exactly up to the polish's length
    assert wp.exact_optimised(long, model=varying) and not wp.exact_optimised(long, "whittle", varying)
    assert not wp.exact_optimised(np.zeros(wp.POLISH_SAMPLES + 1), model=varying)
    with pytest.raises(ValueError, match="fits must be one of"):
        wp.uses_exact(stationary, short, "fast")


CASES = [("white+random-walk", 1, {}), ("fractional+white", 3, {}),
         ("white+gauss-markov", 2, {"gauss-markov.tau_s": 5.0}),
         ("white+resonance", 5, {"resonance.sigma": 0.01, "resonance.bandwidth_hz": 0.5})]


@pytest.mark.parametrize("spec,seed,values", CASES, ids=[c[0] for c in CASES])
def test_the_long_record_path_estimates_are_the_exact_path_s(spec, seed, values):
    """On 12 000 samples of the model the long-record path's fit (its Whittle fit, refined on the exact likelihood
    from there: POLISH_SAMPLES) lies within 0.2 of the exact path's standard errors of the exact path's estimate —
    the Newton decrement it stops at, POLISH_TOLERANCE, bounds the distance by √(2 · 0.02) = 0.2 — and its exact ℓ
    within 0.02 nats; the Whittle estimates alone (``fits="whittle"``) within 0.5 (measured: at most 0.25, a narrow
    resonance's bandwidth; 3.7 for a random walk before its trend was profiled out of the Whittle sum)."""
    y = _series(spec, seed, **values)
    exact = fit_series(spec, [y], H, method="exact", intervals=True, profile=False)[0]
    auto = wp.whittle_estimate(spec, y, H, intervals=True)
    whittle = wp.whittle_estimate(spec, y, H, intervals=True, fits="whittle")
    assert auto.method == "exact" and whittle.method == "whittle"
    assert any("refined by the exact likelihood" in n for n in auto.notes)
    names = [n for n in exact.values if exact.se.get(n)]
    assert len(names) == len(exact.free)
    for fit, bound in ((auto, 0.2), (whittle, 0.5)):
        z = {n: (fit.values[n] - exact.values[n]) / exact.se[n] for n in names}
        assert max(abs(v) for v in z.values()) <= bound, (fit.method, z)
        assert fit.loglik_exact <= exact.loglik_exact + 1e-6  # (the exact maximum is the maximum)
        # its intervals are the exact likelihood's expected information at its point, the exact path's its observed
        # information: they differ where a parameter is poorly determined by 120 s of data (measured: 20 % for a
        # Gauss–Markov time of 5 s, a factor 1.7 for the fractional part, its order's standard error 0.2)
        rel = 0.7 if spec.startswith("fractional") else 0.3
        assert all(fit.se[n] == pytest.approx(exact.se[n], rel=rel) for n in names), (fit.se, exact.se)
    assert auto.loglik_exact >= exact.loglik_exact - 0.02


@pytest.mark.slow
def test_the_loop_on_the_long_record_path_ends_where_the_exact_loop_does():
    """A random walk in white noise: the Whittle path's loop passes through a ramp (a walk's excursion looks like
    one to the Whittle sum of a model without a walk) and must take it away again — every alternative of a long
    record is evaluated by the exact likelihood, not only those within the Whittle window — to end, as the exact
    loop does, with white+random-walk at the same BIC."""
    y = _series("white+random-walk", 1)
    exact = check(y, H, fits="exact").auto()
    long = check(y, H, fits="whittle").auto()
    assert exact.model.spec == long.model.spec == "white+random-walk"
    assert any("ramp" in row["model"] for row in long.step_rows())
    assert long.fit.method == "whittle" and exact.fit.method == "exact"
    assert long.fit.bic_exact == pytest.approx(exact.fit.bic_exact, abs=1.0)


def test_check_json_says_how_the_model_was_fitted(tmp_path):
    y = _series("white+random-walk", 4, n=3000)
    np.savetxt(tmp_path / "rec.csv", y, header="gz", comments="", fmt="%.9g")
    for fits in ("whittle", "exact"):
        out = tmp_path / fits
        assert main(["check", str(tmp_path / "rec.csv"), "--columns", "gz", "--units", "rad/s", "--rate", "100",
                     "--model", "white+random-walk", "--fits", fits, "--no-plots", "--out", str(out)]) == 0
        doc = json.loads((out / "check.json").read_text())
        base = doc["axes"]["gz"]["base"]
        assert base["method"] == fits
        assert "whittle" in doc["meaning"]["method"]
        if fits == "whittle":
            assert all("at the whittle estimate" in w for n, w in base["ci95_method"].items() if base["se"][n])
