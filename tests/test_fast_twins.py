"""The compiled kernel (torchtea.engines._fast_kernel) line by line against the torch step (engines.tea): each
function of the kernel's step is the scalar twin of one torch function, checked on the same inputs here; the
kernel's loop calls the twins in the order ``_tea_step`` calls theirs; every kernel function is a twin or a named
part of one. tests/test_fast.py checks the whole runs against each other, branch by branch."""
import ast
import inspect
import textwrap
from dataclasses import replace

import numpy as np
import pytest
import torch

from torchtea.core.memory import parse_memory
from torchtea.engines import _fast_kernel as kern
from torchtea.engines import tea
from torchtea.engines.fast import memory_arrays
from torchtea.engines.presets import get_preset
from torchtea.engines.results import Carry, ut_weights
from torchtea.engines.structure import Structure

#: The kernel's step functions and the torch function each mirrors, in the order the step calls them.
STEP_TWINS = {
    "sigma_points": "sigma_points",
    "replica": "_replica",
    "ut_update": "ut_update",
    "adapt_q": "adapt_q",
    "kfx_sums": "kfx_sums",  # the memory's method
    "estimate_uncertainty": "_estimate_uncertainty",
    "kfx_update": "_kfx_update",
    "joseph": "_joseph",
    "constant_truth_cov": "_constant_truth_cov",
    "guard": "_guard",
}
#: The memory's twins: its history sums (which the torch replica calls; the kernel calls them before its replica), its
#: push (in the loop, after the step).
MEMORY_TWINS = {"mean_sums": "mean_sums", "push": "push"}
#: The kernel's numerics inside the twins (checked through them; vexp also in tests/test_device.py), and the loop.
PARTS = {"lagf", "rgn", "vexp", "dot", "dot3", "tail", "tails3", "exact_sums3", "window_sum", "push_front", "psd",
         "advance"}

B = 64  # realisations per check


def _rng(seed):
    return np.random.default_rng(seed)


def _t(a, *event):
    """A ``(B,)`` numpy array as a torch tensor with trailing size-1 dims."""
    return torch.from_numpy(np.asarray(a, dtype=np.float64)).reshape((-1,) + (1,) * len(event))


def _close(actual, expected, name, rtol=1e-13, atol=1e-15):
    actual = torch.as_tensor(np.asarray(actual, dtype=np.float64))
    torch.testing.assert_close(actual, expected.reshape(actual.shape).to(torch.float64), rtol=rtol, atol=atol,
                               msg=name, equal_nan=True)


# --------------------------------------------------------------------------- the list and the order


def test_every_kernel_function_is_a_twin_or_a_part_of_one():
    compiled = {n for n, f in vars(kern).items() if hasattr(f, "py_func")}
    listed = set(STEP_TWINS) | set(MEMORY_TWINS) | PARTS
    assert compiled == listed, compiled ^ listed
    # each twin's docstring names the torch function it mirrors (``tea.NAME``, or ``unscented.NAME`` for the filters'
    # linear algebra; the memory's method as ``memory's NAME``)
    import torchtea.engines.unscented as unscented

    for k, t in STEP_TWINS.items():
        doc = getattr(kern, k).py_func.__doc__ or ""
        home = "unscented" if t in vars(unscented) else "tea"
        assert (f"{home}.{t}" in doc) if t != "kfx_sums" else (f"memory's ``{t}``" in doc), k


