"""Exports in the navigation filters' own terms (issue 31): the formats parsed back as their readers do, the
numbers against the truth, the cover and the filter NEES study, the command line and its bad input."""
from __future__ import annotations

import csv
import io
import json
import math

import numpy as np
import pytest
import torch
import yaml

from torchtea.cli import main
from torchtea.export.formats import FORMATS
from torchtea.export.nees import bias_filter, nees_study
from torchtea.export.run import export_axes, write_export
from torchtea.export.terms import cover, format_avar, parse_horizon
from torchtea.fitting import fit_series
from torchtea.noise import default_values, parse_model, simulate_model
from torchtea.sensors.io import write_columns

H = 0.01
#: White noise + random walk per axis (σ_d² per sample, K): accelerometer, then gyroscope (MEMS-like sizes).
TRUTH = {"ax": (4e-4, 2e-3), "ay": (6e-4, 1e-3), "az": (9e-4, 3e-3),
         "gx": (1e-5, 2e-4), "gy": (2e-5, 1e-4), "gz": (1.5e-5, 3e-4)}
#: The formats' documented keys and units (Kalibr wiki "IMU Noise Model"; VINS-Fusion config; ORB-SLAM3 settings).
KALIBR_UNITS = {"accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
                "gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)"}


def _series(label: str, n: int, seed: int):
    r, k = TRUTH[label]
    return simulate_model("white+random-walk", {"white.r": r, "random-walk.sigma": k}, n_steps=n, h=H,
                          generator=torch.Generator().manual_seed(seed))[0, 0].numpy()


@pytest.fixture(scope="module")
def six_axes():
    """Six white + random-walk axes of 20 000 samples, fitted (exact, with intervals), exported."""
    series = {a: _series(a, 20_000, 10 + i) for i, a in enumerate(TRUTH)}
    fits = {a: fit_series("white+random-walk", [y], H, method="exact")[0] for a, y in series.items()}
    sensors = {a: "accelerometer" if a[0] == "a" else "gyroscope" for a in series}
    horizon, _ = parse_horizon(None, H, 20_000)
    axes = export_axes(fits, series, sensors, H, horizon, nees=0)
    return series, fits, axes


def test_the_format_model_avar_is_the_discrete_white_and_walk(six_axes):
    """The cover's basis: the closed forms equal the spectral integral of the model (allan.model_avar)."""
    from torchtea.checking import allan

    m = np.array([1, 3, 10, 100, 1000])
    got = format_avar(m, H) @ np.array([2e-4, 3e-4 ** 2])
    ref = allan.model_avar(parse_model("white+random-walk"), {"white.r": 2e-4, "random-walk.sigma": 3e-4}, H, m)[0]
    assert np.allclose(got, ref, rtol=1e-6)


def test_white_and_walk_come_back_within_their_intervals_and_the_cover_is_the_bare_values(six_axes):
    """Twelve 95 % intervals (Wald on the log scale): each truth within 3.3 of the interval's standard errors (a
    miss has probability 1e-3), and at least 10 of the 12 inside the 95 % interval (P 0.98 when they hold)."""
    series, fits, axes = six_axes
    z = []
    for a in axes:
        r, k = TRUTH[a.label]
        for num, truth in ((a.bare["N"], math.sqrt(r * H)), (a.bare["K"], k)):
            lo, hi = np.log(num.ci95)
            z.append((math.log(truth) - (lo + hi) / 2) / ((hi - lo) / (2 * 1.96)))
    z = np.abs(z)
    assert z.max() < 3.3 and (z < 1.96).sum() >= 10, z
    for a in axes:
        N, K = a.bare["N"], a.bare["K"]
        assert a.covered["N"].value == pytest.approx(N.value, rel=1e-6)
        assert a.covered["K"].value == pytest.approx(K.value, rel=1e-6)
        assert a.factor["N"].value == pytest.approx(1.0, abs=1e-6) and not a.forced_by
        assert a.ieee["N"].value == N.value and a.ieee["K"].value == K.value and a.ieee["Q"].value is None
        assert N.unit == ("m/s^2/sqrt(Hz)" if a.sensor == "accelerometer" else "rad/s/sqrt(Hz)")


