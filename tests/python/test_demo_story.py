"""`drapelab demo`, the whole story (specimen drape, fit of the bundled photo, diagnosis, the skirt in Blender), with
a small time budget: every output exists and is valid, and the demo ends within its budget. Bad input is named."""
import argparse
import json
import shutil
import time

import numpy as np
import pytest

from drapelab import cli, infer, measure
from drapelab.commands import demo
from drapelab.garment import pc2

BUDGET_S = 50.0  # the suite is close to its CI limit: the smallest budget that runs every step on 2 busy cores
BLENDER = shutil.which("blender")


def test_demo_whole_story_within_its_budget(tmp_path, capsys):
    out = tmp_path / "demo"
    t = time.monotonic()
    code = cli.main(["demo", "--mesh-level", "1", "--time-budget", str(BUDGET_S), "--out", str(out)])
    elapsed = time.monotonic() - t
    text = capsys.readouterr()
    assert code == 0, text.out[-3000:] + text.err[-3000:]
    assert elapsed < BUDGET_S, elapsed  # a budget is a promise
    for stage in ("[1/4] specimen circle1", "[2/4] fit", "[3/4] diagnose", "[4/4] skirt"):
        assert stage in text.out, stage
    assert "drape coefficient" in text.out and "epoch" in text.out

    # 1. the specimen drape, as before
    assert (out / "drape.obj").is_file() and (out / "silhouette.png").is_file()
    # 2. the fitted preset loads (validated) and is the bundled photo's fabric
    preset = infer.load_preset(str(out / "fit.json"))
    assert preset["model"] == "bdp" and preset["fabric"]["name"] == "Cotton Blue"
    assert preset["density_kg_m2"] == pytest.approx(0.192) and preset["training"]["epochs"] >= 1
    assert 0.5 < preset["metrics"]["training_image"]["iou"] <= 1.0
    # 3. the diagnosis report parses and ranks the candidate effects
    d = json.loads((out / "diagnosis" / "diagnosis.json").read_text())
    assert d["samples"] == demo.DIAGNOSE_SAMPLES and d["ranking"] and d["base"]["mse"] > 0
    assert (out / "diagnosis" / "index.html").is_file()
    # the summary records every step within the budget
    summary = json.loads((out / "demo.json").read_text())
    assert [s["step"] for s in summary["steps"]] == ["specimen drape", "fit", "diagnose", "skirt render"]
    assert summary["seconds"] <= BUDGET_S and summary["time_budget_s"] == BUDGET_S
    render = summary["steps"][-1]
    if BLENDER is None:
        assert render["status"] == "skipped" and "Blender not found" in text.out
        return
    # 4. the render: the skirt on the dress form, not blank; the saved scene and its bake
    assert render["status"] == "done", render
    img = np.asarray(measure.read_image(str(out / "skirt.png"))[0])
    foreground = np.abs(img - np.median(img[:, :10])) > 0.03  # differs from the background at the left edge
    assert 0.05 < foreground.mean() < 0.9, foreground.mean()
    assert img[foreground].std() > 0.02  # shaded, not one flat colour
    assert (out / "skirt.blend").is_file()
    h = pc2.read_pc2_header(str(out / "drapelab_cache" / "skirt.pc2"))
    assert h["num_samples"] >= 2 and h["num_points"] > 500  # the bake simulated at least one frame
    assert "(draped," in render["detail"], render["detail"]


def test_demo_render_step_without_blender_says_so(tmp_path, capsys):
    args = argparse.Namespace(blender=str(tmp_path / "no-blender"), out=str(tmp_path))
    clock = demo._Clock(120.0)
    try:
        status, why = demo.render_step(args, {"fit.json": "x", "skirt.png": "y", "skirt.blend": "z"}, clock)
    finally:
        clock.stop()
    assert status == "skipped" and "Blender not found" in why
    assert "[4/4] skirt render skipped: Blender not found" in capsys.readouterr().out


def test_demo_bad_output_folder_and_budget(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    t = time.monotonic()
    assert cli.main(["demo", "--out", str(blocker / "demo")]) == 2
    assert "--out" in capsys.readouterr().err
    assert cli.main(["demo", "--out", str(blocker)]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert cli.main(["demo", "--time-budget", "10", "--out", str(tmp_path / "d")]) == 2
    assert "at least" in capsys.readouterr().err
    assert cli.main(["demo", "--time-budget", "nan", "--out", str(tmp_path / "d")]) == 2
    assert time.monotonic() - t < 5.0  # refused before any work
    assert not (tmp_path / "d").exists()


def test_demo_fit_share_too_small_is_named(tmp_path):
    """A fit share the machine cannot use (the fit times a drape and refuses) names the demo's option."""
    clock = demo._Clock(100.0)
    try:
        with pytest.raises(infer.InputError, match="give the demo a larger --time-budget"):
            demo.fit_step(str(tmp_path / "fit.json"), 1.0, clock)
    finally:
        clock.stop()
    assert not (tmp_path / "fit.json").exists()
