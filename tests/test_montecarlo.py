"""Monte Carlo study runner: chunk invariance, per-realisation seeding, statistics, interruption."""
import math

import pytest
import torch

from torchtea.core.stats import over_realisations
from torchtea.engines.presets import get_preset
from torchtea.studies.cluster import run_study
from torchtea.studies.montecarlo import Study, Truth, draw_realisation, realisation_seed, summarise

from .procs import sigint_as_in_a_terminal, wait_for_progress

TRUTH = Truth(h=1e-3, n_steps=150, order="0.35", param=-1.0, q=1e-4, r=1e-3, input_std=1.0)


def test_realisation_seeds_distinct_and_stable():
    seeds = {realisation_seed(7, i) for i in range(1000)}
    assert len(seeds) == 1000
    assert realisation_seed(7, 3) == realisation_seed(7, 3) != realisation_seed(8, 3)
    u1, w1, v1 = draw_realisation(TRUTH, 7, 3)
    u2, w2, v2 = draw_realisation(TRUTH, 7, 3)
    assert torch.equal(u1, u2) and torch.equal(w1, w2) and torch.equal(v1, v2)


def test_chunked_equals_unchunked():
    study = Study(TRUTH, get_preset("paper-example1"), realisations=7, seed=11, chunk=None)
    whole = run_study(study, trajectories=True)
    parts = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=7, seed=11, chunk=3), trajectories=True)
    assert whole.finished == parts.finished == 7
    for name in ("alpha_true", "alpha", "P_alpha", "w", "P_w", "nees", "nis"):
        torch.testing.assert_close(parts.trajectories[name], whole.trajectories[name], rtol=1e-9, atol=1e-12)
    assert torch.equal(parts.diverged, whole.diverged) and torch.equal(parts.index, torch.arange(7))
    torch.testing.assert_close(parts.logged["alpha"], whole.logged["alpha"], rtol=0, atol=0)
    torch.testing.assert_close(parts.nees_sum, whole.nees_sum, rtol=1e-12, atol=0)
    s1, s2 = summarise(whole), summarise(parts)
    assert s1["order"]["rmse"] == pytest.approx(s2["order"]["rmse"], rel=1e-9)
    assert s1["param"]["bias"] == pytest.approx(s2["param"]["bias"], rel=1e-9, abs=1e-12)


def test_truth_simulated_with_soe_by_default_agrees_with_exact():
    """Truths are simulated with exponential sums (O(N)); the exact full-history truth of the same draws differs
    by no more than the kernel's coefficient bound allows (relative 1e-8 of the memory sum), and a study file
    says which was used."""
    from dataclasses import replace

    from torchtea.studies.montecarlo import build_study

    assert TRUTH.memory == "soe"
    soe = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=3, seed=5), trajectories=True)
    exact = run_study(Study(replace(TRUTH, memory="exact"), get_preset("paper-example1"), realisations=3, seed=5),
                      trajectories=True)
    assert 0 < float((soe.trajectories["alpha"] - exact.trajectories["alpha"]).abs().max()) < 1e-6  # estimates on truths that differ by ~1e-9
    study, _ = build_study({"truth": {"memory": "exact"}}, {"preset": "paper-example1"})
    assert study.truth.memory == "exact"
    with pytest.raises(ValueError, match="bad memory spec"):
        build_study({"truth": {"memory": "fast"}}, {"preset": "paper-example1"})


