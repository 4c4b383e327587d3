"""Garment meshes: a 3D placement plus the flat sewing pattern each triangle is cut from.

A ``Garment`` holds (all lengths in metres)
    positions        (V, 3) float64  3D placement
    uv               (V, 2) float64  flat pattern coordinates: u = weft, v = warp (the grain line runs along +v)
    faces            (F, 3) int32    counter-clockwise in uv
    seams            (S, 2) int32    pairs of vertices that are one point of the sewn garment: each pattern piece
                                     is its own uv island, so a vertex on a seam exists once per piece
    waist_vertices   (W,) int32      vertices attached to the body
    hem_vertices     (H,) int32      the free bottom edge
    name             str
    source_vertices  (V,) int32      the input vertex each vertex comes from (``garment_from_arrays`` splits
                                     seam vertices: copies share their source; a Blender mesh's vertex index)

The native cloth model reads the pattern as its rest state (native/src/geometry/mesh.hpp): stretching and
bending tables are in the uv frame, so a garment whose +v is the grain line needs no rotation of the tables.
The native model sees each pattern piece as its own sheet; holding seam pairs together is the garment
simulator's job (``seams``).

Bad input raises InputError (a ValueError) naming the problem and the first offending index.
"""
import os
from dataclasses import dataclass, field

import numpy as np

from . import InputError

__all__ = ["Garment", "garment_from_arrays", "default_uv", "read_garment_obj", "write_garment_obj", "self_intersections",
           "MIN_FACE_AREA_M2", "UV_MATCH_TOLERANCE_M"]

MIN_FACE_AREA_M2 = 1e-12      # a face smaller than this (3D or pattern) is degenerate: 1 micrometre x 1 micrometre
UV_MATCH_TOLERANCE = 1e-9     # relative to the uv extent: corners of one vertex closer than this share a uv
UV_MATCH_TOLERANCE_M = UV_MATCH_TOLERANCE
MAX_COORDINATE = 1e6          # positions (m) and uvs beyond this are refused
MAX_OBJ_BYTES = 1 << 30       # read_garment_obj refuses larger files before reading them
OBJ_MARKER = "# drapelab-garment"


def _int_indices(values, name):
    arr = np.asarray(values if values is not None else [], dtype=np.int64).ravel()
    return arr.astype(np.int32)


