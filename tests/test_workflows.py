"""The library workflows the commands call (one per command; the CLI parses, calls and prints): ``fit`` on a
recording, ``check`` on its channels, the export's plan — each the same as the pieces it runs, called by hand."""
from __future__ import annotations

import pytest
import torch

from torchtea.checking import check
from torchtea.checking.channels import check_measurements, summary_lines
from torchtea.export.run import plan_export
from torchtea.fitting import fit_series
from torchtea.fitting.recording import bootstrap_replicates, fit_lines, fit_recording
from torchtea.sensors.io import read_recording
from torchtea.sensors.measurements import prepare


@pytest.fixture(scope="module")
def accel():
    return prepare(read_recording(columns=("ax", "ay")), samples=600)


def test_fit_recording_is_fit_series_per_channel(accel):
    seen = []
    doc, fits = fit_recording(accel, "fractional+white", bootstrap=0, progress=lambda d, t: seen.append((d, t)))
    assert seen == [(1, 2), (2, 2)]
    assert list(doc["axes"]) == [c.label for c in accel.channels] and doc["bootstrap"] == 0
    for c, f in zip(accel.channels, fits):
        ref = fit_series("fractional+white", [c.values], accel.h)[0]
        for k, v in ref.values.items():
            torch.testing.assert_close(f.values[k], v)
            assert doc["axes"][c.label]["parameters"][k]["value"] == pytest.approx(float(v))
        assert doc["axes"][c.label]["unit"] == c.unit
    lines = fit_lines(doc, {c.label: c.title for c in accel.channels}, {"accelerometer": "m/s^2"}, "rec.txt", 100.0)
    assert lines[0].startswith("rec.txt: 600 samples at 100 Hz, model fractional+white, exact likelihood")
    assert sum(line.startswith(("ax (", "ay (")) for line in lines) == 2
    assert "fractional p n/a" in lines[1]  # no bootstrap: said, not a number


def test_the_bootstrap_rule():
    import torchtea.cli
    import torchtea.cli.common
    import torchtea.fitting.recording

    assert bootstrap_replicates(1000, None) == 99 and bootstrap_replicates(10**6, None) == 0
    assert bootstrap_replicates(10**6, 5) == 5
    assert torchtea.cli.common.BOOTSTRAP_LIMIT == torchtea.fitting.recording.BOOTSTRAP_LIMIT  # fit's help says it
    assert torchtea.cli.BOOTSTRAP_LIMIT is torchtea.cli.common.BOOTSTRAP_LIMIT  # (re-exported)


def test_check_measurements_is_check_per_channel_and_its_lines_name_each(accel):
    logged = []
    res = check_measurements(accel, inputs=None, log=logged.append)
    assert list(res) == ["ax", "ay"] and len(logged) == 2 and "model fractional+white" in logged[0]
    one = check(accel.channel("ay").values, accel.h, model="fractional+white")
    assert res["ay"].adequate == one.adequate and [d.passed for d in res["ay"].diagnostics] == [
        d.passed for d in one.diagnostics]
    for k, v in one.fit.values.items():
        torch.testing.assert_close(res["ay"].fit.values[k], v)
    lines = summary_lines(res, {"ax": "accel x", "ay": "accel y"})
    heads = [line for line in lines if not line.startswith(" ")]
    assert heads[0].startswith("ax (accel x): fractional+white: ") and heads[1].startswith("ay (accel y): ")


def test_the_export_plan_checks_before_any_fit(accel):
    assert plan_export(accel, [], None) is None
    plan = plan_export(accel, ["ieee952"], None)
    assert plan.formats == ["ieee952"] and plan.horizon[1] <= 300 * accel.h and plan.horizon_note
    with pytest.raises(ValueError, match="unknown export format 'kalbr'"):
        plan_export(accel, ["kalbr"], None)
    with pytest.raises(ValueError, match="needs"):
        plan_export(accel, ["kalibr"], None)  # a gyroscope's noise too: the recording's two axes are accelerometer's


