"""The compiled scalar TEA (torchtea.engines.fast) against the batched torch engine: the same recursion, so the
same numbers to float64 rounding, for every memory kind, gaps, inputs, per-axis parameters, record_every, the
divergence guard and the soe clamp count; the stream and the choice of engine."""
from dataclasses import replace

import pytest
import torch

from torchtea.core.memory import parse_memory
from torchtea.engines.presets import SCENARIOS, get_preset
from torchtea.engines.structure import ConstantOrder, Structure
from torchtea.engines.tea import TEAStream, make_params, run_tea, stack_params
from torchtea.noise.simulate import gaussian_input, simulate

FIELDS = ("x", "P", "alpha", "P_alpha", "Q_alpha", "w", "P_w", "Q_w", "innovation", "innovation_cov")


def _mems(batch, n, seed, with_input=False):
    """MEMS-like data (paper §5.1 x-axis setting: h = 0.01, α 0.4, f −4); ``with_input``: Example 1's input."""
    g = torch.Generator().manual_seed(seed)
    u = gaussian_input(batch, n, 1, 1.0, generator=g) if with_input else None
    sim = simulate(Structure(), n_steps=n, h=0.01, order=ConstantOrder(0.4), parameters=[-4.0], process_noise=0.01,
                   measurement_noise=4e-4, inputs=u, batch_shape=batch, generator=g)
    return sim.y, u


def _same(a, b, rtol=1e-10, atol=1e-12):
    for name in FIELDS:
        torch.testing.assert_close(getattr(a, name), getattr(b, name), rtol=rtol, atol=atol, msg=name)
    assert torch.equal(a.diverged, b.diverged) and torch.equal(a.diverged_at, b.diverged_at)
    assert torch.equal(a.steps, b.steps)
    assert (a.memory_clamped is None) == (b.memory_clamped is None)
    if a.memory_clamped is not None:
        assert torch.equal(a.memory_clamped, b.memory_clamped), "memory_clamped"