@dataclass
class Garment:
    """A garment mesh and its flat pattern (see the module docstring for the fields and units)."""
    positions: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    seams: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    waist_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    hem_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    name: str = "garment"
    source_vertices: np.ndarray = None  # (V,) int32: the input vertex each vertex was split from (default: itself)

    def __post_init__(self):
        self.positions = np.ascontiguousarray(self.positions, dtype=np.float64)
        self.uv = np.ascontiguousarray(self.uv, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32)
        self.seams = np.ascontiguousarray(np.asarray(self.seams, dtype=np.int32).reshape(-1, 2))
        self.waist_vertices = np.ascontiguousarray(_int_indices(self.waist_vertices, "waist_vertices"))
        self.hem_vertices = np.ascontiguousarray(_int_indices(self.hem_vertices, "hem_vertices"))
        self.name = str(self.name)
        if self.source_vertices is None:
            self.source_vertices = np.arange(self.positions.shape[0], dtype=np.int32)
        self.source_vertices = np.ascontiguousarray(self.source_vertices, dtype=np.int32).ravel()

    @property
    def num_vertices(self):
        return int(self.positions.shape[0])

    @property
    def num_faces(self):
        return int(self.faces.shape[0])

    def validate(self):
        """Checks shapes, finiteness, index ranges, degenerate and clockwise faces, non-manifold edges, loose
        vertices and seams; raises InputError naming the first problem. Returns self."""
        p, uv, f = self.positions, self.uv, self.faces
        if p.ndim != 2 or p.shape[1] != 3:
            raise InputError(f"{self.name}: positions must have shape (V, 3), got {p.shape}")
        if uv.shape != (p.shape[0], 2):
            raise InputError(f"{self.name}: uv must have shape ({p.shape[0]}, 2), got {uv.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise InputError(f"{self.name}: faces must have shape (F, 3) with F >= 1, got {f.shape}")
        _check_finite(p, "positions")
        _check_finite(uv, "uv")
        _check_range(f, p.shape[0], "faces")
        _check_degenerate(p, f)
        area = _signed_uv_areas(uv, f)
        if (area <= 0).any():
            i = int(np.argmax(area <= 0))
            raise InputError(f"{self.name}: face {i} is not counter-clockwise in uv (signed pattern area {area[i]:.3g} m^2)")
        _check_manifold(f)
        _check_loose(f, p.shape[0])
        for name in ("seams", "waist_vertices", "hem_vertices"):
            _check_range(getattr(self, name), p.shape[0], name)
        if self.source_vertices.shape != (p.shape[0],):
            raise InputError(f"{self.name}: source_vertices must have shape ({p.shape[0]},), got {self.source_vertices.shape}")
        return self

    def to_native_mesh_arrays(self):
        """(positions (V, 3) float64, uv (V, 2) float64, faces (F, 3) int32) as the native TriangleMesh wants
        them (rest uv in metres, faces counter-clockwise in uv): ``sim.ClothModel((positions, faces, uv))``."""
        return (np.ascontiguousarray(self.positions, dtype=np.float64),
                np.ascontiguousarray(self.uv, dtype=np.float64),
                np.ascontiguousarray(self.faces, dtype=np.int32))

    def point_index(self):
        """(V,) int: the sewn-garment point of each vertex (seam pairs share one), numbered 0..P-1 in vertex order."""
        return _seam_points(self.num_vertices, self.seams)

    def copy(self):
        return Garment(self.positions.copy(), self.uv.copy(), self.faces.copy(), self.seams.copy(),
                       self.waist_vertices.copy(), self.hem_vertices.copy(), self.name, self.source_vertices.copy())


# ---------------------------------------------------------------- checks
def _check_finite(arr, name):
    """Finite and within MAX_COORDINATE (larger coordinates are no garment, and would overflow areas)."""
    bad = ~np.isfinite(arr)
    if bad.any():
        index = [int(i) for i in np.argwhere(bad)[0]]
        raise InputError(f"{name}: non-finite value {arr[tuple(index)]} at index {index}"
                         + (f" (vertex {index[0]})" if name in ("positions", "uv") else ""))
    big = np.abs(arr) > MAX_COORDINATE
    if big.any():
        index = [int(i) for i in np.argwhere(big)[0]]
        raise InputError(f"{name}: value {arr[tuple(index)]:g} at index {index} is beyond +-{MAX_COORDINATE:g} (metres "
                         "or uv units): not a garment")


def _check_range(idx, n, name):
    idx = np.asarray(idx)
    if idx.size == 0:
        return
    bad = (idx < 0) | (idx >= n)
    if bad.any():
        where = [int(i) for i in np.argwhere(bad)[0]]
        raise InputError(f"{name}: vertex index {int(idx[tuple(where)])} at {where} out of range [0, {n})")


def _triangle_areas_3d(p, f):
    return 0.5 * np.linalg.norm(np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]), axis=1)


def _signed_uv_areas(uv, f):
    a, b, c = uv[f[:, 0]], uv[f[:, 1]], uv[f[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def _check_degenerate(p, f):
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if repeated.any():
        i = int(np.argmax(repeated))
        raise InputError(f"faces: face {i} {f[i].tolist()} repeats a vertex (degenerate)")
    area = _triangle_areas_3d(p, f)
    small = area <= MIN_FACE_AREA_M2
    if small.any():
        i = int(np.argmax(small))
        raise InputError(f"faces: face {i} is degenerate (3D area {area[i]:.3g} m^2 <= {MIN_FACE_AREA_M2:g})")


def _edges(f):
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return np.sort(e, axis=1), np.tile(np.arange(f.shape[0]), 3)


def _check_manifold(f):
    e, _ = _edges(f)
    uniq, inverse, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    bad = counts > 2
    if bad.any():
        k = int(np.argmax(bad))
        faces = np.flatnonzero(inverse.ravel() == k) % f.shape[0]
        raise InputError(f"faces: non-manifold edge {uniq[k].tolist()} shared by {int(counts[k])} faces "
                         f"(faces {sorted(set(faces.tolist()))})")


def _check_loose(f, n):
    used = np.zeros(n, bool)
    used[f.ravel()] = True
    if not used.all():
        i = int(np.argmin(used))
        raise InputError(f"positions: loose vertex {i} (in no face); {int((~used).sum())} loose vertices in all")


def _seam_points(n, seams):
    parent = np.arange(n)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a
    for a, b in np.asarray(seams).reshape(-1, 2):
        ra, rb = find(int(a)), find(int(b))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(i) for i in range(n)])
    _, point = np.unique(roots, return_inverse=True)
    return point.ravel()


