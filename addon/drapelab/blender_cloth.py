"""A drapelab preset as Blender 3.4's own cloth modifier settings (bpy-free; the add-on applies the dict).

Blender's cloth (source/blender/simulation/intern/SIM_mass_spring.cc, blenkernel/intern/cloth.cc) is a
mass-spring model in its own units; the derivation of every number below is in docs/lab/blender-cloth.md:

- Time runs in frames and gravity is scaled by 0.001 (cloth_calc_force), so a Blender force is 1e-3 N for a
  mass in kg: statics match SI when every stiffness is divided by 1000 (BLENDER_FORCE_SCALE), and one frame is
  sqrt(1e-3) s = 31.6 ms of physical time (time_scale brings it to the scene's frame rate).
- ``mass`` is the mass of each vertex (kg): density x mesh area / vertex count.
- Tension and compression: every mesh edge is a spring of force k (L - L0) with k = stiffness / mean edge
  length. An equilateral triangle lattice of such springs has the 2D modulus Y = 2 k / sqrt(3), so
  stiffness = sqrt(3)/2 Y a / 1000 with Y our small-strain c11, c22 (N/m) and a the mean edge length (m).
  Shear springs exist only across quads (triangle meshes shear through their edges, G = 3/8 Y).
- Bending (angular model): a hinge of rest length L between faces of heights h_a, h_b gets the moment
  0.1 b L h / 3 per radian (force k = 0.1 b L along the face normals, a third on each opposite vertex);
  drapelab's hinge has the moment k_w L / (2 (h1 + h2)). Equal moments give b = 0.015 k_w / (h (h1 + h2)),
  so Blender's bending parameter depends on the mesh's resolution (as 1/h^2), unlike drapelab's tables.
  Blender's hinge is linear, drapelab's tables depend on curvature: k_w is the energy-matched (secant)
  stiffness of the table on the preset's own Cusick drape (or the table at a given curvature), then one
  empirical factor (BEND_CALIBRATION) measured on real Cusick drapes.
- Damping: Blender's damping forces do not scale with mass, so they are set as fractions of critical damping
  (springs) and as a drag rate (air), from the vertex mass, not copied from Blender's presets.

Per-element materials become vertex groups: Blender interpolates a spring's stiffness between the base value
and ``*_stiffness_max`` with the mean of its two end weights; ``vertex_group_weights`` finds vertex weights in
[0, 1] whose end-point means fit the per-spring targets in least squares.
"""
import math

import numpy as np

from . import infer, tables
from ._native import InputError

__all__ = ["cloth_settings", "vertex_group_weights", "mesh_statistics", "secant_bending", "blender_preset",
           "BLENDER_PRESETS",
           "REFERENCE_CURVATURE_PER_M", "BEND_CALIBRATION", "DEFAULT_QUALITY"]

BLENDER_FORCE_SCALE = 1e-3          # cloth_calc_force: gravity x 0.001 (forces in mN for masses in kg)
ANGULAR_BEND_SCALE = 0.1            # cloth_calc_spring_force: k = bending * restlen * 0.1
LATTICE_SPRING_FACTOR = math.sqrt(3.0) / 2.0   # spring constant / (2D modulus x edge) of a triangle lattice
FRAME_SECONDS = math.sqrt(BLENDER_FORCE_SCALE)  # physical seconds of one Blender cloth frame at time_scale 1
DEFAULT_QUALITY = 5                 # Blender's default steps per frame
# Table curvature (the tables' measure alpha = |sin(theta/2)| / (h1 + h2), 1/m) at which the bending table is
# read when a fixed curvature is asked for (curvature=...): column 3, near the energy-weighted alpha of the
# shipped presets' drapes (7.8-12.8 1/m, fabric 3 25.6). The default is the energy-matched (secant) stiffness
# of the preset's own Cusick drape (secant_bending), docs/lab/blender-cloth.md.
REFERENCE_CURVATURE_PER_M = 7.5
SECANT_MESH_LEVEL = 3               # the Cusick template the secant drape runs on (the presets' mesh)
BEND_CALIBRATION = 0.75             # empirical factor on the derived bending, fitted on fabrics 1-5 (docs/lab/blender-cloth.md)
SPRING_DAMPING_RATIO = 0.1          # tension/compression/shear damping as a fraction of a spring's critical
BEND_DAMPING_RATIO = 0.1            # bending damping as a fraction of a hinge's critical damping
# air drag rate (1/s): linearised air drag of a 0.2 kg/m^2 fabric moving at 0.3-1 m/s is 1-4 /s (Blender's Cotton
# preset: 0.01 * 1 / 0.3 kg per time unit = 1.05 /s)
AIR_DRAG_PER_S = 2.0
PIN_GROUP = "drapelab_pin"
STIFFNESS_GROUPS = {"tension": "drapelab_tension", "shear": "drapelab_shear", "bending": "drapelab_bending"}
BLENDER_PRESETS = ("cotton", "denim", "leather", "rubber", "silk")
_BLENDER_SETTING_MAX = 10000.0      # RNA hard maximum of the stiffness settings


