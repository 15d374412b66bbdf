"""One transform per parameter kind, one BIC, one rule of what it counts (issue 47, item 2)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torchtea.effects import register, unregister
from torchtea.fitting.mle import Fit, bic, fit_series
from torchtea.fitting.starts import initial_values, starts_of
from torchtea.noise.components import MeanEffect, ParamSpec
from torchtea.noise.model import parse_model
from torchtea.noise.simulate import default_values, simulate_model

H = 0.01


def test_every_kind_round_trips_and_the_model_uses_the_parameters_own_transform():
    """Each kind's transform and its inverse are inverse to 1e-12 inside its range, and a model's unconstrained
    coordinates are, column by column, its parameters' own transforms (the pole's at its component's order) — the
    same bits."""
    model = parse_model("fractional+white+resonance+ramp")
    v = default_values(model, H)
    u = model.to_unconstrained(v, H)[0]
    back = model.from_unconstrained(u, H)
    for i, n in enumerate(model.names):
        spec = model.param_spec(n)
        order = torch.tensor([v["fractional.order"]], dtype=torch.float64) if spec.kind == "fraction" else None
        x = torch.tensor([v[n]], dtype=torch.float64)
        assert spec.to_unconstrained(x, H, order)[0] == u[i]  # (bit for bit)
        assert float(back[n][0]) == pytest.approx(v[n], rel=1e-12, abs=1e-15)
    assert {model.param_spec(n).scale for n in model.names} == {"log", "logit", "identity"}
    with pytest.raises(ValueError, match="resonance.frequency_hz must lie between 0 and the Nyquist frequency 50 Hz"):
        model.to_unconstrained({**v, "resonance.frequency_hz": 60.0}, H)


class Chirp(MeanEffect):
    """A user's mean with a frequency below Nyquist and a bounded share: A·sin(2π f t)·(1 + s)."""
    name = "test-tone"
    params = (ParamSpec("frequency_hz", "nyquist", "Hz"), ParamSpec("share", "bounded", "-", (0.0, 1.0)),
              ParamSpec("amplitude", "free", "units"))

    def mean(self, v, t, inputs):
        w = 2 * math.pi * v["frequency_hz"].unsqueeze(-1) * t
        return v["amplitude"].unsqueeze(-1) * torch.sin(w) * (1 + v["share"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"frequency_hz": 7.0, "share": 0.5, "amplitude": 0.02}[param]


def test_the_default_least_squares_start_moves_each_parameter_on_its_kinds_scale():
    """A user's mean that no regression takes is started by least squares over its parameters, each on the scale a
    fit moves it on: the frequency stays below the Nyquist frequency and the share inside (0, 1) (the copy of the
    transforms this replaced left a "nyquist" frequency unconstrained and took a pole's fraction as a plain (0, 1)
    value)."""
    register(Chirp)
    try:
        m = parse_model("white+test-tone")
        y = simulate_model(m, {"white.r": 1e-6, "test-tone.frequency_hz": 7.0, "test-tone.share": 0.5,
                               "test-tone.amplitude": 0.02}, n_steps=2000, h=H,
                           generator=torch.Generator().manual_seed(0))[0, 0].numpy()
        start = initial_values(m, torch.as_tensor(y), H)
        assert start["test-tone.frequency_hz"] == 25.0 and start["test-tone.share"] == 0.5  # the kinds' defaults
        resid = y - y.mean()
        t, ok = np.arange(len(y)) * H, np.ones(len(y), dtype=bool)
        comp = dict(m.components)["test-tone"]
        vals = starts_of(comp).fit_residual(comp, "test-tone", resid, t, ok, H, start, None)
        assert 0 < vals["test-tone.frequency_hz"] < 0.5 / H and 0 < vals["test-tone.share"] < 1
    finally:
        unregister("test-tone")


def test_register_refuses_a_kind_without_a_transform_and_a_pole_fraction_without_an_order():
    class Odd(Chirp):
        name = "odd-kind"
        params = (ParamSpec("x", "angle", "rad"),)

    class Pole(Chirp):
        name = "lone-pole"
        params = (ParamSpec("pole", "fraction", "1/s"),)

    with pytest.raises(ValueError, match="kind must be one of positive, bounded, fraction, nyquist, free"):
        register(Odd)
    with pytest.raises(ValueError, match="needs an order_param"):
        register(Pole)


def test_bic_is_one_formula_and_held_estimates_count_once():
    """``Fit.bic`` is the fit's own likelihood's, ``Fit.bic_exact`` the exact one's (what check ranks by), both
    k ln n − 2ℓ; a step's time, held where the data put it, counts in k (once, however often it is counted)."""
    m = "fractional+white+step"
    v = default_values(m, H)
    v.update({"step.size": 0.05, "step.t_step": 12.0})
    y = simulate_model(m, v, n_steps=3000, h=H, generator=torch.Generator().manual_seed(2))[0, 0].numpy()
    f = fit_series(m, [y], H, method="exact", intervals=False)[0]
    assert "step.t_step" in f.free and f.k == len(f.free) == len(parse_model(m).names)
    assert f.bic_exact == f.k * math.log(f.n) - 2 * f.loglik_exact == bic(f.k, f.n, f.loglik_exact)
    assert f.bic == bic(f.k, f.n, f.loglik)
    k = f.k
    f.count(parse_model(m).held_estimates())
    assert f.k == k and isinstance(f, Fit)
    assert parse_model("fractional+white+temperature-bias").held_estimates() == {}  # a reference does not count


def test_a_registered_start_replaces_a_built_in_one_only_when_asked_and_unregistering_restores_it():
    """``register_start`` refuses to overwrite an effect's starts without ``replace=True``; ``unregister_start`` of a
    built-in effect brings its own starts back (not the bare defaults); the effects page names a user's starts class
    without a docstring instead of failing on it."""
    from torchtea.fitting.starts import Starts, register_start, unregister_start
    from torchtea.fitting.starts.markov import RandomWalkStarts
    from torchtea.noise.components import RandomWalk
    from torchtea.reference import effects_page

    class Mine(Starts):
        pass

    with pytest.raises(ValueError, match="RandomWalk has its starts registered already"):
        register_start(RandomWalk)(Mine)
    register_start(RandomWalk, replace=True)(Mine)
    try:
        assert type(starts_of(RandomWalk())) is Mine
        assert "its own (Mine)" in effects_page()
    finally:
        unregister_start(RandomWalk)
    assert type(starts_of(RandomWalk())) is RandomWalkStarts


def test_the_default_starts_are_inside_every_kinds_range():
    """The default start of each kind transforms to a finite unconstrained value: a pole's at half its stability
    limit at the order started from (it was 0.5, a positive pole, whose transform is NaN); a 'bounded' parameter
    needs finite bounds (register refuses others)."""
    class Kinds(MeanEffect):
        name = "test-kinds"
        order_param = "order"
        params = (ParamSpec("order", "bounded", "-", (0.0, 1.0)), ParamSpec("pole", "fraction", "1/s"),
                  ParamSpec("level", "positive", "units"), ParamSpec("f", "nyquist", "Hz"),
                  ParamSpec("x", "free", "units"))

        def mean(self, v, t, inputs):
            return v["x"].unsqueeze(-1) * t

        def typical(self, param, h, t_ref):
            return 0.0

    class Unbounded(Chirp):
        name = "test-unbounded"
        params = (ParamSpec("share", "bounded", "-"),)

    with pytest.raises(ValueError, match="'bounded' parameter needs finite bounds"):
        register(Unbounded)
    register(Kinds)
    try:
        m = parse_model("white+test-kinds")
        y = torch.linspace(0.0, 1.0, 200, dtype=torch.float64)
        start = initial_values(m, y, H)
        assert start["test-kinds.pole"] == pytest.approx(-0.5 * 2 ** 0.3 / H ** 0.3)
        u = m.to_unconstrained({n: [x] for n, x in start.items()}, H)
        assert bool(torch.isfinite(u).all())
    finally:
        unregister("test-kinds")