# ---------------------------------------------------------------- building from arrays
def _polygons(faces):
    """faces as a list of int arrays (one per polygon) and whether all are triangles."""
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        if not np.issubdtype(faces.dtype, np.integer):
            raise InputError(f"faces: expected integer vertex indices, got dtype {faces.dtype}")
        return [np.asarray(row, np.int64) for row in faces]
    try:
        polys = [np.asarray(poly) for poly in faces]
    except TypeError:
        raise InputError(f"faces: expected an (F, 3) array or a list of polygons, got {type(faces).__name__}") from None
    for i, poly in enumerate(polys):
        if poly.ndim != 1 or not (np.issubdtype(poly.dtype, np.integer) or poly.size == 0):
            raise InputError(f"faces: face {i} is not a list of integer vertex indices ({poly.dtype}, shape {poly.shape})")
        if poly.size < 3:
            raise InputError(f"faces: face {i} has {poly.size} vertices (a face needs at least 3)")
    return [p.astype(np.int64) for p in polys]


def garment_from_arrays(positions, faces, corner_uv=None, uv_scale_m=None, name="garment", triangulate=False,
                        waist_vertices=None, hem_vertices=None, corner_uv_ids=None):
    """A validated Garment from a triangle mesh (or polygons) and its per-corner uv map.

    positions: (V, 3) metres. faces: (F, 3) integer triangles, or a list of polygons; quads and n-gons are an
    InputError naming how many there are, unless triangulate=True (fan triangulation from each polygon's first
    corner; corner_uv then follows the polygons' corners, a list of (k, 2) arrays).
    corner_uv: (F, 3, 2) uv per face corner (Blender's UV map). A vertex whose corners carry different uvs lies
    on a seam between pattern pieces: it is split into one vertex per distinct uv and the copies become ``seams``
    pairs (corners whose uvs differ by less than 1e-9 of the uv extent share one). corner_uv=None is an error
    (a garment needs its pattern); ``default_uv(positions, faces)`` gives the documented default.
    corner_uv_ids: optional (F, 3) integer ids that decide the split instead of the uv values (an OBJ's vt
    indices: a seam whose two sides have equal uvs stays a seam).
    uv_scale_m: metres per uv unit; None scales the pattern so that its total area equals the 3D total area.
    waist_vertices, hem_vertices: indices into ``positions``; every copy of a split vertex is included.
    Faces are reoriented counter-clockwise in uv. Checks (InputError naming the first offending index):
    non-finite positions or uvs, out-of-range indices, degenerate faces (3D or in the pattern), non-manifold
    edges (more than two faces on one edge), loose vertices.
    """
    try:
        p = np.asarray(positions, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise InputError(f"positions: not an array of numbers ({e})") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"positions: expected shape (V, 3), got {p.shape}")
    _check_finite(p, "positions")
    polys = _polygons(faces)
    if not polys:
        raise InputError("faces: the mesh has no faces")
    sizes = np.array([len(q) for q in polys])
    if (sizes != 3).any() and not triangulate:
        i = int(np.argmax(sizes != 3))
        raise InputError(f"faces: {int((sizes != 3).sum())} faces are not triangles (first: face {i} with "
                         f"{sizes[i]} vertices); triangulate the mesh or pass triangulate=True")
    for i, q in enumerate(polys):
        if q.min() < 0 or q.max() >= p.shape[0]:
            raise InputError(f"faces: face {i} has a vertex index out of range [0, {p.shape[0]}): {q.tolist()}")
    if corner_uv is None:
        raise InputError(f"{name}: no UV map (corner_uv is None): a garment needs its flat pattern to orient the "
                         "fabric; use default_uv(positions, faces) for the default warp/weft (cylindrical, warp "
                         "vertical)")
    if isinstance(corner_uv, np.ndarray) and corner_uv.ndim == 3:
        cuv = [np.asarray(c, np.float64) for c in corner_uv]
    else:
        try:
            cuv = [np.asarray(c, np.float64) for c in corner_uv]
        except (TypeError, ValueError) as e:
            raise InputError(f"corner_uv: not a list of per-corner uv arrays ({e})") from None
    if len(cuv) != len(polys):
        raise InputError(f"corner_uv: expected one entry per face ({len(polys)}), got {len(cuv)}")
    for i, (q, c) in enumerate(zip(polys, cuv)):
        if c.shape != (len(q), 2):
            raise InputError(f"corner_uv: face {i} has {len(q)} corners but its uv has shape {c.shape}")
        if not np.isfinite(c).all():
            raise InputError(f"corner_uv: non-finite uv in face {i}: {c.tolist()}")
        if np.abs(c).max() > MAX_COORDINATE:
            raise InputError(f"corner_uv: uv beyond +-{MAX_COORDINATE:g} in face {i}: {c.tolist()}")
    ids = None
    if corner_uv_ids is not None:
        ids = [np.asarray(c, np.int64).ravel() for c in corner_uv_ids]
        if len(ids) != len(polys) or any(len(a) != len(q) for a, q in zip(ids, polys)):
            raise InputError("corner_uv_ids: expected one id per face corner")
    # fan triangulation (a no-op on triangles)
    tri, tri_uv, tri_ids = [], [], []
    for k, (q, c) in enumerate(zip(polys, cuv)):
        for j in range(1, len(q) - 1):
            sel = [0, j, j + 1]
            tri.append(q[sel])
            tri_uv.append(c[sel])
            if ids is not None:
                tri_ids.append(ids[k][sel])
    f0 = np.array(tri, np.int64)
    c_uv = np.array(tri_uv, np.float64)
    _check_degenerate(p, f0)
    _check_manifold(f0)
    _check_loose(f0, p.shape[0])
    # split vertices whose corners carry different uvs
    if ids is not None:
        key_uv = np.array(tri_ids, np.int64).reshape(-1, 1)
    else:
        extent = max(float(np.ptp(c_uv.reshape(-1, 2), axis=0).max()), 1e-300)
        key_uv = np.round(c_uv.reshape(-1, 2) / (extent * UV_MATCH_TOLERANCE)).astype(np.int64)
    keys = np.column_stack([f0.reshape(-1, 1), key_uv])
    uniq, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    # number the new vertices in order of (original vertex, first appearance)
    order = np.lexsort((first, uniq[:, 0]))
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    new_faces = rank[inverse].reshape(-1, 3)
    original = uniq[order, 0]
    new_uv = c_uv.reshape(-1, 2)[first[order]]
    new_pos = p[original]
    seams = []
    starts = np.flatnonzero(np.r_[True, original[1:] != original[:-1]])
    ends = np.r_[starts[1:], original.size]
    for s, e in zip(starts, ends):
        seams.extend((s, j) for j in range(s + 1, e))
    seams = np.array(seams, np.int64).reshape(-1, 2)
    # scale
    area_uv_signed = _signed_uv_areas(new_uv, new_faces)
    if uv_scale_m is None:
        total_uv = float(np.abs(area_uv_signed).sum())
        if not total_uv > 0:
            raise InputError(f"{name}: the uv map has zero total area (every face collapsed in the pattern)")
        scale = np.sqrt(_triangle_areas_3d(new_pos, new_faces).sum() / total_uv)
    else:
        try:
            scale = float(uv_scale_m)
        except (TypeError, ValueError):
            raise InputError(f"uv_scale_m: expected a number of metres per uv unit, got {uv_scale_m!r}") from None
        if not np.isfinite(scale) or not 0 < scale <= 1e3:
            raise InputError(f"uv_scale_m: must be a number in (0, 1000] metres per uv unit, got {uv_scale_m!r}")
    new_uv = new_uv * scale
    area_uv = area_uv_signed * scale * scale
    small = np.abs(area_uv) <= MIN_FACE_AREA_M2
    if small.any():
        i = int(np.argmax(small))
        raise InputError(f"corner_uv: face {i} is degenerate in the pattern (uv area {abs(area_uv[i]):.3g} m^2); "
                         "every face needs a non-zero area in the UV map")
    flip = area_uv < 0
    new_faces[flip] = new_faces[flip][:, [0, 2, 1]]
    def mapped(vertices, what):
        if vertices is None:
            return np.zeros(0, np.int32)
        v = np.asarray(vertices, np.int64).ravel()
        _check_range(v, p.shape[0], what)
        return np.flatnonzero(np.isin(original, v)).astype(np.int32)
    g = Garment(new_pos, new_uv, new_faces.astype(np.int32), seams.astype(np.int32),
                mapped(waist_vertices, "waist_vertices"), mapped(hem_vertices, "hem_vertices"), name,
                original.astype(np.int32))
    return g.validate()


