"""The exact likelihood's gradient and information without finite differences (issue 44, item 2): the sensitivity
filter against central differences of ℓ on every registered component, exact identities of its scoring information,
batch against single sets, the observed information from its gradients against the finite-difference Hessian, and
the cases it refuses (a temperature-driven order, missing samples)."""
import math

import numpy as np
import pytest
import torch

from torchtea.checking.screens import candidates
from torchtea.fitting.exact import centred, exact_loglik, exact_loglik_grad, gradient_supported
from torchtea.fitting.mle import fit_series, refine_best
from torchtea.fitting.scoring import fd_hessian, information_from_gradients, objective
from torchtea.noise.components import COMPONENTS, Modifier
from torchtea.noise.model import parse_model
from torchtea.noise.simulate import default_values, simulate_model
from torchtea.studies.hidden import temperature_profile

H = 0.01
N = 1500


def _series(spec, seed=0, n=N):
    T = temperature_profile(n, H, generator=torch.Generator().manual_seed(seed)).numpy()
    v = default_values(spec, H, temperature=T)
    inputs = {"temperature": torch.as_tensor(T)}
    y = simulate_model(spec, v, n_steps=n, h=H, inputs=inputs, generator=torch.Generator().manual_seed(seed + 1))
    return y[0, 0].numpy(), v, {"temperature": T}


def _spec_with(effect):
    if effect == "spikes":
        return "fractional+white+spikes:2"
    if effect == "low-pass" or effect == "digital-filter":
        return f"fractional+white+{effect}"
    if effect == "quantisation":
        return "fractional+white+quantisation"
    return f"fractional+white+{effect}"


GRADIENT_MODELS = ["fractional+white", "offset+fractional+white", "white+random-walk", "fractional+low-pass+white"] + [
    _spec_with(e) for e in candidates() if not isinstance(COMPONENTS[e], Modifier)]


@pytest.mark.parametrize("spec", GRADIENT_MODELS)
def test_gradient_matches_central_differences_on_every_component(spec):
    """At a point off the maximum (the truth moved by 0.05 in every unconstrained coordinate), the sensitivity
    filter's ℓ is the compiled filter's to 1e-9 relative and its gradient the central differences' (step 10⁻⁵, error
    O(10⁻¹⁰) relative) to 10⁻⁴ of the gradient's scale — on every registered component but the temperature-driven
    order, which the filter refuses."""
    model = parse_model(spec)
    y, v, inputs = _series(spec)
    u = model.to_unconstrained(v, H)[0] + 0.05 * torch.as_tensor(np.random.default_rng(3).normal(size=len(model.names)))
    free = [i for i, n in enumerate(model.names) if n not in model.references() and n not in model.located()]
    yc = centred(model, y)
    ll, g, info = exact_loglik_grad(model, u.unsqueeze(0), yc, H, free, inputs=inputs)
    d = 1e-5
    pts = [u]
    for i in free:
        for s in (1, -1):
            w = u.clone()
            w[i] += s * d
            pts.append(w)
    lls = exact_loglik(model, model.from_unconstrained(torch.stack(pts), H), yc, H, inputs=inputs)
    fd = (lls[1::2] - lls[2::2]) / (2 * d)
    assert ll[0] == pytest.approx(lls[0], rel=1e-9)
    scale = max(np.abs(fd).max(), 1.0)
    assert np.abs(g[0] - fd).max() < 1e-4 * scale, (spec, g[0], fd)
    assert np.allclose(info[0], info[0].T) and np.linalg.eigvalsh(info[0]).min() > -1e-8 * np.abs(info[0]).max()


def test_scoring_information_exact_identities():
    """White noise of variance r with its level integrated out: every innovation's variance is r, ∂S/∂log r = S, so
    the information of log r is ½ Σ 1 = N/2 exactly; a ramp's slope adds Σ (tₖ − t̄)²/r (the regressor less the
    integrated level) and nothing across (mean and variance are orthogonal in a Gaussian model)."""
    model = parse_model("white+ramp")
    rng = np.random.default_rng(0)
    r = 0.04
    y = rng.normal(0, math.sqrt(r), N) + 0.1 * np.arange(N) * H
    u = model.to_unconstrained({"white.r": r, "ramp.slope": 0.1}, H)
    _, _, info = exact_loglik_grad(model, u, centred(model, y), H, [0, 1])
    t = np.arange(N) * H
    assert info[0, 0, 0] == pytest.approx(N / 2, rel=1e-12)
    assert info[0, 1, 1] == pytest.approx(np.sum((t - t.mean()) ** 2) / r, rel=1e-9)
    assert abs(info[0, 0, 1]) < 1e-9 * math.sqrt(info[0, 0, 0] * info[0, 1, 1])


def test_a_batch_of_sets_is_each_set_on_its_own():
    spec = "fractional+white+random-walk+sinusoid"
    model = parse_model(spec)
    y, v, _ = _series(spec, seed=4)
    u = model.to_unconstrained(v, H)[0]
    U = torch.stack([u, u + 0.1, u - 0.07])
    free = list(range(len(model.names)))
    yc = centred(model, y)
    ll, g, info = exact_loglik_grad(model, U, yc, H, free)
    for b in range(3):
        l1, g1, i1 = exact_loglik_grad(model, U[b:b + 1], yc, H, free)
        np.testing.assert_allclose(ll[b], l1[0], rtol=1e-13)
        np.testing.assert_allclose(g[b], g1[0], rtol=1e-11, atol=1e-11 * np.abs(g1).max())
        np.testing.assert_allclose(info[b], i1[0], rtol=1e-11, atol=1e-11 * np.abs(i1).max())


