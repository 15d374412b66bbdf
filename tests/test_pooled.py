"""The loop on several recordings of one sensor (``check A B --together``): effects added and taken away by the
pooled BIC, a recording's own fault named and not added, and the command line."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from torchtea.checking.pooled import check_together
from torchtea.fitting.together import fit_together
from torchtea.noise import simulate_model

H = 0.01
LAW = {"white.r": 1e-4, "random-walk.sigma": 1e-3}


def _series(n: int, seed: int, shift: float = 0.0) -> np.ndarray:
    y = simulate_model("white+random-walk", dict(LAW), n_steps=n, h=H,
                       generator=torch.Generator().manual_seed(seed))[0, 0].numpy()
    return y + shift


def test_the_pooled_bic_counts_shared_parameters_once_and_own_terms_per_recording():
    """k = the shared noise parameters once + each recording's mean terms once per recording; BIC on the pooled exact
    ℓ over all the recordings' samples."""
    ys = [_series(2000, 1, 0.1) + 0.01 * np.arange(2000) * H, _series(2500, 2)]
    tg = fit_together("white+random-walk+ramp", ys, H, tests=False)
    assert tg.shared == ["white.r", "random-walk.sigma"] and tg.own == ["ramp.slope"]
    assert tg.k == 2 + 2 * 1 and tg.n == 4500 and tg.parameters == [] and tg.bias is None
    assert tg.bic == pytest.approx(tg.k * math.log(4500) - 2 * tg.loglik)


def test_the_loop_adds_what_the_recordings_share_and_stops_adequate():
    """Two recordings of white noise and a random walk, each with its own level, checked together from white alone:
    the random walk passes a screen, gains pooled BIC and is added; the model is then adequate in both recordings,
    nothing else is added or taken away, and the recordings agree on it (seeded)."""
    ys = [_series(4000, 1, 0.2), _series(4000, 2, -0.3)]
    pc = check_together("white", ys, H, recordings=["a", "b"])
    assert [s.model.spec for s in pc.steps] == ["white", "white+random-walk"]
    first, last = pc.steps
    assert not first.adequate and last.adequate and pc.adequate
    rw = next(c for c in first.candidates if c["effect"] == "random-walk")
    assert rw["gain"] == pytest.approx(first.together.bic - last.together.bic, abs=1e-6) and rw["gain"] > 10
    assert last.gain == pytest.approx(rw["gain"])
    assert {t["change"] for t in last.tried} == {"without white", "without random-walk"}  # (tried, not kept)
    assert all(t["gain"] is None or t["gain"] < 0 for t in last.tried)
    assert pc.loop_end.startswith("adequate in every recording after 1 effect(s) added")
    assert pc.together.verdict == "the 2 recordings agree: one noise model for all"
    doc = pc.as_dict()
    assert doc["replicates"]["verdict"] == "agree" and [s["model"] for s in doc["steps"]] == ["white",
                                                                                             "white+random-walk"]


def test_a_step_in_one_recording_is_its_fault_not_the_sensors():
    """A level step in one of two recordings of one law: its check suggests a step, which the pooled loop names as
    that recording's own fault and does not add; the other recording suggests nothing."""
    a, b = _series(4000, 3), _series(4000, 4)
    b[2500:] += 0.05
    pc = check_together("white+random-walk", [a, b], H, recordings=["a", "b"])
    faults = pc.steps[0].faults
    assert [f["recording"] for f in faults] == ["b"] and faults[0]["effect"] == "step"
    assert "step" not in pc.model.spec
    assert "b: step" in pc.loop_end and "its own fault" in pc.loop_end


def test_a_component_the_recordings_do_not_need_is_taken_away():
    """Started from a model with a Gauss–Markov bias the data lack, the loop takes it away (the pooled BIC falls
    and no recording fails a diagnostic it passed) and says so in the path."""
    ys = [_series(3000, 5), _series(3000, 6, 0.1)]
    pc = check_together("white+random-walk+gauss-markov", ys, H, recordings=["a", "b"])
    assert pc.model.spec == "white+random-walk"
    assert pc.steps[-1].change == "without gauss-markov" and pc.steps[-1].gain > 0


def test_check_takes_several_recordings_together(tmp_path, capsys):
    """``torchtea check A.csv B.csv --together --auto``: check.json with each channel's path and replicates, a report
    with the Allan figure; flags that make no sense together are one clear error each."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    paths = []
    for k in range(2):
        y = _series(3000, 50 + k, shift=0.1 * k)
        paths.append(write_columns(tmp_path / f"r{k}.csv", {"t": np.arange(len(y)) * H, "gyr_x": y}))
    out = tmp_path / "ck"
    args = ["check", *map(str, paths), "--units", "rad/s", "--model", "white", "--rate", "100", "--together"]
    assert main(args + ["--auto", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "2 recordings checked together" in text and "step 1: white+random-walk (added random-walk" in text
    doc = json.loads((out / "check.json").read_text())
    ax = doc["axes"]["gx"]
    assert ax["model"] == "white+random-walk" and ax["steps"][0]["model"] == "white"
    assert ax["replicates"]["recordings"] == ["r0.csv", "r1.csv"] and "steps" in doc["meaning"]
    report = (out / "report.md").read_text()
    assert "## gx" in report and "allan_gx.png" in report and (out / "allan_gx.png").stat().st_size > 1000
    assert main(args + ["--out", str(tmp_path / "once")]) == 0  # (no --auto: the model checked, nothing added)
    once = json.loads((tmp_path / "once" / "check.json").read_text())["axes"]["gx"]
    assert len(once["steps"]) == 1 and once["steps"][0]["candidates"]
    capsys.readouterr()
    assert main(args + ["--windows", "10"]) == 2
    assert "--windows is not available with --together" in capsys.readouterr().err
    assert main(args + ["--exclude", "1:2"]) == 2
    assert "same seconds out of every recording" in capsys.readouterr().err
    assert main(args[:2] + args[3:]) == 2
    assert "two or more recordings" in capsys.readouterr().err
