"""Measurement side of drapelab: images -> silhouettes -> rotation-free drape measures (bpy-free facade).

Arrays in and out are numpy: images and masks (H, W) float64 with rows top to bottom, curves (N,) float64,
meshes (V, 3) float64 metres and (F, 3) int32. Errors in the input raise ``InputError`` (a ValueError)
naming the file or argument and the problem.

Calibration (orthographic top view, ``Calibration(px_per_m, cx, cy)``):
    col = cx + px_per_m x,  row = cy - px_per_m y   (continuous pixel coordinates, x right, y up).
The bundled dataset is 720 px/m with the centre at the image centre, the default. A calibration is
given, or estimated with ``calibrate_from_disk`` (undraped specimen of known diameter) or
``calibrate_from_mesh`` (a reference 3D mesh of the same drape).

Silhouette value s in [0, 1] (1 = cloth): s = 1 - L for dark cloth on a light table, s = L for the
reverse (detected from the image border), L = mean(R, G, B) (alpha composited over white). The
threshold is automatic (Otsu refined by ISODATA: 0.5 on the dataset's clean silhouettes) or given.

Metrics (formula; unit):
    pixel_mse          mean over all pixels of (a - b)^2; unitless
    iou                |A n B| / |A u B| of the masks {a > 0.5}, {b > 0.5}; unitless
    drape_coefficient  (A_shadow - A_disk) / (A_specimen - A_disk), BS EN ISO 9073-9, A_disk = pi 0.09^2,
                       A_specimen = pi 0.15^2 m^2, A_shadow = pixels / px_per_m^2; unitless
    r_theta            per angle theta_k = 2 pi k / N (counter-clockwise from +x), the largest radius along
                       the ray from the centre that is inside the mask (the outer boundary); m
    node_count         maxima of r(theta) smoothed by a circular Gaussian (sigma 2 deg) whose prominence is
                       at least max(2 mm, 10 % of its peak-to-trough range); count
    node_amplitude     (mean r at the nodes - mean r at the deepest points between them) / 2; m
    harmonics          |DFT(r)|: a_0 = |R_0| / N (mean radius), a_k = 2 |R_k| / N (cosine amplitude); m
    r_theta_rmse       min over circular shifts of sqrt(mean (measured - model shifted)^2); m
    hausdorff_distance max of the two directed distances, from each mesh's vertices to the other's
                       triangles ("surface", exact point-triangle) or vertices ("vertices"); m
"""
import json
import os
import tempfile

import numpy as np

from ._native import InputError, native

__all__ = [
    "DATASET_PX_PER_M", "Calibration", "InputError", "calibration", "read_image", "write_image", "to_luminance",
    "extract_silhouette", "load_silhouette", "automatic_threshold", "calibrate_from_disk", "calibrate_from_mesh",
    "check_cusick_calibration", "pixel_mse", "iou", "shadow_area", "drape_coefficient",
    "drape_coefficient_from_area", "r_theta",
    "analyse_nodes", "node_count", "node_amplitude", "harmonics", "two_fold", "r_theta_rmse", "hausdorff_distance",
    "measure_silhouette", "measure_image", "compare_mesh_image", "load_manifest", "check_output_path", "write_json",
    "write_overlay",
]

DATASET_PX_PER_M = native.DATASET_PX_PER_M
Calibration = native.Calibration

# Overlay colours (Okabe-Ito, colour-blind safe): measured only, model only, both.
OVERLAY_COLOURS = {"measured only": (0 / 255, 114 / 255, 178 / 255),
                   "model only": (213 / 255, 94 / 255, 0 / 255),
                   "both": (0.70, 0.70, 0.70)}


# ---------------------------------------------------------------- argument checks
def _image2d(a, name):
    arr = np.asarray(a)
    if arr.ndim != 2 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"{name}: expected a non-empty 2D array (H, W), got shape {arr.shape}")
    if arr.dtype == bool:
        arr = arr.astype(np.float64)
    if not np.issubdtype(arr.dtype, np.number):
        raise InputError(f"{name}: expected a numeric array, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: array has non-finite values")
    return arr


def _curve(r, name):
    arr = np.ascontiguousarray(np.asarray(r, dtype=np.float64))
    if arr.ndim != 1 or arr.size < 3:
        raise InputError(f"{name}: expected a 1D r(theta) array with at least 3 samples, got shape {arr.shape}")
    return arr


