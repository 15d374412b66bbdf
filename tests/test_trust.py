"""Outputs a user can trust (issue 10): strict JSON, one missing-sample policy, time stamps checked against the
rate, warnings where a result should not be trusted, labelled spans, the --config merge, progress off a
terminal, partial results after Ctrl-C, errors that name the column and hint at the delimiter."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from torchtea.cli import main
from torchtea.render.strictjson import dumps, strict
from torchtea.sensors.datacheck import check_timing, find_missing
from torchtea.sensors.io import read_recording
from torchtea.sensors.measurements import prepare

SHARED_TEMP = Path(__file__).resolve().parents[2] / "shared" / "data" / "mpu6050_sensor_fusion_temperature"


def strict_loads(text):
    """A JSON parser that refuses NaN and ±Infinity, as JavaScript's JSON.parse or jq do."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")

    return json.loads(text, parse_constant=refuse)


AX = ("ax", "ay", "az")  # identify's channels by default: the accelerometer's


def run(*argv):
    return main([str(a) for a in argv])


def bundled_csv(tmp_path, n, *, nan_at=(), name="g.csv", time=None):
    """The first n samples of the bundled recording as a generic CSV in g (optionally with empty fields)."""
    g = read_recording().accel_counts[:n] / 16384.0
    lines = ["t,ax,ay,az" if time is not None else "ax,ay,az"]
    for k, row in enumerate(g):
        vals = ["" if (k, j) in nan_at else repr(float(v)) for j, v in enumerate(row)]
        lines.append(",".join(([repr(float(time[k]))] if time is not None else []) + vals))
    f = tmp_path / name
    f.write_text("\n".join(lines) + "\n")
    return f


# --------------------------------------------------------------------------- strict JSON


def test_strict_json_writes_null_for_non_finite_numbers():
    data = {"a": math.nan, "b": [1.5, math.inf, -math.inf], "c": np.float64("nan"), "d": torch.tensor(2.0),
            "e": np.arange(2), "f": (1, None), "g": {"h": np.float32(0.5)}}
    assert strict(data) == {"a": None, "b": [1.5, None, None], "c": None, "d": 2.0, "e": [0, 1], "f": [1, None],
                            "g": {"h": 0.5}}
    assert strict_loads(dumps(data))["b"] == [1.5, None, None]
    assert "NaN" not in json.dumps(strict(data)) and "NaN" in json.dumps({"a": math.nan})  # as json.dumps would


def test_identify_and_estimate_json_are_strict(tmp_path, capsys):
    # 150 samples: some axis has not settled, so its settling time is "no number" — null, not NaN
    assert run("identify", "--samples", 150, "--json", "--no-plots", "--out", tmp_path / "id") == 0
    out = strict_loads(capsys.readouterr().out)
    on_disk = strict_loads((tmp_path / "id" / "summary.json").read_text())
    assert on_disk["axes"] == out["axes"]
    settle = [on_disk["statistics"][a]["alpha_settle_s"] for a in AX]
    assert None in settle  # the case that used to be written as NaN
    sim = tmp_path / "s.csv"
    run("simulate", "--n", 300, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
        "--input-std", 1, "--seed", 2, "--out", sim)
    capsys.readouterr()
    assert run("estimate", sim, "--h", 0.001, "--json") == 0
    strict_loads(capsys.readouterr().out)


def test_montecarlo_summary_is_strict_json(tmp_path, capsys):
    # a single realisation: the standard deviation over realisations is undefined (null)
    assert run("montecarlo", "--preset", "paper-example1", "--n", 60, "--realisations", 1, "--logdir",
               tmp_path / "mc", "--json") == 0
    out = strict_loads(capsys.readouterr().out)
    strict_loads((tmp_path / "mc" / "summary.json").read_text())
    assert out["realisations"] == 1


# --------------------------------------------------------------------------- missing samples: one policy


