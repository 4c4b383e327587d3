"""The headless Blender scripts (tools/blender): fit an image to a preset, diagnose it, render a preset on the skirt;
each as its documented `blender --background --factory-startup --python-exit-code 1 ...` line, with small settings.
A failing operator must make Blender exit non-zero."""
import json
import os
import shutil
import subprocess

import numpy as np
import pytest

from fit_support import ASSET_IMAGE, ROOT

from drapelab import infer, measure

BLENDER = shutil.which("blender")
pytestmark = pytest.mark.skipif(BLENDER is None, reason="needs Blender (Debian package blender)")


def blender(script, *args, tmp=None, timeout=300):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env.update(OPENBLAS_NUM_THREADS="1")
    if tmp is not None:  # the add-on's cache of an unsaved file goes to the temp folder: keep it in the test's
        env["TMPDIR"] = str(tmp)
    return subprocess.run([BLENDER, "--background", "--factory-startup", "--python-exit-code", "1", "--python",
                           os.path.join(ROOT, "tools", "blender", script), "--", *args], env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_fit_then_diagnose_headless(tmp_path):
    preset = str(tmp_path / "cotton.json")
    done = blender("fit_image.py", "--images", ASSET_IMAGE, "--out", preset, "--model", "homo", "--epochs", "1",
                   "--mesh-level", "1", tmp=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "fit_image: wrote" in done.stdout
    p = infer.load_preset(preset)
    assert p["model"] == "homo" and p["fabric"]["name"] == "Cotton Blue" and p["density_kg_m2"] == pytest.approx(0.192)
    report = str(tmp_path / "report")
    done = blender("diagnose.py", "--preset", preset, "--images", ASSET_IMAGE, "--report", report, "--samples", "3",
                   "--time-budget", "40", tmp=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    with open(os.path.join(report, "diagnosis.json")) as f:
        d = json.load(f)
    assert d["samples"] == 3 and d["ranking"] and os.path.isfile(os.path.join(report, "index.html"))
    assert "diagnose:" in done.stdout


def test_a_failing_operator_fails_the_script(tmp_path):
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"not an image")
    done = blender("fit_image.py", "--images", str(bad), "--out", str(tmp_path / "x.json"), "--density", "0.2",
                   "--epochs", "1", tmp=tmp_path)
    assert done.returncode != 0 and "bad.jpg" in done.stdout + done.stderr
    assert not (tmp_path / "x.json").exists()


def test_drape_skirt_renders_the_heat_map(tmp_path):
    out = str(tmp_path / "skirt.png")
    done = blender("drape_skirt.py", "--out", out, "--vertices", "1500", "--samples", "4", "--size", "240x240",
                   "--frames", "4", tmp=tmp_path)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    img = np.asarray(measure.read_image(out)[0])
    assert img.shape == (240, 240)
    foreground = np.abs(img - np.median(img[:, :10])) > 0.03  # differs from the background at the left edge
    assert 0.1 < foreground.mean() < 0.9, foreground.mean()   # the body and the skirt fill part of the frame
    assert img[foreground].std() > 0.02                          # shaded, not one flat colour
    # the simulator exists: the skirt is draped (simulate_garment baked 4 frames and the render shows the last)
    assert "(draped," in done.stdout, done.stdout[-2000:]