# ---------------------------------------------------------------- the default pattern
def default_uv(positions, faces, warp_axis=(0.0, 0.0, 1.0)):
    """The default warp/weft of a garment without a UV map: (F, 3, 2) uv per face corner, in metres.

    Cylindrical projection around the axis through the vertices' centroid along ``warp_axis`` (default z, up):
    v (warp) = height along the axis, u (weft) = the angle around it times the vertices' mean distance from the
    axis (arc length at the mean radius), increasing counter-clockwise seen from the axis' tip. The angle is
    cut at the back (+y for the default axis; the body faces -y): faces crossing the cut get unwrapped
    corners, so ``garment_from_arrays`` splits their vertices into a back seam. The grain line thus runs
    vertically, as for most skirts and dresses; the pattern is exact for a cylinder and stretched elsewhere, so
    use a real UV map for a real pattern.
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"positions: expected shape (V, 3), got {p.shape}")
    _check_finite(p, "positions")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"faces: expected integer triangles (F, 3), got {f.dtype} {f.shape}")
    _check_range(f, p.shape[0], "faces")
    a = np.asarray(warp_axis, dtype=np.float64).ravel()
    if a.shape != (3,) or not np.isfinite(a).all() or np.linalg.norm(a) == 0:
        raise InputError(f"warp_axis: expected a non-zero 3-vector, got {warp_axis!r}")
    a = a / np.linalg.norm(a)
    front = np.array([0.0, -1.0, 0.0])       # the body faces -y; the cut goes opposite, at the back
    front = front - a * (front @ a)
    if np.linalg.norm(front) < 1e-6:
        front = np.array([1.0, 0.0, 0.0]) - a * a[0]
    e1 = front / np.linalg.norm(front)
    e2 = np.cross(a, e1)
    d = p - p.mean(axis=0)
    x1, x2, h = d @ e1, d @ e2, d @ a
    radius = np.hypot(x1, x2)
    r_mean = float(radius.mean())
    if not r_mean > 0:
        raise InputError("default_uv: every vertex lies on the axis; no cylindrical projection exists")
    angle = np.arctan2(x2, x1)                 # 0 at the front, +-pi at the back
    ca = angle[f]                              # (F, 3)
    wrap = (ca.max(axis=1) - ca.min(axis=1)) > np.pi
    ca = np.where(wrap[:, None] & (ca < 0), ca + 2 * np.pi, ca)
    return np.stack([r_mean * ca, h[f]], axis=-1)


# ---------------------------------------------------------------- OBJ
def _atomic_text_write(path, text, what):
    """Writes text atomically (measure's temporary-file-and-rename writer)."""
    from ..measure import _atomic_write

    def write(tmp):
        with open(tmp, "w") as fh:
            fh.write(text)
    _atomic_write(path, what, os.path.splitext(os.fspath(path))[1], write)


def write_garment_obj(path, garment):
    """Writes the garment as an OBJ Blender imports with its UV map, atomically (temporary file, then rename).

    One ``v`` per sewn point (seam copies welded, so Blender sees one connected mesh), one ``vt`` per garment
    vertex in metres (u = weft, v = warp), faces ``f v/vt``; the waist and hem vertices and the uv unit go in
    ``# drapelab-garment`` comment lines that ``read_garment_obj`` reads back (other readers ignore them).
    """
    if not isinstance(garment, Garment):
        raise InputError(f"garment: expected a Garment, got {type(garment).__name__}")
    garment.validate()
    point = garment.point_index()
    n_points = int(point.max()) + 1
    pos = np.zeros((n_points, 3))
    pos[point] = garment.positions
    lines = [f"{OBJ_MARKER} uv_unit_m 1", f"o {garment.name.replace(chr(10), ' ')}"]
    for label in ("waist_vertices", "hem_vertices"):
        idx = getattr(garment, label)
        for k in range(0, idx.size, 64):
            lines.append(f"{OBJ_MARKER} {label} " + " ".join(str(int(i)) for i in idx[k:k + 64]))
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in pos]
    lines += [f"vt {u:.9g} {v:.9g}" for u, v in garment.uv]
    fp, ft = point[garment.faces] + 1, garment.faces + 1
    lines += [f"f {a}/{d} {b}/{e} {c}/{g}" for (a, b, c), (d, e, g) in zip(fp, ft)]
    _atomic_text_write(path, "\n".join(lines) + "\n", "garment OBJ")