def test_missing_samples_are_one_policy_in_identify_and_estimate(tmp_path, capsys):
    f = bundled_csv(tmp_path, 300, nan_at={(120, 1), (121, 1), (200, 0)})
    assert run("identify", f, "--columns", "ax,ay,az", "--units", "g", "--rate", 100, "--no-plots",
               "--out", tmp_path / "id") == 2
    err = capsys.readouterr().err
    assert "3 of 300 samples are missing (sample index 120–121, 200" in err and "--allow-missing" in err
    assert "per channel 'ax': 1, 'ay': 2)" in err and err.count("\n") == 1
    y = tmp_path / "y.csv"
    y.write_text("y\n0.1\n\n0.2\nnan\n" + "0.3\n" * 116)
    assert run("estimate", y, "--h", 0.01) == 2
    err = capsys.readouterr().err
    assert "2 of 120 samples are missing (sample index 1, 3" in err and "--allow-missing" in err
    y.write_text("y\n" + "nan\n" * 119 + "0.1\n")  # allowed, but nothing to estimate
    assert run("estimate", y, "--h", 0.01, "--allow-missing") == 2
    assert "column 'y' has 1 observed sample(s)" in capsys.readouterr().err


def test_allowed_missing_samples_are_stated_and_left_out_of_statistics(tmp_path, capsys):
    f = bundled_csv(tmp_path, 300, nan_at={(120, 1), (121, 1), (200, 0)})
    assert run("identify", f, "--columns", "ax,ay,az", "--units", "g", "--rate", 100, "--allow-missing", "--json",
               "--no-plots", "--out", tmp_path / "id") == 0
    out = strict_loads(capsys.readouterr().out)
    assert out["missing_samples"] == 3 and out["missing"]["ranges"] == [[120, 121], [200, 200]]
    assert out["missing"]["per_column"] == {"ax": 1, "ay": 2, "az": 0}
    assert [out["axes"][a]["missing_samples"] for a in AX] == [1, 2, 0]
    report = (tmp_path / "id" / "report.md").read_text()
    assert "**Missing samples** in the part used: 3 of 300 samples missing (sample index 120–121, 200)" in report
    # NIS over the observed samples only: a missing sample's zero innovation does not count
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    for a in AX:
        seen = ~np.isnan(d[f"y_{a}"])
        seen[0] = False
        nis = d[f"innovation_{a}"] ** 2 / d[f"innovation_var_{a}"]
        assert out["axes"][a]["innovation_nis"] == pytest.approx(nis[seen].mean(), rel=1e-12)
        assert out["axes"][a]["innovation_nis"] != pytest.approx(nis[1:].mean(), rel=1e-6) or a == "az"


def test_too_few_samples_is_an_error_not_a_nan_report(tmp_path, capsys):
    assert run("identify", "--samples", 5, "--out", tmp_path / "id") == 2
    err = capsys.readouterr().err
    assert "5 samples; identify needs at least 100" in err and not (tmp_path / "id").exists()
    assert run("identify", "--samples", "five", "--out", tmp_path / "id") == 2
    assert "--samples must be a whole number or 'all'" in capsys.readouterr().err
    assert run("identify", "--samples", -5, "--out", tmp_path / "id") == 2  # not "all but the last 5"
    assert "--samples must be positive or 'all', got -5" in capsys.readouterr().err
    y = tmp_path / "y.csv"
    y.write_text("y\n" + "0.1\n0.2\n" * 2)
    assert run("estimate", y, "--h", 0.01) == 2
    assert "4 samples; estimate needs at least 100" in capsys.readouterr().err


# --------------------------------------------------------------------------- time stamps


