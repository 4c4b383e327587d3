"""Facade drapelab.render: cameras, hard silhouette, soft renderer forward/backward, errors."""
import os
import threading

import numpy as np
import pytest

from drapelab import render
from drapelab._native import native

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ASSETS = os.path.join(ROOT, "assets", "cusick")


def synthetic_drape(target_vertices=150, wobble=0.002, seed=1):
    """A Cusick specimen pushed into a 6-node drape-like shape (no folds), with a little noise."""
    mesh = native.make_cusick_specimen(target_vertices)
    p = np.array(mesh.positions)
    r = np.hypot(p[:, 0], p[:, 1])
    theta = np.arctan2(p[:, 1], p[:, 0])
    overhang = np.maximum(r - 0.09, 0.0)
    scale = np.where(r > 0.09, (0.09 + overhang * (0.65 + 0.25 * np.cos(6 * theta))) / np.maximum(r, 1e-12), 1.0)
    p[:, 0] *= scale
    p[:, 1] *= scale
    p[:, 2] = -0.8 * overhang
    p += wobble * np.random.default_rng(seed).uniform(-1, 1, p.shape)
    return p, np.array(mesh.faces)


# ---------------------------------------------------------------- cameras
def test_orthographic_camera_matches_calibration():
    cam = render.orthographic_camera()
    assert (cam.width, cam.height, cam.kind) == (256, 256, "ortho")
    q = render.project(cam, [[0.1, 0.05, -0.2], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(q, [[128 + 72, 128 - 36], [128, 128]])


def test_perspective_camera_matches_formula_and_jacobians_match_fd():
    cam = render.perspective_camera(fov_y=0.5, eye_height=0.7, size=(320, 240))
    f = 120 / np.tan(0.25)
    p = np.array([[0.1, -0.05, -0.1]])
    np.testing.assert_allclose(render.project(cam, p), [[160 + f * 0.1 / 0.8, 120 + f * 0.05 / 0.8]])
    jac = cam.jacobians(p)[0]
    h = 1e-6
    for k in range(3):
        e = np.zeros((1, 3))
        e[0, k] = h
        fd = (cam.project(p + e) - cam.project(p - e))[0] / (2 * h)
        np.testing.assert_allclose(jac[:, k], fd, rtol=1e-6, atol=1e-6)


def test_bad_camera_arguments():
    with pytest.raises(ValueError, match="px_per_m"):
        render.orthographic_camera(px_per_m=-1)
    with pytest.raises(ValueError, match="size"):
        render.orthographic_camera(size=(256,))
    with pytest.raises(ValueError, match="fov_y"):
        render.perspective_camera(fov_y=0)
    with pytest.raises(ValueError, match="camera"):
        render.hard_silhouette("ortho", *synthetic_drape())


# ---------------------------------------------------------------- hard silhouette
def test_hard_silhouette_of_specimen_has_calibrated_area():
    mesh = native.make_cusick_specimen(2699)
    image = render.hard_silhouette(render.orthographic_camera(), mesh.positions, mesh.faces)
    assert image.shape == (256, 256) and image.dtype == np.float64
    assert set(np.unique(image)) <= {0.0, 1.0}
    assert abs(image.sum() - np.pi * 108 ** 2) < 0.01 * np.pi * 108 ** 2


def test_hard_silhouette_of_bundled_mesh_matches_its_photo():
    mesh_path = os.path.join(ASSETS, "fabric_02", "meshes", "sample_02_capture_1.obj")
    image_path = os.path.join(ASSETS, "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
    if not (os.path.exists(mesh_path) and os.path.exists(image_path)):
        pytest.skip("bundled Cusick asset missing")
    mesh = native.read_obj(mesh_path)
    rendered = render.hard_silhouette(render.orthographic_camera(), mesh.positions, mesh.faces) > 0.5
    luminance = native.read_luminance(image_path)
    luminance = luminance[0] if isinstance(luminance, tuple) else luminance
    photo = (1.0 - np.asarray(luminance)) > 0.5
    iou = (rendered & photo).sum() / (rendered | photo).sum()
    assert iou > 0.97


# ---------------------------------------------------------------- soft renderer
@pytest.mark.parametrize("profile", ["gaussian", "logistic"])
@pytest.mark.parametrize("camera_kind", ["ortho", "perspective"])
def test_soft_backward_matches_finite_differences(profile, camera_kind):
    cam = (render.orthographic_camera(150, (32, 32), (64, 64)) if camera_kind == "ortho"
           else render.perspective_camera(1.2, 0.5, (64, 64)))
    positions, faces = synthetic_drape()
    renderer = render.SoftRenderer(cam, sigma=0.8, profile=profile, epsilon=1e-15)
    rng = np.random.default_rng(4)
    w = rng.uniform(-1, 1, (64, 64))
    image = renderer.render(positions, faces)
    assert image.shape == (64, 64) and 0 <= image.min() and image.max() <= 1
    grad = renderer.backward(w)
    assert grad.shape == positions.shape and np.isfinite(grad).all()
    for _ in range(3):
        d = rng.normal(size=positions.shape)
        h = 1e-7
        fd = ((renderer.render(positions + h * d, faces) * w).sum()
              - (renderer.render(positions - h * d, faces) * w).sum()) / (2 * h)
        assert abs((grad * d).sum() - fd) <= 1e-5 * np.linalg.norm(grad) * np.linalg.norm(d)


def test_soft_render_converges_to_hard():
    positions, faces = synthetic_drape(1205, wobble=0.0)
    cam = render.orthographic_camera()
    hard = render.hard_silhouette(cam, positions, faces)
    errors = [np.mean((render.SoftRenderer(cam, sigma=s).render(positions, faces) - hard) ** 2)
              for s in (1.0, 0.3, 0.1, 0.01)]
    assert all(a > b for a, b in zip(errors, errors[1:]))
    assert errors[-1] < 2e-4


def test_gradient_descent_recovers_a_shift():
    # The gradient is useful, not only correct: recover a 3-pixel offset of a disk by descent on pixel MSE.
    mesh = native.make_cusick_specimen(297)
    cam = render.orthographic_camera()
    positions = np.array(mesh.positions)
    target = render.hard_silhouette(cam, positions, mesh.faces)
    renderer = render.SoftRenderer(cam, sigma=1.0)
    shift = np.array([3.0, -2.0]) / 720.0  # m
    for _ in range(60):
        moved = positions.copy()
        moved[:, :2] += shift
        image = renderer.render(moved, mesh.faces)
        grad = renderer.backward(2 * (image - target) / image.size)
        g = grad[:, :2].sum(axis=0)
        shift -= 0.25 / 720.0 * g / max(np.linalg.norm(g), 1e-300) * min(1.0, np.linalg.norm(shift) * 720.0)
    assert np.linalg.norm(shift) * 720.0 < 0.2


def test_soft_renderer_errors_are_clear():
    cam = render.orthographic_camera(150, (32, 32), (64, 64))
    positions, faces = synthetic_drape()
    renderer = render.SoftRenderer(cam)
    with pytest.raises(ValueError, match="render"):
        renderer.backward(np.zeros((64, 64)))
    bad = faces.copy()
    bad[5, 1] = len(positions)
    with pytest.raises(ValueError, match="face 5"):
        renderer.render(positions, bad)
    nan = positions.copy()
    nan[7, 2] = np.nan
    with pytest.raises(ValueError, match="vertex 7"):
        renderer.render(nan, faces)
    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        renderer.render(positions[:, :2], faces)
    with pytest.raises(ValueError, match="integer"):
        renderer.render(positions, faces.astype(np.float64))
    renderer.render(positions, faces)
    with pytest.raises(ValueError, match=r"\(64, 64\)"):
        renderer.backward(np.zeros((64, 63)))
    with pytest.raises(ValueError, match="non-finite"):
        renderer.backward(np.full((64, 64), np.inf))
    with pytest.raises(ValueError, match="sigma"):
        render.SoftRenderer(cam, sigma=0)
    with pytest.raises(ValueError, match="profile"):
        render.SoftRenderer(cam, profile="box")
    # The native layer's own errors are ValueErrors too.
    raw = native.SoftRasterizer(cam)
    raw.forward(positions, faces.astype(np.int32))
    with pytest.raises(ValueError, match="rendered image is 64x64"):
        raw.backward(np.zeros((2, 2)))


def test_soft_renderer_is_usable_from_threads():
    cam = render.orthographic_camera(150, (32, 32), (64, 64))
    positions, faces = synthetic_drape()
    expected = render.SoftRenderer(cam).render(positions, faces)
    results = []

    def work():
        r = render.SoftRenderer(cam)
        for _ in range(5):
            results.append(np.abs(r.render(positions, faces) - expected).max())
            r.backward(np.ones((64, 64)))

    threads = [threading.Thread(target=work) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 10 and max(results) == 0.0


def test_time_soft_render_reports_milliseconds():
    positions, faces = synthetic_drape(297)
    timing = render.time_soft_render(positions, faces, repeats=2)
    assert timing["forward_ms"] > 0 and timing["backward_ms"] > 0 and timing["faces"] == len(faces)