def _calls_in_order(fn, names) -> list:
    """The calls to ``names`` (a plain name or an attribute) in ``fn``'s source, in source order."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    calls = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
            if name in names:
                calls.append((node.lineno, node.col_offset, name))
    return [n for *_, n in sorted(calls)]


def test_the_kernel_calls_the_twins_in_the_torch_steps_order():
    """The torch step's calls of the twinned functions, in source order, are the kernel loop's calls of their twins;
    the memory's sums, which ``_replica`` calls first, the kernel calls just before its replica."""
    assert _calls_in_order(tea._replica, {"mean_sums"}) == ["mean_sums"]
    expected = []
    for c in _calls_in_order(tea._tea_step, set(STEP_TWINS.values())):
        expected += ["mean_sums", c] if c == "_replica" else [c]
    twins = {**STEP_TWINS, "mean_sums": "mean_sums"}
    kernel_calls = _calls_in_order(kern.advance.py_func, set(twins))
    assert [twins[c] for c in kernel_calls] == expected
    assert set(kernel_calls) == set(twins)  # every twin is called: the lists hold no function the step lost
    # push where the torch loop pushes: once per step, after the step
    assert _calls_in_order(kern.advance.py_func, {"push", "guard"}) == ["guard", "push"]


# --------------------------------------------------------------------------- the filters' functions


def test_sigma_points():
    g = _rng(1)
    mean, cov = g.normal(size=B), g.uniform(0, 2, size=B)
    cov[:4] = [0.0, -1e-18, 1e-300, 3.0]  # a zero, a rounding negative (projected to 0), a tiny one
    scale = 2.7
    expected = tea.sigma_points(_t(mean, 1), _t(cov, 1, 1), scale)  # (B, 3, 1)
    out, roots = np.empty((B, 3)), np.empty(B)
    for b in range(B):
        roots[b] = kern.sigma_points(mean[b], cov[b], scale, out[b])
    _close(out, expected[..., 0], "points", rtol=0, atol=0)
    _close(roots, expected[:, 1, 0] - expected[:, 0, 0], "root", rtol=1e-15, atol=1e-15)


@pytest.mark.parametrize("start", [0, 1])
def test_ut_update(start):
    g = _rng(2 + start)
    wm, wc, scale = ut_weights(1, 1e-3, 2.0, 0.0)
    mean, Pt, R = g.normal(size=B), g.uniform(0.01, 1, size=B), g.uniform(0.01, 1, size=B)
    y, obs = g.normal(size=B), g.uniform(size=B) > 0.2
    pts = np.stack([mean, mean + np.sqrt(scale * Pt), mean - np.sqrt(scale * Pt)], axis=1)
    Y = g.normal(size=(B, 6))  # the second half: another filter's outputs, which off = 3 reads
    for off in (0, 3):
        exp = tea.ut_update(_t(pts.ravel()).reshape(B, 3, 1), torch.from_numpy(Y[:, off:off + 3]).unsqueeze(-1),
                             _t(mean, 1), _t(Pt, 1, 1), _t(R, 1, 1), _t(np.where(obs, y, 0.0), 1),
                             torch.from_numpy(obs).unsqueeze(-1), wm, wc, start)
        got = np.array([kern.ut_update(Y[b], off, pts[b], mean[b], Pt[b], wm.numpy(), wc.numpy(), start, R[b],
                                       obs[b], y[b] if obs[b] else 0.0) for b in range(B)])
        for i, name in enumerate(("mean", "cov", "gain", "innovation", "Pyy", "Pxy")):
            _close(got[:, i], exp[i], f"{name} (off {off})", rtol=1e-12, atol=1e-14)


def test_adapt_q():
    g = _rng(4)
    Q, K, e = g.uniform(0, 1e-2, size=B), g.normal(size=B), g.normal(size=B)
    qmax = np.where(g.uniform(size=B) > 0.5, 1e-3, np.inf)  # the cap binds for some
    obs = g.uniform(size=B) > 0.2
    for delta in (0.0, 0.05):
        exp = tea.adapt_q(_t(Q, 1, 1), _t(K, 1, 1), _t(e, 1), delta, torch.from_numpy(qmax),
                           torch.from_numpy(obs))
        got = [kern.adapt_q(Q[b], K[b], e[b], delta, qmax[b], obs[b]) for b in range(B)]
        _close(got, exp, f"Q (delta {delta})", rtol=1e-14, atol=0)
        if delta:  # the cap bound somewhere, and a missing sample left Q as it was
            assert np.isclose(got, 1e-3, rtol=1e-15).any() and np.array_equal(np.array(got)[~obs], Q[~obs])


