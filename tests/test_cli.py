"""End-to-end command-line tests: the contract of simulate / estimate / identify, and bad input."""
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from torchtea.cli import main
from torchtea.core.gl import difference
from torchtea.sensors.io import bundled_recording

AXES = ("ax", "ay", "az")  # identify's default channels: the accelerometer's

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "mpu6050_arduino_100hz"


def run(*argv, capsys=None):
    code = main([str(a) for a in argv])
    return code


def test_simulate_contract(tmp_path):
    out = tmp_path / "sim.csv"
    assert run("simulate", "--n", 400, "--h", 0.01, "--order", "linear:0.3,0.2", "--param", -2.0, "--q", 0.01,
               "--r", 1e-3, "--input-std", 0.5, "--seed", 3, "--out", out) == 0
    header = out.read_text().splitlines()[0]
    assert header == "t,u,x,y,alpha"
    d = np.genfromtxt(out, delimiter=",", names=True)
    assert len(d) == 400
    k = np.arange(400)
    np.testing.assert_allclose(d["t"], k * 0.01, rtol=0, atol=1e-15)
    np.testing.assert_allclose(d["alpha"], 0.3 + 0.2 * k * 0.01, rtol=1e-15)
    assert d["x"][0] == 0.0
    # the CSV satisfies the model: h^{-α_{k+1}} Σ c_j(α_{k+1}) x_{k+1−j} − f x_k − u_k = ω_k, Var ω = Q
    lhs = difference(torch.tensor(d["x"]), torch.tensor(d["alpha"]), 0.01, "A").numpy()[1:]
    omega = lhs - (-2.0 * d["x"][:-1] + d["u"][:-1])
    assert abs(omega.var() / 0.01 - 1) < 4 * math.sqrt(2 / 399)
    assert abs(d["u"].std() / 0.5 - 1) < 0.1
    assert abs(np.var(d["y"] - d["x"]) / 1e-3 - 1) < 4 * math.sqrt(2 / 400)


def test_simulate_parabolic_no_input(tmp_path):
    out = tmp_path / "p.csv"
    assert run("simulate", "--n", 50, "--h", 0.1, "--order", "parabolic:0.2,0.05", "--param", -1, "--q", 1e-4,
               "--r", 0, "--out", out) == 0
    d = np.genfromtxt(out, delimiter=",", names=True)
    np.testing.assert_allclose(d["alpha"], 0.2 + 0.05 * (np.arange(50) * 0.1) ** 2)
    assert np.all(d["u"] == 0) and np.all(d["y"] == d["x"])


def test_simulate_seed_reproducible(tmp_path):
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    for o in (a, b):
        run("simulate", "--n", 30, "--h", 0.01, "--order", 0.4, "--param", -1, "--q", 1e-2, "--r", 1e-3,
            "--seed", 9, "--out", o)
    assert a.read_bytes() == b.read_bytes()