def _check_mesh(positions, faces, name="mesh"):
    try:
        x = np.asarray(positions, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} positions: expected an array of numbers (V, 3)") from None
    f = np.asarray(faces)
    if x.ndim != 2 or x.shape[1] != 3 or x.shape[0] < 3:
        raise InputError(f"{name} positions: expected shape (V, 3) with V >= 3, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise InputError(f"{name} positions: contain NaN or infinity")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"{name} faces: expected an integer array (F, 3) of triangles, got {f.dtype} {f.shape}")
    if f.min() < 0 or f.max() >= x.shape[0]:
        raise InputError(f"{name} faces: vertex indices must lie in [0, {x.shape[0]})")
    return x, f.astype(np.int64)


def _edges(faces):
    """Unique undirected edges (E, 2), and per edge its faces (E, 2; -1 on the boundary) and opposite vertices."""
    corners = np.concatenate([faces[:, [0, 1, 2]], faces[:, [1, 2, 0]], faces[:, [2, 0, 1]]])  # (a, b, opposite)
    face_of = np.tile(np.arange(len(faces)), 3)
    key = np.sort(corners[:, :2], axis=1)
    edges, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if counts.max() > 2:
        raise InputError("mesh: non-manifold edges (an edge shared by more than two triangles)")
    order = np.argsort(inverse, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    edge_faces = np.full((len(edges), 2), -1, dtype=np.int64)
    opposite = np.full((len(edges), 2), -1, dtype=np.int64)
    edge_faces[:, 0] = face_of[order[starts]]
    opposite[:, 0] = corners[order[starts], 2]
    two = counts == 2
    edge_faces[two, 1] = face_of[order[starts[two] + 1]]
    opposite[two, 1] = corners[order[starts[two] + 1], 2]
    return edges, edge_faces, opposite


def mesh_statistics(positions, faces):
    """The mesh numbers Blender's cloth units depend on (rest = the given positions, metres):
    vertices, area_m2, mean_edge_m (Blender's avg_spring_len), and per interior edge (hinge) its length,
    its faces' heights h1, h2 over it, and its end vertices."""
    x, f = _check_mesh(positions, faces)
    edges, edge_faces, opposite = _edges(f)
    e = x[edges[:, 1]] - x[edges[:, 0]]
    length = np.linalg.norm(e, axis=1)
    if np.any(length <= 1e-9 * length.mean()):
        raise InputError("mesh: degenerate edges of zero length")
    areas = 0.5 * np.linalg.norm(np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]]), axis=1)
    if np.any(areas <= 1e-9 * areas.mean()):
        raise InputError("mesh: degenerate triangles of zero area")
    interior = edge_faces[:, 1] >= 0
    h = np.zeros((len(edges), 2))
    for s in range(2):
        ok = edge_faces[:, s] >= 0
        h[ok, s] = 2.0 * areas[edge_faces[ok, s]] / length[ok]
    return {
        "vertices": int(x.shape[0]),
        "faces": int(f.shape[0]),
        "area_m2": float(areas.sum()),
        "mean_edge_m": float(length.mean()),
        "edges": edges,
        "hinge_edges": edges[interior],
        "hinge_length_m": length[interior],
        "hinge_heights_m": h[interior],
        "face_areas_m2": areas,
    }


def _bend_at(table, curvature):
    """A (..., 3, 5) bending table read at the curvature measure `curvature` (1/m) as the native term does
    (columns every kBendSampleCurvature = 2.5 1/m, C1 smoothstep between them, clamped), mean over the bias rows."""
    t = np.asarray(table, dtype=float)
    g = min(max(curvature / 2.5, 0.0), 4.0)
    i0 = min(int(g), 3)
    s = g - i0
    s = 3 * s * s - 2 * s ** 3
    return ((1 - s) * t[..., i0] + s * t[..., i0 + 1]).mean(axis=-1)


