"""The loop on several recordings of one sensor (``check A B --together``): effects added and taken away by the
pooled BIC, a recording's own fault named and not added, and the command line."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from scipy import stats

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
    assert tg.k == 2 + 2 * 1 and tg.n == 4500 and tg.parameters == [] and tg.bias is None and tg.finite
    assert tg.verdict.startswith("not tested") and tg.as_dict()["verdict"] == "not tested"
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


def test_a_little_of_an_effect_in_every_recording_is_found_by_their_screens_combined():
    """Three short recordings with a weak random walk, checked from white alone: no recording suggests it (its screen
    does not pass in at least two, where it does its refit gains nothing there), their screens' p-values combined by
    Fisher's method pass, and it becomes a candidate refitted to all together (seeded)."""
    law = {"white.r": 1e-4, "random-walk.sigma": 2e-4}
    ys = [simulate_model("white+random-walk", law, n_steps=4000, h=H,
                         generator=torch.Generator().manual_seed(1 + k))[0, 0].numpy() for k in range(3)]
    pc = check_together("white", ys, H, max_steps=0, simplify=False)
    step = pc.steps[0]
    rows = [next(r for r in c.screens if r.effect == "random-walk") for c in step.checks]
    assert sum(not r.passed for r in rows) >= 2
    assert not any(s.effect == "random-walk" for c in step.checks for s in c.suggestions)
    combined = next(c for c in step.combined if c["effect"] == "random-walk")
    x = -2 * sum(math.log(r.p_value) for r in rows)
    assert combined["p_value"] == pytest.approx(stats.chi2.sf(x, 6)) and combined["passed"]
    assert combined["p_value"] < combined["threshold"] / 10
    rw = next(c for c in step.candidates if c["effect"] == "random-walk")
    assert rw["suggested_by"] == ["the recordings' screens combined"] and rw["model"] == "white+random-walk"


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
    with the Allan figure; without --auto the model checked and its pooled fit exported; flags that make no sense
    together are one clear error each."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    paths = []
    for k in range(2):
        y = _series(3000, 50 + k, shift=0.1 * k)
        paths.append(write_columns(tmp_path / f"r{k}.csv", {"t": np.arange(len(y)) * H, "gyr_x": y}))
    out = tmp_path / "ck"
    args = ["check", *map(str, paths), "--units", "rad/s", "--model", "white", "--rate", "100", "--together"]
    assert main(args + ["--auto", "--out", str(out), "--logdir", str(tmp_path / "tb")]) == 0
    text = capsys.readouterr().out
    assert "2 recordings checked together" in text and "step 1: white+random-walk (added random-walk" in text
    doc = json.loads((out / "check.json").read_text())
    ax = doc["axes"]["gx"]
    assert ax["model"] == "white+random-walk" and ax["steps"][0]["model"] == "white"
    assert ax["replicates"]["recordings"] == ["r0.csv", "r1.csv"] and "steps" in doc["meaning"]
    ea = EventAccumulator(str(tmp_path / "tb" / "gx"), size_guidance={"scalars": 0, "images": 0, "tensors": 0})
    ea.Reload()
    assert [e.value for e in ea.Scalars("pooled/bic")] == pytest.approx([s["bic"] for s in ax["steps"]], rel=1e-6)
    assert ea.Scalars("pooled/gain")[0].step == 1 and ea.Images("pooled/allan")[0].encoded_image_string[:4] == b"\x89PNG"
    verdict = ea.Tensors("verdict/text_summary")[-1].tensor_proto.string_val[0].decode()
    assert "white+random-walk" in verdict and "the 2 recordings" in verdict
    report = (out / "report.md").read_text()
    assert "## gx" in report and "allan_gx.png" in report and (out / "allan_gx.png").stat().st_size > 1000
    # (no --auto: the model checked, nothing added; its pooled model exported)
    assert main(args + ["--out", str(tmp_path / "once"), "--export", "ieee952", "--nees", "0"]) == 0
    once = json.loads((tmp_path / "once" / "check.json").read_text())["axes"]["gx"]
    assert len(once["steps"]) == 1 and once["steps"][0]["candidates"]
    exported = json.loads((tmp_path / "once" / "export" / "export.json").read_text())
    assert exported["pooled"]["recordings"] == ["r0.csv", "r1.csv"] and exported["axes"]["gx"]["model"] == "white"
    capsys.readouterr()
    assert main(args + ["--windows", "10"]) == 2
    assert "--windows is not available with --together" in capsys.readouterr().err
    assert main(args + ["--exclude", "1:2"]) == 2
    assert "same seconds out of every recording" in capsys.readouterr().err
    assert main(args[:2] + args[3:]) == 2
    assert "two or more recordings" in capsys.readouterr().err