def test_estimate_uncertainty():
    g = _rng(5)
    wm, wc, scale = ut_weights(1, 1e-3, 2.0, 0.0)
    mean, Pt, cov = g.normal(size=B), g.uniform(0.01, 1, size=B), g.uniform(0, 1, size=B)
    Pt[:3] = 0.0  # a filter with no spread: J is zero
    r = np.sqrt(scale * Pt)
    pts = np.stack([mean, mean + r, mean - r], axis=1)
    chi = g.normal(size=(B, 3))
    exp = tea._estimate_uncertainty(torch.from_numpy(chi).unsqueeze(-1), torch.from_numpy(pts).unsqueeze(-1),
                                    _t(mean, 1), _t(Pt, 1, 1), _t(cov, 1, 1), wc)
    got = [kern.estimate_uncertainty(chi[b], 0, r[b], wc.numpy(), Pt[b], cov[b]) for b in range(B)]
    _close(got, exp, "J P J", rtol=1e-12, atol=1e-300)
    assert np.count_nonzero(got) == B - 3


def test_kfx_update():
    g = _rng(6)
    model, _ = tea._model_and_weights(Structure(), tea.make_params(get_preset("paper-mems-x"), Structure()), 0.01,
                                      torch.float64, torch.device("cpu"))
    x, P, R, y = g.normal(size=B), g.uniform(0, 1, size=B), g.uniform(1e-4, 1, size=B), g.normal(size=B)
    obs = g.uniform(size=B) > 0.2
    params = tea.make_params(get_preset("paper-mems-x"), Structure())._replace(R=_t(R, 1, 1))
    exp = tea._kfx_update(model, params, _t(x, 1), _t(P, 1, 1), _t(np.where(obs, y, 0.0), 1),
                          torch.from_numpy(obs).unsqueeze(-1))
    got = np.array([kern.kfx_update(x[b], P[b], R[b], obs[b], y[b] if obs[b] else 0.0) for b in range(B)])
    for i, name in enumerate(("x", "P", "e", "S", "K")):
        _close(got[:, i], exp[i], name, rtol=1e-14, atol=1e-16)


def test_joseph_and_constant_truth_cov():
    g = _rng(7)
    P, K, H, R = g.uniform(0, 1, size=B), g.normal(size=B), g.normal(size=B), g.uniform(0, 1, size=B)
    exp = tea._joseph(_t(P, 1, 1), _t(K, 1, 1), _t(H, 1, 1), _t(R, 1, 1))
    _close([kern.joseph(P[b], K[b], H[b], R[b]) for b in range(B)], exp, "joseph", rtol=1e-14, atol=1e-16)
    Sig, Pt, Pyy, Pxy = g.uniform(0, 1, size=B), g.uniform(0, 1, size=B), g.uniform(0.5, 2, size=B), g.normal(size=B)
    Pt[:3] = 0.0
    exp = tea._constant_truth_cov(_t(Sig, 1, 1), _t(Pt, 1, 1), _t(K, 1, 1), _t(Pyy, 1, 1), _t(Pxy, 1, 1))
    got = [kern.constant_truth_cov(Sig[b], Pt[b], K[b], Pyy[b], Pxy[b]) for b in range(B)]
    _close(got, exp, "constant truth", rtol=1e-13, atol=1e-16)


def test_guard():
    fields = [f for f in Carry._fields if f != "diverged"]  # the carry's values, KFx's innovation covariance last
    g = _rng(8)
    vals = g.normal(size=(B, len(fields)))
    vals[1, 0], vals[2, 4], vals[3, len(fields) - 1], vals[4, 7] = np.nan, np.inf, 2e6, -1e7  # beyond 1e6
    vals[5, 9] = 1e6  # on the limit: kept
    limit = 1e6
    scalars = {"x", "alpha", "w"}
    cols = [torch.from_numpy(vals[:, i]).reshape((B, 1) if f in scalars else (B, 1, 1)) for i, f in enumerate(fields)]
    new = Carry(**dict(zip(fields, cols)), diverged=torch.zeros(B, dtype=torch.bool))
    exp = tea._guard(new, new, limit).diverged.numpy()
    got = [kern.guard(tuple(float(v) for v in vals[b]), limit) for b in range(B)]
    assert np.array_equal(got, exp) and exp[1:5].all() and not exp[5] and not exp[0]


