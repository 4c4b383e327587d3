"""Rendering side of drapelab: cameras and silhouette rasterizers (bpy-free facade over render/).

Arrays in and out are numpy: positions (V, 3) float64 metres, faces (F, 3) int32 vertex indices, images
(H, W) float64 with rows top to bottom. Pixel (r, c) covers [c, c+1) x [r, r+1) in image coordinates
(col, row); its centre is (c + 0.5, r + 0.5). Bad input raises ``InputError`` (a ValueError) naming the
argument and the problem.

Cameras (measurement models; swap them freely):
    orthographic_camera   col = cx + px_per_m x,  row = cy - px_per_m y   (top view looking down -z);
                          the bundled Cusick data: 720 px/m, centre (128, 128), 256 x 256.
    perspective_camera    eye at (0, 0, eye_height) looking down -z, f = (H/2) / tan(fov_y/2) pixels:
                          col = W/2 + f x / (eye_height - z),  row = H/2 - f y / (eye_height - z).

hard_silhouette: 1 where a pixel centre lies in a projected triangle (closed), else 0.

SoftRenderer (differentiable): I(p) = 1 - prod_f (1 - D_f(p)) with d_f(p) the distance (pixels) from the
pixel centre to projected face f and sigma (pixels) the edge width:
    profile "gaussian" (default, DIB-R): D_f = 1 inside f, exp(-d_f^2 / sigma^2) outside. Covered pixels
        are exactly 1; gradients come from the uncovered band around the silhouette.
    profile "logistic" (SoftRas): D_f = logistic(+-d_f^2 / sigma^2), + inside. Note: on dense meshes the
        interior dips towards 0.75 along every interior edge.
Pairs with D_f < epsilon are skipped (error below ~1e-6 per pixel at the default 1e-8).
``backward(dL/dI)`` returns dL/dpositions (V, 3), the exact vector-Jacobian product of the last render.
"""
import numpy as np

from ._native import InputError, native

__all__ = [
    "InputError", "Camera", "orthographic_camera", "perspective_camera", "project", "hard_silhouette",
    "SoftRenderer", "time_soft_render",
]

Camera = native.Camera
PROFILES = ("gaussian", "logistic")


# ---------------------------------------------------------------- argument checks
def _size(size, name):
    try:
        width, height = (int(v) for v in size)
    except (TypeError, ValueError):
        raise InputError(f"{name}: size must be a pair (width, height) of pixels, got {size!r}") from None
    if width <= 0 or height <= 0:
        raise InputError(f"{name}: size (width, height) must be positive, got ({width}, {height})")
    return width, height


def _camera(camera, name="camera"):
    if not isinstance(camera, native.Camera):
        raise InputError(f"{name}: expected a camera from orthographic_camera() or perspective_camera(), "
                         f"got {type(camera).__name__}")
    return camera


def _positions(positions, name="positions"):
    arr = np.asarray(positions)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0:
        raise InputError(f"{name}: expected a non-empty array of shape (V, 3), got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"{name}: expected a float array, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise InputError(f"{name}: vertex {int(np.argmax(bad))} has a non-finite position {arr[np.argmax(bad)]}")
    return arr


def _faces(faces, num_vertices, name="faces"):
    arr = np.asarray(faces)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected an array of shape (F, 3), got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.integer):
        raise InputError(f"{name}: expected integer vertex indices, got dtype {arr.dtype}")
    if arr.size and (arr.min() < 0 or arr.max() >= num_vertices):
        f = int(np.argmax(((arr < 0) | (arr >= num_vertices)).any(axis=1)))
        raise InputError(f"{name}: face {f} {arr[f].tolist()} refers to a vertex outside [0, {num_vertices})")
    return np.ascontiguousarray(arr, dtype=np.int32)


def _mesh(positions, faces):
    positions = _positions(positions)
    return positions, _faces(faces, positions.shape[0])


