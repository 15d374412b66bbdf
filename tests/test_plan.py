"""How long to record (issue 45, item 3): the flicker a datasheet's B describes against IEEE 952's Allan floor, the
planned intervals against the spread of fits to simulated records, the tie's length arithmetic, a target turned into
a length, datasheet files and the command line; and (slow) a Gauss–Markov bias with τ at 10 % of the record named a
tie with the random walk, told apart by simulated records of the length the plan gives."""
import json
import math

import numpy as np
import pytest
import torch

from torchtea.checking.allan import model_avar
from torchtea.cli import main
from torchtea.export.terms import BIAS_INSTABILITY_FACTOR
from torchtea.fitting.datasheet import datasheet_model, read_datasheet
from torchtea.fitting.mle import fit_series
from torchtea.fitting.plan import length_for, parse_target, plan, tie_length
from torchtea.noise.model import parse_model
from torchtea.noise.simulate import simulate_model


def test_a_datasheets_bias_instability_is_a_flicker_whose_allan_floor_is_0_664_b():
    """B → the fractional part at order ½, pole 0, q = B²/h: its model Allan deviation is flat at
    √(2 ln 2/π)·B (IEEE Std 952's flicker floor) over three decades of τ."""
    sheet = {"sensor": "gyroscope", "rate_hz": 100.0, "N": 1e-4, "B": 1e-5, "K": None}
    model, values, h, terms, fixed = datasheet_model(sheet)
    assert model.spec == "fractional+white" and set(fixed) == {"fractional.order", "fractional.pole"}
    flicker = parse_model("fractional")
    v = {k: torch.tensor([x]) for k, x in values.items() if k.startswith("fractional")}
    m = np.unique(np.round(np.geomspace(20, 20_000, 12)).astype(int))
    adev = np.sqrt(np.asarray(model_avar(flicker, v, h, m)).reshape(-1))
    assert adev / 1e-5 == pytest.approx(BIAS_INSTABILITY_FACTOR, rel=0.01)
    assert terms["B"] == (1e-5, "fractional.q", 0.5)


H = 0.01
TRUTH = {"white.r": 1e-4, "random-walk.sigma": 2e-3}


def test_planned_intervals_match_the_spread_of_fits_to_simulated_records():
    """White noise + a random walk, 4000 samples: the planned 95 % intervals' widths on the log scale against the
    spread of the exact fits to 40 simulated records — their interquartile range over 1.349, robust to a fit that
    lands on a collapsed walk (the spread of that estimate from 40 draws is about ±17 %; the tolerance ±35 %) — for r
    and for K; and the widths shrink with the record as the plan says."""
    n = 4000
    row = plan("white+random-walk", TRUTH, H, [n])[0]
    planned = {p: math.log(hi / lo) / (2 * 1.959964) for p, (lo, hi) in row.intervals.items() if p in TRUTH}
    fits = {p: [] for p in TRUTH}
    for seed in range(40):
        y = simulate_model("white+random-walk", {k: torch.tensor([v]) for k, v in TRUTH.items()}, n_steps=n, h=H,
                           generator=torch.Generator().manual_seed(100 + seed))[0, 0].numpy()
        f = fit_series("white+random-walk", [y], H, intervals=False)[0]
        for p in TRUTH:
            fits[p].append(math.log(f.values[p]))
    for p in TRUTH:
        q1, q3 = np.percentile(fits[p], [25, 75])
        assert (q3 - q1) / 1.349 == pytest.approx(planned[p], rel=0.35), p
    longer = plan("white+random-walk", TRUTH, H, [4 * n])[0]
    assert longer.relative["white.r"] == pytest.approx(row.relative["white.r"] / 2, rel=0.05)
    assert longer.relative["K"] < row.relative["K"] and row.relative["N"] == pytest.approx(
        row.relative["white.r"] / 2, rel=0.02)


def test_a_target_becomes_the_shortest_length_that_reaches_it():
    """length_for: the planned K interval is within ±10 % at the length it gives and not 2 % shorter."""
    n = length_for("white+random-walk", TRUTH, H, "K", 0.10)
    assert plan("white+random-walk", TRUTH, H, [n])[0].relative["K"] <= 0.10
    assert plan("white+random-walk", TRUTH, H, [int(n * 0.98)])[0].relative["K"] > 0.10
    assert parse_target("K=10%") == ("K", 0.10) and parse_target("white.r=0.05") == ("white.r", 0.05)
    for bad in ("K", "K=", "=10%", "K=-3%", "K=ten"):
        with pytest.raises(ValueError, match="--target"):
            parse_target(bad)


