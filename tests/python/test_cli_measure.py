"""`drapelab measure` and `drapelab compare`: the command modules, and the real CLI end to end."""
import argparse
import importlib
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from drapelab import measure as M
from drapelab.commands import compare as compare_cmd
from drapelab.commands import measure as measure_cmd

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ASSETS = os.path.join(ROOT, "assets", "cusick")
JPG = os.path.join(ASSETS, "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
JPG5 = os.path.join(ASSETS, "fabric_05", "silhouettes", "sample_01_capture_1.jpg")
OBJ = os.path.join(ASSETS, "fabric_02", "meshes", "sample_02_capture_1.obj")


def run(argv):
    """Parses argv with just the two measurement commands and runs it (as drapelab.cli.main would)."""
    parser = argparse.ArgumentParser(prog="drapelab")
    sub = parser.add_subparsers(dest="command", required=True)
    measure_cmd.register(sub)
    compare_cmd.register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


def test_measure_writes_one_object_per_image(tmp_path, capsys):
    out = tmp_path / "m.json"
    assert run(["measure", JPG, JPG5, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert [d["image"] for d in data["images"]] == [JPG, JPG5]
    for d in data["images"]:
        for key in ("drape_coefficient", "node_count", "area_px", "px_per_m", "centre_px", "r_theta_m", "harmonics"):
            assert key in d
        assert len(d["r_theta_m"]) == 360 and len(d["harmonics"]) == 20
        assert d["px_per_m"] == 720.0 and d["centre_px"] == [128.0, 128.0]
    assert data["images"][0]["drape_coefficient"] == pytest.approx(0.670, abs=0.005)
    assert data["images"][1]["drape_coefficient"] > data["images"][0]["drape_coefficient"]
    assert "drape coefficient 0.670" in capsys.readouterr().out


def test_measure_honours_the_given_scale(tmp_path):
    out = tmp_path / "m.json"
    run(["measure", JPG, "--px-per-m", "700", "--json", str(out)])
    d = json.loads(out.read_text())["images"][0]
    assert d["px_per_m"] == 700.0
    assert d["drape_coefficient"] == pytest.approx(((28909 / 700**2) - 0.0254469) / (0.0706858 - 0.0254469), abs=0.005)


def test_measure_stops_on_a_bad_image_and_writes_nothing(tmp_path):
    out = tmp_path / "m.json"
    with pytest.raises(M.InputError, match="missing.jpg.*not found"):
        run(["measure", JPG, str(tmp_path / "missing.jpg"), "--json", str(out)])
    assert not out.exists()


def test_measure_keep_going_records_the_error(tmp_path):
    out = tmp_path / "m.json"
    bad = tmp_path / "empty.png"
    bad.write_bytes(b"")
    assert run(["measure", str(bad), JPG, "--keep-going", "--json", str(out)]) == 1
    data = json.loads(out.read_text())["images"]
    assert "empty" in data[0]["error"] and data[0]["image"] == str(bad)
    assert data[1]["node_count"] == 8


def test_measure_wrong_calibration_is_an_error():
    with pytest.raises(M.InputError, match="wrong calibration"):
        run(["measure", JPG, "--px-per-m", "300"])


def test_measure_unwritable_output(tmp_path):
    with pytest.raises(OSError, match="nowhere.*does not exist"):
        run(["measure", JPG, "--json", str(tmp_path / "nowhere" / "m.json")])


def test_compare_writes_metrics_and_overlay(tmp_path):
    out, png = tmp_path / "c.json", tmp_path / "c.png"
    assert run(["compare", "--mesh", OBJ, "--image", JPG, "--json", str(out), "--overlay", str(png)]) == 0
    d = json.loads(out.read_text())
    for key in ("iou", "mse", "drape_coefficient_mesh", "drape_coefficient_image", "node_count_mesh",
                "node_count_image", "r_theta_rmse_m"):
        assert key in d
    assert d["iou"] > 0.97
    assert png.exists() and png.stat().st_size > 1000
    out2 = tmp_path / "p.json"
    run(["compare", "--mesh", OBJ, "--image", JPG, "--camera", "perspective", "--json", str(out2)])
    assert json.loads(out2.read_text())["iou"] < d["iou"]


def test_compare_bad_inputs_name_the_file(tmp_path):
    with pytest.raises(ValueError, match="nomesh.obj"):
        run(["compare", "--mesh", str(tmp_path / "nomesh.obj"), "--image", JPG])
    with pytest.raises(ValueError, match="noimage.jpg"):
        run(["compare", "--mesh", OBJ, "--image", str(tmp_path / "noimage.jpg")])


def _cli_complete():
    cli = importlib.import_module("drapelab.cli")
    for name in cli.COMMANDS:
        try:
            importlib.import_module(f"drapelab.commands.{name}")
        except ImportError as e:
            return f"drapelab CLI incomplete: command module {name} ({e})"
    return None


def test_cli_end_to_end(tmp_path):
    missing = _cli_complete()
    if missing:
        pytest.skip(missing)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    out = tmp_path / "m.json"
    p = subprocess.run([sys.executable, "-m", "drapelab.cli", "measure", JPG, "--json", str(out)],
                       capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stderr
    assert json.loads(out.read_text())["images"][0]["image"] == JPG
    bad = tmp_path / "cut.jpg"
    bad.write_bytes(open(JPG, "rb").read()[:3000])
    p = subprocess.run([sys.executable, "-m", "drapelab.cli", "measure", str(bad)], capture_output=True, text=True,
                       env=env)
    assert p.returncode == 2
    assert "cut.jpg" in p.stderr and "Traceback" not in p.stderr


def _photo(mask, cloth, table, seed):
    """A raw-photo-like RGB uint16 image: tones, left-to-right shading, noise."""
    rng = np.random.default_rng(seed)
    shade = 1.0 - 0.1 * np.linspace(0, 1, mask.shape[1])[None, :]
    lum = np.where(mask > 0.5, cloth, table) * shade + rng.normal(0, 0.03, mask.shape)
    return np.clip(lum, 0, 1)


def test_raw_photos_measured_with_a_calibration_image(tmp_path):
    # Another camera: 1100 px/m, specimen centre off the image centre, light cloth on a dark table.
    s, cx, cy = 1100.0, 215.0, 192.0
    c, r = np.meshgrid(np.arange(420) + 0.5, np.arange(400) + 0.5)
    x, y = (c - cx) / s, (cy - r) / s
    rho, theta = np.hypot(x, y), np.arctan2(y, x)
    flat = (rho < 0.15).astype(float)
    drape = (rho < 0.12 + 0.012 * np.cos(9 * theta)).astype(float)
    M.write_image(tmp_path / "flat.tif", _photo(flat, 0.8, 0.2, 1), "uint16", 3)
    M.write_image(tmp_path / "drape.png", _photo(drape, 0.8, 0.2, 2), "uint8", 3)
    out = tmp_path / "m.json"
    run(["measure", str(tmp_path / "drape.png"), "--calibration-image", str(tmp_path / "flat.tif"),
         "--json", str(out)])
    d = json.loads(out.read_text())["images"][0]
    assert d["px_per_m"] == pytest.approx(s, rel=0.005)
    assert d["centre_px"] == [pytest.approx(cx, abs=0.3), pytest.approx(cy, abs=0.3)]
    assert not d["dark_on_light"]
    assert d["node_count"] == 9
    assert d["drape_coefficient"] == pytest.approx(M.drape_coefficient(drape, s), abs=0.01)
    # Without the calibration the default 720 px/m scale is implausible for this image.
    with pytest.raises(M.InputError, match="wrong calibration"):
        run(["measure", str(tmp_path / "drape.png")])
    with pytest.raises(ValueError, match="one way"):
        run(["measure", str(tmp_path / "drape.png"), "--px-per-m", "900", "--calibration-image",
             str(tmp_path / "flat.tif")])


def test_compare_with_a_mesh_fitted_calibration(tmp_path):
    out = tmp_path / "c.json"
    run(["compare", "--mesh", OBJ, "--image", JPG, "--calibration-mesh", OBJ, JPG, "--json", str(out)])
    d = json.loads(out.read_text())
    assert d["px_per_m"] == pytest.approx(720.0, rel=0.01)
    assert d["iou"] > 0.99
