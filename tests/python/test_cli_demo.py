"""Smoke test of `drapelab demo --specimen-only` on circle1 (in-process CLI); the whole demo: test_demo_story.py."""
import numpy as np
import pytest

from drapelab import cli, measure, sim


def test_demo_writes_mesh_and_silhouette(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--specimen-only", "--mesh-level", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "drape coefficient" in text and "specimen circle1" in text
    assert text.count("step ") <= 6  # a few progress lines, not one per step
    mesh = sim.read_obj(out / "drape.obj")
    assert mesh.num_vertices == sim.cusick_specimen(1).num_vertices
    positions = np.asarray(mesh.positions)
    assert np.isfinite(positions).all() and positions[:, 2].min() < -0.02
    image, info = measure.read_image(out / "silhouette.png")
    assert np.asarray(image).shape == (256, 256)
    # The printed drape coefficient is the one measured on the written silhouette (dark cloth on white).
    dc = measure.drape_coefficient((np.asarray(image) < 0.5).astype(float))
    assert f"drape coefficient {dc:.3f}" in text
    assert 0.2 < dc < 1.0


def test_demo_rejects_bad_steps(tmp_path, capsys):
    assert cli.main(["demo", "--specimen-only", "--mesh-level", "1", "--steps", "0", "--out", str(tmp_path)]) == 2
    assert "--steps" in capsys.readouterr().err


def test_demo_static_mode(tmp_path, capsys):
    out = tmp_path / "static"
    assert cli.main(["demo", "--specimen-only", "--mesh-level", "1", "--mode", "static", "--out", str(out)]) == 0
    assert "Newton iterations" in capsys.readouterr().out
    assert (out / "drape.obj").exists() and (out / "silhouette.png").exists()


def test_bench_smoke(tmp_path, capsys):
    import json

    out = tmp_path / "bench.json"
    assert cli.main(["bench", "--meshes", "1", "--steps", "2", "--no-static", "--contact-draws", "1", "--no-garment",
                     "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["threads"] == 1 and report["steps"] == 2
    (mesh,) = report["meshes"]
    assert mesh["name"] == "circle1" and mesh["vertices"] == 297
    for key in ("forward_ms_per_step", "backward_ms_per_step", "factorize_ms", "epoch_s", "peak_rss_mb"):
        assert mesh[key] > 0, key
    assert report["render"]["forward_ms"] > 0 and len(report["paper_gpu"]["meshes"]) == 3
    # one row per registered effect beside the base model's (on circle1 here: circle3 is not listed)
    effects = report["effects"]
    assert effects["mesh"] == "circle1" and [r["name"] for r in effects["rows"]] == ["base"] + [
        e["name"] for e in sim.effects()]
    for r in effects["rows"]:
        assert r["forward_ms_per_step"] > 0 and r["backward_ms_per_step"] > 0, r
    # the contact block: the same placement with and without the contact effects, nothing below the disk
    contact = report["contact"]
    assert contact["draws"] == 1 and contact["forward_ratio"] > 0 and contact["backward_ratio"] > 0
    assert contact["vertices_below_disk_max"] == 0 and contact["min_signed_distance_m"] > 0
    assert contact["intersecting_pairs_max"] == 0  # sim.contact_report of the last state
    assert contact["min_self_distance_m"] is None or contact["min_self_distance_m"] > 0
    assert "garment" not in report
    assert "circle1" in capsys.readouterr().out
    assert cli.main(["bench", "--meshes", "7", "--json", str(out)]) == 2


def test_bench_fit_times_a_whole_fit(tmp_path, capsys):
    """`bench --meshes none --fit`: one whole fit (epochs + drape calibration) of the bundled image, in a child
    process, reported against the 300 s target (here on circle1 with a 1-epoch, 2-draw configuration)."""
    import json

    from drapelab import infer

    config = infer.load_config()
    config["mesh_level"] = 1
    config["init"]["scale_search"] = [0.5, 1.0]
    config["calibration"].update({"mesh_level": 1, "draws": 2, "iterations": 1})
    config["calibration"]["node_search"]["enabled"] = False
    cfg = tmp_path / "fit.json"
    cfg.write_text(json.dumps(config))
    out = tmp_path / "bench.json"
    assert cli.main(["bench", "--meshes", "none", "--fit", "--fit-epochs", "1", "--fit-config", str(cfg),
                     "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["meshes"] == [] and report["render"] is None
    fit = report["fit"]
    assert fit["epochs"] == 1 and fit["mesh_level"] == 1 and fit["target_s"] == 300
    assert fit["density_kg_m2"] == 0.192 and fit["image"].endswith("sample_02_capture_1.jpg")
    assert 0 < fit["training_s"] < fit["total_s"] and 0 < fit["calibration_s"] < fit["total_s"]
    assert fit["calibration_sets"] >= 3  # c = 0 and the central difference +-log_step
    assert 0.5 < fit["dc_observed"] < 0.8 and 0 < fit["dc_predicted"] < 1 and 0 < fit["training_iou"] <= 1
    assert "fit (bdp" in capsys.readouterr().out
    # bad input is named before any simulation
    assert cli.main(["bench", "--meshes", "none", "--json", str(out)]) == 2
    assert cli.main(["bench", "--meshes", "none", "--fit", "--fit-epochs", "0", "--json", str(out)]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert cli.main(["bench", "--meshes", "none", "--fit", "--fit-config", str(bad), "--json", str(out)]) == 2
    assert "cannot read the fit configuration" in capsys.readouterr().err