def _mesh(mesh, name):
    """(positions, faces) from a native TriangleMesh, an OBJ path or a (positions, faces) pair."""
    if isinstance(mesh, (str, os.PathLike)):
        mesh = native.read_obj(os.fspath(mesh))
    if hasattr(mesh, "positions") and hasattr(mesh, "faces"):
        positions, faces = mesh.positions, mesh.faces
    else:
        try:
            positions, faces = mesh
        except (TypeError, ValueError):
            raise InputError(f"{name}: expected a mesh, an OBJ path or a (positions, faces) pair") from None
    positions = np.ascontiguousarray(np.asarray(positions, dtype=np.float64))
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise InputError(f"{name}: positions must have shape (V, 3), got {positions.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"{name}: faces must be an integer array of shape (F, 3), got {faces.shape} {faces.dtype}")
    return positions, np.ascontiguousarray(faces, dtype=np.int32)


def calibration(px_per_m=DATASET_PX_PER_M, centre=None):
    """A Calibration; centre (cx, cy) in pixels, None = the image centre."""
    if centre is None:
        return Calibration(float(px_per_m))
    cx, cy = (float(v) for v in centre)
    return Calibration(float(px_per_m), cx, cy)


# ---------------------------------------------------------------- images and silhouettes
def read_image(path):
    """Luminance in [0, 1] of an image file (PNG, JPEG, TIFF, OpenEXR or uncompressed BMP, recognised by content;
    at most 32768 px a side and 64 Mpx) and a dict describing the file."""
    return native.read_luminance(os.fspath(path))


def write_image(path, image, pixel_type="uint8", channels=1):
    """Writes a (H, W) array in [0, 1] as grey (1), RGB (3) or RGBA (4); format from the extension."""
    native.write_image(os.fspath(path), _image2d(image, "write_image"), pixel_type, int(channels))


def to_luminance(image):
    """Luminance in [0, 1] of an in-memory image: (H, W), (H, W, 1|2|3|4); integer or float pixels.

    Same rule as file import: integers are divided by their type's maximum, floats above 1 by their peak,
    L = mean of the colour channels, alpha (2nd or 4th channel) composited over white.
    """
    arr = np.asarray(image)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 2, 3, 4) or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"image: expected shape (H, W) or (H, W, 1..4), got {np.asarray(image).shape}")
    if arr.dtype == bool:
        arr = arr.astype(np.float64)
    elif np.issubdtype(arr.dtype, np.integer):
        arr = arr.astype(np.float64) / np.iinfo(arr.dtype).max
    elif np.issubdtype(arr.dtype, np.floating):
        arr = arr.astype(np.float64)
    else:
        raise InputError(f"image: unsupported dtype {arr.dtype}")
    if not np.all(np.isfinite(arr)):
        raise InputError("image: array has non-finite values")
    has_alpha = arr.shape[2] in (2, 4)
    colour = arr[:, :, :-1] if has_alpha else arr
    lum = np.maximum(colour.mean(axis=2), 0.0)
    if lum.max() > 1.0:
        lum = lum / lum.max()
    if has_alpha:
        a = np.clip(arr[:, :, -1], 0.0, 1.0)
        lum = a * lum + (1.0 - a)
    return np.ascontiguousarray(lum)


def _silhouette_kwargs(threshold, polarity, keep_central_region, max_hole_fraction, min_contrast):
    return dict(threshold=-1.0 if threshold is None else float(threshold), polarity=polarity,
                keep_central_region=bool(keep_central_region), max_hole_fraction=float(max_hole_fraction),
                min_contrast=float(min_contrast))


def extract_silhouette(image, calibration=None, *, threshold=None, polarity="auto", keep_central_region=True,
                       max_hole_fraction=0.05, min_contrast=0.1, source="image"):
    """Silhouette (mask 1 = cloth, cloth_value, threshold, calibration, ...) of an in-memory image.

    threshold None = automatic; polarity "auto" | "dark_on_light" | "light_on_dark".
    """
    return native.extract_silhouette(to_luminance(image), calibration, source=str(source),
                                     **_silhouette_kwargs(threshold, polarity, keep_central_region,
                                                          max_hole_fraction, min_contrast))


def load_silhouette(path, calibration=None, *, threshold=None, polarity="auto", keep_central_region=True,
                    max_hole_fraction=0.05, min_contrast=0.1):
    """Silhouette of an image file; errors name the file."""
    return native.load_silhouette(os.fspath(path), calibration,
                                  **_silhouette_kwargs(threshold, polarity, keep_central_region,
                                                       max_hole_fraction, min_contrast))


def automatic_threshold(values):
    """Otsu's threshold of values in [0, 1], refined by the ISODATA fixed point."""
    return native.automatic_threshold(_image2d(values, "automatic_threshold"))