def test_kalibr_yaml_parses_back_with_its_documented_keys_units_and_the_largest_axis(six_axes, tmp_path):
    _, _, axes = six_axes
    doc = write_export(tmp_path, axes, list(FORMATS), {"recording": "six.csv"}, which="bare", plots=False)
    text = (tmp_path / "imu.yaml").read_text()
    y = yaml.safe_load(text)
    assert set(KALIBR_UNITS) <= set(y) and y["update_rate"] == pytest.approx(1 / H) and y["rostopic"] == "/imu0"
    by = {a.label: a for a in axes}
    assert y["accelerometer_noise_density"] == pytest.approx(max(by[a].bare["N"].value for a in ("ax", "ay", "az")),
                                                             rel=1e-6)
    assert y["gyroscope_random_walk"] == pytest.approx(max(by[a].bare["K"].value for a in ("gx", "gy", "gz")),
                                                       rel=1e-6)
    lines = text.splitlines()
    for key, unit in KALIBR_UNITS.items():  # the comment under each key: its unit, the axis and the interval
        i = next(j for j, line in enumerate(lines) if line.startswith(key + ":"))
        assert lines[i + 1].startswith(f"#   {unit}, the largest of the axes") and "95 % [" in lines[i + 1]
    assert "sigma_d = N/sqrt(dt)" in text and "sigma_bd = K*sqrt(dt)" in text
    assert set(doc["files"]) == set(FORMATS) and not doc["skipped"]