def test_estimate_file_is_run_tea_on_the_column(tmp_path):
    """estimate_file: the TEA on the file's column with the sample time from its stamps, the trajectories written
    beside it; the same estimates as run_tea on the same samples; too short a file is one InputError naming it."""
    import numpy as np

    from torchtea.engines.presets import get_preset
    from torchtea.engines.structure import Structure
    from torchtea.engines.tea import make_params, run_tea
    from torchtea.estimation import estimate_file, estimate_lines
    from torchtea.sensors.io import InputError, write_columns

    y = torch.randn(400, generator=torch.Generator().manual_seed(4), dtype=torch.float64) * 0.02
    f = write_columns(tmp_path / "s.csv", {"t": torch.arange(400, dtype=torch.float64) * 0.01, "v": y})
    cfg = get_preset("paper-mems-x")
    s = estimate_file(f, cfg, column="v", source="test")
    assert s["h"] == pytest.approx(0.01) and s["h_source"] == "the mean interval of column 't'"
    ref = run_tea(y.reshape(1, -1, 1), h=s["h"], params=make_params(cfg, Structure()))
    assert s["alpha_final"] == pytest.approx(float(ref.alpha[0, -1, 0]), rel=1e-12)
    traj = np.genfromtxt(s["out"], delimiter=",", names=True)
    assert len(traj) == 400 and traj["alpha_hat"][-1] == pytest.approx(s["alpha_final"], rel=1e-12)
    lines = estimate_lines(s)
    assert lines[-1] == f"trajectories: {s['out']}" and lines[2].endswith("missing samples: none of 400 samples missing")
    short = write_columns(tmp_path / "short.csv", {"y": y[:20]})
    with pytest.raises(InputError, match="short.csv: 20 samples"):
        estimate_file(short, cfg, h=0.01)


def test_simulate_columns_is_what_simulate_model_writes(tmp_path):
    """``torchtea simulate --model`` writes simulate_columns' columns and values: the temperature drawn first from the
    seed, then one batch, each column its defaults with its --set values on top; a name or column it lacks, refused."""
    import json

    import numpy as np

    from torchtea.cli import main
    from torchtea.noise import default_values, parse_model, simulate_model, temperature_profile
    from torchtea.noise.simulate import simulate_columns

    spec, h, n = "fractional+white+sinusoid", 0.01, 500
    data, per = simulate_columns(spec, n_steps=n, h=h, columns=["ax", "ay"], seed=4,
                                 values={"ay": {"sinusoid.amplitude": 0.2}, "ax": {"white.r": 1e-4}})
    g = torch.Generator().manual_seed(4)
    T = temperature_profile(n, h, generator=g)
    base = default_values(spec, h, T)
    assert per == {"ax": dict(base, **{"white.r": 1e-4}), "ay": dict(base, **{"sinusoid.amplitude": 0.2})}
    y = simulate_model(parse_model(spec), {k: [per["ax"][k], per["ay"][k]] for k in base}, n_steps=n, h=h,
                       inputs={"temperature": T}, generator=g)[:, 0]
    assert torch.equal(data["ax"], y[0]) and torch.equal(data["ay"], y[1]) and torch.equal(data["temp"], T)
    out = tmp_path / "s.csv"
    assert main(["simulate", "--model", spec, "--n", str(n), "--h", str(h), "--seed", "4", "--columns", "ax,ay",
                 "--set", "ay:sinusoid.amplitude=0.2", "--set", "ax:white.r=1e-4", "--out", str(out)]) == 0
    written = np.genfromtxt(out, delimiter=",", names=True)
    np.testing.assert_allclose(written["ay"], data["ay"].numpy(), rtol=1e-9)
    assert json.loads((tmp_path / "s.csv.truth.json").read_text())["values"]["ay"] == per["ay"]
    with pytest.raises(ValueError, match="not parameters of"):
        simulate_columns(spec, n_steps=n, h=h, values={"y": {"sinusoid.nope": 1.0}})
    with pytest.raises(ValueError, match="not among the columns"):
        simulate_columns(spec, n_steps=n, h=h, values={"az": {"white.r": 1.0}})