def _mask_of(mask_or_path, name):
    if isinstance(mask_or_path, (str, os.PathLike)):
        return load_silhouette(mask_or_path).mask
    if hasattr(mask_or_path, "mask"):
        return mask_or_path.mask
    return _image2d(mask_or_path, name)


# ---------------------------------------------------------------- calibration
def calibrate_from_disk(mask_or_path, diameter_m=0.30, max_roundness_error=0.1):
    """Calibration from an undraped specimen of known diameter (default the Cusick 30 cm disk).

    A path is read with the default (dataset) calibration only to find the region; the result replaces it.
    """
    mask = _mask_of(mask_or_path, "calibrate_from_disk")
    source = os.fspath(mask_or_path) if isinstance(mask_or_path, (str, os.PathLike)) else "image"
    return native.calibrate_from_disk(mask, float(diameter_m), source, float(max_roundness_error))


def calibrate_from_mesh(mask_or_path, mesh):
    """(Calibration, iou): scale and centre making the mesh's orthographic shadow match the silhouette."""
    mask = _mask_of(mask_or_path, "calibrate_from_mesh")
    positions, faces = _mesh(mesh, "calibrate_from_mesh")
    source = os.fspath(mask_or_path) if isinstance(mask_or_path, (str, os.PathLike)) else "image"
    return native.calibrate_from_mesh(mask, positions, faces, source)


def check_cusick_calibration(mask, calibration=None, source="image"):
    """Raises InputError when the silhouette is implausible for a Cusick test under the calibration."""
    mask = _image2d(mask, "check_cusick_calibration")
    cal = native.resolve_calibration(calibration or Calibration(), mask.shape[1], mask.shape[0], str(source))
    native.check_cusick_calibration(mask, cal, str(source))


# ---------------------------------------------------------------- metrics
def pixel_mse(a, b):
    """Mean over all pixels of (a - b)^2 (unitless)."""
    return native.pixel_mse(_image2d(a, "pixel_mse: a"), _image2d(b, "pixel_mse: b"))


def iou(a, b):
    """|A n B| / |A u B| of the masks a > 0.5 and b > 0.5."""
    return native.iou(_image2d(a, "iou: a"), _image2d(b, "iou: b"))


def shadow_area(mask, px_per_m=DATASET_PX_PER_M):
    """Shadow area (m^2) of a mask under an orthographic calibration."""
    return native.shadow_area(_image2d(mask, "shadow_area"), float(px_per_m))


def drape_coefficient(mask, px_per_m=DATASET_PX_PER_M, support_radius=0.09, specimen_radius=0.15):
    """(A_shadow - A_disk) / (A_specimen - A_disk) of a mask (unitless)."""
    return native.drape_coefficient(_image2d(mask, "drape_coefficient"), float(px_per_m),
                                    float(support_radius), float(specimen_radius))


def drape_coefficient_from_area(area_m2, support_radius=0.09, specimen_radius=0.15):
    """(A - A_disk) / (A_specimen - A_disk) of a shadow area A (m^2), e.g. a soft silhouette's summed coverage."""
    return native.drape_coefficient_from_area(float(area_m2), float(support_radius), float(specimen_radius))


def r_theta(mask, calibration=None, samples=360, step_px=0.1):
    """Radius-angle curve (m) about the calibrated centre: outer boundary along each of `samples` rays."""
    return native.radius_angle_curve(_image2d(mask, "r_theta"), calibration, int(samples), float(step_px))


def analyse_nodes(r, smoothing_deg=2.0, min_prominence_m=0.002, min_relative_prominence=0.1):
    """NodeAnalysis (count, amplitude_m, angles_rad, prominences_m, smoothed) of an r(theta) curve."""
    return native.analyse_nodes(_curve(r, "analyse_nodes"), smoothing_deg=float(smoothing_deg),
                                min_prominence_m=float(min_prominence_m),
                                min_relative_prominence=float(min_relative_prominence))


def node_count(r, **options):
    """Number of nodes (folds) of r(theta); see analyse_nodes for the options."""
    return analyse_nodes(r, **options).count


def node_amplitude(r, **options):
    """Node amplitude (m) of r(theta); see analyse_nodes."""
    return analyse_nodes(r, **options).amplitude_m


def harmonics(r, count=20):
    """Harmonic amplitudes a_0..a_{count-1} (m) of r(theta)."""
    return native.harmonic_spectrum(_curve(r, "harmonics"), int(count))