def test_gtsam_files_carry_each_axis_and_set_gtsams_own_preintegration_params(six_axes, tmp_path):
    """gtsam_imu.yaml holds per axis x, y, z the four densities; gtsam_imu.py, run, sets gtsam's own
    PreintegrationCombinedParams to their squares on the diagonal (read back with gtsam's getters)."""
    import importlib.util

    _, _, axes = six_axes
    write_export(tmp_path, axes, ["gtsam", "gtsam-python"], {"recording": "six.csv"}, which="bare", plots=False)
    y = yaml.safe_load((tmp_path / "gtsam_imu.yaml").read_text())
    by = {a.label: a for a in axes}
    for key, labels, term in (("accelerometer_noise_density", "ax ay az", "N"),
                              ("gyroscope_random_walk", "gx gy gz", "K")):
        assert y[key] == pytest.approx([by[a].bare[term].value for a in labels.split()], rel=1e-6)
    spec = importlib.util.spec_from_file_location("gtsam_imu", tmp_path / "gtsam_imu.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.ACCELEROMETER_NOISE_DENSITY == pytest.approx(y["accelerometer_noise_density"], rel=1e-6)
    gtsam = pytest.importorskip("gtsam")
    params = module.preintegration_params()
    assert isinstance(params, gtsam.PreintegrationCombinedParams)
    assert np.diag(params.getAccelerometerCovariance()) == pytest.approx(np.square(y["accelerometer_noise_density"]))
    assert np.diag(params.getGyroscopeCovariance()) == pytest.approx(np.square(y["gyroscope_noise_density"]))
    assert np.diag(params.getBiasOmegaCovariance()) == pytest.approx(np.square(y["gyroscope_random_walk"]))
    assert np.diag(params.getBiasAccCovariance()) == pytest.approx(np.square(y["accelerometer_random_walk"]))


def test_vins_and_orbslam3_files_read_back_with_opencv_filestorage(six_axes, tmp_path):
    """The readers of VINS and ORB-SLAM3 are OpenCV's FileStorage: parse the files with it."""
    cv2 = pytest.importorskip("cv2")
    _, _, axes = six_axes
    write_export(tmp_path, axes, ["vins", "orbslam3"], {"recording": "six.csv"}, plots=False)
    by = {a.label: a for a in axes}
    big = lambda s, t: max(by[a].covered[t].value for a in by if a[0] == s)  # noqa: E731
    fs = cv2.FileStorage(str(tmp_path / "vins_imu.yaml"), cv2.FILE_STORAGE_READ)
    got = {k: fs.getNode(k).real() for k in ("acc_n", "gyr_n", "acc_w", "gyr_w")}
    fs.release()
    assert got == pytest.approx({"acc_n": big("a", "N"), "gyr_n": big("g", "N"), "acc_w": big("a", "K"),
                                 "gyr_w": big("g", "K")}, rel=1e-6)
    fs = cv2.FileStorage(str(tmp_path / "orbslam3_imu.yaml"), cv2.FILE_STORAGE_READ)
    got = {k: fs.getNode(k).real() for k in ("IMU.NoiseGyro", "IMU.NoiseAcc", "IMU.GyroWalk", "IMU.AccWalk",
                                             "IMU.Frequency")}
    fs.release()
    assert got == pytest.approx({"IMU.NoiseGyro": big("g", "N"), "IMU.NoiseAcc": big("a", "N"),
                                 "IMU.GyroWalk": big("g", "K"), "IMU.AccWalk": big("a", "K"),
                                 "IMU.Frequency": 1 / H}, rel=1e-6)


def test_the_openvins_file_reads_back_as_openvins_reads_it(six_axes, tmp_path):
    """OpenVINS parses kalibr_imu_chain.yaml with OpenCV's FileStorage and takes the four densities from its imu0
    node (and the intrinsics beside them): read them so, and its Kalibr-keyed values are Kalibr's file's."""
    cv2 = pytest.importorskip("cv2")
    _, _, axes = six_axes
    write_export(tmp_path, axes, ["openvins", "kalibr"], {"recording": "six.csv"}, plots=False)
    fs = cv2.FileStorage(str(tmp_path / "kalibr_imu_chain.yaml"), cv2.FILE_STORAGE_READ)
    imu0 = fs.getNode("imu0")
    keys = ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
            "gyroscope_random_walk")
    got = {k: imu0.getNode(k).real() for k in keys}
    rate, model = imu0.getNode("update_rate").real(), imu0.getNode("model").string()
    mats = {k: np.array([[imu0.getNode(k).at(i).at(j).real() for j in range(3)] for i in range(3)])
            for k in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC", "Tg")}
    fs.release()
    kalibr = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    assert got == pytest.approx({k: kalibr[k] for k in keys}, rel=1e-12) and all(v > 0 for v in got.values())
    assert rate == pytest.approx(1 / H) and model == "kalibr"
    assert all(np.array_equal(mats[k], np.eye(3)) for k in ("Tw", "R_IMUtoGYRO", "Ta", "R_IMUtoACC"))
    assert not mats["Tg"].any()


def test_the_ieee952_table_has_every_axis_and_coefficient_with_units(six_axes, tmp_path):
    _, _, axes = six_axes
    write_export(tmp_path, axes, ["ieee952"], {"recording": "six.csv"}, plots=False)
    rows = list(csv.DictReader(io.StringIO((tmp_path / "ieee952.csv").read_text())))
    assert len(rows) == 6 * 5 and {r["coefficient"] for r in rows} == set("QNBKR")
    units = {(r["sensor"], r["coefficient"]): r["unit"] for r in rows}
    assert units[("gyroscope", "N")] == "rad/s/sqrt(Hz)" and units[("gyroscope", "K")] == "rad/s^2/sqrt(Hz)"
    assert units[("gyroscope", "B")] == "rad/s" and units[("accelerometer", "R")] == "m/s^3"
    b = next(r for r in rows if r["axis"] == "gx" and r["coefficient"] == "B")
    assert "/ 0.664" in b["how"] and float(b["ci95_low"]) <= float(b["value"]) <= float(b["ci95_high"])
    q = next(r for r in rows if r["coefficient"] == "Q")
    assert q["value"] == "" and "not in the model" in q["how"]


@pytest.fixture(scope="module")
def fractional_axis():
    m = "fractional+white"
    y = simulate_model(m, default_values(m, H), n_steps=30_000, h=H,
                       generator=torch.Generator().manual_seed(1))[0, 0].numpy()
    fit = fit_series(m, [y], H, method="exact")[0]
    a = export_axes({"ax": fit}, {"ax": y}, {"ax": "accelerometer"}, H, (0.01, 100.0), nees=0)[0]
    return fit, a


def test_on_fractional_noise_the_cover_exceeds_the_bare_values_and_names_the_fractional_part(fractional_axis):
    fit, a = fractional_axis
    assert a.bare["K"].value == 0.0  # the model has no random walk
    assert a.covered["N"].value > 1.5 * a.bare["N"].value and a.covered["K"].value > 0
    assert a.factor["N"].ci95[0] > 1.0
    assert {v["component"] for v in a.forced_by.values()} == {"fractional"}
    assert any(c["term"] is None and c["effect"] == "fractional" for c in a.components)
    # the cover is what it says: the format's AVAR nowhere below the model's over the horizon
    c = a.curves
    assert np.all(np.asarray(c["adev_covered"]) >= np.asarray(c["adev_model"]) * (1 - 1e-6))
    assert np.any(np.asarray(c["adev_bare"]) < 0.8 * np.asarray(c["adev_model"]))


def test_the_filter_nees_shows_the_bare_values_overconfident_and_the_covered_not(fractional_axis):
    """Outage NEES (torchtea.export.nees) on series drawn from the fitted fractional model: the bare white
    noise (no walk) is overconfident at every outage, the covered values are within or below the 95 % band."""
    fit, a = fractional_axis
    sets = {"bare": (a.bare["N"].value, a.bare["K"].value), "covered": (a.covered["N"].value, a.covered["K"].value)}
    r = nees_study(fit.model, fit.values, H, 20_000, sets, taus=(0.1, 1.0, 10.0), realisations=64, seed=3)
    lo, hi = r["band"]
    assert [row["verdict"] for row in r["bare"]["outages"]] == ["overconfident"] * 3
    assert all(row["nees_end"] <= hi for row in r["covered"]["outages"])


def test_the_nees_study_is_consistent_when_the_model_is_the_formats_own():
    """White + random walk simulated and filtered with its own values: every outage's NEES within its band."""
    v = {"white.r": 1e-4, "random-walk.sigma": 3e-4}
    r = nees_study(parse_model("white+random-walk"), v, H, 8000, {"true": (math.sqrt(1e-4 * H), 3e-4)},
                   taus=(0.1, 1.0, 10.0), realisations=200, seed=5)
    assert [row["verdict"] for row in r["true"]["outages"]] == ["consistent"] * 3


def test_the_bias_filter_is_the_textbook_scalar_kalman_filter():
    """Against a loop written out from the textbook equations (predict, gain, update) on one series."""
    rng = np.random.default_rng(0)
    y = rng.standard_normal(500) * 0.1 + np.cumsum(rng.standard_normal(500)) * 0.01
    N, K = 0.1 * math.sqrt(H), 0.01 / math.sqrt(H)
    b, P = bias_filter(y, H, N, K)
    x, p = y[0], N * N / H
    for k in range(1, 500):
        p_pred = p + K * K * H
        gain = p_pred / (p_pred + N * N / H)
        x = x + gain * (y[k] - x)
        p = (1 - gain) * p_pred
        assert b[0, k] == pytest.approx(x, rel=1e-12) and P[k] == pytest.approx(p, rel=1e-12)


def test_the_cover_is_the_least_pair_above_the_bare_values():
    """The linear programme against a grid search of (r, K²) on a made-up AVAR curve."""
    m = np.unique(np.rint(np.logspace(0, 4, 40)).astype(int))
    basis = format_avar(m, H)
    target = basis @ np.array([1e-4, 1e-8]) * (1 + 0.5 * np.exp(-((np.log(m) - 5) ** 2)))  # a bump at m ≈ 150
    r, k2, binding = cover(target, basis, 1e-4, 1e-4 ** 2)
    assert np.all(basis @ np.array([r, k2]) >= target * (1 - 1e-9)) and len(binding) >= 1
    a_s, b_s = target[0] / basis[0, 0], target[-1] / basis[-1, 1]
    best = min((rr / a_s + kk / b_s, rr, kk) for rr in np.linspace(1e-4, 3e-4, 201) for kk in
               np.linspace(1e-8, 3e-8, 201) if np.all(basis @ np.array([rr, kk]) >= target * (1 - 1e-9)))
    assert r / a_s + k2 / b_s <= best[0] + 1e-9


# --------------------------------------------------------------------------- the command line

def _six_csv(tmp_path, n=6000, sensors="ag"):
    cols = {"t": np.arange(n) * H}
    for i, a in enumerate(TRUTH):
        if a[0] in sensors:
            cols[("acc_" if a[0] == "a" else "gyr_") + a[1]] = _series(a, n, 40 + i)
    path = write_columns(tmp_path / "six.csv", cols)
    units = ",".join("ms2" if k.startswith("acc") else "rad/s" for k in cols if k != "t")
    return path, units


def test_export_on_the_command_line_writes_every_format(tmp_path, capsys):
    path, units = _six_csv(tmp_path)
    out = tmp_path / "e"
    assert main(["export", str(path), "--units", units, "--format", "all", "--model", "white+random-walk",
                 "--nees", "16", "--out", str(out)]) == 0
    doc = json.loads((out / "export.json").read_text())
    assert set(doc["files"]) == set(FORMATS) and set(doc["axes"]) == set(TRUTH)
    assert yaml.safe_load((out / "imu.yaml").read_text())["update_rate"] == pytest.approx(100.0)
    assert (out / "allan.png").stat().st_size > 10_000 and "IEEE Std 952" in (out / "export.md").read_text()
    assert doc["axes"]["gx"]["nees"]["realisations"] == 16
    printed = capsys.readouterr().out
    assert "export kalibr:" in printed and "bare → covered" in printed


@pytest.mark.parametrize("argv, words", [
    (["--format", "kalibr2"], "unknown export format 'kalibr2'"),
    (["--format", "ieee952", "--horizon", "0.001:10"], "outside what the recording shows"),
    (["--format", "ieee952", "--horizon", "10"], "expected LO:HI"),
    (["--format", "ieee952", "--horizon", "1:1000"], "outside what the recording shows"),
    (["--format", "kalibr", "--out", "imu.yaml"], "--out imu.yaml: --out is the folder"),
])
def test_bad_export_input_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, argv, words):
    path, units = _six_csv(tmp_path, n=2000)
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(path), "--units", units, "--model", "white", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0]
    assert not (tmp_path / "imu.yaml").exists()  # (not made a folder)