_SECANT_CACHE = {}


def secant_bending(preset, level=None):
    """The energy-matched stiffness of the preset's bending table on its own Cusick drape: drapelab drapes the
    preset's posterior median on circle{level} (100 steps of 0.05 s, a few seconds), and returns
    (k_secant (N m), alpha_w (1/m)) with k_secant = sum_w k_w(alpha_w) E1_w / sum_w E1_w, E1_w = the hinge energy
    at unit stiffness (L / (2 (h1 + h2)) theta^2 / 2): the linear hinge stiffness that stores the drape's bending
    energy, and alpha_w the energy-weighted curvature measure. Cached per table, stretching, density and level."""
    from . import sim
    preset = _preset_arg(preset)
    level = SECANT_MESH_LEVEL if level is None else level
    bend = np.exp(np.asarray(preset["posterior"]["bend"]["log_mean"], dtype=float))
    stretch = np.asarray(preset["stretch_N_m"], dtype=float)
    density = float(preset["density_kg_m2"])
    key = (bend.tobytes(), stretch.tobytes(), density, int(level))
    if key not in _SECANT_CACHE:
        model = sim.ClothModel(sim.cusick_specimen(level), density=density)
        x = np.asarray(model.simulate(model.parameters(stretch=stretch, bend=bend)))
        rest = np.asarray(model.rest_positions)
        a, b, c, d = np.asarray(model.bending_edges).T
        e = rest[b] - rest[a]
        length = np.linalg.norm(e, axis=1)
        h1 = np.linalg.norm(np.cross(e, rest[c] - rest[a]), axis=1) / length
        h2 = np.linalg.norm(np.cross(e, rest[d] - rest[a]), axis=1) / length
        e = x[b] - x[a]
        n1, n2 = np.cross(e, x[c] - x[a]), np.cross(x[d] - x[a], e)
        cos = np.sum(n1 * n2, axis=1) / (np.linalg.norm(n1, axis=1) * np.linalg.norm(n2, axis=1))
        theta = np.arccos(np.clip(cos, -1.0, 1.0))
        alpha = np.abs(np.sin(theta / 2)) / (h1 + h2)
        unit_energy = length / (2 * (h1 + h2)) * theta ** 2 / 2
        k = np.array([_bend_at(bend, v) for v in alpha])
        total = float(unit_energy.sum())
        if not np.isfinite(total) or total <= 0:
            raise InputError("preset: its Cusick drape does not bend (no bending energy): cannot read its table")
        _SECANT_CACHE[key] = (float(np.sum(k * unit_energy) / total), float(np.sum(alpha * unit_energy) / total))
    return _SECANT_CACHE[key]


def _hinge_bending(k_N_m, stats):
    """Blender's bending setting per hinge for drapelab's hinge stiffness k (N m) (module docstring)."""
    L = stats["hinge_length_m"]
    h1, h2 = stats["hinge_heights_m"].T
    hbar = 0.5 * (h1 + h2)
    # moment per radian: Blender (in SI) 1000 * 0.1 b L hbar / 3; drapelab k L / (2 (h1 + h2))
    return k_N_m * L / (2.0 * (h1 + h2)) / (ANGULAR_BEND_SCALE / 3.0 * L * hbar / BLENDER_FORCE_SCALE)


def _bending_per_N_m(stats):
    """Blender's one bending setting per N m of drapelab hinge stiffness on this mesh: the value whose hinge
    moments sum to drapelab's (the moment-weighted mean of the per-hinge settings, which differ only by geometry)."""
    weight = stats["hinge_length_m"] * stats["hinge_heights_m"].mean(axis=1)
    return float(np.sum(_hinge_bending(1.0, stats) * weight) / np.sum(weight))


def _preset_arg(preset):
    if isinstance(preset, dict):
        return infer.validate_preset(preset, "preset")
    if isinstance(preset, (str, bytes)) or hasattr(preset, "__fspath__"):
        return infer.load_preset(preset)
    raise InputError(f"preset: expected a preset dict or a path to a preset JSON, got {type(preset).__name__}")


def _positive(value, name, unit=""):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value) or value <= 0:
        raise InputError(f"{name}: expected a positive number{unit}, got {value!r}")
    return float(value)


