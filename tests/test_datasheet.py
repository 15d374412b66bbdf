"""The fitted numbers held against a datasheet (issue 46, item 2): within spec, worse than spec (by how much, with its
interval), not determined by this record (and how long would tell), none in the model — through `check` and
`export --datasheet`, in the terminal, report.md, check.json and export.json."""
import json

import numpy as np
import pytest
import torch

from torchtea.cli import main
from torchtea.export.terms import axis_terms
from torchtea.fitting.datasheet import compare
from torchtea.fitting.mle import fit_series
from torchtea.noise import simulate_model
from torchtea.sensors.io import write_columns

H = 0.01
N_TRUE = 2e-4  # rad/s/√Hz
K_TRUE = 2e-5  # rad/s²/√Hz


def _gyro(n=6000, seed=4):
    v = {"white.r": torch.tensor([N_TRUE ** 2 / H]), "random-walk.sigma": torch.tensor([K_TRUE])}
    return simulate_model("white+random-walk", v, n_steps=n, h=H, generator=torch.Generator().manual_seed(seed))[0, 0] \
        .numpy()


def _sheet(**terms):
    units = {"N": "rad/s/sqrt(Hz)", "B": "rad/s", "K": "rad/s^2/sqrt(Hz)"}
    out = {"sensor": "gyroscope", "rate_hz": 1 / H, "source": "test", "N": None, "B": None, "K": None,
           "printed": {}}
    for t, v in terms.items():
        out[t] = v
        out["printed"][t] = f"{v} {units[t]}"
    return out


@pytest.fixture(scope="module")
def fitted():
    y = _gyro()
    fit = fit_series("white+random-walk", [y], H)[0]
    terms = axis_terms(fit, y, H, "gyroscope", "gz", (H, 10.0))
    return fit, terms


def test_the_verdicts_follow_the_interval_against_the_datasheets_value(fitted):
    """N of twice the fitted value: within spec; half of it: worse than spec, by a ratio ≈ 2 whose interval is above
    1; the fitted value itself (× 1.001): not determined, with a record length beyond this one's; a model without a
    random walk: K none in the model, not compared."""
    fit, terms = fitted
    n = terms.ieee["N"].value
    lo, hi = terms.ieee["N"].ci95
    assert lo < n < hi
    rows = {r["verdict"]: r for r in (compare(terms, _sheet(N=f * n), fit, H)["rows"][0] for f in (2.0, 0.5, 1.001))}
    assert set(rows) == {"within spec", "worse than spec", "not determined by this record"}
    worse = rows["worse than spec"]
    assert worse["ratio"] == pytest.approx(2.0) and worse["ratio_ci95"][0] > 1.0
    assert rows["within spec"]["ratio_ci95"][1] <= 1.0
    undecided = rows["not determined by this record"]
    assert undecided["record_for_s"] > len(_gyro()) * H
    y = _gyro()
    white = fit_series("white", [y], H)[0]
    k = compare(axis_terms(white, y, H, "gyroscope", "gz", (H, 10.0)), _sheet(K=K_TRUE), white, H)["rows"][0]
    assert k["verdict"] == "none in the model" and k["ratio"] is None


