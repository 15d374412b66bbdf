"""Several recordings of one sensor fitted together: the pooled likelihood and its gradient, the per-parameter tests,
the bias's repeatability, and ``fit A B --together``."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from torchtea.fitting.mle import fit_series
from torchtea.fitting.together import _Joint, bias_repeatability, fit_together
from torchtea.noise import simulate_model
from torchtea.noise.model import parse_model

H = 0.01
MODEL = "white+random-walk"
LAW = {"white.r": 1e-4, "random-walk.sigma": 3e-4}


def _series(n: int, seed: int, law: dict | None = None, model: str = MODEL, shift: float = 0.0) -> np.ndarray:
    y = simulate_model(model, dict(LAW if law is None else law), n_steps=n, h=H,
                       generator=torch.Generator().manual_seed(seed))[0, 0].numpy()
    return y + shift


def test_the_pooled_gradient_is_the_sum_of_the_recordings_and_matches_differences():
    """The joint gradient (shared coordinates summed over the recordings, each recording's own apart) agrees with
    central differences of the pooled −ℓ; the pooled −ℓ is the sum of the recordings' exact −ℓ."""
    model = parse_model("white+random-walk+ramp")
    ys = [_series(3000, s, model="white+random-walk") + 0.001 * s * np.arange(3000) * H for s in (1, 2)]
    fits = [fit_series(model, [y], H, intervals=False)[0] for y in ys]
    names = model.names
    shared = [names.index("white.r"), names.index("random-walk.sigma")]
    own = [names.index("ramp.slope")]
    joint = _Joint.split(model, ys, H, [None, None], [f.u.clone() for f in fits], shared, own)
    assert joint.exact_gradient and joint.D == 4
    x = joint.pack([f.u for f in fits])
    f, g, info = joint.vgi(x[None])
    separate = sum(-float(fi.loglik) for fi in fits)
    assert f[0] >= separate - 1e-6  # (the shared values are the two fits' average: no better than each its own)
    d = 1e-5
    fd = [(joint.neg_loglik((x + d * e)[None])[0] - joint.neg_loglik((x - d * e)[None])[0]) / (2 * d)
          for e in np.eye(4)]
    np.testing.assert_allclose(g[0], fd, rtol=1e-4, atol=1e-3)
    assert np.all(np.linalg.eigvalsh(info[0]) > 0)


def test_recordings_of_one_law_agree_and_pool_their_information():
    """Two recordings of one law with different levels and ramps of their own: the recordings agree (seeded; each
    test's p above its threshold), the pooled ℓ is at most the separate fits' sum and above each start, and the
    pooled interval of the white level is narrower than either recording's alone (about 1/√2 of it)."""
    ys = [_series(20_000, 3, shift=0.2), _series(20_000, 4, shift=-0.5)]
    tg = fit_together(MODEL, ys, H, recordings=["a", "b"])
    assert tg.verdict.startswith("the 2 recordings agree"), tg.parameters
    assert all(not p["differs"] and p["p_value"] > tg.threshold and p["df"] == 1 for p in tg.parameters)
    assert tg.loglik <= sum(f.loglik for f in tg.separate) + 1e-3
    assert tg.threshold == pytest.approx(0.05 / 2)

    def width(ci):
        return math.log(ci[1] / ci[0])

    ratio = width(tg.ci95["white.r"]) / np.mean([width(f.ci95["white.r"]) for f in tg.separate])
    assert 0.6 < ratio < 0.8, ratio
    lo, hi = tg.ci95["white.r"]
    assert lo < LAW["white.r"] < hi
    doc = tg.as_dict()
    assert doc["verdict"] == "agree" and doc["recordings"] == ["a", "b"] and doc["bias_repeatability"] is None
    assert [p["name"] for p in doc["parameters"]] == ["white.r", "random-walk.sigma"]
    assert len(doc["parameters"][0]["values"]) == 2


def test_a_white_level_that_differs_is_named():
    """The second recording's white variance twice the first's: the recordings differ in white.r and in nothing
    else, each recording's own value within its interval of the truth."""
    law2 = dict(LAW, **{"white.r": 2 * LAW["white.r"]})
    ys = [_series(20_000, 5), _series(20_000, 6, law2)]
    tg = fit_together(MODEL, ys, H)
    assert tg.differs == ["white.r"], tg.parameters
    white = next(p for p in tg.parameters if p["name"] == "white.r")
    assert white["p_value"] < 1e-10 and white["statistic"] > 40 and white["given"] == []
    walk = next(p for p in tg.parameters if p["name"] == "random-walk.sigma")
    assert walk["given"] == ["white.r"] and not walk["differs"]  # (tested again with the white levels apart)
    for v, truth in zip(white["values"], (LAW["white.r"], law2["white.r"])):
        assert v["ci95"][0] < truth < v["ci95"][1]


def test_the_pooled_fit_without_sensitivity_gradients_reaches_the_same_maximum():
    """Where a recording has no sensitivity gradient (missing samples, a temperature-driven order) the pooled
    likelihood is climbed by L-BFGS-B on differences: on complete records, forced onto that path, it reaches the
    maximum the scoring reaches; on a record with missing samples it is the path taken, and its maximum is above
    every start."""
    ys = [_series(4000, 7), _series(4000, 8)]
    model = parse_model(MODEL)
    fits = [fit_series(model, [y], H, intervals=False)[0] for y in ys]
    joint = _Joint.split(model, ys, H, [None, None], [f.u.clone() for f in fits], [0, 1], [])
    start = joint.pack([f.u for f in fits])
    assert joint.exact_gradient
    x_scored, ll_scored = joint.maximise([start])
    joint.exact_gradient = False
    x_fd, ll_fd = joint.maximise([start + np.array([0.3, -0.5])])
    assert ll_fd == pytest.approx(ll_scored, abs=2e-3)
    np.testing.assert_allclose(x_fd, x_scored, atol=2e-2)
    gapped = [ys[0].copy(), ys[1]]
    gapped[0][1000:1003] = np.nan
    joint = _Joint.split(model, gapped, H, [None, None], [f.u.clone() for f in fits], [0, 1], [])
    assert not joint.exact_gradient
    x, ll = joint.maximise([start, start + np.array([0.3, -0.5])])
    assert ll >= -float(joint.neg_loglik(start[None])[0]) and math.isfinite(ll)


def test_three_recordings_at_other_temperatures_share_one_reference():
    """Three recordings, each with its own bias and temperature (offset first in the model, so a recording's own
    coordinate comes before the shared ones): one temperature reference for all (the recordings' mean, weighted by
    their samples), the mean terms each recording's own — its temperature coefficient found in each —, the noise
    shared, the levels' spread reported."""
    from torchtea.noise import temperature_profile

    model = "offset+white+random-walk+temperature-bias"
    ys, inputs = [], []
    for k, (bias, shift) in enumerate([(0.02, 0.0), (-0.01, 3.0), (0.005, -2.0)]):
        T = temperature_profile(4000, H, generator=torch.Generator().manual_seed(70 + k)).numpy() + shift
        y = _series(4000, 80 + k) + bias + 0.01 * (T - 25.0)
        ys.append(y)
        inputs.append({"temperature": T})
    tg = fit_together(model, ys, H, inputs=inputs)
    refs = {v["temperature-bias.t_ref"] for v in tg.values}
    assert len(refs) == 1 and refs.pop() == pytest.approx(np.mean([i["temperature"].mean() for i in inputs]))
    assert {"temperature-bias.bias_per_degC", "offset.value"} <= set(tg.own)
    assert tg.shared == ["white.r", "random-walk.sigma"] and [p["name"] for p in tg.parameters] == tg.shared
    assert all(0.0 < v["temperature-bias.bias_per_degC"] < 0.02 for v in tg.values), tg.values
    assert tg.bias is not None and len(tg.bias["levels"]) == 3 and tg.bias["ci95"][0] <= tg.bias["spread"]


def test_the_levels_spread_is_found_within_its_interval():
    """Five recordings whose levels are 0.01 apart (a spread of 0.0158): each level recovered within four of its
    standard errors, the spread's interval holds the recordings' own spread; five recordings at one level: the
    interval starts at zero."""
    shifts = [0.0, 0.01, 0.02, 0.03, 0.04]
    ys = [_series(3000, 10 + k, shift=s) for k, s in enumerate(shifts)]
    model = parse_model(MODEL)
    values = [fit_series(model, [y], H, intervals=False)[0].values for y in ys]
    b = bias_repeatability(model, ys, values, H)
    for lv, s in zip(b["levels"], shifts):
        assert abs(lv["level"] - s) < 4 * lv["se"], (lv, s)
    assert b["ci95"][0] < np.std(shifts, ddof=1) < b["ci95"][1]
    same = [_series(3000, 20 + k) for k in range(5)]
    b0 = bias_repeatability(model, same, [fit_series(model, [y], H, intervals=False)[0].values for y in same], H)
    assert b0["ci95"][0] == 0.0 and b0["spread"] < b0["ci95"][1]


def test_fit_takes_several_recordings_together(tmp_path, capsys):
    """``torchtea fit A.csv B.csv --together``: one document with each channel's replicates; several recordings
    without --together, or of different rates, are one clear error each."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    paths = []
    for k in range(2):
        y = _series(3000, 30 + k, shift=0.1 * k)
        paths.append(write_columns(tmp_path / f"r{k}.csv", {"t": np.arange(len(y)) * H, "gyr_x": y}))
    out = tmp_path / "together.json"
    args = ["fit", *map(str, paths), "--units", "rad/s", "--model", MODEL, "--rate", "100"]
    assert main(args + ["--together", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "2 recordings fitted together" in text and "white.r" in text and "r1.csv" in text
    doc = json.loads(out.read_text())
    rep = doc["axes"]["gx"]["replicates"]
    assert rep["recordings"] == ["r0.csv", "r1.csv"] and rep["verdict"] in ("agree", "differ")
    assert {"name", "p_value", "differs", "values"} <= set(rep["parameters"][0])
    assert "replicates" in doc["meaning"] and len(doc["recordings"]) == 2
    assert (tmp_path / "allan_together_gx.png").stat().st_size > 1000
    assert main(args) == 2
    assert "--together" in capsys.readouterr().err
    assert main(["fit", str(paths[0]), str(paths[1]), "--units", "rad/s", "--together", "--rate", "100",
                 "--samples", "50"]) == 2
    assert "50 samples" in capsys.readouterr().err
    two = write_columns(tmp_path / "two.csv", {"t": np.arange(3000) * H, "gyr_x": _series(3000, 41),
                                               "gyr_y": _series(3000, 42)})
    assert main(["fit", str(paths[0]), str(two), "--units", "rad/s", "--rate", "100", "--together"]) == 2
    assert "need the same channels" in capsys.readouterr().err
    y = _series(3000, 40)
    other = write_columns(tmp_path / "fast.csv", {"t": np.arange(len(y)) * 0.005, "gyr_x": y})
    assert main(["fit", str(paths[0]), str(other), "--units", "rad/s", "--together", "--model", MODEL]) == 2
    assert "share their rate" in capsys.readouterr().err


@pytest.mark.slow
def test_a_white_level_that_doubles_is_found_where_it_changes():
    """A record whose white variance doubles at 2/3 of it (a ramp on top): the white level's constancy test rejects,
    the change is located within 5 % of the record of the truth, the random walk is not blamed; a record of one law
    (the same seed without the change) claims no change."""
    from torchtea.fitting.windows import noise_over_time

    n = 30_000
    base = _series(n, 50)
    extra = np.random.default_rng(51).standard_normal(n) * math.sqrt(LAW["white.r"])
    ramp = 0.002 * np.arange(n) * H
    y = base + ramp
    y[19_500:] += extra[19_500:]  # (at 195 s: within a piece of the test, not on a boundary between pieces)
    d = noise_over_time(MODEL + "+ramp", y, H, 30.0)
    assert d["model"] == MODEL and d["length_s"] == 30.0 and len(d["rows"]) == 19
    assert {c["name"]: c["changes"] for c in d["constancy"]} == {"white.r": True, "random-walk.sigma": False}
    (change,) = d["changes"]
    assert change["parameters"] == ["white.r"] and abs(change["at_s"] - 195.0) < 3.0, change
    assert change["after"]["white.r"] / change["before"]["white.r"] == pytest.approx(2.0, rel=0.15)
    assert "within the record" in change["advice"]
    still = noise_over_time(MODEL + "+ramp", base + ramp, H, 30.0)
    assert still["changes"] == [] and not any(c["changes"] for c in still["constancy"])


def test_check_shows_the_noise_over_time(tmp_path, capsys):
    """``check --windows``: check.json's windows (rows, constancy, changes, what they mean), the report's section
    with the parameters over time and the dynamic Allan deviation; windows the record cannot hold twice are refused
    before any work."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    y = _series(6000, 60)
    y[4000:] += np.random.default_rng(61).standard_normal(2000) * 2 * math.sqrt(LAW["white.r"])
    path = write_columns(tmp_path / "r.csv", {"t": np.arange(len(y)) * H, "gyr_x": y})
    out = tmp_path / "ck"
    args = ["check", str(path), "--units", "rad/s", "--rate", "100", "--model", MODEL, "--no-intervals"]
    assert main(args + ["--windows", "8", "--out", str(out), "--logdir", str(tmp_path / "tb")]) == 0
    printed = capsys.readouterr().out
    assert "noise over time" in printed and "white.r CHANGES" in printed
    doc = json.loads((out / "check.json").read_text())
    w = doc["axes"]["gx"]["windows"]
    assert w["length_s"] == 8.0 and len(w["rows"]) == 14 and "windows" in doc["meaning"]
    assert {"from_s", "to_s", "parameters", "ci95"} <= set(w["rows"][0])
    assert w["changes"] and abs(w["changes"][0]["at_s"] - 40.0) < 3.0
    report = (out / "report.md").read_text()
    assert "the noise over time" in report and "windows_gx.png" in report and "dadev_gx.png" in report
    assert (out / "windows_gx.png").stat().st_size > 1000 and (out / "dadev_gx.png").stat().st_size > 1000
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(tmp_path / "tb" / "gx"), size_guidance={"scalars": 0, "images": 0, "tensors": 0})
    ea.Reload()
    white = ea.Scalars("windows/white.r")
    assert [e.step for e in white] == [round(0.5 * (r["from_s"] + r["to_s"])) for r in w["rows"]]
    assert white[-1].value == pytest.approx(w["rows"][-1]["parameters"]["white.r"], rel=1e-6)
    assert {"windows/windows", "windows/dadev"} <= set(ea.Tags()["images"])
    assert main(args + ["--windows", "40", "--out", str(tmp_path / "no")]) == 2
    assert "must hold two windows" in capsys.readouterr().err and not (tmp_path / "no").exists()