def test_the_pooled_model_as_one_recordings_fit_keeps_the_pooled_intervals():
    """``Together.as_fit(r)``: the shared parameters at their pooled values with the pooled intervals (the others'
    own terms profiled out), recording r's own terms at its values, every estimate counted."""
    ys = [_series(3000, 7) + 0.01 * np.arange(3000) * H, _series(3000, 8) + 0.02 * np.arange(3000) * H]
    tg = fit_together("white+random-walk+ramp", ys, H)
    for r in (0, 1):
        f = tg.as_fit(r, H)
        assert f.values == tg.values[r] and f.n == 3000 and set(f.free) == {"white.r", "random-walk.sigma",
                                                                           "ramp.slope"}
        for name in tg.shared:
            np.testing.assert_allclose(f.ci95[name], tg.ci95[name], rtol=1e-9)
        lo, hi = f.ci95["ramp.slope"]
        assert lo < tg.values[r]["ramp.slope"] < hi
    assert tg.as_fit(0, H).values["ramp.slope"] != tg.as_fit(1, H).values["ramp.slope"]
    assert tg.as_fit(0, H).loglik + tg.as_fit(1, H).loglik == pytest.approx(tg.loglik, abs=1e-6)
    with pytest.raises(ValueError, match="sample time"):
        tg.as_fit(0)


def test_a_datasheets_repeatability_is_read_and_held_against_the_recordings_spread(tmp_path):
    """A datasheet's turn-on bias repeatability (1σ, a bias's units) read to SI; the recordings' spread against it:
    within spec when its whole interval is below, worse when above, not determined when it holds it."""
    from torchtea.fitting.datasheet import _repeatability_row, read_datasheet

    path = tmp_path / "gyro.toml"
    path.write_text('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 0.005, unit = "deg/s/sqrt(Hz)" }\n'
                    'repeatability = { value = 0.2, unit = "deg/s" }\n')
    sheet = read_datasheet(path)
    assert sheet["repeatability"] == pytest.approx(0.2 * math.pi / 180)
    spec = sheet["repeatability"]
    levels = [{"recording": "a", "level": 0.0, "se": 1e-5}] * 5
    for ci, verdict in (([0.1 * spec, 0.9 * spec], "within spec"), ([1.1 * spec, 3 * spec], "worse than spec"),
                        ([0.0, math.inf], "not determined by this record")):
        row = _repeatability_row(sheet, {"spread": 0.5 * sum(c for c in ci if math.isfinite(c)), "ci95": ci,
                                         "levels": levels}, "rad/s")
        assert row["verdict"] == verdict and row["term"] == "repeatability" and "5 power-ups" in row["words"]
    two = _repeatability_row(sheet, {"spread": None, "ci95": None, "levels": levels[:2]}, "rad/s")
    assert two["verdict"] == "not determined by this record" and "three or more" in two["words"]
    path.write_text('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 0.005, unit = "deg/s/sqrt(Hz)" }\n'
                    'repeatability = { value = 0.2, unit = "deg/s/sqrt(Hz)" }\n')
    with pytest.raises(ValueError, match="repeatability must be"):
        read_datasheet(path)