def test_check_and_export_hold_the_axes_against_a_datasheet_file(tmp_path, capsys):
    """`check --datasheet` prints a verdict per term and writes it into check.json and report.md; `export
    --datasheet` into export.json and export.md; a datasheet for a sensor the channels lack, two of one sensor and
    --no-intervals are one line, exit 2."""
    y = _gyro()
    rec = write_columns(tmp_path / "r.csv", {"t": np.arange(len(y)) * H, "gz": y})
    sheet = tmp_path / "gyro.toml"
    sheet.write_text(f'sensor = "gyroscope"\nrate_hz = 100\nsource = "a test sheet"\n'
                     f'N = {{ value = {2 * N_TRUE}, unit = "rad/s/sqrt(Hz)" }}\n'
                     f'K = {{ value = {K_TRUE / 100}, unit = "rad/s^2/sqrt(Hz)" }}\n')
    assert main(["check", str(rec), "--units", "rad/s", "--model", "white+random-walk", "--no-plots",
                 "--datasheet", str(sheet), "--out", str(tmp_path / "c")]) == 0
    printed = capsys.readouterr().out
    assert "against the datasheet" in printed and "gz N:" in printed and "within spec" in printed
    assert "gz K:" in printed and "worse than spec" in printed
    doc = json.loads((tmp_path / "c" / "check.json").read_text())
    verdicts = {r["term"]: r["verdict"] for r in doc["axes"]["gz"]["datasheet"]["rows"]}
    assert verdicts == {"N": "within spec", "K": "worse than spec"}
    assert "Against the datasheet" in (tmp_path / "c" / "report.md").read_text()
    assert main(["export", str(rec), "--units", "rad/s", "--format", "ieee952", "--model", "white+random-walk",
                 "--no-plots", "--nees", "0", "--datasheet", str(sheet), "--out", str(tmp_path / "e")]) == 0
    assert "gz K:" in capsys.readouterr().out
    ex = json.loads((tmp_path / "e" / "export.json").read_text())
    assert {r["term"] for r in ex["axes"]["gz"]["datasheet"]["rows"]} == {"N", "K"}
    assert "## Against the datasheet" in (tmp_path / "e" / "export.md").read_text()
    # check --export: the export's verdicts are the report's, made and printed once
    assert main(["check", str(rec), "--units", "rad/s", "--model", "white+random-walk", "--no-plots",
                 "--datasheet", str(sheet), "--export", "ieee952", "--nees", "0", "--out", str(tmp_path / "ce")]) == 0
    printed = capsys.readouterr().out
    assert printed.count("against the datasheet (fitted") == 1 and "export ieee952:" in printed
    both = json.loads((tmp_path / "ce" / "check.json").read_text())["axes"]["gz"]["datasheet"]
    assert both == json.loads((tmp_path / "ce" / "export" / "export.json").read_text())["axes"]["gz"]["datasheet"]
    accel = tmp_path / "accel.toml"
    accel.write_text('sensor = "accelerometer"\nrate_hz = 100\nN = { value = 400, unit = "ug/sqrt(Hz)" }\n')
    for extra, words in ((["--datasheet", str(accel)], "the datasheet(s) are for the accelerometer"),
                         (["--datasheet", str(sheet), "--datasheet", str(sheet)], "a second datasheet"),
                         (["--datasheet", str(sheet), "--no-intervals"], "drop --no-intervals")):
        assert main(["check", str(rec), "--units", "rad/s", "--model", "white", "--no-plots",
                     "--out", str(tmp_path / "never"), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err


def test_a_walk_the_fit_collapsed_is_none_seen_and_fit_needs_export(tmp_path, capsys):
    """White noise fitted as white + random walk: the walk's σ goes to ≈ 0 and its interval has no upper end — K is
    'none seen', not 'not determined' with a length computed from σ ≈ 0. `fit --datasheet` without `--export`: one
    line, exit 2."""
    y = 1e-3 * np.random.default_rng(8).standard_normal(6000)
    fit = fit_series("white+random-walk", [y], H)[0]
    terms = axis_terms(fit, y, H, "gyroscope", "gz", (H, 10.0))
    row = compare(terms, _sheet(K=K_TRUE), fit, H)["rows"][0]
    assert row["verdict"] == "none seen" and row["record_for_s"] is None
    rec = write_columns(tmp_path / "r.csv", {"t": np.arange(len(y)) * H, "gz": y})
    sheet = tmp_path / "gyro.toml"
    sheet.write_text('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 1e-4, unit = "rad/s/sqrt(Hz)" }\n')
    assert main(["fit", str(rec), "--units", "rad/s", "--model", "white", "--datasheet", str(sheet)]) == 2
    assert "give --export FORMAT too" in capsys.readouterr().err