def test_observed_information_from_gradients_matches_the_finite_difference_hessian():
    """At the exact maximum of a 6000-sample fractional+white+random-walk, the observed information by central
    differences of the exact gradients and the Hessian by central differences of ℓ (step 3·10⁻³) give standard errors
    within 3 % (the latter's own accuracy on 30 000 samples, scoring.HESSIAN_STEP)."""
    spec = "fractional+white+random-walk"
    model = parse_model(spec)
    y, v, _ = _series(spec, seed=7, n=6000)
    f = fit_series(model, [y], H, intervals=False)[0]
    yc = centred(model, y)
    free = torch.ones(len(model.names), dtype=torch.bool)
    Hg = information_from_gradients(model, yc, H, f.u, free, None, "soe:1e-4").numpy()
    Hd = fd_hessian(objective(model, yc, H, f.u.clone(), np.arange(len(model.names)), None, "soe:1e-4"),
                     f.u.numpy().copy())
    se_g = np.sqrt(np.diag(np.linalg.inv(Hg)))
    se_d = np.sqrt(np.diag(np.linalg.inv(Hd)))
    np.testing.assert_allclose(se_g, se_d, rtol=0.03)


def test_refused_where_the_filter_cannot_differentiate_and_the_fits_keep_differences():
    """A temperature-driven order and missing samples: exact_loglik_grad refuses by name, and the fits run their
    central-difference path (same maximum as before issue 44)."""
    spec = "fractional+white+temperature-order"
    model = parse_model(spec)
    y, v, inputs = _series(spec, seed=2)
    assert "temperature-driven order" in gradient_supported(model, y)
    with pytest.raises(ValueError, match="no sensitivity gradient"):
        exact_loglik_grad(model, model.to_unconstrained(v, H), centred(model, y), H, [0], inputs=inputs)
    gappy = y.copy()
    gappy[100:120] = np.nan
    assert "missing samples" in gradient_supported(parse_model("fractional+white"), gappy)
    f = fit_series("fractional+white", [gappy], H, intervals=True)[0]
    assert f.converged and all(f.se[n] is not None for n in ("fractional.order", "white.r"))


def test_refine_best_keeps_the_highest_maximum_and_the_forced_starts():
    """refine_best evaluates every start, refines the forced one even far below the others, and returns the highest
    maximum with the tried starts listed."""
    spec = "fractional+white+random-walk"
    model = parse_model(spec)
    y, v, _ = _series(spec, seed=9, n=3000)
    bad = dict(v, **{"fractional.order": 0.97, "random-walk.sigma": v["random-walk.sigma"] * 1e-4})
    fit, tried = refine_best(model, y, H, [("truth", v), ("bad", bad)], must=["bad"])
    names = [t[0] for t in tried]
    assert set(names) == {"truth", "bad"}
    assert fit.loglik == pytest.approx(max(t[2] for t in tried))
    assert fit.loglik >= max(t[1] for t in tried) - 1e-6


def test_the_gain_still_to_come_is_the_geometric_series_of_the_last_gains():
    """remaining: gains shrinking by a factor r each iteration sum to last·r/(1−r) from here on; gains that do not
    shrink (or a step that gained nothing) promise no bound (∞), nor does a history shorter than the window."""
    from torchtea.fitting.scoring import RACE_WINDOW, remaining

    r, first = 0.8, 0.5
    gains = first * r ** np.arange(RACE_WINDOW)
    f = 100.0 - np.concatenate([[0.0], np.cumsum(gains)])
    assert remaining(list(f)) == pytest.approx(gains[-1] * r / (1 - r), rel=1e-9)
    assert remaining(list(f[:RACE_WINDOW])) == math.inf
    assert remaining(list(100.0 - np.arange(RACE_WINDOW + 1) * 0.1)) == math.inf  # constant gains
    flat = f.copy()
    flat[-1] = flat[-2]
    assert remaining(list(flat)) == math.inf


@pytest.mark.slow
def test_a_start_that_cannot_catch_up_is_left_and_the_fit_is_the_same(monkeypatch):
    """On the bundled gx (fractional+white, 44 930 samples) a second Whittle mode crawls along the curved order–pole
    ridge 0.04 nats below the best maximum: left once it cannot catch up (CATCH_SAFETY), the fit is the one the
    scoring finds when every start runs to its end — the same ℓ and values, to the scoring's convergence tolerance —
    in fewer iterations."""
    import torchtea.fitting.scoring as scoring
    from torchtea.sensors.io import read_recording

    y = read_recording(columns=["gx"]).channels[0].values
    calls = []
    score = scoring.score_batch

    def counted(*a, **k):
        out = score(*a, **k)
        calls.append(int(out[3].sum()))
        return out

    monkeypatch.setattr(scoring, "score_batch", counted)
    fast = fit_series("fractional+white", [y], 0.01, intervals=False)[0]
    fast_iterations = sum(calls)  # (the modes' batch and the grid's)
    calls.clear()
    monkeypatch.setattr(scoring, "CATCH_SAFETY", math.inf)
    full = fit_series("fractional+white", [y], 0.01)[0]
    tol = scoring.decrement_tolerance(-full.loglik)
    assert fast.loglik == pytest.approx(full.loglik, abs=tol)
    for n in full.values:  # the same maximum to the convergence tolerance: within √(2·tol) standard errors
        assert abs(fast.values[n] - full.values[n]) <= math.sqrt(2 * tol) * full.se[n]
    assert fast_iterations < sum(calls)
