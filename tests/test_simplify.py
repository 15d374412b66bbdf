"""The loop takes away and swaps (issue 45, item 1) and names what the record cannot tell apart (item 2): the
alternatives it tries, white noise + a random walk ending `white+random-walk` with K within its interval of the
truth, a temperature effect masked by a random walk added first swapped in, and ties in the verdict."""
import json
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from torchtea.checking.check import change_words, check
from torchtea.checking.screening import ScreenRow
from torchtea.checking.simplify import alternatives, carried_labels, simplify
from torchtea.noise.model import parse_model
from torchtea.noise.simulate import simulate_model, temperature_profile


def _step(spec, passed=()):
    return SimpleNamespace(model=parse_model(spec), screens=[ScreenRow(e, "a test", passed=True) for e in passed])


def test_the_alternatives_are_each_component_dropped_its_special_cases_and_the_added_effects_swapped():
    """From fractional+white+resonance, reached by adding the resonance while low-pass and random-walk passed
    their screens too: each of the three dropped, the fractional part by its special cases (a random walk, a
    Gauss–Markov bias) — in its place where a low-pass after it filtered it —, the resonance by the two others
    that passed — each model once; a dropped component leaving no stochastic part is no alternative."""
    start = _step("fractional+white", passed=("resonance", "low-pass", "random-walk"))
    end = _step("fractional+white+resonance")
    res = SimpleNamespace(model=end.model, steps=[start, end])
    got = {(a.kind, a.removed, a.added): a.model.spec for a in alternatives(res)}
    assert got == {
        ("drop", "fractional", None): "white+resonance",
        ("simpler", "fractional", "random-walk"): "white+resonance+random-walk",
        ("simpler", "fractional", "gauss-markov"): "white+resonance+gauss-markov",
        ("drop", "white", None): "fractional+resonance",
        ("drop", "resonance", None): "fractional+white",
        ("swap", "resonance", "low-pass"): "fractional+white+low-pass",  # (where extend puts a low-pass)
        ("swap", "resonance", "random-walk"): "fractional+white+random-walk",
    }
    assert alternatives(SimpleNamespace(model=parse_model("white"), steps=[_step("white")])) == []
    # a special case stays where the component was: before the low-pass that filtered it
    filtered = _step("fractional+white+low-pass")
    got = {(a.kind, a.added): a.model.spec for a in alternatives(SimpleNamespace(model=filtered.model,
                                                                                 steps=[filtered]))}
    assert got[("simpler", "random-walk")] == "random-walk+white+low-pass"
    assert change_words({"added": "random-walk", "removed": "fractional"}) == "fractional → random-walk"
    assert change_words({"added": "", "removed": "ramp"}) == "− ramp"
    assert change_words({"added": "ramp", "removed": ""}) == "+ ramp"


def test_a_component_left_by_a_drop_is_started_from_its_own_values_not_the_dropped_ones():
    """Labels are numbered anew (without the first of two lines the second is ``sinusoid``): the alternative's fit
    starts each component left from its own values in the model (:func:`carried_labels` maps the labels), not from the
    values of the one that had its label."""
    m = parse_model("fractional+white+sinusoid+sinusoid")
    one = parse_model("fractional+white+sinusoid")
    assert carried_labels(m, one, "sinusoid") == {"fractional": "fractional", "white": "white", "sinusoid": "sinusoid2"}
    assert carried_labels(m, one, "sinusoid2") == {"fractional": "fractional", "white": "white", "sinusoid": "sinusoid"}
    assert carried_labels(m, parse_model("white+random-walk+sinusoid+sinusoid"), "fractional") == {
        "white": "white", "sinusoid": "sinusoid", "sinusoid2": "sinusoid2"}


H = 0.005
K_TRUE = 2e-5


def _white_and_walk(n=20000, seed=3, k=K_TRUE):
    v = {"white.r": torch.tensor([(1.7e-4) ** 2 / H]), "random-walk.sigma": torch.tensor([k])}
    return simulate_model("white+random-walk", v, n_steps=n, h=H,
                          generator=torch.Generator().manual_seed(seed))[0, 0].numpy()