@pytest.mark.parametrize("memory", ["exact", "soe", "window:40"])
def test_numba_equals_torch_per_axis_params_gaps_and_record_every(memory):
    y, _ = _mems((3, 2), 500, seed=1)
    y = y.clone()
    y[0, 1, 200:207] = float("nan")  # a gap in one realisation
    y[2, :, 0] = float("nan")  # the first sample missing
    cfgs = [replace(get_preset(f"paper-mems-{a}"), memory=parse_memory(memory)) for a in "xyz"]
    params = stack_params([make_params(c, Structure()) for c in cfgs])  # (3,) against the data's (3, 2)
    params = params._replace(**{f: getattr(params, f).unsqueeze(1) for f in params._fields[:-1]})
    for every in (1, 7):
        a = run_tea(y, h=0.01, params=params, engine="torch", record_every=every)
        b = run_tea(y, h=0.01, params=params, engine="numba", record_every=every)
        assert b.x.shape == (3, 2, (500 - 1) // every + 1, 1)
        _same(a, b)
        if memory == "soe":
            assert torch.equal(a.memory_clamped, b.memory_clamped)
        else:
            assert a.memory_clamped is None and b.memory_clamped is None


@pytest.mark.parametrize("memory", ["exact", "soe"])
def test_numba_equals_torch_with_input_on_example1(memory):
    sc = SCENARIOS["paper-example1"]
    g = torch.Generator().manual_seed(3)
    u = gaussian_input((4,), 800, 1, sc.input_std, generator=g)
    sim = simulate(Structure(), n_steps=800, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
                   measurement_noise=sc.r, inputs=u, batch_shape=(4,), generator=g)
    cfg = replace(get_preset("paper-example1"), memory=parse_memory(memory))
    a = run_tea(sim.y, h=sc.h, params=make_params(cfg, Structure()), inputs=u, engine="torch")
    b = run_tea(sim.y, h=sc.h, params=make_params(cfg, Structure()), inputs=u, engine="numba")
    _same(a, b)


def test_numba_divergence_guard_and_settings_as_printed():
    """A corrupt realisation is flagged at the same step and frozen the same way; the paper's printed settings
    (sums from i = 1, unscaled Q, no cap, no adaptation of KFw) follow the same branches."""
    y, _ = _mems((4,), 300, seed=5)
    y = y.clone()
    y[1, 150:] = 1e12
    base = get_preset("paper-mems-x")
    printed = replace(base, sigma_sum_start=1, noise_scaling="unscaled", kfo=replace(base.kfo, Q_max="none"),
                      kfw=replace(base.kfw, delta=0.0))
    for cfg in (base, printed):
        a = run_tea(y, h=0.01, params=make_params(cfg, Structure()), engine="torch")
        b = run_tea(y, h=0.01, params=make_params(cfg, Structure()), engine="numba")
        assert b.diverged.tolist() == [False, True, False, False]
        _same(a, b)


def test_stream_numba_equals_stream_torch_and_run_tea():
    y, _ = _mems((3,), 300, seed=7)
    y = y.clone()
    y[1, 40] = float("nan")
    params = stack_params([make_params(replace(get_preset(f"paper-mems-{a}"), memory=parse_memory("soe")), Structure())
                           for a in "xyz"])
    runs = {}
    for engine in ("torch", "numba"):
        s = TEAStream(h=0.01, params=params, batch=(3,), horizon=300, engine=engine)
        rows = [s.step(y[:, k]) for k in range(300)]
        runs[engine] = (torch.stack([c.alpha for c, _ in rows], 1), torch.stack([o.innovation for _, o in rows], 1),
                        torch.stack([o.innovation_cov for _, o in rows], 1))
    ref = run_tea(y, h=0.01, params=params, engine="numba")
    for t, n in zip(runs["torch"], runs["numba"]):
        torch.testing.assert_close(t, n, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(runs["numba"][0], ref.alpha, rtol=0, atol=0)
    torch.testing.assert_close(runs["numba"][1], ref.innovation, rtol=0, atol=0)


def test_engine_choice_and_errors():
    y, _ = _mems((2,), 50, seed=8)
    params = make_params(get_preset("paper-mems-x"), Structure())
    with pytest.raises(ValueError, match="float32"):
        run_tea(y.float(), h=0.01, params=params, engine="numba")
    with pytest.raises(ValueError, match="engine must be"):
        run_tea(y, h=0.01, params=params, engine="gpu")
    two = Structure(A=__import__("torchtea.engines.structure", fromlist=["ParametricMatrix"]).ParametricMatrix(
        torch.zeros(1, 1, dtype=torch.float64), torch.tensor([[[2.0]]], dtype=torch.float64)))
    with pytest.raises(ValueError, match="A\\(w\\) is not w"):
        run_tea(y, h=0.01, params=make_params(get_preset("paper-mems-x"), two), structure=two, engine="numba")
    # auto = numba here: the same numbers as asking for it
    _same(run_tea(y, h=0.01, params=params), run_tea(y, h=0.01, params=params, engine="numba"), rtol=0, atol=0)


def test_interrupted_run_counts_only_finished_steps_as_clamped(monkeypatch):
    """A Ctrl-C drops the block it interrupts, and that block's soe clamp count with it: both engines report the
    same count for the same finished steps."""
    import torchtea.engines.fast as fast

    monkeypatch.setattr(fast, "BLOCK", 50)
    y, _ = _mems((2,), 400, seed=11)
    cfg = get_preset("paper-mems-x")
    cfg = replace(cfg, memory=replace(parse_memory("soe"), order_range=(0.3, 0.6)))  # sigma orders leave it often

    def stop(k, N):
        if k == 150:
            raise KeyboardInterrupt

    runs = {e: run_tea(y, h=0.01, params=make_params(cfg, Structure()), engine=e, progress=stop, partial=True)
            for e in ("torch", "numba")}
    assert runs["numba"].alpha.shape[-2] == runs["torch"].alpha.shape[-2] == 151
    assert int(runs["torch"].memory_clamped.min()) > 0
    assert torch.equal(runs["torch"].memory_clamped, runs["numba"].memory_clamped)


def test_block_size_shrinks_where_a_block_would_be_slow():
    from torchtea.engines.fast import BLOCK, block_steps

    class Eng:
        kind = 0

    assert block_steps(Eng, 10, 1) == BLOCK
    assert 1 <= block_steps(Eng, 100_000, 1000) < BLOCK  # exact memory late in a long, wide run
    Eng.kind = 1
    assert block_steps(Eng, 100_000, 1000) == BLOCK and block_steps(Eng, 5, 10**6) == 1


def test_data_with_gradients_take_the_torch_engine():
    y, _ = _mems((1,), 40, seed=12)
    plain = run_tea(y, h=0.01, params=make_params(get_preset("paper-mems-x"), Structure()))
    y = y.clone().requires_grad_()
    res = run_tea(y, h=0.01, params=make_params(get_preset("paper-mems-x"), Structure()))  # not .numpy() of it
    torch.testing.assert_close(res.alpha.detach(), plain.alpha, rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="gradients"):
        run_tea(y, h=0.01, params=make_params(get_preset("paper-mems-x"), Structure()), engine="numba")


def test_the_compiled_kernel_takes_its_arguments_by_name():
    """FastTEA passes the kernel's arguments by name (Settings, State, History, the outputs by TEAResult field): the
    names, in the order the compiled function declares them, are the kernel's own parameters."""
    import inspect

    from torchtea.engines import _fast_kernel
    from torchtea.engines.fast import OUTPUTS, kernel_arguments
    from torchtea.engines.results import STEP_OUTPUTS

    assert list(inspect.signature(_fast_kernel.advance.py_func).parameters) == list(kernel_arguments())
    assert tuple(OUTPUTS) == STEP_OUTPUTS


#: Every switch of the compiled kernel (its Settings that choose a branch) with the TEA setting that sets it.
SWITCHES = {
    "kind": ("memory", ["exact", "soe", "window:40"]),
    "mode": ("kfx_uncertainty", ["paper", "propagated", "paper-gain"]),
    "const": ("estimate_uncertainty", ["paper", "constant-truth"]),
    "inn_o": ("kfo.R", [None, "innovation"]),
    "inn_w": ("kfw.R", [None, "innovation"]),
    "scaled": ("noise_scaling", ["scaled", "unscaled"]),
    "start": ("sigma_sum_start", [0, 1]),
    "delta": ("kfw.delta", [None, 0.0]),  # 0: adapt_q's early return
    "has_u": ("input", [False, True]),
}


def _pairs(case: dict) -> set:
    names = sorted(case)
    return {(a, repr(case[a]), b, repr(case[b])) for i, a in enumerate(names) for b in names[i + 1:]}


def _switch_cases(seed: int = 0, pool: int = 400) -> list:
    """Combinations of the switches' values that together contain every pair of values of every two switches
    (pairwise coverage): greedily, each time the one of a seeded pool of random combinations that adds the most
    pairs not yet covered."""
    import itertools
    import random

    rnd = random.Random(seed)
    names = list(SWITCHES)
    need = {(a, repr(va), b, repr(vb)) for a, b in itertools.combinations(sorted(names), 2)
            for va in SWITCHES[a][1] for vb in SWITCHES[b][1]}
    candidates = [{n: rnd.choice(SWITCHES[n][1]) for n in names} for _ in range(pool)]
    cases = []
    while need:
        best = max(candidates, key=lambda c: len(_pairs(c) & need))
        cases.append(best)
        need -= _pairs(best)
    return cases


def test_every_switch_of_the_kernel_against_the_torch_step():
    """The compiled kernel is the torch step's twin, function by function (tests/test_fast_twins.py); here every
    branch it takes is checked against that step as a whole run:
    combinations of all its switches that contain every pair of values of every two switches (pairwise coverage,
    seeded), on the same data with a gap, every carry output of every step to float64 rounding. The switches listed are the kernel's own
    (a test below keeps the list complete). KFo and KFw start at the truth with Q₀ = 1e-3: from the MEMS preset's
    start (α 1, w 0, Q₀ 0.1) the filters wander (α̂ 0 … 2.5 from step to step here) and amplify a rounding
    difference to 1e-6 within 150 steps, which a comparison to rounding cannot take. The uncapped adaptation
    (``Q_max = "none"``, open point 4) does the same here even from the truth, so it is left to
    test_numba_divergence_guard_and_settings_as_printed."""
    y, u = _mems((3,), 150, seed=21, with_input=True)
    y = y.clone()
    y[1, 60:63] = float("nan")
    cases = _switch_cases()
    assert len(cases) <= 16  # (a pairwise cover of these switches takes 9 at least: kind × mode)
    base = get_preset("paper-mems-x")
    base = replace(base, kfo=replace(base.kfo, x0=0.4, Q0=1e-3), kfw=replace(base.kfw, x0=-4.0, Q0=1e-3))
    for c in cases:
        kfo, kfw = base.kfo, base.kfw
        if c["inn_o"]:
            kfo = replace(kfo, R=c["inn_o"])
        if c["inn_w"]:
            kfw = replace(kfw, R=c["inn_w"])
        if c["delta"] is not None:
            kfw = replace(kfw, delta=c["delta"])
        cfg = replace(base, memory=parse_memory(c["kind"]), kfx_uncertainty=c["mode"],
                      estimate_uncertainty=c["const"], noise_scaling=c["scaled"], sigma_sum_start=c["start"],
                      kfo=kfo, kfw=kfw)
        inputs = u if c["has_u"] else None
        a = run_tea(y, h=0.01, params=make_params(cfg, Structure()), inputs=inputs, engine="torch")
        b = run_tea(y, h=0.01, params=make_params(cfg, Structure()), inputs=inputs, engine="numba")
        assert not bool(a.diverged.any()), c
        _same(a, b, rtol=1e-9, atol=1e-12)


def test_the_switch_list_is_the_kernels():
    """SWITCHES names every branching setting the kernel takes (a new switch in Settings must join the sweep)."""
    from torchtea.engines.fast import Settings

    branching = {"kind", "mode", "const", "inn_o", "inn_w", "scaled", "start"}
    numbers = {"h", "Q", "R", "Ro", "Rw", "qmax_o", "qmax_w", "lo", "hi", "limit", "delta_o", "delta_w", "wm_o",
               "wc_o", "scale_o", "wm_w", "wc_w", "scale_w", "xl", "pl", "H", "ka", "kb", "kbig", "decay", "inject",
               "eta", "klo", "khi", "count_lo", "count_hi", "la", "lb"}
    assert set(Settings._fields) == branching | numbers, set(Settings._fields) ^ (branching | numbers)
    assert branching <= set(SWITCHES)