def cloth_settings(preset, quality=DEFAULT_QUALITY, *, mesh, fps=24.0, curvature=None,
                   bend_calibration=BEND_CALIBRATION, collision_distance_m=None, pin_group=PIN_GROUP):
    """Blender 3.4 cloth settings for `preset` (dict or path) on `mesh` = (rest positions (V, 3) m, faces (F, 3)).

    Blender's units depend on the mesh (vertex mass, mean edge length, triangle heights), so the mesh the
    modifier will run on is required. Returns a dict: ClothSettings attribute -> value (apply with setattr),
    plus "collision_settings" (ClothCollisionSettings attribute -> value) and "derivation" (the SI numbers
    they came from: not Blender settings). quality: Blender's steps per frame (integer >= 1); fps: the scene
    frame rate that time_scale makes physical; curvature: the table curvature measure (1/m) the bending is
    read at (None: the energy-matched stiffness of the preset's own Cusick drape, ``secant_bending``, which
    drapes it once: a few seconds, cached); collision_distance_m: cloth/body and self-collision distance (default: 0.3 mean edges, 1-15 mm).
    """
    preset = _preset_arg(preset)
    if isinstance(quality, bool) or not isinstance(quality, (int, np.integer)) or quality < 1:
        raise InputError(f"quality: expected an integer >= 1 (Blender's steps per frame), got {quality!r}")
    fps = _positive(fps, "fps", " (frames per second)")
    if curvature is not None:
        curvature = _positive(curvature, "curvature", " (1/m)")
    bend_calibration = _positive(bend_calibration, "bend_calibration")
    if not isinstance(mesh, (tuple, list)) or len(mesh) != 2:
        raise InputError("mesh: expected (positions (V, 3), faces (F, 3)) of the mesh the cloth runs on")
    stats = mesh_statistics(*mesh)
    if len(stats["hinge_length_m"]) == 0:
        raise InputError("mesh: has no interior edge (no two triangles share an edge): nothing can bend")

    density = float(preset["density_kg_m2"])
    mass = density * stats["area_m2"] / stats["vertices"]
    a = stats["mean_edge_m"]
    c11, c12, c22, c33 = (float(v) for v in np.asarray(preset["stretch_N_m"], dtype=float)[0])
    modulus = 0.5 * (c11 + c22)  # Blender's springs are isotropic: the mean of warp and weft
    tension = LATTICE_SPRING_FACTOR * modulus * a * BLENDER_FORCE_SCALE
    # a quad's diagonal springs carry shear: with the same lattice reading, G = c33 and edge a sqrt(2)
    shear = c33 * a * math.sqrt(2.0) * BLENDER_FORCE_SCALE

    if curvature is None:
        k_ref, curvature = secant_bending(preset)
        reading = "secant"
    else:
        bend_table = np.exp(np.asarray(preset["posterior"]["bend"]["log_mean"], dtype=float))  # posterior median
        k_ref = float(_bend_at(bend_table, curvature))
        reading = "curvature"
    bending = k_ref * _bending_per_N_m(stats) * bend_calibration
    for name, value in (("tension_stiffness", tension), ("shear_stiffness", shear), ("bending_stiffness", bending)):
        if value > _BLENDER_SETTING_MAX:
            raise InputError(f"preset: {name} would be {value:.4g}, above Blender's maximum "
                             f"{_BLENDER_SETTING_MAX:g} on this mesh (too stiff for its resolution)")

    # damping, in Blender's time unit (force per m per time unit): critical c = 2 sqrt(k m)
    k_spring = tension / a
    spring_damping = SPRING_DAMPING_RATIO * 2.0 * math.sqrt(k_spring * mass)
    hbar = float(np.mean(stats["hinge_heights_m"]))
    k_hinge = ANGULAR_BEND_SCALE * bending * a / hbar  # normal force per normal displacement of a hinge's tip
    bend_damping = BEND_DAMPING_RATIO * 2.0 * math.sqrt(k_hinge * mass)
    time_scale = (1.0 / fps) / FRAME_SECONDS
    frame_s = FRAME_SECONDS * time_scale
    # drag force = air_damping * 0.01 * velocity, in Blender's time unit (FRAME_SECONDS of physical time)
    air_damping = AIR_DRAG_PER_S * FRAME_SECONDS * mass / 0.01

    if collision_distance_m is None:
        collision_distance_m = min(max(0.3 * a, 0.001), 0.015)
    collision_distance_m = _positive(collision_distance_m, "collision_distance_m", " (m)")
    if not 0.001 <= collision_distance_m <= 0.1:
        raise InputError(f"collision_distance_m: Blender accepts 0.001 to 0.1 m, got {collision_distance_m!r}")

    settings = {
        "quality": int(quality),
        "mass": mass,
        "air_damping": min(air_damping, 10.0),
        "bending_model": "ANGULAR",
        "tension_stiffness": tension, "tension_stiffness_max": tension,
        "compression_stiffness": tension, "compression_stiffness_max": tension,
        "shear_stiffness": shear, "shear_stiffness_max": shear,
        "bending_stiffness": bending, "bending_stiffness_max": bending,
        "tension_damping": spring_damping, "compression_damping": spring_damping, "shear_damping": spring_damping,
        "bending_damping": bend_damping,
        "time_scale": time_scale,
        "vertex_group_mass": pin_group or "",
        "pin_stiffness": 1.0,
        "use_internal_springs": False,
        "use_pressure": False,
        "use_sewing_springs": False,
        "use_dynamic_mesh": False,
        "shrink_min": 0.0,
        "collision_settings": {
            "distance_min": collision_distance_m,
            "self_distance_min": collision_distance_m,
        },
        "derivation": {
            "density_kg_m2": density,
            "area_m2": stats["area_m2"],
            "vertices": stats["vertices"],
            "mean_edge_m": a,
            "mean_hinge_height_m": hbar,
            "membrane_modulus_N_m": modulus,
            "shear_modulus_N_m": c33,
            "poisson_coupling_N_m": c12,
            "bend_reading": reading,
            "bend_curvature_per_m": curvature,
            "bend_stiffness_N_m": k_ref,
            "bend_calibration": bend_calibration,
            "blender_force_scale": BLENDER_FORCE_SCALE,
            "frame_seconds": frame_s,
        },
    }
    return settings