def test_white_noise_and_a_random_walk_end_as_white_plus_random_walk():
    """The textbook IMU noise (white + a bias random walk, Kalibr-like densities, 100 s at 200 Hz): the loop starts
    from fractional+white, whose fractional part at order ≈ 1 stands in for the walk, and replaces it by its special
    case; the walk's K is fitted with an interval that holds the truth, and the loop's steps and end say so."""
    y = _white_and_walk()
    first = check(y, H)
    assert first.auto(simplify=False).model.spec == "fractional+white"  # (the loop that only adds)
    res = first.auto()
    assert res.model.spec == "white+random-walk"
    step = res.step_rows()[-1]
    assert (step["change"], step["removed"], step["added"]) == ("simpler", "fractional", "random-walk")
    assert step["gain"] > 0 and res.adequate
    lo, hi = res.fit.ci95["random-walk.sigma"]
    assert lo < K_TRUE < hi
    assert "1 change(s) taking away or swapping" in res.loop_end
    doc = json.loads(json.dumps(res.as_dict(), default=float))
    assert doc["steps"][-1]["change"] == "simpler" and {a["kind"] for a in doc["alternatives"]} == {"drop"}


def _fitted_on_the_way(res) -> set:
    return {f.model.spec for st in res.steps
            for f in [st.fit] + [s.fit for s in st.suggestions] + [a.fit for a in st.alternatives if a.fit is not None]}


def test_a_weak_effect_never_fitted_on_the_way_is_named_as_a_tie():
    """White noise + a weak walk (K 8·10⁻⁶, seed 0): the loop ends `white+random-walk`; a ramp's screen does not pass
    and the loop never fits it, but its likelihood ratio says the model with it would be within the tie margin — it
    is refitted at the loop's end and named: the record cannot tell whether a ramp is there."""
    from torchtea.checking.ranking import CLOSE_BIC

    res = check(_white_and_walk(seed=0, k=8e-6), H).auto()
    assert res.model.spec == "white+random-walk" and res.adequate
    ramp = next(r for r in res.screens if r.effect == "ramp")
    assert not ramp.passed
    tie = next(t for t in res.ties if t["effects"] == ["ramp"])
    assert tie["kind"] == "add" and 0 <= tie["bic_difference"] < CLOSE_BIC and not tie["fails"]
    assert tie["model"] not in _fitted_on_the_way(res) and "ramp" in res.near
    assert "with or without ramp" in tie["words"] and tie["words"] in res.loop_end


def test_a_lower_bic_alternative_that_fails_a_diagnostic_is_named():
    """White noise + a weak walk (K 8·10⁻⁶, seed 7): white alone has the lower BIC but fails the change test (the drift
    it sees is the walk's), so the loop keeps `white+random-walk` — and says that by BIC the record cannot tell
    whether the walk is there, naming the diagnostic."""
    res = check(_white_and_walk(seed=7, k=8e-6), H).auto()
    assert res.model.spec == "white+random-walk" and res.adequate
    tie = next(t for t in res.ties if t["model"] == "white")
    assert tie["kind"] == "drop" and tie["effects"] == ["random-walk"]
    assert tie["bic_difference"] < 0 and tie["fails"] == ["change"]
    assert "fails change" in tie["words"] and "whether random-walk is there" in tie["words"]
    doc = json.loads(json.dumps(res.as_dict(), default=float))
    assert doc["ties"][0]["fails"] == ["change"]


def test_a_kept_effect_whose_drop_is_within_the_tie_margin_but_fails_a_diagnostic_is_named():
    """White noise + a walk (K 2·10⁻⁵, seed 1009): the loop ends `white+random-walk`; white alone is only 2.1 higher by
    BIC (inside the tie margin) and fails the change test. The walk is kept, and the verdict says that by BIC the
    record cannot tell, and which diagnostic points to the walk."""
    from torchtea.checking.ranking import CLOSE_BIC

    res = check(_white_and_walk(seed=1009), H).auto()
    assert res.model.spec == "white+random-walk" and res.adequate
    tie = next(t for t in res.ties if t["model"] == "white")
    assert tie["kind"] == "drop" and tie["effects"] == ["random-walk"]
    assert 0 < tie["bic_difference"] < CLOSE_BIC and tie["fails"] == ["change"]
    assert "by BIC this record cannot tell" in tie["words"] and "fails change" in tie["words"]


