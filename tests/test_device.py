"""The torch engine off the CPU (issue 13): the same numbers on every device, to float64 rounding.

CI has no accelerator: there the device cases run on the CPU and the CUDA ones are skipped with the reason; the
arithmetic that only a GPU takes (small matrix products as broadcast sums, the GL scan along the outer dimension)
is forced on the CPU by :func:`gpu_arithmetic` and compared with the CPU's own."""
import math

import numpy as np
import pytest
import torch

from torchtea import ConstantOrder, Structure, get_preset, make_params, run_tea, simulate
from torchtea.core.memory import MemoryConfig
from torchtea.engines.structure import ParametricMatrix

DEVICES = [
    pytest.param("cpu", id="cpu"),
    pytest.param("cuda", id="cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(),
                                                             reason="no CUDA device on this machine")),
    pytest.param("mps", id="mps", marks=pytest.mark.skip(
        reason="torchtea computes in float64, which the MPS backend does not have (the CLI refuses --device mps)")),
]


def _mems(B, N, seed, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    return simulate(Structure(), n_steps=N, h=0.01, order=ConstantOrder(0.4), parameters=[-4.0], process_noise=0.01,
                    measurement_noise=4e-4, batch_shape=(B,), generator=g, memory="soe").y.to(device)


def _params(kind, structure=None, device="cpu"):
    from dataclasses import replace

    cfg = replace(get_preset("paper-mems-x"), memory=MemoryConfig(kind))
    return make_params(cfg, structure or Structure(), device=device)


def _two_state():
    """A(w) = [[w₁, 1], [0, w₂]], both orders estimated, one output y = x₁ + x₂: 2×2 matrices and 5 KFo sigma points."""
    base = torch.tensor([[0.0, 1.0], [0.0, 0.0]], dtype=torch.float64)
    basis = torch.tensor([[[1.0, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 1.0]]], dtype=torch.float64)
    return Structure(A=ParametricMatrix(base, basis), B=torch.eye(2, dtype=torch.float64),
                     C=torch.tensor([[1.0, 1.0]], dtype=torch.float64), estimated=(True, True),
                     fixed_orders=torch.ones(2, dtype=torch.float64))


@pytest.fixture
def gpu_arithmetic(monkeypatch):
    """The CPU computing as the torch engine does on a GPU."""
    import torchtea.core.gl as gl
    import torchtea.engines.unscented as unscented  # (where _mm reads it)

    monkeypatch.setattr(unscented, "MATMUL_DEVICES", set())
    monkeypatch.setattr(gl, "INNER_SCAN_DEVICES", set())


FIELDS = ("x", "P", "alpha", "P_alpha", "w", "P_w", "innovation", "innovation_cov")


@pytest.mark.parametrize("kind", ["soe", "window", "exact"])
@pytest.mark.parametrize("two", [False, True], ids=["scalar", "two-state"])
def test_gpu_arithmetic_on_the_cpu_equals_the_cpu_path(request, kind, two):
    # the two-state filter on this one-state data is ill-conditioned: any change of summation order (1e-16) grows
    # to ~1e-4 by step 100, so it is compared over 60 steps, where it still agrees to ~1e-12
    y = _mems(3, 60 if two else 250, seed=21)
    structure = _two_state() if two else Structure()
    params = _params(kind, structure)
    ref = run_tea(y, h=0.01, params=params, structure=structure, engine="torch")
    request.getfixturevalue("gpu_arithmetic")
    gpu = run_tea(y, h=0.01, params=params, structure=structure, engine="torch")
    assert not ref.diverged.any()
    for f in FIELDS:
        torch.testing.assert_close(getattr(gpu, f), getattr(ref, f), rtol=1e-10, atol=1e-12, msg=f)


def test_gl_coefficients_scanned_along_the_outer_dimension(gpu_arithmetic):
    from torchtea.core.gl import gl_coefficients, gl_tail_coefficients

    orders = torch.linspace(-0.9, 3.4, 40, dtype=torch.float64).reshape(4, 10)
    outer = gl_tail_coefficients(orders, 30)
    assert outer.shape == (4, 10, 30)
    assert torch.equal(outer, gl_coefficients(orders, 30)[..., 1:])  # the same products in the same order


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("kind", ["soe", "exact"])
def test_torch_engine_on_the_device_equals_the_compiled_cpu_engine(device, kind):
    y = _mems(16, 400, seed=5)
    ref = run_tea(y, h=0.01, params=_params(kind))  # the compiled engine on the CPU
    out = run_tea(y.to(device), h=0.01, params=_params(kind, device=device), engine="torch")
    assert out.alpha.device.type == device
    for f in FIELDS:
        torch.testing.assert_close(getattr(out, f).cpu(), getattr(ref, f), rtol=1e-9, atol=1e-11, msg=f)
    assert torch.equal(out.diverged.cpu(), ref.diverged)
    if kind == "soe":
        assert torch.equal(out.memory_clamped.cpu(), ref.memory_clamped)


@pytest.mark.parametrize("device", DEVICES)
def test_simulation_on_the_device_equals_the_cpu(device):
    g = torch.Generator().manual_seed(4)
    draws = (torch.randn(20, 600, 1, generator=g, dtype=torch.float64), torch.randn(20, 600, 1, generator=g, dtype=torch.float64))
    sims = [simulate(Structure(), n_steps=600, h=0.01, order=ConstantOrder(0.4), parameters=[-4.0], process_noise=0.01,
                     measurement_noise=4e-4, standard_draws=tuple(d.to(dev) for d in draws), memory="soe", device=dev)
            for dev in ("cpu", device)]
    assert sims[1].y.device.type == device
    scale = float(sims[0].x.abs().max())
    torch.testing.assert_close(sims[1].x.cpu(), sims[0].x, rtol=0, atol=1e-12 * scale)


def test_vectorised_exp_against_libm():
    """The compiled engine's exp (vexp): within 3 ulp of numpy's over the range it is used in; clamped below."""
    from torchtea.engines._fast_kernel import vexp

    x = np.concatenate([np.linspace(-708.0, 709.0, 200_001), np.random.default_rng(0).uniform(-40.0, 3.0, 100_000),
                        [0.0, -1e-300, 1e-300, math.log(2.0), -math.log(2.0)]])
    out, ib = np.empty_like(x), np.empty(x.shape[0], np.int64)
    vexp(x, out, ib, ib.view(np.float64), x.shape[0])
    ref = np.exp(x)
    assert np.max(np.abs(out - ref) / ref) <= 3 * np.finfo(np.float64).eps
    tiny, ib1 = np.empty(2), np.empty(2, np.int64)
    vexp(np.array([-745.0, -1e4]), tiny, ib1, ib1.view(np.float64), 2)
    assert np.all((tiny > 0) & (tiny <= math.exp(-708.0) * 1.0000001))  # e^−708 at most: no sum here can tell it from 0


def test_cli_device_options(tmp_path, capsys):
    """simulate and identify take --device: cpu gives the default's numbers, a missing accelerator or a --model
    simulation off the CPU is one clear error naming the option, before anything is written."""
    from torchtea.cli import main

    flags = ["simulate", "--n", "200", "--h", "0.01", "--order", "0.4", "--param", "-4", "--q", "0.01", "--r", "4e-4",
             "--seed", "3", "--memory", "soe"]
    assert main(flags + ["--out", str(tmp_path / "a.csv")]) == 0
    assert main(flags + ["--device", "cpu", "--out", str(tmp_path / "b.csv")]) == 0
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "b.csv").read_text()
    capsys.readouterr()
    assert main(["simulate", "--model", "fractional+white", "--n", "100", "--h", "0.01", "--device", "cuda",
                 "--out", str(tmp_path / "c.csv")]) == 2
    assert "--model simulations run on the CPU" in capsys.readouterr().err and not (tmp_path / "c.csv").exists()
    if not torch.cuda.is_available():
        assert main(flags + ["--device", "cuda", "--out", str(tmp_path / "d.csv")]) == 2
        assert "--device cuda: no CUDA device" in capsys.readouterr().err and not (tmp_path / "d.csv").exists()
        assert main(["identify", "--samples", "200", "--r", "measured", "--no-plots", "--device", "cuda",
                     "--out", str(tmp_path / "id")]) == 2
        assert "--device cuda: no CUDA device" in capsys.readouterr().err and not (tmp_path / "id").exists()


@pytest.mark.parametrize("device", DEVICES)
def test_identify_on_the_device(device):
    """identify's TEA on the device gives the CPU's estimates (the report reads them back on the CPU)."""
    from torchtea.identification import identify
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare

    m = prepare(read_recording(columns=("ax", "ay", "az")), samples=400)  # the bundled recording's accelerometer
    cpu = identify(m, r_mode="measured")
    dev = identify(m, r_mode="measured", device=device)
    assert dev.result.alpha.device.type == "cpu"
    torch.testing.assert_close(dev.result.alpha, cpu.result.alpha, rtol=1e-9, atol=1e-11)
    torch.testing.assert_close(dev.result.w, cpu.result.w, rtol=1e-9, atol=1e-11)
