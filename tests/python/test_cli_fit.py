"""`drapelab fit` and `drapelab evaluate` through the CLI (in-process): the contract's options, files and fields."""
import copy
import json
import os

import numpy as np

from drapelab import cli, infer

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
IMAGE = os.path.join(ROOT, "assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")


def test_fit_then_evaluate_writes_a_calibrated_preset_and_the_evaluation_json(tmp_path, capsys):
    cfg = copy.deepcopy(infer.load_config())
    cfg["mesh_level"] = 1
    cfg["init"]["scale_search"] = [0.5, 1.0, 2.0]
    cfg["calibration"]["draws"] = 4
    cfg["calibration"]["mesh_level"] = 1
    config = tmp_path / "fit.json"
    config.write_text(json.dumps(cfg))
    preset_path = tmp_path / "cotton_blue.json"
    assert cli.main(["fit", "--images", IMAGE, "--density", "0.192", "--model", "bdp", "--epochs", "1", "--seed", "3",
                     "--config", str(config), "--out", str(preset_path)]) == 0
    text = capsys.readouterr().out
    assert "wrote" in text and "drape calibration" in text
    preset = infer.load_preset(str(preset_path))
    assert preset["model"] == "bdp" and preset["training"]["epochs"] == 1
    assert preset["provenance"]["images"][0]["path"] == IMAGE and len(preset["provenance"]["images"][0]["sha256"]) == 64
    c = preset["calibration"]
    assert abs(c["dc_predicted"] - c["dc_observed"]) <= abs(c["dc_predicted_before"] - c["dc_observed"])
    # The calibration reports each set of drapes as it goes (minutes on the real meshes): one line per evaluation.
    lines = [l for l in text.splitlines() if l.startswith("calibration ")]
    assert len(lines) == len(c["evaluated"]) >= 3, text
    first = c["evaluated"][0]
    assert f"drape coefficient {first['dc']:.3f}" in "\n".join(lines) and f"observed {c['dc_observed']:.3f}" in lines[0]
    assert preset["posterior"]["bend"]["global_log_std"] == c["global_log_std"] >= 0
    out = tmp_path / "eval.json"
    assert cli.main(["evaluate", "--preset", str(preset_path), "--images", IMAGE, "--samples", "3", "--seed", "1",
                     "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    entry = result["images"][0]
    assert entry["image"] == IMAGE
    lo, hi = entry["drape_coefficient"]["interval90"]
    assert lo <= entry["drape_coefficient"]["predicted_mean"] <= hi
    assert set(result["mean"]) >= {"mse", "iou", "dc_abs_error", "dc_coverage90", "node_within1", "amplitude_bias_m",
                                   "amplitude_coverage90"}
    assert np.isfinite(result["mean"]["mse"])
    assert f"node amplitude bias {1000 * result['mean']['amplitude_bias_m']:+.1f} mm" in capsys.readouterr().out


def test_fit_with_bad_density_fails_cleanly_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert cli.main(["fit", "--images", IMAGE, "--density", "-1", "--epochs", "1", "--out", str(out)]) != 0
    assert "density" in capsys.readouterr().err
    assert not out.exists()


def test_fit_with_a_bare_effect_parameter_fits_that_parameter_only(tmp_path, capsys):
    # --effects tilt.angle_rad: the angle fitted from its off value, the azimuth held off; the preset says which.
    cfg = copy.deepcopy(infer.load_config())
    cfg["mesh_level"] = 1
    cfg["init"]["scale_search"] = [1.0]
    config = tmp_path / "fit.json"
    config.write_text(json.dumps(cfg))
    preset_path = tmp_path / "tilted.json"
    assert cli.main(["fit", "--images", IMAGE, "--density", "0.192", "--model", "homo", "--epochs", "1",
                     "--no-calibration", "--config", str(config), "--effects", "tilt.angle_rad",
                     "--out", str(preset_path)]) == 0
    assert "tilt.angle_rad" in capsys.readouterr().out
    tilt = infer.load_preset(str(preset_path))["active_effects"]["tilt"]
    assert tilt["angle_rad"]["fitted"] and not tilt["azimuth_rad"]["fitted"]
    assert tilt["azimuth_rad"]["value"] == 0.0 and np.isfinite(tilt["angle_rad"]["value"])
    bad = tmp_path / "bad.json"
    assert cli.main(["fit", "--images", IMAGE, "--density", "0.192", "--epochs", "1", "--effects", "tilt.angle",
                     "--out", str(bad)]) != 0
    assert "no parameter 'angle'" in capsys.readouterr().err and not bad.exists()