def two_fold(r):
    """(amplitude m, axis degrees mod 180) of the k = 2 harmonic of r(theta): how much longer the drape is along one
    axis, and that axis, in r_theta's angle (harmonics gives amplitudes only; the axis needs the phase)."""
    rt = _curve(r, "two_fold")
    c = np.exp(-2j * np.arange(rt.size) * 2 * np.pi / rt.size) @ rt * 2 / rt.size  # = amplitude e^(-2i axis)
    axis = float(-np.degrees(np.angle(c)) / 2 % 180)
    return float(abs(c)), (0.0 if axis >= 180 else axis)  # -1e-15 % 180 rounds to 180


def r_theta_rmse(measured, model):
    """(rmse_m, rotation_rad): r(theta) RMSE after the best circular shift of the model curve."""
    a = native.r_theta_rmse(_curve(measured, "r_theta_rmse: measured"), _curve(model, "r_theta_rmse: model"))
    return a.rmse_m, a.rotation_rad


def hausdorff_distance(mesh_a, mesh_b, mode="surface"):
    """Symmetric Hausdorff distance (m) between two meshes (paths, meshes or (positions, faces))."""
    pa, fa = _mesh(mesh_a, "hausdorff_distance: mesh_a")
    pb, fb = _mesh(mesh_b, "hausdorff_distance: mesh_b")
    return native.hausdorff_distance(pa, fa, pb, fb, mode)


# ---------------------------------------------------------------- aggregates
def measure_silhouette(silhouette, harmonics_count=20, r_theta_samples=360):
    """Dict of rotation-free measures of a native Silhouette (see measure_image)."""
    m = native.measure_drape(silhouette.mask, silhouette.calibration, r_theta_samples=int(r_theta_samples),
                             harmonics=int(harmonics_count))
    return {
        "drape_coefficient": float(m.drape_coefficient),
        "node_count": int(m.nodes.count),
        "node_amplitude_m": float(m.nodes.amplitude_m),
        "area_px": int(m.area_px),
        "px_per_m": float(m.px_per_m),
        "centre_px": [float(v) for v in m.centre_px],
        "r_theta_m": [float(v) for v in m.r_theta_m],
        "harmonics": [float(v) for v in m.harmonics_m],
        "threshold": float(silhouette.threshold),
        "dark_on_light": bool(silhouette.dark_on_light),
    }


def measure_image(path, calibration=None, check_calibration=True, **silhouette_options):
    """Measures one image file: a JSON-ready dict with `image` (the path as given), drape_coefficient,
    node_count, node_amplitude_m, area_px, px_per_m, centre_px [cx, cy], r_theta_m (360 values, m),
    harmonics (a_0..a_19, m), threshold, dark_on_light. With check_calibration, an implausible
    silhouette for a Cusick test (see check_cusick_calibration) raises InputError naming the file."""
    sil = load_silhouette(path, calibration, **silhouette_options)
    if check_calibration:
        native.check_cusick_calibration(sil.mask, sil.calibration, os.fspath(path))
    return {"image": os.fspath(path), **measure_silhouette(sil)}


def compare_mesh_image(mesh, image_path, camera="ortho", calibration=None, **silhouette_options):
    """Compares a 3D drape with a measured silhouette.

    Returns (metrics dict, measured mask, model mask). The metrics: iou, mse (binary silhouettes, model
    under `camera`), drape_coefficient_mesh / _image, node_count_mesh / _image, r_theta_rmse_m and
    r_theta_rotation_deg (mesh measures from its orthographic top-down shadow at the image's calibration).
    """
    if camera not in ("ortho", "perspective"):
        raise InputError(f"camera must be 'ortho' or 'perspective', not {camera!r}")
    positions, faces = _mesh(mesh, "compare")
    sil = load_silhouette(image_path, calibration, **silhouette_options)
    c = native.compare_mesh_to_silhouette(positions, faces, sil, camera)
    metrics = {
        "iou": float(c.iou),
        "mse": float(c.mse),
        "drape_coefficient_mesh": float(c.mesh.drape_coefficient),
        "drape_coefficient_image": float(c.image.drape_coefficient),
        "node_count_mesh": int(c.mesh.nodes.count),
        "node_count_image": int(c.image.nodes.count),
        "r_theta_rmse_m": float(c.r_theta.rmse_m),
        "r_theta_rotation_deg": float(np.degrees(c.r_theta.rotation_rad)),
        "camera": camera,
        "px_per_m": float(sil.calibration.px_per_m),
        "centre_px": [float(sil.calibration.cx), float(sil.calibration.cy)],
    }
    return metrics, np.asarray(sil.mask), np.asarray(c.model_mask)