# --------------------------------------------------------------------------- the memory's functions


def _histories(memory_spec, gain, K, seed):
    """The same random past x̂_0 … x̂_{K−1}, P, Pg pushed into the torch memory and into the kernel's arrays, each by
    its own push; returns (torch memory, torch history, kernel settings, kernel history of realisation b → dict)."""
    g = _rng(seed)
    cfg = replace(get_preset("paper-mems-x"), memory=parse_memory(memory_spec))
    N = K + 1
    memory = tea._make_memory(cfg, N, torch.float64, torch.device("cpu"))
    xs, Ps, Pgs = g.normal(size=(K, B)), g.uniform(0, 1, size=(K, B)), g.uniform(0, 1, size=(K, B))
    if memory.bounded:
        hist = memory.init((B,), 1, torch.float64, torch.device("cpu"), gain)
        for k in range(K):
            hist = memory.push(hist, _t(xs[k], 1), _t(Ps[k], 1, 1), k, _t(Pgs[k], 1, 1) if gain else None)
    else:  # the exact history, newest first, as tea._loop slices it
        rev = lambda a: torch.from_numpy(a[::-1].T.copy())  # (B, K), x̂_{K−1} first  # noqa: E731
        hist = (rev(xs).unsqueeze(1), rev(Ps).reshape(B, 1, 1, K)) + ((rev(Pgs).reshape(B, 1, 1, K),) if gain else ())
    mem, kh = memory_arrays(memory, N, B, gain)
    for k in range(K):
        for b in range(B):
            kern.push(mem["kind"], gain, k, xs[k, b], Ps[k, b], Pgs[k, b], kh.xh[b], kh.Ph[b], kh.Pgh[b], kh.win[b],
                      mem["xl"], kh.modes[b], mem["decay"], mem["inject"], kh.Pwin[b], mem["pl"], kh.Pwin_g[b],
                      mem["H"], kh.Phead[b], kh.Phead_g[b])
    return memory, hist, mem, kh


MEMORIES = ["exact", "soe", "window:40"]


@pytest.mark.parametrize("memory_spec", MEMORIES)
@pytest.mark.parametrize("K", [9, 200])
def test_push_keeps_the_history_the_torch_memory_keeps(memory_spec, K):
    memory, hist, mem, kh = _histories(memory_spec, True, K, seed=K)
    if not memory.bounded:
        assert np.array_equal(kh.xh[:, :K], hist[0][:, 0].flip(-1).numpy())
        assert np.array_equal(kh.Ph[:, :K], hist[1][:, 0, 0].flip(-1).numpy())
        assert np.array_equal(kh.Pgh[:, :K], hist[2][:, 0, 0].flip(-1).numpy())
        return
    assert np.array_equal(kh.win, hist[0].window[:, 0].numpy())
    np.testing.assert_allclose(kh.modes, hist[0].modes[:, 0].numpy(), rtol=1e-13, atol=1e-13)  # modes cancel: absolute
    for k_arr, t in ((kh.Pwin, hist[1]), (kh.Phead, hist[2]), (kh.Pwin_g, hist[3]), (kh.Phead_g, hist[4])):
        assert np.array_equal(k_arr, t[:, 0, 0].numpy())


def _scratch(M):
    ib = np.empty(M, np.int64)
    return (np.empty(M), np.empty(M), np.empty(M), np.empty(M), ib, ib.view(np.float64))


