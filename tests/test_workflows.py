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
    assert bootstrap_replicates(1000, None) == 99 and bootstrap_replicates(10**6, None) == 0
    assert bootstrap_replicates(10**6, 5) == 5


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