def test_a_format_that_needs_a_sensor_the_recording_lacks_is_refused_and_all_skips_it(tmp_path, capsys):
    path, units = _six_csv(tmp_path, n=2000, sensors="a")
    assert main(["export", str(path), "--units", units, "--model", "white", "--format", "kalibr"]) == 2
    assert "no gyroscope channel" in capsys.readouterr().err
    out = tmp_path / "e"
    assert main(["export", str(path), "--units", units, "--model", "white+random-walk", "--format", "all",
                 "--nees", "0", "--out", str(out)]) == 0
    doc = json.loads((out / "export.json").read_text())
    assert set(doc["files"]) == {"ieee952"} and "no gyroscope" in doc["skipped"]["kalibr"]


def test_a_signal_column_is_not_exported(tmp_path, capsys):
    n = 2000
    path = write_columns(tmp_path / "s.csv", {"t": np.arange(n) * H, "y": np.random.default_rng(0).standard_normal(n)})
    assert main(["export", str(path), "--columns", "y", "--model", "white", "--format", "ieee952"]) == 2
    assert "not an accelerometer or gyroscope axis" in capsys.readouterr().err


def test_the_model_spectrum_is_the_sum_of_its_components():
    m = parse_model("fractional+white+random-walk+low-pass")
    v = default_values(m, H)
    w = torch.linspace(0.01, math.pi, 50, dtype=torch.float64)
    parts = m.component_spectra(v, w, H)
    assert set(parts) == {"fractional", "white", "random-walk"}
    assert torch.allclose(sum(parts.values()), m.spectrum(v, w, H), rtol=1e-12)