def read_garment_obj(path, uv_scale_m=None, triangulate=False, name=None):
    """A Garment from an OBJ with per-corner ``vt`` (Blender's OBJ export with UVs).

    Vertices are split where their corners use different ``vt`` (the pattern's seams). uv_scale_m: metres per
    uv unit; None: 1 for files written by ``write_garment_obj``, else the pattern is scaled to the 3D area.
    Quads and n-gons: an error unless triangulate=True. Errors name the file and line.
    """
    path = os.fspath(path)
    try:
        size = os.path.getsize(path)
    except OSError as e:
        raise InputError(f"{path}: cannot read garment OBJ: {e.strerror}") from None
    if size > MAX_OBJ_BYTES:
        raise InputError(f"{path}: garment OBJ is {size} bytes, above the {MAX_OBJ_BYTES} byte limit")
    verts, texs, faces, face_vt, extra = [], [], [], [], {"waist_vertices": [], "hem_vertices": []}
    obj_name, unit = None, None
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for lineno, line in enumerate(fh, 1):
                if line.startswith(OBJ_MARKER):
                    parts = line.split()[2:]
                    try:
                        if parts and parts[0] == "uv_unit_m":
                            unit = float(parts[1])
                        elif parts and parts[0] in extra:
                            extra[parts[0]].extend(int(t) for t in parts[1:])
                    except (ValueError, IndexError):
                        raise InputError(f"{path}:{lineno}: malformed drapelab-garment line") from None
                    continue
                parts = line.split()
                if not parts or parts[0].startswith("#"):
                    continue
                tag = parts[0]
                try:
                    if tag == "v":
                        verts.append([float(t) for t in parts[1:4]])
                        if len(verts[-1]) != 3:
                            raise ValueError("a vertex needs x y z")
                    elif tag == "vt":
                        texs.append([float(t) for t in parts[1:3]])
                        if len(texs[-1]) != 2:
                            raise ValueError("a texture coordinate needs u v")
                    elif tag == "f":
                        fv, ft = [], []
                        for t in parts[1:]:
                            s = t.split("/")
                            iv = int(s[0])
                            fv.append(iv - 1 if iv > 0 else len(verts) + iv)
                            if len(s) < 2 or s[1] == "":
                                raise InputError(f"{path}:{lineno}: face corner {t!r} has no texture coordinate: "
                                                 "the garment has no UV map (export with UVs, or use default_uv)")
                            it = int(s[1])
                            ft.append(it - 1 if it > 0 else len(texs) + it)
                        if len(fv) < 3:
                            raise ValueError("a face needs at least 3 corners")
                        faces.append(fv)
                        face_vt.append(ft)
                    elif tag in ("o", "g") and obj_name is None and len(parts) > 1:
                        obj_name = " ".join(parts[1:])
                except ValueError as e:
                    if isinstance(e, InputError):
                        raise
                    raise InputError(f"{path}:{lineno}: malformed {tag!r} line: {e}") from None
    except OSError as e:
        raise InputError(f"{path}: cannot read garment OBJ: {e.strerror}") from None
    if not faces:
        raise InputError(f"{path}: no faces")
    for i, (fv, ft) in enumerate(zip(faces, face_vt)):
        if min(fv) < 0 or max(fv) >= len(verts):
            raise InputError(f"{path}: face {i} refers to a vertex out of range (1..{len(verts)})")
        if min(ft) < 0 or max(ft) >= len(texs):
            raise InputError(f"{path}: face {i} refers to a texture coordinate out of range (1..{len(texs)})")
    tex = np.array(texs, np.float64).reshape(-1, 2)
    if uv_scale_m is None and unit is not None:
        uv_scale_m = unit
    try:
        return garment_from_arrays(np.array(verts, np.float64).reshape(-1, 3), [np.array(f) for f in faces],
                                   corner_uv=[tex[t] for t in face_vt], uv_scale_m=uv_scale_m,
                                   name=name or obj_name or os.path.splitext(os.path.basename(path))[0],
                                   triangulate=triangulate, corner_uv_ids=face_vt,
                                   waist_vertices=_points_of(extra["waist_vertices"], faces, face_vt, path),
                                   hem_vertices=_points_of(extra["hem_vertices"], faces, face_vt, path))
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def _points_of(vt_indices, faces, face_vt, path):
    """The OBJ vertex (v) indices of garment vertices given as vt indices (write_garment_obj numbers garment
    vertices by their vt)."""
    if not vt_indices:
        return None
    vt_to_v = {}
    for fv, ft in zip(faces, face_vt):
        for a, t in zip(fv, ft):
            vt_to_v[t] = a
    try:
        return [vt_to_v[t] for t in vt_indices]
    except KeyError as e:
        raise InputError(f"{path}: drapelab-garment line names vertex {e.args[0]}, which no face uses") from None