@pytest.mark.parametrize("memory_spec", MEMORIES)
@pytest.mark.parametrize("gain", [False, True])
@pytest.mark.parametrize("K", [9, 200])
def test_kfx_sums_mean_sums_and_the_replica(memory_spec, gain, K):
    """At step K: KFx's sums at its order, the replica's sums at KFo's sigma orders (with the exponentials the KFx
    sums left, as the kernel reuses them, and without) and the replica's outputs from them."""
    memory, hist, mem, kh = _histories(memory_spec, gain, K, seed=100 + K)
    g = _rng(K)
    a = g.uniform(0.05, 0.9, size=B)
    a[:2] = [-0.3, 1.4]  # orders the soe kernel serves beyond the bounds, as sigma orders do
    ro = g.uniform(0, 0.3, size=B)
    w, x, up = g.uniform(-5, -1, size=B), g.normal(size=B), g.normal(size=B)
    rw = g.uniform(0, 1, size=B)
    h = 0.01
    exp_mean, exp_cov, exp_covg = memory.kfx_sums(hist, _t(a, 1), K)
    orders = torch.from_numpy(np.stack([a, a + ro, a - ro], axis=1)).unsqueeze(-1)
    exp_ms = memory.mean_sums(hist, orders)[..., 0]  # (B, 3)
    sw = np.stack([w, w + rw, w - rw], axis=1)
    model, _ = tea._model_and_weights(Structure(), tea.make_params(get_preset("paper-mems-x"), Structure()), h,
                                      torch.float64, torch.device("cpu"))
    exp_Y, _ = tea._replica(model, memory, hist, orders, _t(w, 1), torch.from_numpy(sw).unsqueeze(-1), _t(x, 1),
                            _t(up, 1))
    M = kh.modes.shape[1]
    got = np.empty((B, 3))
    ms, ms_have, Y = np.empty((B, 3)), np.empty((B, 3)), np.empty((B, 6))
    for b in range(B):
        Ex = np.empty(M)
        arg, E, D, Di, ib, fb = _scratch(M)
        common = (mem["la"], mem["lb"], kh.win[b], mem["xl"])
        got[b] = kern.kfx_sums(mem["kind"], gain, a[b], K, kh.xh[b], kh.Ph[b], kh.Pgh[b], *common, mem["pl"],
                               kh.Pwin[b], kh.Pwin_g[b], mem["H"], kh.Phead[b], kh.Phead_g[b], kh.modes[b], mem["ka"],
                               mem["kb"], mem["eta"], mem["klo"], mem["khi"], arg, Ex, ib, fb)
        so = np.array([a[b], a[b] + ro[b], a[b] - ro[b]])
        tail = (kh.modes[b], mem["ka"], mem["kb"], mem["kbig"], mem["eta"], mem["klo"], mem["khi"])
        kern.mean_sums(mem["kind"], so, ro[b], K, kh.xh[b], *common, *tail, False, np.empty(M), *_scratch(M), ms[b])
        have = mem["kind"] == 1 and min(max(a[b], mem["klo"]), mem["khi"]) == a[b]  # Ex holds exp(ka + a kb)
        kern.mean_sums(mem["kind"], so, ro[b], K, kh.xh[b], *common, *tail, have, Ex, *_scratch(M), ms_have[b])
        kern.replica(so, sw[b], w[b], x[b], up[b], h, ms[b], Y[b])
    _close(got[:, 0], exp_mean, "KFx mean sum", rtol=1e-12, atol=1e-13)
    _close(got[:, 1], exp_cov, "KFx covariance sum", rtol=1e-12, atol=1e-13)
    if gain:
        _close(got[:, 2], exp_covg, "KFx gain covariance sum", rtol=1e-12, atol=1e-13)
    for arr, name in ((ms, "mean sums"), (ms_have, "mean sums, exponentials reused")):
        _close(arr, exp_ms, name, rtol=1e-12, atol=1e-13)
    _close(Y, exp_Y[..., 0], "replica", rtol=1e-12, atol=1e-13)
    assert np.abs(got[:, 1]).max() > 0 and np.abs(ms).max() > 0  # the sums are not trivially empty
