"""A check's loop in TensorBoard (issue 46, item 5), read back with TensorBoard's own event reader: each step's
scalars (the same numbers as check.json's steps), each step's figures as images, the verdict as text."""
import json

import numpy as np
import pytest

from torchtea.cli import main
from torchtea.sensors.io import write_columns


def test_check_logdir_writes_each_step_of_the_loop_as_a_run(tmp_path, capsys):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    h, n = 0.01, 3000
    t = np.arange(n) * h
    y = 1e-3 * np.random.default_rng(3).standard_normal(n) + 4e-4 * np.sin(2 * np.pi * 7.3 * t + 0.4)
    rec = write_columns(tmp_path / "r.csv", {"t": t, "gz": y})
    assert main(["check", str(rec), "--units", "rad/s", "--model", "white", "--auto", "--no-intervals",
                 "--out", str(tmp_path / "c"), "--logdir", str(tmp_path / "tb")]) == 0
    assert "TensorBoard: 1 run(s)" in capsys.readouterr().err
    steps = json.loads((tmp_path / "c" / "check.json").read_text())["steps"]
    assert len(steps) >= 2 and steps[1]["added"] == "sinusoid"
    ea = EventAccumulator(str(tmp_path / "tb" / "gz"), size_guidance={"scalars": 0, "images": 0, "tensors": 0})
    ea.Reload()
    nll = ea.Scalars("loop/nll_per_sample")
    assert [e.step for e in nll] == list(range(len(steps)))
    for e, s in zip(nll, steps):
        assert e.value == pytest.approx(s["nll_per_sample"], rel=1e-6)  # (float32 in the event file)
    gain = ea.Scalars("loop/gain")
    assert [e.step for e in gain] == list(range(1, len(steps)))
    assert gain[0].value == pytest.approx(steps[1]["gain"], rel=1e-5)
    assert [e.value for e in ea.Scalars("loop/failed_diagnostics")] == [len(s["failed"]) for s in steps]
    images = [tag for tag in ea.Tags()["images"] if tag.startswith("figures/")]
    assert images and all(len(ea.Images(tag)) == len(steps) for tag in images)
    assert ea.Images(images[0])[0].encoded_image_string[:4] == b"\x89PNG"
    texts = {tag: ea.Tensors(tag) for tag in ea.Tags()["tensors"]}
    verdict = texts["verdict/text_summary"][-1].tensor_proto.string_val[0].decode()
    assert steps[-1]["model"] in verdict and "adequate" in verdict
    assert len(texts["loop/step/text_summary"]) == len(steps)
    assert main(["export", str(rec), "--units", "rad/s", "--format", "ieee952", "--model", "white",
                 "--logdir", str(tmp_path / "tb2")]) == 2
    assert "with --model there is none" in capsys.readouterr().err
