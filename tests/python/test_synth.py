"""drapelab.synth and `drapelab synth`: synthetic drapes in the dataset's layout and calibration, with known truth.

Fast: circle1, two drapes per run (about 0.3 s a drape)."""
import json
import os
import re
import struct
import threading

import numpy as np
import pytest

from drapelab import cli, measure, sim, synth
from drapelab.commands import synth as synth_command

LEVEL, COUNT, DENSITY = 1, 2, 0.192
TILT = {"angle_rad": 0.15, "azimuth_rad": 1.2}  # moderate angle, towards +y a little past the diagonal


def run(out, **options):
    options = {"count": COUNT, "seed": 1, "mesh_level": LEVEL, **options}
    return synth.synth(out, DENSITY, **options)


@pytest.fixture(scope="module")
def control(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "control"
    return str(out), run(out)


@pytest.fixture(scope="module")
def tilted(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "tilt"
    text = ",".join(f"tilt.{k}={v}" for k, v in TILT.items())
    return str(out), run(out, effects=text)


def files(out):
    """Every file under `out`, relative path -> bytes."""
    found = {}
    for root, _, names in os.walk(out):
        for n in names:
            path = os.path.join(root, n)
            with open(path, "rb") as f:
                found[os.path.relpath(path, out)] = f.read()
    return found


def test_files_and_manifest_follow_the_dataset_layout(control):
    out, truth = control
    expected = {"manifest.csv", "truth.json"}
    for s in range(1, COUNT + 1):
        expected |= {f"fabric_00/silhouettes/sample_{s:02d}_capture_1.png", f"fabric_00/meshes/sample_{s:02d}_capture_1.obj"}
    assert set(files(out)) == expected
    text = open(os.path.join(out, "manifest.csv")).read().splitlines()
    assert text[0] == "fabric,name,material,weave,density_kg_m2,thickness_mm,sample,capture,silhouette,mesh"
    assert all(",fabric_00/silhouettes/" in line for line in text[1:])  # relative to DIR
    rows = measure.load_manifest(os.path.join(out, "manifest.csv"), check_files=True)
    assert [(r["fabric"], r["sample"], r["capture"]) for r in rows] == [(0, s, 1) for s in range(1, COUNT + 1)]
    assert all(r["density_kg_m2"] == DENSITY for r in rows)
    for r in rows:
        mesh = sim.read_obj(r["mesh"])
        assert np.asarray(mesh.positions).shape == (sim.cusick_specimen(LEVEL).num_vertices, 3)


def test_images_read_like_the_dataset_scale_centre_and_polarity(control):
    out, truth = control
    for d, r in zip(truth["drapes"], measure.load_manifest(os.path.join(out, "manifest.csv"))):
        luminance, info = measure.read_image(r["silhouette"])
        assert np.asarray(luminance).shape == (256, 256)
        m = measure.measure_image(r["silhouette"])  # the default (dataset) calibration and its plausibility check
        assert m["px_per_m"] == 720 and m["centre_px"] == [128, 128] and m["dark_on_light"]
        assert m["drape_coefficient"] == pytest.approx(d["drape_coefficient"], abs=1e-9)
        # Scale and centre recovered from the written mesh against the written image: the image is the mesh's
        # shadow in the dataset's calibration.
        cal, fit = measure.calibrate_from_mesh(r["silhouette"], r["mesh"])
        assert cal.px_per_m == pytest.approx(720, rel=0.01), cal.px_per_m
        assert abs(cal.cx - 128) < 1 and abs(cal.cy - 128) < 1, (cal.cx, cal.cy)
        assert fit > 0.97


def test_same_seed_same_files_and_another_seed_other_drapes(control, tmp_path):
    out, _ = control
    again = tmp_path / "again"
    run(again)
    assert files(again) == files(out)
    other = tmp_path / "other"
    run(other, seed=2)
    a, b = files(out), files(other)
    for s in range(1, COUNT + 1):
        png = f"fabric_00/silhouettes/sample_{s:02d}_capture_1.png"
        obj = f"fabric_00/meshes/sample_{s:02d}_capture_1.obj"
        assert a[png] != b[png] and a[obj] != b[obj]
    # Within one run the drapes differ too (placement noise), by more than round-off.
    x1, x2 = (np.asarray(sim.read_obj(os.path.join(out, f"fabric_00/meshes/sample_{s:02d}_capture_1.obj")).positions)
              for s in (1, 2))
    assert np.abs(x1 - x2).max() > 1e-3


def test_truth_json_records_effects_material_and_protocol(control, tilted):
    for (out, returned), effects in ((control, {}), (tilted, {"tilt": TILT})):
        truth = json.load(open(os.path.join(out, "truth.json")))
        assert truth == returned
        assert truth["effects"] == effects
        assert truth["density_kg_m2"] == DENSITY and truth["seed"] == 1 and truth["count"] == COUNT
        assert truth["complete"] and truth["requested_count"] == COUNT and truth["mesh_level"] == LEVEL
        assert truth["material"]["name"] == "Cotton Blue tables" and np.shape(truth["material"]["bend_N_m"]) == (3, 5)
        assert truth["camera"] == {"kind": "ortho", "px_per_m": 720.0, "centre_px": [128.0, 128.0],
                                   "size_px": [256, 256], "polarity": "dark_on_light"}
        assert truth["placement_noise"]["velocity_m_s"] > 0


@pytest.mark.parametrize("effect", sim.effects(), ids=lambda e: e["name"])
def test_every_registered_effect_synthesises_and_a_bare_name_is_its_moderate_strength(tmp_path, effect):
    truth = run(tmp_path / "bare", effects=effect["name"], count=1)
    assert truth["effects"] == {effect["name"]: {q["name"]: (q["moderate"] if i == 0 else q["off"])
                                                 for i, q in enumerate(effect["parameters"])}}
    assert measure.measure_image(str(tmp_path / "bare" / truth["drapes"][0]["silhouette"]))["px_per_m"] == 720


def test_nothing_but_truth_json_names_the_effect(control, tilted):
    a, b = files(control[0]), files(tilted[0])
    assert set(a) == set(b)
    assert a["manifest.csv"] == b["manifest.csv"]  # same columns and names for control and effect data
    words = {w for e in sim.effects() for w in [e["name"]] + [q["name"] for q in e["parameters"]]}
    pattern = re.compile(r"\b(" + "|".join(map(re.escape, sorted(words))) + r")\b", re.IGNORECASE)
    for name, data in b.items():
        if name.endswith(".png"):
            data = png_metadata(data)  # the pixels are compressed; the chunks around them could hold text
        if name != "truth.json":
            assert not pattern.search(data.decode("latin-1")), name


def png_metadata(data):
    """Every chunk of a PNG file but its compressed pixels (IDAT): signature, type and content bytes."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    out, i = [], 8
    while i < len(data):
        length, kind = struct.unpack(">I4s", data[i:i + 8])
        if kind != b"IDAT":
            out.append(kind + data[i + 8:i + 8 + length])
        i += 12 + length
    return b" ".join(out)


def test_the_tilted_drape_leans_towards_the_tilt_azimuth(control, tilted):
    """Gravity off vertical towards azimuth phi: the skirt hangs further out on that side, so the silhouette's
    centroid moves from the control's (same placements, seed 1) towards phi (x right, y up in the image)."""
    def centroid(out, s):
        mask = np.asarray(measure.load_silhouette(os.path.join(out, f"fabric_00/silhouettes/sample_{s:02d}_capture_1.png")).mask)
        rows, cols = np.nonzero(mask > 0.5)
        return np.array([cols.mean() - 128, 128 - rows.mean()]) / 720.0  # metres, x right, y up

    shifts = np.array([centroid(tilted[0], s) - centroid(control[0], s) for s in range(1, COUNT + 1)])
    for shift in shifts:
        assert np.linalg.norm(shift) > 2e-3, shift  # about 3 px at 720 px/m; control drapes scatter < 1 px
        angle = np.arctan2(shift[1], shift[0])
        assert abs(np.angle(np.exp(1j * (angle - TILT["azimuth_rad"])))) < 0.35, (angle, TILT["azimuth_rad"])


def test_cancel_keeps_the_drapes_done(tmp_path):
    cancel = threading.Event()
    out = tmp_path / "cancelled"
    with pytest.raises(synth.Cancelled):
        run(out, count=3, progress=lambda d: cancel.set(), cancel_event=cancel)
    truth = json.load(open(out / "truth.json"))
    assert truth["count"] == 1 and truth["requested_count"] == 3 and not truth["complete"]
    rows = measure.load_manifest(str(out / "manifest.csv"), check_files=True)
    assert [r["sample"] for r in rows] == [1]


def test_an_existing_folder_is_refused_unless_forced_over_a_previous_synth(control, tmp_path):
    out = tmp_path / "again"
    run(out)
    with pytest.raises(sim.InputError, match="not empty.*--force"):
        run(out, count=1)
    truth = run(out, count=1, force=True)
    assert truth["count"] == 1 and sorted(files(out)) == ["fabric_00/meshes/sample_01_capture_1.obj",
                                                           "fabric_00/silhouettes/sample_01_capture_1.png",
                                                           "manifest.csv", "truth.json"]
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(sim.InputError, match="no truth.json"):
        run(foreign, force=True)
    assert os.listdir(foreign) == ["notes.txt"]
    (tmp_path / "empty").mkdir()
    assert run(tmp_path / "empty", count=1)["count"] == 1


@pytest.mark.parametrize("options, message", [
    ({"effects": "tlt=0.1"}, "unknown effect 'tlt'"),
    ({"effects": "tilt.angle=0.1"}, "no parameter 'angle'"),
    ({"effects": "tilt=0.9"}, "tilt.angle_rad"),  # out of range, by the native registry
    ({"effects": "tilt=abc"}, "tilt.angle_rad: expected a number"),
    ({"count": 0}, "count"),
    ({"density": 0.0}, "density"),
    ({"density": -1.0}, "density"),
    ({"seed": -1}, "seed"),
    ({"mesh_level": 7}, "mesh_level"),
    ({"material": "no_such_preset"}, "material: 'no_such_preset'.*shipped: fabric_01"),
    ({"material_draw": "per-drape"}, "give a material preset"),
    ({"material_draw": "median"}, "material_draw"),
])
def test_bad_arguments_are_errors_naming_the_field_before_any_file(tmp_path, options, message):
    out = tmp_path / "never"
    density = options.pop("density", DENSITY)
    with pytest.raises(sim.InputError, match=message):
        synth.synth(out, density, **{"count": 1, "mesh_level": LEVEL, **options})
    assert not out.exists()


def test_a_preset_material_is_its_posterior_median_or_a_draw_per_drape(tmp_path):
    name = "fabric_02_cotton_blue_bdp"
    preset = synth.resolve_material(name)["preset"]
    truth = run(tmp_path / "mean", material=name, count=1)
    m = truth["material"]
    assert m["source"].endswith(name + ".json") and m["draw"] == "mean" and m["name"] == "Cotton Blue"
    assert np.allclose(m["bend_N_m"], np.exp(preset["posterior"]["bend"]["log_mean"]))
    assert np.allclose(m["stretch_N_m"], preset["stretch_N_m"])
    drawn = run(tmp_path / "draw", material=name, material_draw="per-drape")
    assert drawn["material"]["draw"] == "per-drape" and drawn["material"]["posterior"]["log_std"]
    # Same placement as the mean run's drape 1, another material: a different drape.
    a = files(tmp_path / "mean")["fabric_00/meshes/sample_01_capture_1.obj"]
    assert files(tmp_path / "draw")["fabric_00/meshes/sample_01_capture_1.obj"] != a


def test_cli_writes_the_dataset_and_reports_each_drape_on_stderr(tmp_path, capsys):
    out = tmp_path / "cli"
    assert cli.main(["synth", "--effects", "tilt=0.1", "--density", "0.2", "--count", "2", "--seed", "4",
                     "--mesh-level", "1", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert [l for l in captured.err.splitlines() if l.startswith("drape ")][-1].startswith("drape 2/2 ")
    assert "wrote 2 drapes" in captured.out
    truth = json.load(open(out / "truth.json"))
    assert truth["effects"]["tilt"]["angle_rad"] == 0.1 and truth["density_kg_m2"] == 0.2 and truth["seed"] == 4
    assert cli.main(["synth", "--density", "0.2", "--count", "1", "--mesh-level", "1", "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert cli.main(["synth", "--effects", "tilt.angle=1", "--density", "0.2", "--out", str(tmp_path / "x")]) == 2
    assert "no parameter 'angle'" in capsys.readouterr().err


def test_cli_defaults_are_the_facades():
    assert synth_command.MATERIAL_DRAWS == synth.MATERIAL_DRAWS
    assert synth_command.DEFAULT_COUNT == synth.DEFAULT_COUNT
    assert synth_command.DEFAULT_MESH_LEVEL == synth.DEFAULT_MESH_LEVEL