def test_summary_matches_direct_statistics():
    study = Study(TRUTH, get_preset("paper-example1"), realisations=6, seed=2)
    full = run_study(study, trajectories=True)
    res = full.trajectories
    s = summarise(full)
    keep = ~full.diverged
    direct = over_realisations(res["alpha"][:, -1:, None], res["alpha_true"][:, -1:, None], keep)
    assert s["order"]["bias"] == pytest.approx(float(direct["bias"][0, 0]))
    assert s["order"]["std"] == pytest.approx(float(res["alpha"][keep, -1].std()))
    assert s["param"]["bias"] == pytest.approx(float((res["w"][keep, -1] + 1.0).mean()))
    assert s["realisations"] == 6
    # ±2σ coverage: the fraction of (realisation, step) pairs whose truth lies within α̂ ± 2√Pᵒ, counted here
    inside = (res["alpha"][keep] - res["alpha_true"][keep]).abs() <= 2 * res["P_alpha"][keep].clamp(min=0).sqrt()
    assert s["order"]["coverage_2sigma"] == pytest.approx(inside.double().mean().item(), rel=1e-12)
    # and by thirds of the 150 steps: 0–49, 50–99, 100–149; NEES from step 1: 1–49, 50–98, 99–149
    for part, (lo, hi) in zip(s["order"]["coverage_2sigma_by_third"], ((0, 50), (50, 100), (100, 150))):
        assert part == pytest.approx(inside[:, lo:hi].double().mean().item(), rel=1e-12)
    for part, (lo, hi) in zip(s["nees"]["mean_by_third"], ((1, 50), (50, 99), (99, 150))):
        assert part == pytest.approx(res["nees"][keep][:, lo:hi].mean().item(), rel=1e-12)
    assert s["nees"]["mean"] == pytest.approx(res["nees"][keep][:, 1:].mean().item(), rel=1e-12)
    # the convergence times: the last step outside the tolerance, found here by a loop
    err = (res["alpha"] - res["alpha_true"]).abs()
    for r in range(6):
        outside = [k for k in range(TRUTH.n_steps) if not err[r, k] < 0.05]
        expect = math.nan if outside and outside[-1] == TRUTH.n_steps - 1 else (outside[-1] + 1 if outside else 0) * TRUTH.h
        assert full.converged_at["order"][r].item() == pytest.approx(expect, nan_ok=True)
    assert s["nees"]["band_95"][0] < 1.0 < s["nees"]["band_95"][1]


def test_interrupt_keeps_finished_chunks():
    calls = []

    def progress(done, total):
        calls.append(done)
        if done >= 4:
            raise KeyboardInterrupt

    study = Study(TRUTH, get_preset("paper-example1"), realisations=10, seed=5, chunk=2)
    res = run_study(study, progress=progress)
    assert res.interrupted and res.finished == 4 and res.logged["alpha"].shape[0] == 4
    full = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=4, seed=5, chunk=2))
    torch.testing.assert_close(res.final["alpha"], full.final["alpha"], rtol=0, atol=0)
    torch.testing.assert_close(res.logged["w"], full.logged["w"], rtol=0, atol=0)
    s = summarise(res)
    assert s["interrupted"] and s["realisations"] == 4 and s["requested"] == 10