def test_estimate_json_contract_and_outputs(tmp_path, capsys):
    sim = tmp_path / "ex1.csv"
    run("simulate", "--n", 1500, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
        "--input-std", 1, "--seed", 1, "--out", sim)
    capsys.readouterr()
    assert run("estimate", sim, "--h", 0.001, "--preset", "paper-example1", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("alpha_final", "alpha_mean_last_third", "param_final", "param_mean_last_third", "diverged"):
        assert key in out
    assert out["diverged"] is False
    assert abs(out["alpha_mean_last_third"] - 0.35) < 0.05
    traj = Path(out["out"])
    assert traj == sim.with_suffix(".tea.csv") and traj.exists()
    d = np.genfromtxt(traj, delimiter=",", names=True)
    assert len(d) == 1500
    assert out["alpha_final"] == pytest.approx(d["alpha_hat"][-1], rel=1e-12)
    assert out["alpha_mean_last_third"] == pytest.approx(d["alpha_hat"][1000:].mean(), rel=1e-12)
    assert traj.with_suffix(".toml").exists()


def test_estimate_with_config_file(tmp_path, capsys):
    sim = tmp_path / "s.csv"
    run("simulate", "--n", 300, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
        "--input-std", 1, "--seed", 2, "--out", sim)
    cfg = tmp_path / "c.toml"
    cfg.write_text('preset = "paper-example1"\norder_bounds = [0.3, 0.4]\n[kfw]\ndelta = 0.0\n')
    capsys.readouterr()
    assert run("estimate", sim, "--h", 0.001, "--config", cfg, "--json", "--out", tmp_path / "o.csv") == 0
    out = json.loads(capsys.readouterr().out)
    assert 0.3 <= out["alpha_final"] <= 0.4
    written = (tmp_path / "o.toml").read_text()
    assert "delta = 0.0" in written and "order_bounds = [0.3, 0.4]" in written


def test_estimate_uncertainty_flags(tmp_path, capsys):
    """--kfx-uncertainty and --estimate-uncertainty on estimate: written to the settings file beside the trajectory;
    the same α̂, a different P_alpha column (the constant-truth one smaller once settled) and the paper's P smaller
    than the default's."""
    sim = tmp_path / "s.csv"
    run("simulate", "--n", 400, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
        "--input-std", 1, "--seed", 3, "--out", sim)
    base = ["estimate", sim, "--h", 0.001, "--preset", "paper-example1", "--json"]
    assert run(*base, "--out", tmp_path / "a.csv") == 0
    assert run(*base, "--out", tmp_path / "b.csv", "--kfx-uncertainty", "paper", "--estimate-uncertainty",
               "constant-truth") == 0
    capsys.readouterr()
    written = (tmp_path / "b.toml").read_text()
    assert 'kfx_uncertainty = "paper"' in written and 'estimate_uncertainty = "constant-truth"' in written
    a, b = (np.genfromtxt(tmp_path / f, delimiter=",", names=True) for f in ("a.csv", "b.csv"))
    assert np.array_equal(a["alpha_hat"], b["alpha_hat"])
    assert (b["P_alpha"][200:] < a["P_alpha"][200:]).all() and (b["P"][200:] < a["P"][200:]).all()


def test_estimate_missing_samples(tmp_path, capsys):
    f = tmp_path / "gap.csv"
    body = "\n".join(f"{0.01 * ((7 * k) % 11 - 5)}" for k in range(120))
    f.write_text("y\n0.1\n\n0.2\nnan\n" + body + "\n")
    assert run("estimate", f, "--h", 0.01, "--preset", "paper-mems-x", "--json") == 2
    assert "--allow-missing" in capsys.readouterr().err
    f.write_text("y\n0.1\n\n0.2\nnan\n" + body + "\n\n")
    # an interior blank line is an empty sample; the trailing one is not a sample
    assert run("estimate", f, "--h", 0.01, "--preset", "paper-mems-x", "--allow-missing", "--json") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] == 124 and out["missing_samples"] == 2 and not out["diverged"]
    assert out["missing"]["ranges"] == [[1, 1], [3, 3]]


@pytest.mark.parametrize("content,needle", [
    ("x,u\n1,2\n", "missing column(s) 'y'"),
    ("y\n0.1\nabc\n", "line 3: column 'y' holds 'abc'"),
    ("y\n0.1\ninf\n", "line 3: column 'y' is not finite"),
    ("y,u\n0.1,1\n0.2\n", "line 3: 1 fields"),
    ("", "empty file"),
])
def test_estimate_bad_files(tmp_path, capsys, content, needle):
    f = tmp_path / "bad.csv"
    f.write_text(content)
    assert run("estimate", f, "--h", 0.01) == 2
    err = capsys.readouterr().err
    assert needle in err and str(f) in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_bad_arguments_one_line(tmp_path, capsys):
    assert run("estimate", tmp_path / "nope.csv", "--h", 0.01) == 2
    assert "no such file" in capsys.readouterr().err
    f = tmp_path / "ok.csv"
    f.write_text("y\n0.1\n0.2\n")
    assert run("estimate", f, "--h", 0.01, "--preset", "paper-example9") == 2
    err = capsys.readouterr().err
    assert "unknown preset 'paper-example9'" in err and "paper-mems-z" in err
    assert run("simulate", "--n", 10, "--h", 0.1, "--order", "cubic:1,2", "--param", -1, "--q", 1, "--r", 1,
               "--out", tmp_path / "x.csv") == 2
    assert "bad order SPEC 'cubic:1,2'" in capsys.readouterr().err
    cfg = tmp_path / "bad.toml"
    cfg.write_text("[kfo]\ngain = 3\n")
    assert run("estimate", f, "--h", 0.01, "--config", cfg) == 2
    assert "unknown settings in [kfo]: ['gain']" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["simulate", "--n", "10", "--h", "-1", "--order", "0.3", "--param", "1", "--q", "1", "--r", "1",
              "--out", "x.csv"])