@pytest.mark.slow
def test_a_temperature_effect_masked_by_a_random_walk_added_first_is_swapped_in():
    """A bias of 0.004 per °C over an 8 °C warm-up and white noise, no walk: with a random walk added first (as a
    greedy loop may), the temperature bias and the thermal lag both passed their screens at that step; the
    simplification swaps the walk for the temperature bias, which gains more, and the step says so."""
    n, h = 8000, 0.01
    T = temperature_profile(n, h, warmup=8.0, tau_s=30.0, generator=torch.Generator().manual_seed(1))
    v = {"white.r": torch.tensor([1e-4]), "temperature-bias.bias_per_degC": torch.tensor([0.004]),
         "temperature-bias.t_ref": torch.tensor([25.0])}
    y = simulate_model("white+temperature-bias", v, n_steps=n, h=h, inputs={"temperature": T},
                       generator=torch.Generator().manual_seed(2))[0, 0].numpy()
    first = check(y, h, inputs={"temperature": T.numpy()}, intervals=False)
    assert "temperature-bias" in {r.effect for r in first.screens if r.passed}
    masked = first.add("random-walk", intervals=False)
    res = simplify(masked, intervals=False)
    assert res is not masked
    assert res.change == {"kind": "swap", "removed": "random-walk", "added": "temperature-bias"}
    assert not res.model.has("random-walk") and res.model.has("temperature-bias")
    tried = {a.model.spec: a.bic for a in masked.alternatives}
    assert tried[res.model.spec] == min(b for b in tried.values() if np.isfinite(b))


def test_export_of_white_noise_and_a_random_walk_gives_the_fitted_walk_with_its_interval(tmp_path, capsys):
    """`torchtea export` (which runs the loop) on the same textbook gyroscope axis in a CSV: the model
    `white+random-walk`, K the fitted walk with an interval holding the truth, N and K the same bare and covered
    (nothing else in the model to cover)."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    y = _white_and_walk()
    path = write_columns(tmp_path / "wrw.csv", {"t": np.arange(len(y)) * H, "gyr_x": y})
    assert main(["export", str(path), "--units", "rad/s", "--format", "ieee952", "--no-plots",
                 "--out", str(tmp_path / "e")]) == 0
    axis = json.loads((tmp_path / "e" / "export.json").read_text())["axes"]["gx"]
    assert axis["model"] == "white+random-walk"
    k = axis["bare"]["K"]
    assert k["ci95"][0] < K_TRUE < k["ci95"][1] and axis["covered"]["K"]["value"] == pytest.approx(k["value"])
    assert "no random walk" not in k["how"]


def test_identify_from_a_check_that_dropped_the_fractional_part_names_the_channels(tmp_path, capsys):
    """A check whose model has no fractional part (as the loop leaves a channel where BIC prefers that) cannot feed
    the TEA: `identify --from-check` stops with one line naming the channel and what to do, exit 2."""
    from torchtea.cli import main
    from torchtea.sensors.io import write_columns

    y = _white_and_walk(n=3000)
    path = write_columns(tmp_path / "w.csv", {"t": np.arange(len(y)) * H, "gyr_x": y})
    assert main(["check", str(path), "--units", "rad/s", "--model", "white", "--no-plots", "--no-intervals",
                 "--out", str(tmp_path / "c")]) == 0
    capsys.readouterr()
    assert main(["identify", str(path), "--units", "rad/s", "--from-check", str(tmp_path / "c" / "check.json")]) == 2
    err = capsys.readouterr().err
    assert "without a fractional part on gx (white)" in err and "--no-simplify" in err


def test_auto_leaves_the_result_it_starts_from_as_it_is():
    """A loop that adds and changes nothing still returns a result of its own: the check it started from keeps
    its loop_end, ties and timings (a second auto() from it gives the same end)."""
    y = np.random.default_rng(5).standard_normal(3000) * 0.01
    first = check(y, 0.01, model="white", intervals=False)
    before = (first.loop_end, list(first.ties), dict(first.timings), first.seconds)
    end = first.auto(intervals=False)
    assert end is not first and end.model.spec == "white"
    assert end.loop_end.startswith("adequate after 0 effect(s) added")
    assert (first.loop_end, first.ties, first.timings, first.seconds) == before
    assert first.auto(intervals=False).loop_end == end.loop_end
    assert [r.model.spec for r in end.steps] == ["white"]