def vertex_group_weights(positions, faces, *, face_stretch_N_m=None, hinge_bend_N_m=None, settings=None,
                         curvature=REFERENCE_CURVATURE_PER_M, bend_calibration=BEND_CALIBRATION, iterations=400):
    """Per-vertex stiffness vertex groups for a per-element material on the mesh (positions, faces).

    face_stretch_N_m: per triangle, its stretch table (F, 6, 4) or small-strain row (F, 4) (N/m);
    hinge_bend_N_m: per interior edge in ``mesh_statistics(...)["hinge_edges"]`` order, its bending table
    (H, 3, 5) or stiffness (H,) (N m). Blender gives a spring the stiffness base + w (max - base) with w the
    mean of its two end weights; each spring's target w is its element value mapped into [min, max] of the
    field, and the vertex weights are the least-squares fit of those means, clipped to [0, 1] (projected
    Jacobi iterations). Returns {"tension"|"bending": {"group": name, "weights": (V,), "min": base, "max": max,
    "rms_error": fit error in setting units}} for the fields given; ranges are in Blender's units on this mesh.
    """
    x, f = _check_mesh(positions, faces)
    stats = mesh_statistics(x, f)
    if settings is not None and not isinstance(settings, dict):
        raise InputError("settings: expected the dict of cloth_settings, or None")
    out = {}
    if face_stretch_N_m is not None:
        s = np.asarray(face_stretch_N_m, dtype=float)
        if s.ndim == 3 and s.shape[1:] == (6, 4):
            s = s[:, 0, :]
        if s.shape != (len(f), 4) or not np.all(np.isfinite(s)):
            raise InputError(f"face_stretch_N_m: expected finite (F, 6, 4) or (F, 4) with F = {len(f)}, got "
                             f"{np.shape(face_stretch_N_m)}")
        if np.any(s[:, [0, 2, 3]] < 0):
            raise InputError("face_stretch_N_m: c11, c22 and c33 must be >= 0")
        modulus = 0.5 * (s[:, 0] + s[:, 2])
        # a structural spring (mesh edge) takes the mean modulus of the faces beside it
        edges, edge_faces, _ = _edges(f)
        m = modulus[edge_faces[:, 0]].copy()
        two = edge_faces[:, 1] >= 0
        m[two] = 0.5 * (m[two] + modulus[edge_faces[two, 1]])
        target = LATTICE_SPRING_FACTOR * m * stats["mean_edge_m"] * BLENDER_FORCE_SCALE
        out["tension"] = _fit_group(edges, target, len(x), STIFFNESS_GROUPS["tension"], iterations)
    if hinge_bend_N_m is not None:
        b = np.asarray(hinge_bend_N_m, dtype=float)
        n = len(stats["hinge_edges"])
        if b.ndim == 3 and b.shape[1:] == tables.BEND_SHAPE:
            b = _bend_at(b, _positive(curvature, "curvature", " (1/m)"))
        if b.shape != (n,) or not np.all(np.isfinite(b)) or np.any(b <= 0):
            raise InputError(f"hinge_bend_N_m: expected positive finite (H, 3, 5) or (H,) with H = {n} interior "
                             f"edges, got shape {np.shape(hinge_bend_N_m)}")
        # the material field only: the per-hinge geometric factor (1/h^2, mesh irregularity) cannot be carried
        # by vertex weights shared between hinges, so every hinge uses the mesh's mean factor, as the scalar does
        target = b * _bending_per_N_m(stats) * _positive(bend_calibration, "bend_calibration")
        out["bending"] = _fit_group(stats["hinge_edges"], target, len(x), STIFFNESS_GROUPS["bending"], iterations)
    if not out:
        raise InputError("vertex_group_weights: give face_stretch_N_m, hinge_bend_N_m or both")
    return out


