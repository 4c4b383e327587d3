"""drapelab.measure: the numpy facade of the measurement side (no Blender)."""
import csv
import json
import os

import numpy as np
import pytest

from drapelab import measure as M
from drapelab import paths

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ASSETS = os.path.join(ROOT, "assets", "cusick")
JPG = os.path.join(ASSETS, "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
OBJ = os.path.join(ASSETS, "fabric_02", "meshes", "sample_02_capture_1.obj")
CUSICK = paths.cusick_dataset_dir()
README_DC = {1: 0.504, 2: 0.643, 3: 0.157, 4: 0.582, 5: 0.795}


def polar_mask(radius_fn, px_per_m=720.0, size=256, cx=128.0, cy=128.0):
    """Binary (H, W) mask of r < radius_fn(theta) sampled at pixel centres (theta from +x, +y up)."""
    c, r = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    x, y = (c - cx) / px_per_m, (cy - r) / px_per_m
    return (np.hypot(x, y) < radius_fn(np.arctan2(y, x))).astype(np.float64)


def folds(n=8, mean=0.12, amplitude=0.015):
    return polar_mask(lambda t: mean + amplitude * np.cos(n * t))


# ---------------------------------------------------------------- images in memory
def test_to_luminance_handles_dtypes_and_channels():
    grey = np.array([[0, 255]], dtype=np.uint8)
    np.testing.assert_allclose(M.to_luminance(grey), [[0.0, 1.0]])
    np.testing.assert_allclose(M.to_luminance(np.array([[65535]], dtype=np.uint16)), [[1.0]])
    rgb = np.zeros((1, 1, 3), dtype=np.uint8)
    rgb[0, 0] = (30, 60, 90)
    np.testing.assert_allclose(M.to_luminance(rgb), [[60 / 255]])
    rgba = np.array([[[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]])  # transparent, opaque black
    np.testing.assert_allclose(M.to_luminance(rgba), [[1.0, 0.0]])
    np.testing.assert_allclose(M.to_luminance(np.array([[0.5, 4.0]])), [[0.125, 1.0]])  # HDR floats
    np.testing.assert_allclose(M.to_luminance(np.array([[True, False]])), [[1.0, 0.0]])
    for bad in (np.zeros((2, 2, 5)), np.zeros(4), np.zeros((0, 3)), np.array([[np.nan]])):
        with pytest.raises(ValueError):
            M.to_luminance(bad)


def test_extract_silhouette_from_numpy_rgb_both_polarities():
    truth = folds()
    dark = (255 * (1 - truth))[:, :, None].repeat(3, axis=2).astype(np.uint8)
    s = M.extract_silhouette(dark)
    assert s.dark_on_light
    assert s.mask.shape == (256, 256) and s.mask.dtype == np.float64
    assert np.array_equal(s.mask, truth)
    light = M.extract_silhouette(truth)
    assert not light.dark_on_light and np.array_equal(light.mask, truth)
    assert M.automatic_threshold(1 - truth) == pytest.approx(0.5)


def test_specks_and_holes():
    truth = folds()
    img = truth.copy()
    img[3:6, 3:6] = 1
    img[120:122, 150:152] = 0
    s = M.extract_silhouette(1 - img)
    assert s.specks_removed_px == 9 and s.holes_filled_px == 4
    assert np.array_equal(s.mask, truth)


# ---------------------------------------------------------------- the synthetic checks
def test_drape_coefficient_of_specimen_and_support_disks():
    assert M.drape_coefficient(polar_mask(lambda t: 0.15 + 0 * t)) == pytest.approx(1.0, abs=0.005)
    assert M.drape_coefficient(polar_mask(lambda t: 0.09 + 0 * t)) == pytest.approx(0.0, abs=0.005)
    assert M.drape_coefficient(np.ones((10, 10)), px_per_m=1.0, support_radius=0.0,
                               specimen_radius=np.sqrt(100 / np.pi)) == pytest.approx(1.0)


def test_eight_sinusoidal_folds_give_node_count_eight():
    r = M.r_theta(folds(8))
    assert r.shape == (360,)
    assert M.node_count(r) == 8
    nodes = M.analyse_nodes(r)
    assert len(nodes.angles_rad) == 8
    assert M.node_amplitude(r) == pytest.approx(0.015 * np.exp(-0.5 * (8 * np.radians(2)) ** 2), abs=1.5 / 720)
    h = M.harmonics(r)
    assert h.shape == (20,)
    assert h[0] == pytest.approx(0.12, abs=0.5 / 720)
    assert h[8] == pytest.approx(0.015, abs=1 / 720)
    assert int(np.argmax(h[1:])) + 1 == 8


def test_disk_has_no_nodes_and_constant_r_theta():
    r = M.r_theta(polar_mask(lambda t: 0.13 + 0 * t))
    assert np.all(np.abs(r - 0.13) < 1 / 720)
    assert M.node_count(r) == 0


def test_two_fold_gives_the_long_axis_and_its_amplitude():
    theta = np.arange(360) * 2 * np.pi / 360
    for axis_deg in (0.0, 30.0, 110.0, 170.0):
        r = 0.13 + 0.004 * np.cos(2 * (theta - np.radians(axis_deg))) + 0.002 * np.cos(6 * theta)
        amplitude, axis = M.two_fold(r)
        assert amplitude == pytest.approx(0.004) and 0 <= axis < 180
        assert (axis - axis_deg + 90) % 180 - 90 == pytest.approx(0.0, abs=1e-9)  # mod 180: 0 and 179.999... alike
    with pytest.raises(M.InputError, match="two_fold"):
        M.two_fold([0.1, 0.1])


def test_r_theta_rmse_after_best_rotation():
    a = M.r_theta(folds(7))
    b = np.roll(a, 25)
    rmse, rotation = M.r_theta_rmse(a, b)
    assert rmse == pytest.approx(0.0, abs=1e-15)
    assert np.degrees(rotation) == pytest.approx(25)  # model(theta + rotation) = measured(theta)
    with pytest.raises(ValueError, match="differ in length"):
        M.r_theta_rmse(a, a[:100])


def test_mse_and_iou():
    a, b = np.zeros((4, 4)), np.zeros((4, 4))
    a[:2] = 1
    b[1:3] = 1
    assert M.pixel_mse(a, b) == pytest.approx(0.5)
    assert M.iou(a, b) == pytest.approx(1 / 3)
    with pytest.raises(ValueError, match="shapes differ"):
        M.iou(a, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="2D"):
        M.pixel_mse(np.zeros(4), np.zeros(4))


def test_hausdorff_between_meshes_in_metres():
    mesh = M.native.read_obj(OBJ)
    lifted = (mesh.positions + [0.0, 0.0, 0.02], mesh.faces)
    assert M.hausdorff_distance(OBJ, lifted) == pytest.approx(0.02, abs=1e-12)
    assert M.hausdorff_distance(mesh, lifted, mode="vertices") == pytest.approx(0.02, abs=1e-12)
    assert M.hausdorff_distance(OBJ, OBJ) == 0.0
    with pytest.raises(ValueError, match="mode"):
        M.hausdorff_distance(OBJ, OBJ, mode="nearest")
    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        M.hausdorff_distance((np.zeros((3, 2)), np.zeros((1, 3), int)), OBJ)


# ---------------------------------------------------------------- files, calibration, real data
def test_measure_image_of_the_bundled_asset():
    r = M.measure_image(JPG)
    assert r["image"] == JPG
    assert r["drape_coefficient"] == pytest.approx((28909 - 13192) / (36644 - 13192), abs=0.003)
    assert r["node_count"] == 8
    assert r["px_per_m"] == 720.0 and r["centre_px"] == [128.0, 128.0]
    assert len(r["r_theta_m"]) == 360 and len(r["harmonics"]) == 20
    json.dumps(r)  # JSON-ready


def test_calibration_given_and_wrong():
    cal = M.calibration(700.0, (127.5, 128.5))
    s = M.load_silhouette(JPG, cal)
    assert s.calibration.px_per_m == 700.0 and s.calibration.cx == 127.5
    with pytest.raises(ValueError, match="wrong calibration"):
        M.measure_image(JPG, M.calibration(350.0))
    with pytest.raises(ValueError, match="wrong calibration"):
        M.measure_image(JPG, M.calibration(720.0, (400.0, 10.0)))
    assert M.measure_image(JPG, M.calibration(350.0), check_calibration=False)["px_per_m"] == 350.0


def test_calibration_estimated_from_a_disk_and_from_a_mesh():
    flat = polar_mask(lambda t: 0.15 + 0 * t, px_per_m=600.0, cx=120.0, cy=131.0)
    cal = M.calibrate_from_disk(flat, diameter_m=0.30)
    assert cal.px_per_m == pytest.approx(600.0, rel=0.003)
    assert (cal.cx, cal.cy) == (pytest.approx(120.0, abs=0.05), pytest.approx(131.0, abs=0.05))
    cal, fit_iou = M.calibrate_from_mesh(JPG, OBJ)
    assert cal.px_per_m == pytest.approx(720.0, rel=0.01)
    assert fit_iou > 0.98


@pytest.mark.parametrize("content,problem", [(None, "not found"), (b"", "empty"),
                                             (b"not an image at all", "cannot read image")])
def test_bad_files_name_the_file(tmp_path, content, problem):
    path = str(tmp_path / "drape.jpg")
    if content is not None:
        with open(path, "wb") as f:
            f.write(content)
    with pytest.raises(ValueError) as e:
        M.measure_image(path)
    assert path in str(e.value) and problem in str(e.value)
    assert isinstance(e.value, M.InputError)


def test_truncated_jpeg_names_the_file(tmp_path):
    data = open(JPG, "rb").read()
    path = tmp_path / "cut.jpg"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="cut.jpg.*truncated or corrupt"):
        M.load_silhouette(path)


@pytest.mark.parametrize("value,problem", [(0.0, "all dark"), (1.0, "all light")])
def test_uniform_images_name_the_problem(tmp_path, value, problem):
    path = str(tmp_path / "flat.png")
    M.write_image(path, np.full((64, 64), value))
    with pytest.raises(ValueError, match=f"flat.png.*no contrast.*{problem}"):
        M.measure_image(path)


def test_image_without_a_central_region(tmp_path):
    path = str(tmp_path / "corner.tif")
    M.write_image(path, 1 - polar_mask(lambda t: 0.03 + 0 * t, cx=30, cy=30), "uint16", 3)
    with pytest.raises(ValueError, match="corner.tif.*no specimen region at the centre"):
        M.measure_image(path)


@pytest.mark.parametrize("name,pixel_type,channels", [("a.png", "uint8", 1), ("b.tif", "uint16", 3),
                                                      ("c.exr", "float", 4), ("d.jpg", "uint8", 3)])
def test_formats_give_the_same_measurement(tmp_path, name, pixel_type, channels):
    lum, info = M.read_image(JPG)
    assert info["format"] == "jpeg" and lum.shape == (256, 256)
    path = str(tmp_path / name)
    M.write_image(path, lum, pixel_type, channels)
    ref = M.measure_image(JPG)
    got = M.measure_image(path)
    assert got["drape_coefficient"] == pytest.approx(ref["drape_coefficient"], abs=0.003)
    assert got["node_count"] == ref["node_count"]


def test_manifest_loader():
    rows = M.load_manifest(os.path.join(ASSETS, "manifest.csv"), check_files=True)
    assert [r["fabric"] for r in rows] == [2, 3, 5]
    assert rows[0]["mesh"] and os.path.exists(rows[0]["mesh"])
    assert rows[1]["mesh"] is None
    assert rows[0]["density_kg_m2"] == pytest.approx(0.192)
    with pytest.raises(ValueError, match="no-such.csv"):
        M.load_manifest("/no-such.csv")


def test_compare_mesh_with_its_silhouette():
    metrics, measured, model = M.compare_mesh_image(OBJ, JPG)
    assert metrics["iou"] > 0.97 and metrics["mse"] < 0.01
    assert metrics["node_count_mesh"] == metrics["node_count_image"] == 8
    assert metrics["drape_coefficient_mesh"] == pytest.approx(metrics["drape_coefficient_image"], abs=0.03)
    assert metrics["r_theta_rmse_m"] < 0.003
    assert measured.shape == model.shape == (256, 256)
    persp, _, _ = M.compare_mesh_image(OBJ, JPG, camera="perspective")
    assert persp["iou"] < metrics["iou"]
    with pytest.raises(ValueError, match="camera"):
        M.compare_mesh_image(OBJ, JPG, camera="fisheye")


@pytest.mark.dataset
@pytest.mark.skipif(CUSICK is None, reason=paths.NO_DATASET_REASON)
def test_real_data_drape_coefficients_match_the_readme_table():
    dcs = {f: [] for f in README_DC}
    for row in M.load_manifest(os.path.join(CUSICK, "manifest.csv")):
        if row["capture"] == 1 and row["fabric"] in dcs:
            dcs[row["fabric"]].append(M.measure_image(row["silhouette"])["drape_coefficient"])
    for fabric, expected in README_DC.items():
        assert len(dcs[fabric]) == 12
        assert np.mean(dcs[fabric]) == pytest.approx(expected, abs=0.01), f"fabric {fabric}"


# ---------------------------------------------------------------- outputs
def test_write_json_is_atomic_and_reports_unwritable_paths(tmp_path):
    out = tmp_path / "out.json"
    M.write_json(out, {"images": [1, 2]})
    assert json.loads(out.read_text()) == {"images": [1, 2]}
    assert sorted(os.listdir(tmp_path)) == ["out.json"]  # no temporary file left
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask  # like a plain open(), not the temporary file's 0600
    with pytest.raises(OSError, match="does not exist"):
        M.write_json(tmp_path / "missing" / "out.json", {})
    with pytest.raises(OSError, match="is a directory"):
        M.write_json(tmp_path, {})
    with pytest.raises(ValueError):
        M.write_json(out, {"x": float("nan")})
    assert json.loads(out.read_text()) == {"images": [1, 2]}  # the old file survives a failed write
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        with pytest.raises(OSError, match="cannot write JSON"):
            M.write_json(ro / "out.json", {})


def test_overlay_uses_three_colours_and_writes_a_png(tmp_path):
    a = polar_mask(lambda t: 0.10 + 0 * t)
    b = polar_mask(lambda t: 0.10 + 0 * t, cx=140.0)
    rgb = M.overlay_rgb(a, b)
    colours = {tuple(np.round(c, 3)) for c in rgb.reshape(-1, 3)}
    expected = {tuple(np.round(c, 3)) for c in M.OVERLAY_COLOURS.values()} | {(1.0, 1.0, 1.0)}
    assert colours == expected
    path = tmp_path / "overlay.png"
    M.write_overlay(path, a, b, title="t", notes=["IoU 0.8"], calibration=M.calibration(720, (128, 128)))
    lum, info = M.read_image(path)
    assert info["format"] == "png" and lum.shape[0] > 200
    assert sorted(os.listdir(tmp_path)) == ["overlay.png"]


def test_drape_coefficient_from_area_is_the_masks_own_and_of_soft_coverage():
    mask = M.load_silhouette(JPG, None).mask
    area = M.shadow_area(mask, M.DATASET_PX_PER_M)
    assert M.drape_coefficient_from_area(area) == pytest.approx(M.drape_coefficient(mask, M.DATASET_PX_PER_M),
                                                                abs=1e-12)
    # a soft silhouette's area is its summed coverage: half coverage everywhere halves the area
    half = 0.5 * np.asarray(mask, dtype=float)
    disk, span = np.pi * 0.09 ** 2, np.pi * (0.15 ** 2 - 0.09 ** 2)
    got = M.drape_coefficient_from_area(float(np.sum(half)) / M.DATASET_PX_PER_M ** 2)
    assert got == pytest.approx((area / 2 - disk) / span, rel=1e-12)
    with pytest.raises(M.InputError, match="specimen radius must exceed the support-disk radius"):
        M.drape_coefficient_from_area(area, support_radius=0.2, specimen_radius=0.15)