@pytest.mark.slow
def test_debug_shows_traceback(tmp_path):
    f = tmp_path / "bad.csv"
    f.write_text("x\n1\n")
    r = subprocess.run([sys.executable, "-m", "torchtea.cli", "--debug", "estimate", str(f), "--h", "0.01"],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "Traceback" in r.stderr
    r = subprocess.run([sys.executable, "-m", "torchtea.cli", "estimate", str(f), "--h", "0.01"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stderr.count("\n") == 1


def test_identify_bundled_json_contract(tmp_path, capsys):
    assert run("identify", "--json", "--samples", 600, "--out", tmp_path / "id") == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["axes"]) == {"ax", "ay", "az"}
    assert all(out["axes"][a]["unit"] == "m/s²" and out["channels"][a]["sensor"] == "accelerometer" for a in out["axes"])
    # the CLI's numbers are the library's: identify() on the same recording and settings
    from torchtea.identification import identify
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare

    lib = identify(prepare(read_recording(columns=AXES), samples=600)).summary()
    for axis in AXES:
        for key in ("alpha", "param", "alpha_final", "innovation_nis", "R"):
            assert out["axes"][axis][key] == pytest.approx(lib["axes"][axis][key], rel=1e-12), (axis, key)
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    assert len(d) == 600
    assert out["axes"]["ay"]["alpha"] == pytest.approx(d["alpha_ay"][400:].mean(), rel=1e-12)
    # the mean was removed per axis, and R is the fitted white-noise variance, Q the fitted drive
    assert abs(d["y_az"].mean()) < 1e-12
    for axis in AXES:
        fit = out["fit"][axis]["parameters"]
        assert out["axes"][axis]["R"] == pytest.approx(fit["white.r"]["value"], rel=1e-12)
        assert out["fit"][axis]["nis"] == pytest.approx(1.0, abs=0.1)  # the fitted model's own innovations
    assert out["r_mode"] == "fitted"
    for axis in AXES:
        png = tmp_path / "id" / f"channel_{axis}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_identify_runs_a_check_grown_model(tmp_path, capsys):
    """``identify --model``: the model is fitted per channel, its random walk joins KFx's state (two states) and a
    ramp leaves the series at its fitted slope; the report says where each component went. A filter the TEA cannot
    hold is refused by name, and a grown model with the paper's R rule too."""
    spec = "fractional+white+random-walk+ramp"
    assert run("identify", "--json", "--samples", 600, "--model", spec, "--out", tmp_path / "id") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == spec and "order 1" in out["tea_model"]["az"]["random-walk"]
    assert "removed" in out["tea_model"]["ax"]["ramp"]
    for axis in AXES:
        fit = out["fit"][axis]["parameters"]
        assert set(fit) >= {"random-walk.sigma", "ramp.slope"}
        assert out["axes"][axis]["R"] == pytest.approx(fit["white.r"]["value"], rel=1e-12)
        assert math.isfinite(out["axes"][axis]["alpha"]) and not out["axes"][axis]["diverged"]
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    t = np.arange(600) * 0.01
    slope = out["fit"]["az"]["parameters"]["ramp.slope"]["value"]
    # the TEA saw the channel without its fitted ramp (and, the model having no offset, without its mean)
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare

    raw = next(c.values for c in prepare(read_recording(columns=AXES), samples=600).channels if c.label == "az")
    expected = raw - slope * t
    np.testing.assert_allclose(d["y_az"], expected - expected.mean(), rtol=0, atol=1e-9)
    assert abs(slope) * t[-1] > 1e-3 * np.std(raw)  # a ramp that matters
    assert "How the TEA runs these models" in (tmp_path / "id" / "report.md").read_text()
    assert run("identify", "--samples", 600, "--model", "fractional+white+low-pass", "--out", tmp_path / "b") == 2
    assert "low-pass" in capsys.readouterr().err
    assert run("identify", "--samples", 600, "--model", spec, "--r", "paper", "--out", tmp_path / "c") == 2
    assert "--r fitted" in capsys.readouterr().err


@pytest.mark.slow
def test_identify_from_a_checks_json(tmp_path, capsys):
    """``identify --from-check``: each channel runs the model its check ended with, at the check's values, no refit;
    channels of different models run as separate batches and come back in channel order (a channel's estimates are
    those of a run of it alone: a channel of the paper's model keeps its series), the shorter state NaN-padded; the check's recording and samples are required."""
    for spec, out in (("fractional+white+random-walk", "a"), ("fractional+white", "b")):
        assert run("check", "--samples", 1000, "--columns", "ax,gy", "--model", spec, "--no-plots",
                   "--out", tmp_path / out) == 0
    capsys.readouterr()
    doc = json.loads((tmp_path / "a" / "check.json").read_text())
    doc["axes"]["gy"] = json.loads((tmp_path / "b" / "check.json").read_text())["axes"]["gy"]
    mixed = tmp_path / "mixed.json"
    mixed.write_text(json.dumps(doc))
    assert run("identify", "--json", "--samples", 1000, "--from-check", mixed, "--out", tmp_path / "id") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == "per channel"
    assert out["models"] == {"ax": "fractional+white+random-walk", "gy": "fractional+white"}
    for a in ("ax", "gy"):  # the check's values, not a refit
        assert out["fit"][a]["parameters"]["white.r"]["value"] == doc["axes"][a]["base"]["parameters"]["white.r"]
    assert run("identify", "--json", "--samples", 1000, "--from-check", mixed, "--columns", "gy",
               "--out", tmp_path / "gy") == 0
    alone = json.loads(capsys.readouterr().out)
    for key in ("alpha", "param", "alpha_final", "innovation_nis"):  # the same series, the same run
        assert out["axes"]["gy"][key] == pytest.approx(alone["axes"]["gy"][key], rel=1e-12)
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    assert len(d) == 1000 and np.isfinite(d["x_hat_ax"]).all() and np.isfinite(d["x_hat_gy"]).all()
    assert run("identify", "--samples", 1100, "--from-check", mixed, "--out", tmp_path / "c") == 2
    assert "it checked 1000 samples" in capsys.readouterr().err
    assert run("identify", "--samples", 1000, "--from-check", mixed, "--model", "fractional+white+ramp",
               "--out", tmp_path / "c") == 2
    assert "leave out --model" in capsys.readouterr().err
    assert run("identify", "--samples", 1000, "--from-check", mixed, "--columns", "az", "--out", tmp_path / "c") == 2
    assert "no check of channel(s) az" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{}")
    assert run("identify", "--from-check", tmp_path / "bad.json", "--out", tmp_path / "c") == 2
    assert "not a check.json" in capsys.readouterr().err


def test_identify_report_and_tensorboard(tmp_path, capsys):
    """report.md carries the numbers of summary.json; the TensorBoard events read back to the trajectories."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    assert run("identify", "--r", "measured", "--json", "--samples", 450, "--out", tmp_path / "id") == 0
    out = json.loads(capsys.readouterr().out)
    report = (tmp_path / "id" / "report.md").read_text()
    for axis, a in out["axes"].items():
        st = out["statistics"][axis]
        row = next(ln for ln in report.splitlines() if ln.startswith(f"| {axis} | {a['alpha']:.4f} |"))
        assert f"| {a['param']:.4f} |" in row
        assert f"{st['noise_var']:.4e}" in report and st["noise_var"] == pytest.approx(a["R"], rel=1e-12)
    assert "Samples**: 450 of 44930 at 100 Hz" in report
    for png in ("channel_ax.png", "channel_ay.png", "channel_az.png", "orders.png"):
        assert f"]({png})" in report and (tmp_path / "id" / png).read_bytes()[:4] == b"\x89PNG"
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    ea = EventAccumulator(str(tmp_path / "id" / "tb"), size_guidance={"scalars": 0})
    ea.Reload()
    ev = ea.Scalars("order/ay")
    assert len(ev) == 450 and ev[-1].step == 449
    assert ev[-1].value == pytest.approx(d["alpha_ay"][-1], rel=1e-6)  # float32 in the event file
    assert {"param/az", "innovation/ax", "order_sd/ax"} <= set(ea.Tags()["scalars"])


@pytest.mark.slow
def test_identify_generic_csv_columns_and_units(tmp_path, capsys):
    from torchtea.sensors.io import read_recording

    rec = read_recording()
    g = rec.accel_counts[:400] / 16384.0
    f = tmp_path / "g.csv"
    np.savetxt(f, np.column_stack([np.arange(400), g]), delimiter=",", header="i,X,Y,Z", comments="", fmt="%.17g")
    assert run("identify", f, "--columns", "X,Y,Z", "--units", "g", "--rate", 100, "--json", "--no-plots",
               "--out", tmp_path / "a") == 0
    generic = json.loads(capsys.readouterr().out)
    assert run("identify", "--samples", 400, "--json", "--no-plots", "--out", tmp_path / "b") == 0
    bundled = json.loads(capsys.readouterr().out)
    for axis in AXES:
        assert generic["axes"][axis]["alpha"] == pytest.approx(bundled["axes"][axis]["alpha"], rel=1e-9, abs=1e-12)
    # any number of columns; one of them alone gives what it gave among three (a batch of independent channels)
    assert run("identify", f, "--columns", "Y", "--units", "g", "--rate", 100, "--json", "--no-plots",
               "--out", tmp_path / "c") == 0
    one = json.loads(capsys.readouterr().out)
    assert set(one["axes"]) == {"ay"}
    # (to rounding: the likelihood fit of one series and of a batch of three round differently in batched linear
    # algebra, which the optimiser and the TEA carry to ~1e-7)
    assert one["axes"]["ay"]["alpha"] == pytest.approx(bundled["axes"]["ay"]["alpha"], rel=1e-6)
    named = tmp_path / "named.csv"  # columns whose names say accelerometer need a unit in a generic CSV
    named.write_text(f.read_text().replace("i,X,Y,Z", "i,acc_x,acc_y,acc_z"))
    assert run("identify", named, "--rate", 100) == 2
    assert "unknown unit of column 'acc_x' (accelerometer x): give --units" in capsys.readouterr().err
    assert run("identify", f, "--columns", "X,Y,Z", "--units", "g,g", "--rate", 100) == 2
    assert "2 units for 3 columns" in capsys.readouterr().err


def test_identify_batched_equals_per_axis(tmp_path, capsys):
    """The three axes in one batch give what each axis gives alone through `estimate`."""
    run("identify", "--r", "measured", "--json", "--samples", 300, "--no-plots", "--out", tmp_path / "id")
    ident = json.loads(capsys.readouterr().out)
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    for axis in AXES:
        f = tmp_path / f"{axis}.csv"
        np.savetxt(f, d[f"y_{axis}"], header="y", comments="", fmt="%.17g")
        r = ident["axes"][axis]["R"]
        cfg = tmp_path / f"{axis}.toml"
        cfg.write_text(f'preset = "paper-mems-{axis[1]}"\n[kfx]\nR = {r!r}\n[kfo]\nR = {r!r}\n[kfw]\nR = {r!r}\n')
        assert run("estimate", f, "--h", 0.01, "--config", cfg, "--json") == 0
        one = json.loads(capsys.readouterr().out)
        assert one["alpha_mean_last_third"] == pytest.approx(ident["axes"][axis]["alpha"], rel=1e-9, abs=1e-12)
        assert one["param_mean_last_third"] == pytest.approx(ident["axes"][axis]["param"], rel=1e-9, abs=1e-12)


def test_identify_bad_recordings(tmp_path, capsys):
    f = tmp_path / "r.csv"
    f.write_text("Fs,100\nax,ay,gz\n1,2,3\n")
    assert run("identify", f, "--columns", "ax,ay,az") == 2
    err = capsys.readouterr().err
    assert "line 2: the header lacks column(s) 'az' (it has ax, ay, gz)" in err and "--columns" in err
    f.write_text("Fs,100\nax,ay,az\n1,2,3\n1,x,3\n")
    assert run("identify", f) == 2
    assert "line 4: column 'ay' holds 'x'" in capsys.readouterr().err
    f.write_text("ax,ay,az\n1,2,3\n")
    assert run("identify", f) == 2
    assert "--rate" in capsys.readouterr().err
    assert run("identify", tmp_path / "missing.csv") == 2
    assert "no such file" in capsys.readouterr().err


def test_bundled_recording_is_the_shared_one():
    """The vendored copy is byte-for-byte the recording in shared/data (and its licence travels with it)."""
    ours = bundled_recording()
    assert (ours.parent / "LICENSE").read_text().startswith("MIT License")
    if SHARED.exists():
        assert ours.read_bytes() == (SHARED / "example_data_tinit_calc.csv").read_bytes()


def test_presets_command(capsys):
    assert run("presets") == 0
    names = capsys.readouterr().out
    for n in ("paper-example1", "paper-example2", "paper-mems-x", "paper-mems-y", "paper-mems-z"):
        assert n in names
    assert run("presets", "paper-mems-z") == 0
    text = capsys.readouterr().out
    assert "R = 0.0011" in text and 'preset = "paper-mems-z"' in text


def test_bundled_recordings_read_completely():
    """Every data row is read: 4 `key,value` lines and the column header precede the samples. (PROVENANCE.md's
    `genfromtxt(..., skip_header=6)` skips the first sample: 44,929 rows there, 44,930 in the file.)"""
    from torchtea.sensors.io import read_recording

    main_rec = read_recording(bundled_recording("main"))
    assert main_rec.accel_counts.shape == (44930, 3) and main_rec.rate_hz == 100.0
    assert main_rec.accel_counts[0].tolist() == [2508.0, -604.0, 14684.0]
    assert main_rec.gyro_counts[0].tolist() == [-429.0, 140.0, -53.0]
    assert main_rec.metadata["Logging Type"] == "1"
    second = read_recording(bundled_recording("second"))
    assert second.accel_counts.shape == (9986, 3)
    lines = bundled_recording("second").read_text().splitlines()
    assert len(lines) == 5 + 9986


@pytest.mark.slow
def test_identify_warns_about_long_recordings(tmp_path, capsys, monkeypatch):
    import torchtea.identification as identification

    monkeypatch.setattr(identification, "EXACT_COST_SAMPLES", 100)
    assert run("identify", "--samples", 150, "--no-plots", "--json", "--out", tmp_path / "id") == 0
    err = capsys.readouterr().err
    assert "150 samples" in err and "O(N²)" in err
    monkeypatch.setattr(identification, "EXACT_COST_SAMPLES", 1000)
    assert run("identify", "--samples", 150, "--no-plots", "--json", "--out", tmp_path / "id") == 0
    assert "O(N²)" not in capsys.readouterr().err


def test_generic_csv_in_g(tmp_path, capsys):
    f = tmp_path / "g.csv"
    rows = "\n".join(f"{0.001 * ((7 * i) % 5 - 2)},{0.002 * ((3 * i) % 7 - 3)},{1 + 0.001 * ((5 * i) % 3 - 1)}"
                     for i in range(200))
    f.write_text("ax,ay,az\n" + rows + "\n")
    assert run("identify", f, "--rate", 100, "--lsb-per-g", 1, "--no-plots", "--json", "--out", tmp_path / "o") == 0
    out = json.loads(capsys.readouterr().out)
    assert out["samples"] == 200
    assert out["axes"]["az"]["mean_removed"] == pytest.approx(9.80665 * (1 + 0.001 * np.mean([(5 * i) % 3 - 1 for i in range(200)])))


@pytest.mark.slow
def test_memory_option_on_estimate_identify_simulate(tmp_path, capsys, monkeypatch):
    sim = tmp_path / "s.csv"
    assert run("simulate", "--n", 1200, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
               "--input-std", 1, "--seed", 4, "--out", sim, "--memory", "soe") == 0
    exact_sim = tmp_path / "e.csv"
    assert run("simulate", "--n", 1200, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
               "--input-std", 1, "--seed", 4, "--out", exact_sim) == 0
    a, b = (np.genfromtxt(p, delimiter=",", names=True) for p in (sim, exact_sim))
    assert np.abs(a["x"] - b["x"]).max() < 1e-8 * np.abs(b["x"]).max()
    capsys.readouterr()
    outs = {}
    for mem in ("exact", "soe:1e-10", "window:100"):
        assert run("estimate", sim, "--h", 0.001, "--preset", "paper-example1", "--memory", mem, "--json",
                   "--out", tmp_path / f"{mem.replace(':', '_')}.csv") == 0
        outs[mem] = json.loads(capsys.readouterr().out)
    assert outs["soe:1e-10"]["memory"] == "soe:1e-10" and outs["exact"]["memory"] == "exact"
    assert outs["soe:1e-10"]["memory_clamped_steps"] == 0
    assert abs(outs["soe:1e-10"]["alpha_final"] - outs["exact"]["alpha_final"]) < 1e-8
    assert abs(outs["window:100"]["alpha_final"] - outs["exact"]["alpha_final"]) > 1e-6  # short memory is biased
    written = (tmp_path / "soe_1e-10.toml").read_text()
    assert "[memory]" in written and 'kind = "soe"' in written
    # the written config reproduces the run
    assert run("estimate", sim, "--h", 0.001, "--config", tmp_path / "soe_1e-10.toml", "--json",
               "--out", tmp_path / "again.csv") == 0
    assert json.loads(capsys.readouterr().out)["alpha_final"] == outs["soe:1e-10"]["alpha_final"]
    assert run("estimate", sim, "--h", 0.001, "--memory", "fast") == 2
    assert "bad memory spec 'fast'" in capsys.readouterr().err
    # identify: no O(N²) note with soe, per-axis clamp counts in the summary
    import torchtea.identification as identification

    monkeypatch.setattr(identification, "EXACT_COST_SAMPLES", 100)
    assert run("identify", "--samples", 400, "--no-plots", "--json", "--memory", "soe", "--out", tmp_path / "id") == 0
    cap = capsys.readouterr()
    assert "O(N²)" not in cap.err
    summary = json.loads(cap.out)
    assert summary["memory"] == "soe:1e-08"
    assert all("memory_clamped_steps" in s for s in summary["axes"].values())


@pytest.mark.slow
@pytest.mark.parametrize("kfx_uncertainty", ["paper", "paper-gain"])
def test_compiled_bounded_loop_equals_eager(monkeypatch, kfx_uncertainty):
    """torch.compile of blocks of steps gives the eager numbers (blocks of 2 here to keep compiling short); with
    "paper-gain" the compiled blocks carry the gain's covariance and its history as well."""
    from dataclasses import replace

    import torchtea.engines.tea as tea
    from torchtea import SCENARIOS, MemoryConfig, Structure, gaussian_input, get_preset, make_params, run_tea, simulate

    monkeypatch.setattr(tea, "COMPILE_BLOCK", 2)
    sc = SCENARIOS["paper-example1"]
    g = torch.Generator().manual_seed(5)
    u = gaussian_input((2,), 301, 1, sc.input_std, generator=g)
    sim = simulate(Structure(), n_steps=301, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
                   measurement_noise=sc.r, inputs=u, batch_shape=(2,), generator=g)
    params = make_params(replace(get_preset("paper-example1"), memory=MemoryConfig("soe"),
                                 kfx_uncertainty=kfx_uncertainty), Structure())
    eager = run_tea(sim.y, h=sc.h, params=params, inputs=u)
    compiled = run_tea(sim.y, h=sc.h, params=params, inputs=u, compile=True, record_every=3)
    torch.testing.assert_close(compiled.alpha, eager.alpha[:, ::3], rtol=0, atol=1e-12)
    torch.testing.assert_close(compiled.x, eager.x[:, ::3], rtol=0, atol=1e-12)
    torch.testing.assert_close(compiled.P, eager.P[:, ::3], rtol=1e-10, atol=0)
    assert torch.equal(compiled.memory_clamped, eager.memory_clamped)


def test_identify_refuses_an_unscaled_drive_for_a_model_of_several_states(tmp_path):
    """A grown model's states' drives are written for noise_scaling 'scaled': an override to 'unscaled' is refused
    with the channel named, not run with drives h^-2α too large."""
    from torchtea.identification import identify
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare

    m = prepare(read_recording(columns=["az"]), samples=600)
    with pytest.raises(ValueError, match="channel az: a model of several KFx states needs noise_scaling 'scaled'"):
        identify(m, model="fractional+white+random-walk", overrides={"noise_scaling": "unscaled"})


def test_the_progress_line_does_not_take_a_one_time_cost_for_the_pace(monkeypatch, capsys):
    """A headless run's progress lines: the first window holds numba's compile (100 s for one step), so the first
    line gives no time left; the next takes the pace since the line before (1000 steps in 10 s → 90 s for the 8999 left of
    10 000), not since the start (which said 'about 5953 s left' of a run of minutes)."""
    import sys

    import torchtea.cli.common as common  # where _progress reads the clock

    clock = iter([0.0, 100.0, 110.0])
    monkeypatch.setattr(common.time, "monotonic", lambda: next(clock))
    monkeypatch.setattr(sys.stderr, "isatty", lambda: False)
    step, close = common._progress(10_000, "TEA")
    for done in (0, 1, 1001):
        step(done, 10_000)
    close()
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2
    assert "1/10000 steps" in lines[0] and "the time left follows at the next line" in lines[0]
    assert "1001/10000 steps" in lines[1] and "about 90 s left" in lines[1]


def test_simulate_sets_are_one_clear_error_each_and_the_truth_file_is_what_its_meaning_says(tmp_path, capsys):
    """The ``--set`` grammar and the truth file live in the library (torchtea.noise.simulate): a value that is not a
    number is one error naming the item, exit 2 (it was a traceback), as is an unknown name; the truth file holds
    exactly the entries TRUTH_MEANING describes, the values set among them."""
    from torchtea.noise.simulate import TRUTH_MEANING

    out = tmp_path / "s.csv"
    assert run("simulate", "--model", "fractional+white", "--n", 200, "--h", 0.01, "--set", "white.r=abc",
               "--out", out) == 2
    assert "--set 'white.r=abc': the value must be a finite number" in capsys.readouterr().err and not out.exists()
    assert run("simulate", "--model", "fractional+white", "--n", 200, "--h", 0.01, "--set", "white.q=1",
               "--out", out) == 2
    assert "expected NAME=VALUE or COLUMN:NAME=VALUE with NAME one of" in capsys.readouterr().err
    assert run("simulate", "--model", "fractional+white", "--n", 200, "--h", 0.01, "--set", "ay:white.r=2e-3",
               "--columns", "ax,ay", "--out", out) == 0
    truth = json.loads((tmp_path / "s.csv.truth.json").read_text())
    assert set(truth) == set(TRUTH_MEANING)
    assert truth["values"]["ay"]["white.r"] == 2e-3 and truth["values"]["ax"]["white.r"] != 2e-3


def test_forward_mode_derivatives_print_no_warning_of_torchs_own(tmp_path):
    """The exact likelihood's gradient and a component's derivatives use forward-mode AD, whose first call makes torch
    build its own rules with ``torch.jit.script`` and warn that it is deprecated (torch's code, nothing a user can act
    on). In a fresh process with every warning shown, a fit prints no such warning — and a warning of the user's own
    still shows (the filter is for that loading only)."""
    code = ("import warnings, numpy as np\n"
            "from torchtea.fitting.mle import fit_series\n"
            "y = np.random.default_rng(0).standard_normal(2000) * 0.01\n"
            "fit_series('fractional+white', [y], 0.01, intervals=False)\n"
            "warnings.warn('the user warns', DeprecationWarning)\n")
    r = subprocess.run([sys.executable, "-W", "always", "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "jit.script" not in r.stderr and "the user warns" in r.stderr, r.stderr