# ---------------------------------------------------------------- cameras
def orthographic_camera(px_per_m=720.0, centre=(128.0, 128.0), size=(256, 256)):
    """Calibrated top view: col = cx + px_per_m x, row = cy - px_per_m y.

    centre = (cx, cy) image coordinates (pixels) of the origin; size = (width, height) in pixels.
    """
    try:
        cx, cy = (float(v) for v in centre)
    except (TypeError, ValueError):
        raise InputError(f"orthographic_camera: centre must be a pair (cx, cy) of pixels, got {centre!r}") from None
    width, height = _size(size, "orthographic_camera")
    return native.OrthographicCamera(float(px_per_m), cx, cy, width, height)


def perspective_camera(fov_y=0.5, eye_height=0.7, size=(256, 256)):
    """Eye at (0, 0, eye_height) m looking down -z; vertical field of view fov_y (radians); size (width, height)."""
    width, height = _size(size, "perspective_camera")
    return native.PerspectiveCamera(float(fov_y), float(eye_height), width, height)


def project(camera, points):
    """Image coordinates (N, 2) = (col, row) of (N, 3) points."""
    return _camera(camera).project(_positions(points, "points"))


# ---------------------------------------------------------------- rasterizers
def hard_silhouette(camera, positions, faces):
    """Binary silhouette (H, W) float64 of a mesh seen by the camera."""
    positions, faces = _mesh(positions, faces)
    return native.hard_silhouette(_camera(camera), positions, faces)


class SoftRenderer:
    """Differentiable soft silhouette: ``render(positions, faces)`` then ``backward(grad_image)``.

    sigma: soft edge width in pixels (> 0); profile: "gaussian" (DIB-R, default) or "logistic" (SoftRas);
    epsilon: coverage below which a face is skipped at a pixel, in (0, 0.5).
    """

    def __init__(self, camera, sigma=1.0, profile="gaussian", epsilon=1e-8):
        if profile not in PROFILES:
            raise InputError(f"SoftRenderer: profile must be one of {PROFILES}, got {profile!r}")
        self.camera = _camera(camera)
        self._native = native.SoftRasterizer(self.camera, float(sigma), float(epsilon), profile)
        self._num_vertices = None

    @property
    def sigma(self):
        return self._native.sigma

    @property
    def profile(self):
        return self._native.profile

    @property
    def epsilon(self):
        return self._native.epsilon

    @property
    def cutoff_radius_px(self):
        """Distance (pixels) beyond which a face's coverage is below epsilon and skipped."""
        return self._native.cutoff_radius_px

    @property
    def shape(self):
        """(H, W) of the rendered images."""
        return (self.camera.height, self.camera.width)

    def render(self, positions, faces):
        """Soft occupancy image (H, W) float64 in [0, 1]; keeps what backward needs."""
        positions, faces = _mesh(positions, faces)
        self._num_vertices = None
        image = self._native.forward(positions, faces)
        self._num_vertices = positions.shape[0]
        return image

    def backward(self, grad_image):
        """dL/dpositions (V, 3) of the last render, given dL/dimage of shape (H, W)."""
        if self._num_vertices is None:
            raise InputError("SoftRenderer.backward: call render() first")
        grad = np.asarray(grad_image)
        if grad.shape != self.shape:
            raise InputError(f"SoftRenderer.backward: grad_image must have the image shape {self.shape}, "
                             f"got {grad.shape}")
        if not (np.issubdtype(grad.dtype, np.floating) or np.issubdtype(grad.dtype, np.integer)):
            raise InputError(f"SoftRenderer.backward: grad_image must be numeric, got dtype {grad.dtype}")
        grad = np.ascontiguousarray(grad, dtype=np.float64)
        if not np.isfinite(grad).all():
            raise InputError("SoftRenderer.backward: grad_image has non-finite values")
        return self._native.backward(grad)

    def __repr__(self):
        return f"SoftRenderer({self.camera!r}, sigma={self.sigma}, profile={self.profile!r}, epsilon={self.epsilon})"


def time_soft_render(positions, faces, repeats=20, camera=None, sigma=1.0, profile="gaussian"):
    """Median forward / backward times (ms) of the soft renderer: dict forward_ms, backward_ms, repeats, ..."""
    positions, faces = _mesh(positions, faces)
    if int(repeats) < 1:
        raise InputError(f"time_soft_render: repeats must be at least 1, got {repeats}")
    camera = orthographic_camera() if camera is None else _camera(camera)
    return native.time_soft_render(positions, faces, int(repeats), camera, float(sigma), profile)