@pytest.mark.slow
def test_fit_and_check_export_the_model_they_end_with(tmp_path, capsys):
    """``fit --export`` writes beside its JSON; ``check --export`` into OUT/export, from the model the loop ends
    with (here one gyroscope axis of white noise + random walk, checked from white + random-walk)."""
    path, units = _six_csv(tmp_path, n=4000)
    assert main(["fit", str(path), "--units", units, "--model", "white+random-walk", "--out", str(tmp_path / "f" / "fit.json"),
                 "--export", "ieee952", "--nees", "0"]) == 0
    rows = list(csv.DictReader(io.StringIO((tmp_path / "f" / "export" / "ieee952.csv").read_text())))
    fit = json.loads((tmp_path / "f" / "fit.json").read_text())
    n_ax = next(float(r["value"]) for r in rows if r["axis"] == "ax" and r["coefficient"] == "N")
    assert n_ax == pytest.approx(fit["axes"]["ax"]["white_noise_density"], rel=1e-6)
    assert main(["check", str(path), "--units", "rad/s", "--columns", "gyr_x", "--model", "white+random-walk",
                 "--no-plots", "--out", str(tmp_path / "c"), "--export", "ieee952", "--nees", "8"]) == 0
    doc = json.loads((tmp_path / "c" / "export" / "export.json").read_text())
    assert list(doc["axes"]) == ["gx"] and doc["axes"]["gx"]["model"] == json.loads(
        (tmp_path / "c" / "check.json").read_text())["axes"]["gx"]["model"]
    assert main(["check", str(path), "--units", "rad/s", "--columns", "gyr_x", "--no-intervals", "--export", "ieee952",
                 "--out", str(tmp_path / "c2")]) == 2
    assert "drop --no-intervals" in capsys.readouterr().err