def test_tensorboard_event_files_read_back(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from torchtea.studies.tblog import log_study

    study = Study(TRUTH, get_preset("paper-example1"), realisations=5, seed=3, log_points=50)
    res = run_study(study, trajectories=True)
    summary = summarise(res)
    log_study(tmp_path / "run", res, summary, {"realisations": 5, "order": "0.35", "preset": "paper-example1"})
    ea = EventAccumulator(str(tmp_path / "run"), size_guidance={"scalars": 0, "histograms": 0, "tensors": 0})
    ea.Reload()
    tags = ea.Tags()
    for tag in ("order/truth", "order/mean", "order/q05", "order/q95", "order/rmse", "param/mean",
                "consistency/nees", "consistency/nis", "metric/order_rmse"):
        assert tag in tags["scalars"], tag
    assert "final/order" in tags["histograms"]
    mean = ea.Scalars("order/mean")
    assert len(mean) == 50 and [e.step for e in mean[:3]] == [0, 3, 6]
    k = mean[-1].step
    keep = ~res.diverged
    assert mean[-1].value == pytest.approx(float(res.trajectories["alpha"][keep, k].mean()), rel=1e-6)
    nees = ea.Scalars("consistency/nees")
    assert nees[-1].step == k and nees[-1].value == pytest.approx(float(res.trajectories["nees"][keep, k].mean()), rel=1e-6)
    tr = res.trajectories
    inside = (tr["alpha"][keep, k] - tr["alpha_true"][keep, k]).abs() <= 2 * tr["P_alpha"][keep, k].sqrt()
    assert ea.Scalars("consistency/order_coverage")[-1].value == pytest.approx(inside.double().mean().item(), rel=1e-6)
    assert ea.Scalars("metric/nees_mean")[0].value == pytest.approx(summary["nees"]["mean"], rel=1e-6)
    assert ea.Scalars("metric/order_coverage")[0].value == pytest.approx(summary["order"]["coverage_2sigma"], rel=1e-6)
    assert ea.Scalars("order/truth")[0].value == pytest.approx(0.35)
    assert ea.Scalars("metric/order_rmse")[0].value == pytest.approx(summary["order"]["rmse"], rel=1e-6)
    assert any("summary" in t for t in tags["tensors"])


def test_montecarlo_cli_json_contract_and_run_directory(tmp_path, capsys):
    import json

    import numpy as np

    from torchtea.cli import main

    logdir = tmp_path / "mc"
    code = main(["montecarlo", "--preset", "paper-example1", "--n", "120", "--realisations", "6", "--seed", "4",
                 "--chunk", "4", "--logdir", str(logdir), "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["realisations"] == 6 and out["logdir"] == str(logdir)
    for name in ("order", "param"):
        assert set(("bias", "std", "rmse")) <= set(out[name])
    fin_div = np.genfromtxt(logdir / "final_estimates.csv", delimiter=",", names=True)["diverged"]
    assert out["diverged"] == int(fin_div.sum()) and out["diverged_fraction"] == pytest.approx(fin_div.mean(), abs=1e-15)
    for f in ("study.toml", "estimator.toml", "summary.json", "final_estimates.csv"):
        assert (logdir / f).exists(), f
    assert any(p.name.startswith("events.out.tfevents") for p in logdir.iterdir())
    fin = np.genfromtxt(logdir / "final_estimates.csv", delimiter=",", names=True)
    assert len(fin) == 6
    keep = fin["diverged"] == 0
    assert out["order"]["bias"] == pytest.approx((fin["alpha_final"][keep] - 0.35).mean(), rel=1e-9, abs=1e-12)
    # the written study file reproduces the run
    code = main(["montecarlo", "--config", str(logdir / "study.toml"), "--logdir", str(tmp_path / "again"), "--json"])
    again = json.loads(capsys.readouterr().out)
    assert again["order"]["rmse"] == pytest.approx(out["order"]["rmse"], rel=1e-9)


def test_montecarlo_cli_errors(tmp_path, capsys):
    from torchtea.cli import main

    assert main(["montecarlo", "--preset", "paper-mems-x", "--realisations", "2", "--logdir", str(tmp_path)]) == 2
    assert "the truth needs" in capsys.readouterr().err
    bad = tmp_path / "s.toml"
    bad.write_text("realisations = 3\n[truht]\nh = 0.1\n")
    assert main(["montecarlo", "--config", str(bad)]) == 2
    assert "unknown study settings ['truht']" in capsys.readouterr().err
    assert main(["montecarlo", "--config", str(tmp_path / "none.toml")]) == 2
    assert "no such study file" in capsys.readouterr().err


def test_tensorboard_server_serves_a_scalar_series(tmp_path):
    """The real `tensorboard` server on a free loopback port serves the study's scalars over its HTTP API."""
    import json
    import socket
    import subprocess
    import sys
    import time
    import urllib.request

    from torchtea.studies.tblog import log_study

    res = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=3, seed=1, log_points=20))
    log_study(tmp_path / "run", res, summarise(res), {"realisations": 3})
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "tensorboard.main", "--logdir", str(tmp_path / "run"),
                             "--host", "127.0.0.1", "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 90
        runs = None
        while time.monotonic() < deadline:
            try:
                with urllib.request.urlopen(base + "/data/runs", timeout=5) as r:
                    runs = json.loads(r.read())
                if runs:
                    break
            except OSError:
                pass
            time.sleep(0.5)
        assert runs == ["."]
        with urllib.request.urlopen(base + "/data/plugin/scalars/scalars?run=.&tag=order%2Ftruth", timeout=10) as r:
            series = json.loads(r.read())
        stride = math.ceil(150 / 20)  # ≤ 20 points of a 150-sample series
        assert len(series) == len(range(0, 150, stride)) == 19
        assert [p[1] for p in series[:2]] == [0, stride] and all(p[2] == pytest.approx(0.35) for p in series)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    assert proc.returncode is not None


def test_fan_charts_in_tensorboard(tmp_path):
    """The margin charts of CUSTOM SCALARS name logged tags (always written); the matplotlib fan figures are
    PNG images when asked for, and absent otherwise."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.custom_scalar import layout_pb2, metadata

    from torchtea.studies.tblog import log_study

    res = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=3, seed=1, log_points=20))
    log_study(tmp_path / "run", res, summarise(res), {"realisations": 3}, figures=True)
    log_study(tmp_path / "plain", res, summarise(res), {"realisations": 3})
    ea = EventAccumulator(str(tmp_path / "run"), size_guidance={"images": 0, "tensors": 0})
    ea.Reload()
    assert {"figures/order_fan", "figures/param_fan"} <= set(ea.Tags()["images"])
    img = ea.Images("figures/order_fan")[0]
    assert img.encoded_image_string[:8] == b"\x89PNG\r\n\x1a\n" and img.width > 100
    plain = EventAccumulator(str(tmp_path / "plain"), size_guidance={"images": 0, "tensors": 0})
    plain.Reload()
    assert not plain.Tags()["images"]
    layout = layout_pb2.Layout()
    layout.ParseFromString(plain.Tensors(metadata.CONFIG_SUMMARY_TAG)[0].tensor_proto.string_val[0])
    margins = [c.margin for cat in layout.category for c in cat.chart if c.HasField("margin")]
    assert [(m.series[0].value, m.series[0].lower, m.series[0].upper) for m in margins][:2] == [
        ("order/q50", "order/q05", "order/q95"), ("order/q50", "order/q25", "order/q75")]
    logged = set(plain.Tags()["scalars"])
    assert all({s.value, s.lower, s.upper} <= logged for m in margins for s in m.series)


@pytest.mark.slow
def test_sigint_leaves_a_readable_partial_run(tmp_path):
    """Ctrl-C (a real SIGINT) during `torchtea montecarlo`: exit 130, and the run directory holds the finished
    realisations' summary, final estimates and event files."""
    import json
    import signal
    import subprocess
    import sys

    import numpy as np

    logdir = tmp_path / "mc"
    progress = tmp_path / "progress"
    proc = subprocess.Popen([sys.executable, "-m", "torchtea.cli", "montecarlo", "--preset", "paper-example1",
                             "--n", "100", "--realisations", "5000", "--chunk", "1", "--logdir", str(logdir),
                             "--progress-file", str(progress), "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=sigint_as_in_a_terminal)
    done = wait_for_progress(progress, proc, 3, timeout=120)
    assert done >= 3, "no progress within 120 s"
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, (proc.returncode, out, err)
    assert "interrupted: kept" in err, err
    summary = json.loads((logdir / "summary.json").read_text())
    assert summary["interrupted"] and 3 <= summary["realisations"] < 5000, (summary, err)
    assert json.loads(out)["realisations"] == summary["realisations"], (out, err)
    fin = np.genfromtxt(logdir / "final_estimates.csv", delimiter=",", names=True)
    assert len(np.atleast_1d(fin)) == summary["realisations"]
    assert any(p.name.startswith("events.out.tfevents") for p in logdir.iterdir())


def test_device_option_runs_on_cpu_and_names_a_missing_accelerator(tmp_path, capsys):
    from torchtea.cli import main

    study = Study(TRUTH, get_preset("paper-example1"), realisations=3, seed=9)
    a, b = run_study(study), run_study(study, device="cpu")
    assert torch.equal(a.final["alpha"], b.final["alpha"]) and torch.equal(a.nees_sum, b.nees_sum)
    assert main(["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "2", "--device", "cpu",
                 "--logdir", str(tmp_path / "mc"), "--json"]) == 0
    capsys.readouterr()
    if not torch.cuda.is_available():
        assert main(["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "2", "--device", "cuda",
                     "--logdir", str(tmp_path / "mc2")]) == 2
        assert "--device cuda: no CUDA device is available" in capsys.readouterr().err
    assert main(["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "2", "--device", "tpu",
                 "--logdir", str(tmp_path / "mc3")]) == 2
    assert "--device 'tpu'" in capsys.readouterr().err
    assert not (tmp_path / "mc3").exists()  # checked before anything is written
    assert main(["montecarlo", "--preset", "paper-example1", "--n", "60", "--realisations", "2", "--device", "mps",
                 "--logdir", str(tmp_path / "mc4")]) == 2
    assert "float64, which the MPS backend does not have" in capsys.readouterr().err
    with pytest.raises(ValueError, match="SPEC string"):
        __import__("torchtea.studies.montecarlo", fromlist=["build_study"]).build_study(
            {"truth": {"memory": {"kind": "soe"}}}, {"preset": "paper-example1"})


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_study_on_cuda_equals_cpu():
    """The torch engine on the GPU against the compiled engine on the CPU: the same study to float64 rounding."""
    study = Study(TRUTH, get_preset("paper-example1"), realisations=8, seed=3)
    cpu, gpu = run_study(study, trajectories=True), run_study(study, device="cuda", trajectories=True)
    for name in ("alpha_true", "alpha", "P_alpha", "w", "P_w", "nees", "nis"):
        torch.testing.assert_close(gpu.trajectories[name], cpu.trajectories[name], rtol=1e-9, atol=1e-11)


def test_a_two_sample_study_has_no_thirds_to_split(tmp_path, capsys):
    """The shortest study the CLI accepts (n = 2): the statistics by thirds of the run are null where a third is
    empty, not a division by zero."""
    import json

    from torchtea.cli import main

    assert main(["montecarlo", "--preset", "paper-example1", "--n", "2", "--realisations", "3", "--logdir",
                 str(tmp_path / "mc"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["order"]["coverage_2sigma_by_third"][:2] == [None, None]
    assert 0 <= out["order"]["coverage_2sigma_by_third"][2] <= 1
    assert out["nees"]["mean_by_third"][:2] == [None, None] and out["nees"]["mean_by_third"][2] > 0


# --------------------------------------------------------------------------- consistent priors (issue 15)


def test_consistent_prior_draws_follow_the_estimators_priors_around_the_truth():
    """draw_prior: x̂₀, α̂₀, ŵ₀ ~ N(truth, P₀) with the estimator's own P₀ — a 3 × 3 correlated P₀ʷ too — checked
    against 4000 draws (means within 5 standard errors, covariances within 5 SE of the sample covariance); a zero
    P₀ gives the truth itself; the draws use a stream of their own."""
    from torchtea.engines.structure import Structure
    from torchtea.engines.tea import make_params, sqrt_psd
    from torchtea.studies.montecarlo import draw_prior

    params = make_params(get_preset("paper-example1"), Structure())
    Pw = torch.tensor([[0.04, -0.018, 0.006], [-0.018, 0.01, 0.002], [0.006, 0.002, 0.03]], dtype=torch.float64)
    root = sqrt_psd(Pw)
    assert not torch.allclose(root, root.T)  # so a transposed root would draw another covariance
    params = params._replace(P0w=Pw, P0o=torch.tensor([[0.02]], dtype=torch.float64))
    x_true, a_true, w_true = (torch.tensor(v, dtype=torch.float64) for v in ([0.3], [0.35], [-1.0, 2.0, 0.5]))
    n = 4000
    at = lambda v, rows: v.expand(len(rows), -1)  # noqa: E731  the truth of every realisation
    draws = draw_prior(params, 9, range(n), at(x_true, range(n)), at(a_true, range(n)), w_true)
    for k, (truth, P) in enumerate(((x_true, params.P0), (a_true, params.P0o), (w_true, Pw))):
        d = draws[k]
        assert d.shape == (n, truth.shape[0])
        se_mean = (torch.diagonal(P) / n).sqrt()
        assert ((d.mean(0) - truth).abs() < 5 * se_mean).all(), k
        err = d - truth
        S = err.T @ err / n
        se_cov = ((P ** 2 + torch.outer(torch.diagonal(P), torch.diagonal(P))) / n).sqrt()  # SE of a Gaussian sample covariance
        assert ((S - P).abs() < 5 * se_cov).all(), (k, S, P)
    assert realisation_seed(9, 3, stream=1) != realisation_seed(9, 3)
    one = range(3, 4)
    a = draw_prior(params, 9, one, at(x_true, one), at(a_true, one), w_true)
    b = draw_prior(params, 9, one, at(x_true, one), at(a_true, one), w_true)
    assert all(torch.equal(u, v) for u, v in zip(a, b))
    assert all(torch.equal(u[0], v[3]) for u, v in zip(a, draws))  # realisation 3 alone draws as within a batch
    zero = params._replace(P0=torch.zeros(1, 1, dtype=torch.float64), P0o=torch.zeros(1, 1, dtype=torch.float64),
                           P0w=torch.zeros(3, 3, dtype=torch.float64))
    assert all(torch.equal(u[0], v) for u, v in zip(draw_prior(zero, 9, one, at(x_true, one), at(a_true, one), w_true),
                                                 (x_true, a_true, w_true)))
    # α̂₀ is kept inside the order bounds
    wide = params._replace(P0o=torch.tensor([[100.0]], dtype=torch.float64))
    lo, hi = params.config.order_bounds
    alphas = draw_prior(wide, 9, range(200), at(x_true, range(200)), at(a_true, range(200)), w_true)[1]
    assert alphas.min() == lo and alphas.max() == hi


def test_consistent_prior_starts_each_realisation_from_its_draw_on_the_same_noise(monkeypatch):
    """prior = "consistent": the same truths as "preset" (the draws come from another stream), KFx, KFo and KFw
    start at draw_prior's values around the truth at step 0 (x₀ = 0), and the study does not depend on the
    chunking."""
    import torchtea.studies.montecarlo as mc
    from torchtea.engines.structure import Structure
    from torchtea.engines.tea import make_params
    from torchtea.studies.montecarlo import draw_prior

    preset = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=5, seed=11), trajectories=True)
    seen = []
    run_tea = mc.run_tea
    monkeypatch.setattr(mc, "run_tea", lambda *a, params, **k: seen.append(params) or run_tea(*a, params=params, **k))
    whole = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=5, seed=11, prior="consistent"),
                      trajectories=True)
    monkeypatch.undo()
    parts = run_study(Study(TRUTH, get_preset("paper-example1"), realisations=5, seed=11, prior="consistent", chunk=2),
                      trajectories=True)
    assert torch.equal(whole.trajectories["alpha_true"], preset.trajectories["alpha_true"])
    for name in ("alpha", "P_alpha", "w", "P_w", "nees", "nis"):
        torch.testing.assert_close(parts.trajectories[name], whole.trajectories[name], rtol=1e-12, atol=0)
    params = make_params(get_preset("paper-example1"), Structure())
    w_true = torch.tensor([TRUTH.param], dtype=torch.float64)
    starts = draw_prior(params, 11, range(5), torch.zeros(5, 1, dtype=torch.float64),
                        torch.full((5, 1), 0.35, dtype=torch.float64), w_true)
    for i, (x0, a0, w0) in enumerate(zip(*starts)):
        # the starts the filters were given
        assert torch.equal(seen[0].x0[i], x0) and torch.equal(seen[0].alpha0[i], a0) and torch.equal(seen[0].w0[i], w0)
        # KFo and KFw do not update at step 0: their first row is the prior itself
        assert whole.trajectories["alpha"][i, 0] == a0[0] and whole.trajectories["w"][i, 0] == w0[0]
    assert not torch.equal(whole.trajectories["alpha"][:, 0], preset.trajectories["alpha"][:, 0])
    with pytest.raises(ValueError, match="prior must be one of preset, consistent"):
        Study(TRUTH, prior="truth")


def test_montecarlo_prior_flag_study_file_and_sweep(tmp_path, capsys):
    """--prior consistent reaches the study, its summary, its study.toml (which reproduces the run) and its
    hparams; a study file's prior can be swept (two sub-studies on the same realisations); bad values are refused
    naming where they came from."""
    import json

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    from tensorboard.plugins.hparams import metadata as hp_metadata
    from tensorboard.plugins.hparams import plugin_data_pb2

    from torchtea.cli import PRIOR_CHOICES, main
    from torchtea.studies.montecarlo import PRIORS

    assert PRIOR_CHOICES == PRIORS
    logdir = tmp_path / "mc"
    args = ["montecarlo", "--preset", "paper-example1", "--n", "120", "--realisations", "4", "--seed", "4", "--json"]
    assert main(args + ["--prior", "consistent", "--logdir", str(logdir)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["prior"] == "consistent"
    assert 'prior = "consistent"' in (logdir / "study.toml").read_text()
    assert main(["montecarlo", "--config", str(logdir / "study.toml"), "--logdir", str(tmp_path / "again"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["order"]["rmse"] == out["order"]["rmse"]
    assert main(args + ["--logdir", str(tmp_path / "preset")]) == 0
    assert json.loads(capsys.readouterr().out)["order"]["rmse"] != out["order"]["rmse"]
    ea = EventAccumulator(str(logdir), size_guidance={"tensors": 0})
    ea.Reload()
    content = ea.PluginTagToContent(hp_metadata.PLUGIN_NAME)
    start = plugin_data_pb2.HParamsPluginData.FromString(content[hp_metadata.SESSION_START_INFO_TAG])
    assert start.session_start_info.hparams["prior"].string_value == "consistent"
    cfg = tmp_path / "sweep.toml"
    cfg.write_text('realisations = 3\nseed = 2\n[estimator]\npreset = "paper-example1"\n[truth]\nn = 100\n'
                   '[sweep]\nprior = ["preset", "consistent"]\n')
    assert main(["montecarlo", "--config", str(cfg), "--logdir", str(tmp_path / "sw"), "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    assert sorted(s["sweep"]["name"] for s in table["studies"]) == ["prior=consistent", "prior=preset"]
    assert {s["prior"] for s in table["studies"]} == {"preset", "consistent"}
    assert main(["montecarlo", "--config", str(cfg), "--prior", "preset", "--logdir", str(tmp_path / "x")]) == 2
    assert "prior is swept; leave out --prior" in capsys.readouterr().err
    from torchtea.engines.config import read_toml
    from torchtea.studies.sweep import build_sweep

    with pytest.raises(ValueError, match="prior is swept; leave out --prior"):  # the API refuses it too
        build_sweep(read_toml(str(cfg), "study"), {"prior": "preset"}, source=str(cfg))
    bad = tmp_path / "bad.toml"
    bad.write_text('prior = "truth"\n[estimator]\npreset = "paper-example1"\n')
    assert main(["montecarlo", "--config", str(bad), "--logdir", str(tmp_path / "y")]) == 2
    assert f"{bad}: prior must be one of preset, consistent, got 'truth'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(args + ["--prior", "truth"])