def _fit_group(edges, target, num_vertices, group, iterations):
    """Vertex weights w in [0, 1] with (w_i + w_j) / 2 ~ (target - lo) / (hi - lo) per spring (least squares)."""
    lo, hi = float(target.min()), float(target.max())
    if hi <= lo * (1 + 1e-9):
        return {"group": group, "weights": np.zeros(num_vertices), "min": lo, "max": hi, "rms_error": 0.0}
    t = (target - lo) / (hi - lo)
    i, j = edges[:, 0], edges[:, 1]
    degree = np.bincount(i, minlength=num_vertices) + np.bincount(j, minlength=num_vertices)
    # start: each vertex the mean target of its springs (exact for a field that is smooth at the vertex)
    w = (np.bincount(i, t, num_vertices) + np.bincount(j, t, num_vertices)) / np.maximum(degree, 1)
    for _ in range(int(iterations)):
        r = 0.5 * (w[i] + w[j]) - t
        g = np.bincount(i, r, num_vertices) + np.bincount(j, r, num_vertices)
        # Jacobi step on the normal equations: diagonal 0.5 * degree (each spring adds 1/4 to w_i's row, x2)
        w = np.clip(w - g / np.maximum(0.5 * degree, 1e-12) * 0.5, 0.0, 1.0)
    r = 0.5 * (w[i] + w[j]) - t
    return {"group": group, "weights": w, "min": lo, "max": hi,
            "rms_error": float(np.sqrt(np.mean(r ** 2)) * (hi - lo))}


def blender_preset(name):
    """The settings of one of Blender's shipped cloth presets (scripts/presets/cloth/NAME.py), read from the file
    Blender ships (found with ``blender_preset_path``); returns {setting: value}."""
    path = blender_preset_path(name)
    out = {}
    with open(path) as f:
        for line in f:
            line = line.strip()
            prefix = "bpy.context.cloth.settings."
            if line.startswith(prefix) and "=" in line:
                key, value = (p.strip() for p in line[len(prefix):].split("=", 1))
                out[key] = float(value) if key != "quality" else int(float(value))
    if not out:
        raise InputError(f"{path}: no cloth settings found")
    return out


def blender_preset_path(name, search=None):
    """Path of Blender's shipped cloth preset NAME (cotton, denim, leather, rubber, silk)."""
    import glob
    import os
    if not isinstance(name, str) or name.lower() not in BLENDER_PRESETS:
        raise InputError(f"blender preset: expected one of {', '.join(BLENDER_PRESETS)}, got {name!r}")
    roots = list(search or []) + ["/usr/share/blender/scripts", "/usr/share/blender/*/scripts",
                                  "/usr/lib/blender/scripts", "/usr/local/share/blender/*/scripts"]
    for root in roots:
        for folder in sorted(glob.glob(root)):
            path = os.path.join(folder, "presets", "cloth", name.capitalize() + ".py")
            if os.path.isfile(path):
                return path
    raise InputError(f"blender preset {name!r}: Blender's presets/cloth/{name.capitalize()}.py not found "
                     f"(searched {', '.join(roots)})")