def load_manifest(path, check_files=False):
    """Rows of a manifest.csv dataset as dicts (paths resolved against the manifest's folder; mesh None
    when absent)."""
    rows = native.read_manifest(os.fspath(path), bool(check_files))
    return [{"fabric": e.fabric, "name": e.name, "material": e.material, "weave": e.weave,
             "density_kg_m2": e.density_kg_m2, "thickness_mm": e.thickness_mm, "sample": e.sample,
             "capture": e.capture, "silhouette": e.silhouette, "mesh": e.mesh or None} for e in rows]


# ---------------------------------------------------------------- outputs
def check_output_path(path, what="output"):
    """Raises OSError naming `path` when it cannot be an output file (a folder, or in a missing or
    read-only folder); called before long work so that it fails early."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path):
        raise OSError(f"{path}: cannot write {what}: it is a directory")
    if not os.path.isdir(folder):
        raise OSError(f"{path}: cannot write {what}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise OSError(f"{path}: cannot write {what}: folder {folder} is not writable")
    return path, folder


def _atomic_write(path, what, suffix, write):
    """Calls write(temporary_path) for a temporary file beside `path`, then renames it into place."""
    path, folder = check_output_path(path, what)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=".tmp_", suffix=suffix, dir=folder)
        os.close(fd)
        write(tmp)
        umask = os.umask(0)  # mkstemp makes the file private (0600); give it the permissions a plain open would
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except OSError as e:
        raise OSError(f"{path}: cannot write {what}: {e.strerror or e}") from None
    finally:
        if tmp is not None and os.path.exists(tmp):
            try:
                os.unlink(tmp)
            except OSError:
                pass


def write_json(path, data):
    """Writes `data` as JSON atomically (temporary file in the same folder, then os.replace)."""
    text = json.dumps(data, indent=1, allow_nan=False) + "\n"

    def write(tmp):
        with open(tmp, "w") as f:
            f.write(text)
    _atomic_write(path, "JSON", ".json", write)


def overlay_rgb(measured, model):
    """(H, W, 3) float image: white = neither, and OVERLAY_COLOURS for measured only, model only, both."""
    a = _image2d(measured, "overlay: measured") > 0.5
    b = _image2d(model, "overlay: model") > 0.5
    if a.shape != b.shape:
        raise InputError(f"overlay: mask shapes differ ({a.shape} vs {b.shape})")
    rgb = np.ones(a.shape + (3,))
    rgb[a & ~b] = OVERLAY_COLOURS["measured only"]
    rgb[b & ~a] = OVERLAY_COLOURS["model only"]
    rgb[a & b] = OVERLAY_COLOURS["both"]
    return rgb


def write_overlay(path, measured, model, title=None, notes=None, calibration=None, support_radius=0.09,
                  specimen_radius=0.15):
    """PNG overlay of a measured and a model silhouette with a legend (pixel counts), the support disk and
    flat specimen outlines (dashed, when a calibration is given) and optional note lines."""
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.patches import Circle, Patch

    rgb = overlay_rgb(measured, model)
    a, b = np.asarray(measured) > 0.5, np.asarray(model) > 0.5
    counts = {"measured only": int((a & ~b).sum()), "model only": int((b & ~a).sum()), "both": int((a & b).sum())}
    h, w = a.shape
    fig = Figure(figsize=(6.4, 4.4), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_axes([0.02, 0.03, 0.62, 0.85])
    ax.imshow(rgb, interpolation="nearest", extent=(0, w, h, 0))
    if calibration is not None:
        for radius in (support_radius, specimen_radius):
            ax.add_patch(Circle((calibration.cx, calibration.cy), radius * calibration.px_per_m, fill=False,
                                ls="--", lw=0.8, ec=(0.5, 0.5, 0.5)))
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=9)
    handles = [Patch(facecolor=OVERLAY_COLOURS[k], edgecolor="black", lw=0.5, label=f"{k} ({counts[k]} px)")
               for k in ("measured only", "model only", "both")]
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=(0.66, 0.9), fontsize=8, frameon=False,
               title="silhouette pixels", title_fontsize=8)
    if notes:
        fig.text(0.67, 0.62, "\n".join(notes), fontsize=8, va="top", family="monospace")
    if calibration is not None:
        fig.text(0.67, 0.06, "dashed: support disk and\nflat specimen outlines", fontsize=7, color=(0.4, 0.4, 0.4))
    _atomic_write(path, "overlay", ".png", lambda tmp: fig.savefig(tmp, format="png"))