def test_check_timing_regular_mismatched_and_bursty():
    h = 0.01
    t = np.arange(1000) * h
    ok = check_timing(t, 100.0, column="t", rate_source="--rate")
    assert ok.warnings == () and ok.irregular_fraction == 0 and abs(ok.rate_mismatch) < 1e-12
    slow = check_timing(t * 1.007, 100.0, column="t", rate_source="--rate")  # the clock runs 0.7 % slower
    assert slow.stamp_rate_hz == pytest.approx(100 / 1.007) and slow.rate_mismatch == pytest.approx(0.007)
    assert len(slow.warnings) == 1 and "+0.70 %" in slow.warnings[0] and "span 10.1 s" in slow.warnings[0]
    # host stamps: bursts of 5 samples 2 ms apart, then a 42 ms wait (mean 10 ms)
    burst = np.array([(i // 5) * 0.05 + (i % 5) * 0.002 for i in range(1000)])
    b = check_timing(burst, 100.0, column="sec", rate_source="--rate")
    assert b.irregular_fraction == pytest.approx(1.0) and any("irregular" in w for w in b.warnings)
    assert b.interval_median_s == pytest.approx(0.002)
    back = t.copy()
    back[500] = back[499]
    assert any("backwards" in w and "sample 500" in w for w in check_timing(back, 100.0, column="t",
                                                                             rate_source="--rate").warnings)


@pytest.mark.slow
def test_time_column_is_read_and_checked_in_identify(tmp_path, capsys):
    stamps = np.arange(400) * 0.01 * 1.0068  # 400 samples whose stamps run 0.68 % long
    f = bundled_csv(tmp_path, 400, time=stamps)
    assert run("identify", f, "--units", "g", "--rate", 100, "--json", "--no-plots", "--out", tmp_path / "a") == 0
    cap = capsys.readouterr()
    out = strict_loads(cap.out)
    assert out["timing"]["column"] == "t" and out["timing"]["span_s"] == pytest.approx(399 * 0.01 * 1.0068)
    assert "time column 't'" in cap.err and "+0.68 %" in cap.err
    assert any("+0.68 %" in w for w in out["warnings"])
    # without --rate the stamps give the rate, and then they agree with it
    assert run("identify", f, "--units", "g", "--json", "--no-plots", "--out", tmp_path / "b") == 0
    out = strict_loads(capsys.readouterr().out)
    assert out["rate_hz"] == pytest.approx(100 / 1.0068) and "time column 't'" in out["rate_source"]
    assert out["timing"]["warnings"] == []
    # --time-column none ignores them
    assert run("identify", f, "--units", "g", "--rate", 100, "--time-column", "none", "--json", "--no-plots",
               "--out", tmp_path / "c") == 0
    assert strict_loads(capsys.readouterr().out)["timing"] is None


@pytest.mark.skipif(not SHARED_TEMP.exists(), reason="shared/data not beside the checkout")
def test_bursty_host_stamps_of_a_real_recording_are_warned_about(tmp_path, capsys):
    f = SHARED_TEMP / "unmoved_x_forward.csv"
    rec = read_recording(f, columns=("acc_x", "acc_y", "acc_z"), lsb_per_g=1.0, rate_hz=100.0)
    tm = check_timing(rec.time_s, rec.rate_hz, column=rec.time_column, rate_source=rec.rate_source)
    # PROVENANCE.md: 12 243 rows, 123.2 s, 99.38 Hz mean, median spacing 2.09 ms, 99th percentile ≈ 60 ms
    assert tm.column == "sec" and tm.stamped == 12243
    assert tm.span_s == pytest.approx(123.2, abs=0.05) and tm.stamp_rate_hz == pytest.approx(99.38, abs=0.01)
    assert tm.interval_median_s == pytest.approx(2.09e-3, abs=0.01e-3) and 0.05 < tm.interval_p99_s < 0.07
    assert len(tm.warnings) == 2 and "+0.63 %" in tm.warnings[0] and "irregular" in tm.warnings[1]  # 100 Hz vs 99.37
    # and the command says so, on stderr and in the summary (the first 300 samples here)
    assert run("identify", f, "--columns", "acc_x,acc_y,acc_z", "--units", "g", "--rate", 100, "--samples", 300,
               "--json", "--no-plots", "--out", tmp_path / "id") == 0
    cap = capsys.readouterr()
    out = strict_loads(cap.out)
    assert out["timing"]["column"] == "sec" and "the stamps are irregular" in cap.err
    assert any("the stamps are irregular" in w for w in out["warnings"])


@pytest.mark.slow
def test_time_stamps_in_other_units_or_as_text(tmp_path, capsys):
    stamps_ms = np.arange(300) * 10.0  # milliseconds
    f = bundled_csv(tmp_path, 300, time=stamps_ms)
    assert run("identify", f, "--units", "g", "--no-plots", "--out", tmp_path / "a") == 2  # no --rate: 0.1 Hz?
    err = capsys.readouterr().err
    assert "gives a sample rate of 0.1 Hz, implausible for an IMU" in err and "--rate" in err
    assert run("identify", f, "--units", "g", "--rate", 100, "--json", "--no-plots", "--out", tmp_path / "b") == 0
    cap = capsys.readouterr()
    assert "a factor of about 10^3: they look like milliseconds" in cap.err
    assert not any("% from the stamps" in w for w in strict_loads(cap.out)["warnings"])  # the units, not the rate
    text = tmp_path / "iso.csv"
    lines = f.read_text().splitlines()
    text.write_text("\n".join([lines[0]] + [f"2024-06-29T10:00:{k // 100:02d}.{k % 100:02d}," + ln.partition(",")[2]
                                            for k, ln in enumerate(lines[1:])]) + "\n")
    assert run("identify", text, "--units", "g", "--rate", 100, "--json", "--no-plots", "--out", tmp_path / "c") == 0
    cap = capsys.readouterr()
    assert "note: column 't' is not in seconds" in cap.err and strict_loads(cap.out)["timing"] is None
    assert run("identify", text, "--units", "g", "--rate", 100, "--time-column", "t", "--out", tmp_path / "d") == 2
    assert "time stamps must be seconds (--time-column none ignores them)" in capsys.readouterr().err


def test_recorder_file_device_clock_is_checked(tmp_path):
    from torchtea.identification import identify

    rows = ["# torchtea-recording 1", "# units", "segment,counter,t_s,ax,ay,az,gx,gy,gz,temp",
            '# segment 0: {"rate_hz": "100", "accel_lsb_per_g": "4096", "gyro_lsb_per_dps": "131"}']
    rng = np.random.default_rng(0)
    for k in range(300):
        t = k * 0.0102  # the device's clock says 98 Hz; its header says 100
        a = rng.integers(-20, 20, 3) * 9.80665 / 4096
        rows.append(f"0,{k},{t!r}," + ",".join(repr(float(v)) for v in a) + ",0,0,0,25")
    f = tmp_path / "rec.csv"
    f.write_text("\n".join(rows) + "\n")
    rec = read_recording(f, columns=("ax", "ay", "az"))
    assert rec.time_column == "t_s" and rec.rate_source == "the device's header (rate_hz)"
    ident = identify(prepare(rec))
    assert ident.timing.rate_mismatch == pytest.approx(0.02, rel=1e-9)
    assert any("+2.00 %" in w for w in ident.timing.warnings)


# --------------------------------------------------------------------------- results that should not be trusted


def test_nis_far_from_one_is_warned_about_with_labelled_spans(tmp_path, capsys):
    assert run("identify", "--r", "measured", "--samples", 600, "--json", "--no-plots", "--out", tmp_path / "id") == 0
    cap = capsys.readouterr()
    out = strict_loads(cap.out)
    x = out["axes"]["ax"]
    assert x["innovation_nis_last_third"] < 0.5  # the bundled x axis: the MEMS noise levels do not fit
    msg = f"channel ax: NIS over the last third is {x['innovation_nis_last_third']:.3g}, outside [0.5, 2]"
    assert msg in cap.err and any(w.startswith(msg) for w in out["warnings"])
    report = (tmp_path / "id" / "report.md").read_text()
    assert msg in report and "## Warnings" in report
    # an order whose own filter σ is large is called poorly determined, with the numbers; one that is not, is not
    for a in AX:
        sd = out["axes"][a]["alpha_filter_sd_final"]
        said = any(w.startswith(f"channel {a}: α̂ is poorly determined: σ at the last sample is {sd:.3g}, KFo's own ")
                   for w in out["warnings"])
        assert said == (sd > 0.1), (a, sd)
    assert out["axes"]["az"]["alpha_filter_sd_final"] > 0.1 > out["axes"]["ax"]["alpha_filter_sd_final"]
    # each number says over which span it is: the last third is samples 400–599
    assert out["last_third"] == {"first_sample": 400, "last_sample": 599, "t0_s": 4.0, "t1_s": 5.99}
    assert "samples 400–599" in out["meaning"]["alpha"] and "not an uncertainty" in out["meaning"]["alpha_std_last_third"]
    assert "last ⅓ = samples 400–599 (4.00–5.99 s)" in report
    assert "| NIS, last ⅓ | NIS, whole run |" in report and "not an uncertainty" in report
    assert "± sd" not in report
    # the NIS of the last third is the last third's, not the whole run's
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    nis = d["innovation_ax"] ** 2 / d["innovation_var_ax"]
    assert x["innovation_nis_last_third"] == pytest.approx(nis[400:].mean(), rel=1e-12)
    assert x["innovation_nis"] == pytest.approx(nis[1:].mean(), rel=1e-12)


def test_order_at_bound_and_parameter_that_never_moved_are_warned_about(tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("order_bounds = [0.6, 0.7]\n[kfw]\nP0 = 1e-14\nQ0 = 1e-14\n")
    assert run("identify", "--r", "measured", "--samples", 300, "--config", cfg, "--json", "--no-plots", "--out", tmp_path / "id") == 0
    cap = capsys.readouterr()
    out = strict_loads(cap.out)
    x = out["axes"]["ax"]
    assert x["alpha_at_bound_fraction"] > 0.1
    assert "channel ax: α̂ sits at its bound (order_bounds [0.6, 0.7])" in cap.err
    assert x["param_max_move"] < 1e-9 and "channel ax: ŵ never left its start value 0" in cap.err
    # and where they do not apply, they are not said: the default bounds and KFw's own priors
    assert run("identify", "--r", "measured", "--samples", 300, "--json", "--no-plots", "--out", tmp_path / "id2") == 0
    cap = capsys.readouterr()
    assert "sits at its bound" not in cap.err and "never left its start value" not in cap.err
    assert all(strict_loads(cap.out)["axes"][a]["param_max_move"] > 1e-3 for a in AX)


def test_consistent_filter_on_its_own_model_gives_no_warning(tmp_path, capsys):
    """The positive control: data from the paper's Example 1 model, estimated with its settings — NIS near 1,
    α̂ inside its bounds, both estimates moved and settled: nothing to warn about."""
    sim = tmp_path / "s.csv"
    run("simulate", "--n", 1500, "--h", 0.001, "--order", 0.35, "--param", -1, "--q", 1e-4, "--r", 1e-3,
        "--input-std", 1, "--seed", 1, "--out", sim)
    capsys.readouterr()
    assert run("estimate", sim, "--h", 0.001, "--preset", "paper-example1", "--json") == 0
    cap = capsys.readouterr()
    out = strict_loads(cap.out)
    assert 0.5 <= out["innovation_nis_last_third"] <= 2.0
    assert out["warnings"] == [] and "warning" not in cap.err
    assert out["timing"]["column"] == "t" and out["timing"]["warnings"] == []  # simulate's t column, checked


def test_not_settled_is_warned_about():
    from torchtea.engines.presets import get_preset
    from torchtea.engines.tea import TEAResult
    from torchtea.reports.identify import summarise

    N = 300
    drift = torch.linspace(0.2, 0.8, N, dtype=torch.float64)  # α̂ still climbing at the end
    flat = torch.full((N,), 0.4, dtype=torch.float64)
    ones = torch.ones(2, N, 1, 1, dtype=torch.float64)
    alpha = torch.stack([drift, flat]).unsqueeze(-1)
    w = torch.stack([flat - 1.0, torch.linspace(-1.0, -0.5, N, dtype=torch.float64)]).unsqueeze(-1)
    res = TEAResult(x=torch.zeros(2, N, 1), P=ones, alpha=alpha, P_alpha=ones * 1e-2, Q_alpha=ones, w=w,
                    P_w=ones * 1e-2, Q_w=ones, innovation=torch.ones(2, N, 1, dtype=torch.float64), innovation_cov=ones,
                    diverged=torch.zeros(2, dtype=torch.bool), diverged_at=torch.full((2,), -1))
    cfg = get_preset("paper-mems-x")
    s = summarise(res, (cfg, cfg), h=0.01, names=("a", "b"))
    assert any(m.startswith("axis a: α̂ is still drifting: its mean moved by +0.1") for m in s["warnings"])
    assert not any(m.startswith("axis b: α̂ is still drifting") for m in s["warnings"])
    assert any(m.startswith("axis b: ŵ is still drifting") for m in s["warnings"])
    assert not any(m.startswith("axis a: ŵ") for m in s["warnings"])
    assert s["axes"]["a"]["alpha_drift_last_third"] == pytest.approx(0.6 / (N - 1) * 50, rel=0.02)


def test_montecarlo_prints_nees_and_warns_outside_its_band(tmp_path, capsys):
    # an estimator told R = 1e-5 where the truth has r = 1e-3: its innovations are ~100× larger than it predicts
    study = tmp_path / "s.toml"
    study.write_text('realisations = 8\nseed = 3\n[truth]\nh = 0.001\nn = 300\norder = "0.35"\nparam = -1.0\n'
                     'q = 1e-4\nr = 1e-3\ninput_std = 1.0\n[estimator]\npreset = "paper-example1"\n'
                     '[estimator.kfx]\nR = 1e-5\n')
    assert run("montecarlo", "--config", study, "--logdir", tmp_path / "mc") == 0
    cap = capsys.readouterr()
    s = strict_loads((tmp_path / "mc" / "summary.json").read_text())
    lo, hi = s["nis"]["band_95"]
    # (NIS ≈ 20: the default KFx's S includes the order's and parameter's uncertainty, so not the full 100×)
    assert s["nis"]["mean"] > 5 * hi and s["nis"]["fraction_of_steps_inside_band"] < 0.8
    assert f"NIS: mean {s['nis']['mean']:.4g} over steps and realisations" in cap.out
    assert f"[{lo:.3g}, {hi:.3g}]" in cap.out and "NEES: mean" in cap.out
    msg = "NIS (innovations against KFx's S): its mean over realisations lies inside the per-step 95 % band"
    assert msg in cap.err and any(w.startswith(msg) for w in s["warnings"])  # in summary.json too
    # the same study with the right R: consistent innovations, no NIS warning
    study.write_text(study.read_text().replace("R = 1e-5", "R = 1e-3"))
    assert run("montecarlo", "--config", study, "--logdir", tmp_path / "mc2") == 0
    cap = capsys.readouterr()
    s = strict_loads((tmp_path / "mc2" / "summary.json").read_text())
    assert s["nis"]["fraction_of_steps_inside_band"] >= 0.8 and "NIS (innovations" not in cap.err


# --------------------------------------------------------------------------- identify --config


def test_identify_config_merges_onto_the_mems_settings_and_keeps_its_r(tmp_path, capsys):
    import tomllib

    cfg = tmp_path / "c.toml"
    cfg.write_text("[kfo]\ndelta = 0.3\n")  # no preset line, no R
    assert run("identify", "--r", "measured", "--samples", 300, "--config", cfg, "--json", "--no-plots", "--out", tmp_path / "a") == 0
    out = strict_loads(capsys.readouterr().out)
    used = tomllib.loads((tmp_path / "a" / "config_ax.toml").read_text())
    assert used["kfo"]["delta"] == 0.3
    assert used["kfx"]["Q0"] == 0.01 and used["kfo"]["x0"] == 1.0  # the MEMS preset's, not TEAConfig's defaults
    assert used["kfx"]["R"] == pytest.approx(out["statistics"]["ax"]["noise_var"], rel=1e-12)  # measured, per axis
    assert out["settings_changed"] == ["kfo.delta: 0.5 → 0.3"]
    report = (tmp_path / "a" / "report.md").read_text()
    assert f"**Changed from those settings** by `--config {cfg}`: `kfo.delta: 0.5 → 0.3`" in report
    # x's own config reused: no change on x, but y and z now run with x's R — and say so
    rx = used["kfx"]["R"]
    cfg.write_text(f"[kfx]\nR = {rx!r}\n[kfo]\nR = {rx!r}\n[kfw]\nR = {rx!r}\n")
    assert run("identify", "--r", "measured", "--samples", 300, "--config", cfg, "--json", "--no-plots", "--out", tmp_path / "b") == 0
    out = strict_loads(capsys.readouterr().out)
    assert [out["axes"][a]["R"] for a in AX] == [rx] * 3  # the file's R is kept
    ry = out["statistics"]["ay"]["noise_var"]
    assert f"channel ay: kfx.R: {ry!r} → {rx!r}" in out["settings_changed"]
    assert not any(c.startswith("channel ax") for c in out["settings_changed"])
    assert run("identify", "--r", "measured", "--samples", 300, "--json", "--no-plots", "--out", tmp_path / "c") == 0
    plain = strict_loads(capsys.readouterr().out)
    assert plain["settings_changed"] == [] and "Changed from" not in (tmp_path / "c" / "report.md").read_text()
    cfg.write_text("[kfo]\ngain = 1\n")
    assert run("identify", "--samples", 300, "--config", cfg) == 2
    assert f"{cfg}: unknown settings in [kfo]: ['gain']" in capsys.readouterr().err


# --------------------------------------------------------------------------- progress, partial results


def test_progress_lines_when_stderr_is_not_a_terminal(tmp_path, capsys, monkeypatch):
    import torchtea.cli.common as common  # where _progress reads it

    monkeypatch.setattr(common, "PROGRESS_EVERY_S", 0.0)
    assert run("identify", "--samples", 200, "--no-plots", "--out", tmp_path / "id") == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("torchtea TEA ax,ay,az: ")]
    # the compiled engine reports once per block of steps (fast.BLOCK), the torch engine once per step
    assert len(lines) >= 1 and lines[-1].startswith("torchtea TEA ax,ay,az: 199/199 steps (100 %)")
    assert "s elapsed, about 0 s left" in lines[-1]


@pytest.mark.parametrize("engine", ["torch", "numba"])
def test_run_tea_partial_equals_the_first_steps_of_a_full_run(engine, monkeypatch):
    import torchtea.engines.fast as fast
    from torchtea.engines.presets import get_preset
    from torchtea.engines.structure import Structure
    from torchtea.engines.tea import make_params, run_tea

    monkeypatch.setattr(fast, "BLOCK", 8)  # the compiled engine reports after steps 8, 16, …, 120, …

    y = torch.as_tensor(read_recording().accel_counts[:250].T.copy() / 16384.0).unsqueeze(-1)
    y = y - y.mean(-2, keepdim=True)
    params = make_params(get_preset("paper-mems-x"), Structure())
    full = run_tea(y, h=0.01, params=params, engine=engine)

    def stop_at(k, N):
        if k == 120:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_tea(y, h=0.01, params=params, progress=stop_at, engine=engine)
    part = run_tea(y, h=0.01, params=params, progress=stop_at, partial=True, engine=engine)
    assert part.interrupted and not full.interrupted
    assert part.alpha.shape == (3, 121, 1) and part.steps.tolist() == list(range(121))
    for name in ("x", "P", "alpha", "P_alpha", "w", "innovation", "innovation_cov"):
        torch.testing.assert_close(getattr(part, name), getattr(full, name)[:, :121], rtol=0, atol=0)


def ctrl_c_at_step(monkeypatch, step):
    """Make identify's TEA see a Ctrl-C when it reaches ``step`` (as a user pressing it would); the compiled
    engine runs blocks of one step so that the Ctrl-C lands there."""
    import torchtea.engines.fast as fast
    import torchtea.identification as ident_mod

    monkeypatch.setattr(fast, "BLOCK", 1)

    real = ident_mod.run_tea

    def interrupted_run(*a, progress=None, **kw):
        def p(k, N):
            if k == step:
                raise KeyboardInterrupt

        return real(*a, progress=p, **kw)

    monkeypatch.setattr(ident_mod, "run_tea", interrupted_run)


def test_identify_stopped_by_ctrl_c_writes_its_partial_results(tmp_path, capsys, monkeypatch):
    ctrl_c_at_step(monkeypatch, 150)
    assert run("identify", "--samples", 400, "--json", "--no-plots", "--out", tmp_path / "id") == 130
    cap = capsys.readouterr()
    out = strict_loads(cap.out)
    assert out["interrupted"] and out["steps_done"] == 151 and out["samples"] == 400
    assert "interrupted (Ctrl-C) after 151 of 400 steps" in cap.err
    assert any(w.startswith("interrupted (Ctrl-C) after 151 of 400 steps") for w in out["warnings"])
    d = np.genfromtxt(tmp_path / "id" / "trajectories.csv", delimiter=",", names=True)
    assert len(d) == 151
    assert "Interrupted (Ctrl-C) after 151 of 400 steps" in (tmp_path / "id" / "report.md").read_text()
    assert strict_loads((tmp_path / "id" / "summary.json").read_text())["steps_done"] == 151


def test_a_run_stopped_too_early_says_its_checks_did_not_run(tmp_path, capsys, monkeypatch):
    ctrl_c_at_step(monkeypatch, 1)
    assert run("identify", "--samples", 300, "--json", "--no-plots", "--out", tmp_path / "id") == 130
    out = strict_loads(capsys.readouterr().out)
    assert out["steps_done"] == 2 and out["axes"]["ax"]["alpha"] is None
    assert "only 2 steps: the last-third statistics need at least 100" in out["warnings"][0]
    assert "channel ay: NIS over the last third cannot be computed" in " ".join(out["warnings"])
    assert out["statistics"]["ax"]["alpha_settle_s"] is None  # not "settled after 0.0 s"
    report = (tmp_path / "id" / "report.md").read_text()
    assert "None: every axis" not in report and "last ⅓ = no samples (too few steps)" in report


# --------------------------------------------------------------------------- errors that help


@pytest.mark.parametrize("header, sep", [("ax;ay;az", ";"), ("ax\tay\taz", "\t"), ("ax|ay|az", "|")])
def test_other_separators_are_read_and_an_unknown_one_gets_a_hint(tmp_path, capsys, header, sep):
    f = tmp_path / "semi.csv"
    rng = np.random.default_rng(0)
    f.write_text(header + "\n" + "\n".join(sep.join(f"{v:.5f}" for v in rng.normal(0, 0.01, 3) + [0, 0, 1])
                                            for _ in range(200)) + "\n")
    code = run("fit", f, "--units", "g", "--rate", 100, "--model", "white", "--json")
    err = capsys.readouterr().err
    if sep == "|":
        assert code == 2 and "no accelerometer or gyroscope column recognised in the header" in err
        assert "separated by '|', which torchtea does not read" in err and err.count("\n") == 1
    else:
        assert code == 0 and ("semicolon" if sep == ";" else "tab") + "-separated" in err


def test_identify_names_the_missing_column(tmp_path, capsys):
    f = bundled_csv(tmp_path, 150)
    assert run("identify", f, "--columns", "ax,ay,accz", "--units", "g", "--rate", 100) == 2
    err = capsys.readouterr().err
    assert "the header lacks column(s) 'accz' (it has ax, ay, az)" in err


def test_find_missing_ranges():
    v = np.zeros((10, 2))
    v[[2, 3, 4, 8], 0] = np.nan
    v[3, 1] = np.nan
    m = find_missing(v, ["a", "b"])
    assert (m.count, m.per_column, m.ranges) == (4, {"a": 4, "b": 1}, [[2, 4], [8, 8]])
    assert m.describe() == "4 of 10 samples missing (sample index 2–4, 8)"