def test_the_tie_length_is_where_the_expected_bic_difference_reaches_the_level():
    """tie_length: d(n) = L₀ n/n₀ + Δk ln n with L₀ = d₀ − Δk ln n₀; its answer reaches the level and a sample
    fewer does not; none when the likelihoods do not part and the penalty alone would take beyond the limit."""
    d0, dk, n0 = 5.38, 1, 6000
    n = tie_length(d0, dk, n0, 12.0)
    L0 = d0 - dk * math.log(n0)
    d = lambda m: L0 * m / n0 + dk * math.log(m)  # noqa: E731
    assert abs(d(n)) >= 12.0 > abs(d(n - 1))
    assert tie_length(0.0, 0, n0, 6.0) is None


def test_datasheet_files_are_read_in_their_units_and_bad_ones_named(tmp_path):
    """The shipped example files read in SI (0.15 °/√h = 4.36·10⁻⁵ rad/s/√Hz, 400 µg/√Hz; a bias stability of
    2 °/h = 9.70·10⁻⁶ rad/s at the Allan floor is B = 1.46·10⁻⁵ rad/s, given as the coefficient 9.70·10⁻⁶); a unit
    the table lacks, a missing N, a bad sensor, an unknown B convention: one ValueError naming the file."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "examples" / "datasheets"
    adis = read_datasheet(root / "adis16465-1_gyroscope.toml")
    assert adis["N"] == pytest.approx(0.15 * math.pi / 180 / 60)
    # its in-run bias stability is the Allan deviation's floor: IEEE 952's B is that over 0.664
    assert adis["B"] == pytest.approx(2 * math.pi / 180 / 3600 / BIAS_INSTABILITY_FACTOR)
    coefficient = tmp_path / "coefficient.toml"
    coefficient.write_text('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 0.1, unit = "deg/sqrt(h)" }\n'
                           'B = { value = 2, unit = "deg/h", convention = "ieee952" }')
    assert read_datasheet(coefficient)["B"] == pytest.approx(2 * math.pi / 180 / 3600)
    assert read_datasheet(root / "mpu6050_accelerometer.toml")["N"] == pytest.approx(400e-6 * 9.80665)
    for text, words in [('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 1, unit = "furlongs" }', "unit one of"),
                        ('sensor = "gyroscope"\nrate_hz = 100\nB = { value = 1, unit = "deg/h" }', "is needed"),
                        ('sensor = "magnetometer"\nrate_hz = 100', "sensor must be"),
                        ('sensor = "gyroscope"\nrate_hz = 100\nN = { value = 0.1, unit = "deg/sqrt(h)" }\n'
                         'B = { value = 1, unit = "deg/h", convention = "floor" }', "convention must be")]:
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(ValueError, match=words) as err:
            read_datasheet(bad)
        assert "bad.toml" in str(err.value)


def test_plan_on_the_command_line_from_a_datasheet_and_from_a_check(tmp_path, capsys):
    """`torchtea plan --datasheet` prints the table and the target's length and writes JSON; `--from-check` plans
    every axis of a check.json; a bad target is one line and exit 2."""
    from pathlib import Path

    sheet = Path(__file__).resolve().parents[1] / "examples" / "datasheets" / "adis16465-1_gyroscope.toml"
    assert main(["plan", "--datasheet", str(sheet), "--target", "B=20%", "--out", str(tmp_path / "p.json")]) == 0
    printed = capsys.readouterr().out
    assert "B within ±20 %" in printed and "length | N | B" in printed
    doc = json.loads((tmp_path / "p.json").read_text())
    t = doc["axes"]["gyroscope"]["targets"][0]
    assert t["name"] == "B" and t["samples"] > 0
    assert main(["plan", "--datasheet", str(sheet), "--target", "B"]) == 2
    assert "--target 'B'" in capsys.readouterr().err
    y = simulate_model("white+random-walk", {k: torch.tensor([v]) for k, v in TRUTH.items()}, n_steps=3000, h=H,
                       generator=torch.Generator().manual_seed(5))[0, 0].numpy()
    from torchtea.sensors.io import write_columns

    rec = write_columns(tmp_path / "r.csv", {"t": np.arange(len(y)) * H, "gyr_x": y})
    assert main(["check", str(rec), "--units", "rad/s", "--model", "white+random-walk", "--no-plots",
                 "--out", str(tmp_path / "c")]) == 0
    capsys.readouterr()
    assert main(["plan", "--from-check", str(tmp_path / "c" / "check.json"), "--lengths", "30,300", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    rows = out["axes"]["gx"]["rows"]
    assert [r["samples"] for r in rows] == [3000, 30000] and rows[1]["relative_half_width"]["K"] < \
        rows[0]["relative_half_width"]["K"]
    check_doc = json.loads((tmp_path / "c" / "check.json").read_text())
    assert check_doc["axes"]["gx"]["plan"]["rows"][0]["samples"] == 3000


@pytest.mark.slow
def test_a_gauss_markov_bias_at_a_tenth_of_the_record_is_a_tie_told_apart_at_the_planned_length():
    """A Gauss–Markov bias with τ = 10 % of a 60 s record beside white noise: the loop ends with one of the random
    walk and the Gauss–Markov bias and names the other as a tie, with the length expected to tell them apart; at that
    length, of 6 records simulated from the truth, most are told apart (|ΔBIC| ≥ 6) in the Gauss–Markov bias's
    favour."""
    from torchtea.checking.check import check

    n, h = 6000, 0.01
    truth = {"white.r": torch.tensor([1e-4]), "gauss-markov.sigma": torch.tensor([0.01]),
             "gauss-markov.tau_s": torch.tensor([0.1 * n * h])}
    y = simulate_model("white+gauss-markov", truth, n_steps=n, h=h,
                       generator=torch.Generator().manual_seed(0))[0, 0].numpy()
    res = check(y, h, intervals=False).auto(intervals=False)
    tie = next(t for t in res.ties if set(t["effects"]) == {"random-walk", "gauss-markov"})
    assert res.model.has("random-walk") or res.model.has("gauss-markov")
    n_tie = tie["resolve_samples"]
    assert n < n_tie < 20 * n and "would tell them apart" in tie["words"]
    told = 0
    for seed in range(6):
        z = simulate_model("white+gauss-markov", truth, n_steps=n_tie, h=h,
                           generator=torch.Generator().manual_seed(50 + seed))[0, 0].numpy()
        gm = fit_series("white+gauss-markov", [z], h, intervals=False)[0]
        rw = fit_series("white+random-walk", [z], h, intervals=False)[0]
        told += rw.bic - gm.bic >= 6.0
    assert told >= 4


def test_a_check_document_gives_plan_the_samples_the_fit_saw_not_the_rows(tmp_path):
    """A recording with missing samples: check.json's base says how many samples its fit saw, and read_check (plan
    --from-check, export) takes that n, not the recording's rows."""
    from torchtea.checking.check import check, read_check
    y = np.random.default_rng(2).standard_normal(4000) * 0.01
    y[1000:1600] = np.nan
    res = check(y, 0.01, model="white", intervals=False)
    axis = res.as_dict()
    assert axis["base"]["observed"] == 3400
    path = tmp_path / "check.json"
    path.write_text(json.dumps({"samples": 4000, "rate_hz": 100.0, "axes": {"x": axis}}, default=float))
    _, fits = read_check(path)
    assert fits["x"].n == 3400