def test_export_takes_several_recordings_together(tmp_path, capsys):
    """``torchtea export A B C --together --model …``: the pooled model exported — the pooled fit's numbers, what
    comes from where said in export.json and export.md — and the three recordings' turn-on bias spread held against
    the datasheet's repeatability."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    paths = []
    for k, bias in enumerate((0.01, -0.02, 0.015)):
        y = _series(3000, 60 + k, shift=bias)
        paths.append(write_columns(tmp_path / f"r{k}.csv", {"t": np.arange(len(y)) * H, "gyr_x": y}))
    sheet = tmp_path / "gyro.toml"
    sheet.write_text('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 0.005, unit = "deg/s/sqrt(Hz)" }\n'
                     'repeatability = { value = 1e-4, unit = "rad/s" }\n')
    out = tmp_path / "ex"
    assert main(["export", *map(str, paths), "--together", "--units", "rad/s", "--rate", "100", "--model",
                 "white+random-walk", "--format", "ieee952", "--nees", "0", "--datasheet", str(sheet),
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "gx: white+random-walk: the 3 recordings agree" in text
    doc = json.loads((out / "export.json").read_text())
    assert doc["pooled"]["recordings"] == ["r0.csv", "r1.csv", "r2.csv"] and "pooled" in doc["meaning"]
    tg = fit_together("white+random-walk", [_series(3000, 60 + k) for k in range(3)], H)
    assert doc["axes"]["gx"]["bare"]["N"]["value"] == pytest.approx(math.sqrt(tg.values[0]["white.r"] * H),
                                                                     rel=1e-3)
    row = next(r for r in doc["axes"]["gx"]["datasheet"]["rows"] if r["term"] == "repeatability")
    assert row["verdict"] == "worse than spec" and row["ci95"][0] > 1e-4  # (levels 0.01 apart, the sheet's 1e-4)
    assert "Pooled:" in (out / "export.md").read_text()


def test_plan_takes_several_recordings_together(tmp_path, capsys):
    """``torchtea plan A B --together --model …``: the plan from the pooled fit (the pooled values as the truth), its
    source saying so; --datasheet with it is one clear error."""
    from torchtea.cli import main
    from torchtea.fitting.plan import plan_document
    from torchtea.sensors.io import write_columns

    ys = [_series(3000, 70), _series(3000, 71, 0.05)]
    paths = [write_columns(tmp_path / f"r{k}.csv", {"t": np.arange(len(y)) * H, "gyr_x": y}) for k, y in enumerate(ys)]
    out = tmp_path / "plan.json"
    args = ["plan", *map(str, paths), "--together", "--units", "rad/s", "--rate", "100", "--model",
            "white+random-walk", "--lengths", "30,600"]
    assert main(args + ["--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["source"].startswith("white+random-walk fitted to 2 recordings together (r0.csv, r1.csv)")
    tg = fit_together("white+random-walk", ys, H, tests=False)
    expected = plan_document(tg.model, tg.values[0], H, [3000, 60000], recorded=3000)
    assert json.loads(json.dumps(doc["axes"]["gx"])) == json.loads(json.dumps(expected))
    capsys.readouterr()
    assert main(args + ["--datasheet", "examples/datasheets/mpu6050_gyroscope.toml"]) == 2
    assert "--together plans from a model fitted" in capsys.readouterr().err


def test_what_belongs_to_one_recording_and_why_the_loop_ended():
    """A located effect (a step, even a second one) or one configured on its record (spikes:K) is a recording's
    fault; the loop's words put max_steps before adequacy when the loop would have gone on, and say where a
    recording's screen passed but its refit failed (the optimiser's failure)."""
    from types import SimpleNamespace

    from torchtea.checking.pooled import _loop_end, _own_fault

    assert _own_fault("step", "step") and _own_fault("spikes", "spikes:3") and not _own_fault("random-walk", None)
    tg = SimpleNamespace(recordings=["a", "b"], finite=True)
    fine = SimpleNamespace(failed_refits=[], unconfirmed=[])
    node = SimpleNamespace(together=tg, adequate=True, failing=[[], []], faults=[], checks=[fine, fine],
                           candidates=[{"effect": "sinusoid", "gain": 42.0}])
    end = _loop_end([node], 2, 0, 2, 10.0)
    assert end.startswith("stopped after 2 effects added (max_steps), adequate in every recording; sinusoid would")
    node.candidates = [{"effect": "sinusoid", "gain": 4.0}]
    assert _loop_end([node], 2, 0, 2, 10.0).startswith("adequate in every recording after 2 effect(s) added (sinusoid")
    node.candidates, tg.finite = [{"effect": "ramp", "gain": None}], False
    assert "not finite" in _loop_end([node], 0, 0, 6, 10.0)
    node.checks = [fine, SimpleNamespace(failed_refits=["gauss-markov"], unconfirmed=[])]
    assert ("in b the screens of gauss-markov passed, but their refits failed to find what the screens saw — an "
            "optimiser's failure" in _loop_end([node], 0, 0, 6, 10.0))


def test_check_together_reads_the_temperature_for_its_screens(tmp_path, capsys):
    """``check A B --together --temperature temp`` from a model without temperature terms: the temperature is read
    (its diagnostic and screens run, as for one recording), and a bias per °C that both recordings share is added."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    paths = []
    for k in range(2):
        y = _series(3000, 80 + k, shift=0.05 * k)
        temp = 20.0 + 10.0 * np.linspace(0, 1, 3000) ** (1 + k)
        paths.append(write_columns(tmp_path / f"r{k}.csv", {"t": np.arange(3000) * H, "gyr_x": y + 0.004 * temp,
                                                            "temp": temp}))
    assert main(["check", *map(str, paths), "--together", "--auto", "--units", "rad/s", "--rate", "100",
                 "--model", "white+random-walk", "--temperature", "temp", "--out", str(tmp_path / "ck")]) == 0
    assert "--temperature is not used" not in capsys.readouterr().err
    ax = json.loads((tmp_path / "ck" / "check.json").read_text())["axes"]["gx"]
    assert "temperature-bias" in ax["model"], [s["candidates"] for s in ax["steps"]]