def test_a_ramp_is_ieee952s_r_and_named_as_outside_the_filter_formats(tmp_path):
    n = 6000
    y = _series("gx", n, 7) + 2e-4 * (np.arange(n) * H)  # a rate ramp of 2e-4 rad/s² on white + walk
    fit = fit_series("white+random-walk+ramp", [y], H, method="exact")[0]
    a = export_axes({"gx": fit}, {"gx": y}, {"gx": "gyroscope"}, H, (0.01, 20.0), nees=0)[0]
    assert a.ieee["R"].value == pytest.approx(abs(fit.values["ramp.slope"])) and a.ieee["R"].unit == "rad/s^2"
    lo, hi = a.ieee["R"].ci95
    assert lo <= 2e-4 <= hi
    assert any(c["term"] == "R" and "no term for it" in c["words"] for c in a.components)
    text = FORMATS["ieee952"].render([a], {}) + FORMATS["kalibr"].preamble([a], {}, "covered")[-1]
    assert "# not in the format (gx): ramp: a rate ramp" in text


def test_the_delta_interval_takes_one_scale_per_number(six_axes):
    """A number that is positive at the estimate but not at every perturbation gets the linear-scale interval
    throughout (a regression: log-scale gradients of earlier parameters were mixed into a linear one)."""
    from torchtea.export.terms import _delta_intervals

    _, fits, _ = six_axes
    fit = fits["ax"]
    r = fit.values["white.r"]
    fn = lambda v: {"r": v["white.r"], "mixed": v["white.r"] - r * (1 - 1e-9)}  # noqa: E731 (≈ 0 at the estimate)
    ci, why, held = _delta_intervals(fit, H, fn, ("r", "mixed"))
    assert not why and not held
    half_log = math.log(ci["r"][1] / ci["r"][0]) / 2  # 1.96 × the SE of log r
    assert ci["mixed"][0] == 0.0  # (clipped at 0: the number is ≈ 0 at the estimate)
    half_lin = ci["mixed"][1] - r * 1e-9  # 1.96 × the SE of r: r × that of log r
    assert half_lin == pytest.approx(r * half_log, rel=1e-3)