def test_a_component_the_fit_collapsed_is_none_seen_and_the_others_keep_their_intervals():
    """White noise fitted as white + random walk: the walk's σ goes to ~0, its information to ~0. The plan says
    'none seen' for σ and K and still gives N and r their intervals (before, the whole information was singular
    and no number got one); the white noise's interval is the one planned for white noise alone."""
    y = np.random.default_rng(1).standard_normal(6000) * 0.01
    f = fit_series("white+random-walk", [y], 0.01, intervals=False)[0]
    assert f.values["random-walk.sigma"] < 1e-6
    rows = plan(f.model, f.values, 0.01, [6000, 60000])
    alone = plan("white", {"white.r": f.values["white.r"]}, 0.01, [6000, 60000])
    for r, a in zip(rows, alone):
        assert not r.singular
        assert set(r.collapsed) == {"random-walk.sigma", "K"}
        assert r.relative["N"] == pytest.approx(a.relative["N"], rel=1e-3)
    from torchtea.fitting.plan import plan_document, plan_lines
    text = "\n".join(plan_lines("x", plan_document(f.model, f.values, 0.01, [6000], targets=[("K", 0.2)])))
    assert "none seen" in text and "±" in text
    assert "K within ±20 %: none seen: the fit puts almost no K in the record" in text