# ---------------------------------------------------------------- self-intersection
def self_intersections(positions, faces, points=None, max_pairs=None):
    """(K, 2) int64 pairs of faces (i < j, sharing no vertex) that intersect: an edge of one crosses the
    other's interior. Broad phase: the faces' bounding boxes on a uniform grid (cell = the largest face's box);
    exact phase: segment-triangle crossings with signed volumes. Coplanar touching is not counted. Meant for
    checks (rest placements, final frames of a drape): O(F) memory, seconds for 100k faces.
    points: (V,) the sewn point of each vertex (``Garment.point_index()``): faces meeting at a seam share
    points, not vertices, and touch there without crossing. max_pairs: at most this many (None: all)."""
    p = np.asarray(positions, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    fp = f if points is None else np.asarray(points, dtype=np.int64)[f]
    lo, hi = p[f].min(axis=1), p[f].max(axis=1)
    cell = max(float((hi - lo).max()), 1e-12)
    origin = lo.min(axis=0)
    clo = np.floor((lo - origin) / cell).astype(np.int64)
    chi = np.floor((hi - origin) / cell).astype(np.int64)
    # every face in every cell its box touches (at most 2 x 2 x 2 cells: the cell is the largest box)
    ids, keys = [], []
    dims = chi.max(axis=0) + 2
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                c = clo + np.array([dx, dy, dz])
                ok = (c <= chi).all(axis=1)
                ids.append(np.flatnonzero(ok))
                keys.append((c[ok, 0] * dims[1] + c[ok, 1]) * dims[2] + c[ok, 2])
    ids, keys = np.concatenate(ids), np.concatenate(keys)
    order = np.argsort(keys, kind="stable")
    ids, keys = ids[order], keys[order]
    starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    ends = np.r_[starts[1:], len(keys)]
    pairs = []
    for s, e in zip(starts, ends):
        if e - s < 2:
            continue
        members = ids[s:e]
        i, j = np.triu_indices(len(members), 1)
        pairs.append(np.stack([members[i], members[j]], axis=1))
    if not pairs:
        return np.zeros((0, 2), np.int64)
    pairs = np.unique(np.sort(np.vstack(pairs), axis=1), axis=0)
    a, b = pairs[:, 0], pairs[:, 1]
    overlap = ((lo[a] <= hi[b]) & (lo[b] <= hi[a])).all(axis=1)
    shared = (fp[a][:, :, None] == fp[b][:, None, :]).any(axis=(1, 2))
    pairs = pairs[overlap & ~shared]
    hits = np.zeros(len(pairs), bool)
    for first, second in ((0, 1), (1, 0)):
        tri = p[f[pairs[:, second]]]                     # (K, 3, 3)
        for k in range(3):
            q0 = p[f[pairs[:, first], k]]
            q1 = p[f[pairs[:, first], (k + 1) % 3]]
            hits |= _segment_crosses_triangle(q0, q1, tri)
    out = pairs[hits]
    return out if max_pairs is None else out[:max_pairs]


def _segment_crosses_triangle(q0, q1, tri):
    def vol(a, b, c, d):
        return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    s0, s1 = vol(a, b, c, q0), vol(a, b, c, q1)
    straddle = s0 * s1 < 0
    e0, e1, e2 = vol(q0, q1, a, b), vol(q0, q1, b, c), vol(q0, q1, c, a)
    inside = ((e0 > 0) & (e1 > 0) & (e2 > 0)) | ((e0 < 0) & (e1 < 0) & (e2 < 0))
    return straddle & inside
