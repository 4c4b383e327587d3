"""Parametric skirts: sewing patterns in uv (metres, grain line along +v) and their 3D placement on the body.

Every style is cut from annular sectors (the pattern of a cone): a piece spans the pattern radii
rho0 .. rho0 + length and the angles psi in [-beta, beta] about its centre line, which runs along +v (the
grain line is the piece's centre front or centre back). The pieces' angles add up to Theta; the waist edge is
then Theta * rho0 = the waist circumference, so rho0 = waist / Theta.

    circle   one piece, a full annulus (Theta = 2 pi), one back seam; grain line = centre front
    flared   one piece, a half annulus (Theta = pi), one back seam; grain line = centre front
    aline    two pieces, front and back (Theta = 0.6 pi in all), side seams; grain line = centre front and
             centre back.
A flared or A-line cone that would touch the hips is widened (Theta grows) until it clears them, as a pattern
maker's would. The pieces are the trapezoid panels of an A-line skirt with the waist and hem
             curved so that the panels sew into a cone (the curve a pattern maker adds to a flared panel).

3D placement: the pattern wrapped around the body axis (z up, the body faces -y), hanging from the waist at
waist_height_m. Pattern angle psi maps to azimuth phi = phi_piece + psi * 2 pi / Theta (phi = 0 at the centre
front, counter-clockwise seen from above), pattern radius to distance down the skirt. A pattern with
Theta / 2 pi = sin(alpha) is exactly a cone of half-angle alpha: the aline (alpha = 17.5 deg) and flared (30 deg)
skirts are placed without strain. A circle skirt is a flat disk as a cone; it starts as a cone of
CIRCLE_CONE_SINE with FOLDS radial folds whose depth per row makes the row's 3D length equal to its pattern
length, spread evenly along the folds. Folds of a cone are not developable (that start shears the cloth on
the folds' flanks: Green strain median 0.12, max 0.28), so the placement is then relaxed towards the pattern's
edge lengths and, weakly, the flat distances across its interior edges (position-based projections, the
waist edge held, seams welded, the body's clearance kept;
relaxed at 2000 vertices, mapped to finer meshes through the coarse triangles and polished there): Green
strain median 0.003, 99th percentile 0.02, max 0.06 on the default body, dihedral angles at most 40-50 deg (``rest_strain``; tested, also on
random bodies: max < 0.2), no self-intersection (``mesh.self_intersections``).
Rows come no closer to the body than
clearance_m (the body's waist, where the skirt's waist equals it, stretches the waistband by clearance / r).

Mesh: rows of vertices at fixed pattern radius (a row lands on the waistband's lower edge), as many vertices
per row as keep edges about equal, neighbouring rows zipped into triangles: near-equilateral triangles
(min angle > 20 degrees, tested; a waistband thinner than half a row is the waist edge's row alone).
``waist_vertices`` = the rows from the waist edge down to waistband_m,
``hem_vertices`` = the last row.
"""
import numpy as np

from . import InputError
from .body import Body, make_body
from .mesh import Garment

__all__ = ["make_skirt", "STYLES", "rest_strain", "triangle_angles"]

STYLES = ("circle", "flared", "aline")
ALINE_CONE_SINE = 0.3         # sin(half-angle) of the A-line cone: 17.5 degrees (more if the hips need it)
FLARED_CONE_SINE = 0.5        # the flared skirt's: a half circle, 30 degrees (more if the hips need it)
MAX_CONE_SINE = 0.95
CIRCLE_CONE_SINE = 0.6        # the circle skirt's mean cone (37 degrees) before its folds
FOLDS = 10                    # radial folds of the circle skirt's placement
DEFAULT_CLEARANCE_M = 0.005   # nearest distance of a row from the body
MAX_WAIST_STRETCH = 0.10      # a skirt waist smaller than the body's by more than this fraction is refused
MIN_VERTICES, MAX_VERTICES = 200, 200000
PIECE_GAP_M = 0.05            # between pattern pieces in uv
RELAX_ITERATIONS = 800        # the circle skirt's relaxation at ...
RELAX_COARSE_VERTICES = 2000  # ... this resolution, then interpolated to the requested one
RELAX_POLISH_ITERATIONS = 150 # and polished there
RELAX_OMEGA = 1.5             # over-relaxation of the Jacobi projections
RELAX_BEND_WEIGHT = 0.1       # weight of the cross-edge distances (a bending surrogate) against the edges'


def _pieces(style, sine):
    """[(beta, phi_piece)] per piece and the total angle Theta, for a cone of sin(half-angle) = sine (the circle
    skirt's pattern is the full annulus whatever its placement)."""
    if style == "circle":
        return [(np.pi, 0.0)], 2 * np.pi
    theta = 2 * np.pi * sine
    if style == "flared":
        return [(theta / 2, 0.0)], theta
    return [(theta / 4, 0.0), (theta / 4, np.pi)], theta


def _cone_sine(style, waist, length, body, z_waist, clearance):
    """sin(half-angle) of the skirt's cone: the style's, or as much more as keeps the cone off the hips (in steps
    of 0.01): the pattern follows the body as a pattern maker's would. A waist tighter than the body's (the
    waistband is then stretched) lowers the bar by the same deficit everywhere."""
    sine = {"circle": CIRCLE_CONE_SINE, "flared": FLARED_CONE_SINE, "aline": ALINE_CONE_SINE}[style]
    if style == "circle":
        return sine
    r_waist = waist / (2 * np.pi)
    s = np.linspace(0.0, length, 200)
    deficit = max(0.0, float(body.max_radius(np.array([z_waist]))[0]) + clearance - r_waist)
    while sine < MAX_CONE_SINE:
        need = body.max_radius(z_waist - s * np.sqrt(1 - sine * sine)) + clearance - deficit
        if (r_waist + s * sine >= need - 1e-9).all():
            break
        sine = min(MAX_CONE_SINE, sine + 0.01)
    return sine


def _rows(length, waistband, ds):
    """Row distances from the waist edge: about ds apart, one on the waistband's lower edge unless the band is
    thinner than half a row (then the band is the waist edge's row alone: a thinner row makes slivers)."""
    if waistband >= 0.5 * ds:
        n_wb = max(1, int(round(waistband / ds)))
        n_rest = max(1, int(round((length - waistband) / ds)))
        return np.concatenate([np.linspace(0, waistband, n_wb + 1), np.linspace(waistband, length, n_rest + 1)[1:]])
    return np.linspace(0, length, max(2, int(round(length / ds))) + 1)


def _piece_mesh(rho0, s_rows, beta, h):
    """Vertices (rows of (rho, psi)) and triangles of one annular sector piece, rows zipped together."""
    rho_list, psi_list, row_of, faces = [], [], [], []
    starts = []
    for j, s in enumerate(s_rows):
        rho = rho0 + s
        m = max(2, int(round(2 * beta * rho / h)))
        starts.append(len(rho_list))
        psi = np.linspace(-beta, beta, m + 1)
        rho_list += [rho] * (m + 1)
        psi_list += psi.tolist()
        row_of += [j] * (m + 1)
    starts.append(len(rho_list))
    for j in range(len(s_rows) - 1):
        a0, a1, b0, b1 = starts[j], starts[j + 1], starts[j + 1], starts[j + 2]
        ma, mb = a1 - a0 - 1, b1 - b0 - 1
        i = k = 0
        while i < ma or k < mb:
            # advance along the row whose next vertex comes first (by angle): keeps triangles well shaped
            if k >= mb or (i < ma and (i + 1) / ma <= (k + 1) / mb):
                faces.append([a0 + i, a0 + i + 1, b0 + k])
                i += 1
            else:
                faces.append([a0 + i, b0 + k + 1, b0 + k])
                k += 1
    return np.array(rho_list), np.array(psi_list), np.array(row_of), np.array(faces, np.int64)


def _ring_length(R, a, n, samples=720):
    phi = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    r = R + a * np.cos(n * phi)
    dr = -n * a * np.sin(n * phi)
    return float(np.mean(np.sqrt(r * r + dr * dr)) * 2 * np.pi)


def _fold_amplitude(R, target, n):
    """Fold depth a in [0, R) whose ring R + a cos(n phi) has length `target` (>= 2 pi R)."""
    if target <= 2 * np.pi * R:
        return 0.0
    lo, hi = 0.0, 0.999 * R
    if _ring_length(R, hi, n) < target:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _ring_length(R, mid, n) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _arc_length_azimuth(phi, R, A, samples=2048):
    """Azimuths on the folded rings R + A cos(FOLDS phi) at which the arc length from the back (phi = -pi) is
    the fraction (phi + pi) / 2 pi of the ring's length: a row's pattern length spreads evenly along its folds.
    The identity where A = 0; the centre front (0) and back (+-pi) stay put (the folds are symmetric)."""
    out = np.array(phi, dtype=np.float64)
    grid = np.linspace(-np.pi, np.pi, samples + 1)
    folded = A > 0
    if not folded.any():
        return out
    for R_row, A_row in np.unique(np.stack([R[folded], A[folded]], axis=1), axis=0):
        sel = (R == R_row) & (A == A_row)
        r = R_row + A_row * np.cos(FOLDS * grid)
        dr = -FOLDS * A_row * np.sin(FOLDS * grid)
        speed = np.sqrt(r * r + dr * dr)
        ell = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(grid))])
        out[sel] = np.interp((phi[sel] + np.pi) / (2 * np.pi) * ell[-1], ell, grid)
    return out


def _row_placement(style, s_rows, rho0, theta, body, z_waist, clearance):
    """Per row: mean radius R, fold depth a, height z."""
    cone = CIRCLE_CONE_SINE if style == "circle" else theta / (2 * np.pi)
    r_waist = theta * rho0 / (2 * np.pi)
    R = np.empty(len(s_rows))
    A = np.zeros(len(s_rows))
    Z = np.empty(len(s_rows))
    for j, s in enumerate(s_rows):
        target = theta * (rho0 + s)                          # the row's length in the pattern
        R_j = r_waist + s * cone
        z_j = z_waist if j == 0 else Z[j - 1] - np.sqrt(max((s - s_rows[j - 1]) ** 2 - (R_j - R[j - 1]) ** 2,
                                                             0.25 * (s - s_rows[j - 1]) ** 2))
        for _ in range(50):
            a_j = _fold_amplitude(R_j, target, FOLDS) if style == "circle" else 0.0
            need = body.max_radius(np.array([z_j, z_j - 0.01, z_j + 0.01])).max() + clearance
            if R_j - a_j >= need:
                break
            R_j += max(need - (R_j - a_j), 1e-4)
            if j > 0:
                ds = s - s_rows[j - 1]
                z_j = Z[j - 1] - np.sqrt(max(ds * ds - (R_j - R[j - 1]) ** 2, 0.25 * ds * ds))
        R[j], A[j], Z[j] = R_j, a_j, z_j
    return R, A, Z


def make_skirt(style="circle", waist_circumference_m=0.70, length_m=0.55, vertices=6000, waistband_m=0.03,
               waist_height_m=None, body=None, clearance_m=DEFAULT_CLEARANCE_M, name=None):
    """A skirt Garment of the given style (``STYLES``), deterministic (no randomness).

    waist_circumference_m: the waist edge's length; length_m: waist to hem along the skirt; vertices: about
    this many vertices (within 15 %; 2k-20k is the intended range, 200-200000 accepted); waistband_m: the
    top band (``waist_vertices``); body: the Body it hangs on (default ``make_body()``), waist_height_m its
    waist height unless given; clearance_m: nearest distance of the cloth from the body at rest.
    """
    if style not in STYLES:
        raise InputError(f"style: expected one of {', '.join(STYLES)}, got {style!r}")

    def number(v, what, lo, hi):
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{what}: expected a number, got {v!r}") from None
        if not np.isfinite(x) or not lo <= x <= hi:
            raise InputError(f"{what}: must lie in [{lo}, {hi}] m, got {v!r}")
        return x
    waist = number(waist_circumference_m, "waist_circumference_m", 0.3, 3.0)
    length = number(length_m, "length_m", 0.05, 1.5)
    waistband = number(waistband_m, "waistband_m", 0.0, 0.5 * length)
    clearance = number(clearance_m, "clearance_m", 0.0, 0.1)
    if isinstance(vertices, bool) or not isinstance(vertices, (int, np.integer)) or \
            not MIN_VERTICES <= vertices <= MAX_VERTICES:
        raise InputError(f"vertices: expected an integer in [{MIN_VERTICES}, {MAX_VERTICES}], got {vertices!r}")
    if body is None:
        body = make_body()
    elif not isinstance(body, Body):
        raise InputError(f"body: expected a Body (make_body), got {type(body).__name__}")
    z_waist = body.waist_height_m if waist_height_m is None else number(waist_height_m, "waist_height_m", 0.2, 2.5)
    body_waist = 2 * np.pi * float(body.max_radius(np.array([z_waist]))[0])
    if body_waist > 0 and waist < body_waist * (1 - MAX_WAIST_STRETCH):
        raise InputError(f"waist_circumference_m: {waist:.3f} m is more than {MAX_WAIST_STRETCH:.0%} smaller than the "
                         f"body's girth {body_waist:.3f} m at the waist height {z_waist:.3f} m")
    g, layout = _build(style, waist, length, waistband, vertices, body, z_waist, clearance, name)
    if style == "circle":
        g = _relaxed(g, layout, style, waist, length, waistband, vertices, body, z_waist, clearance, name)
    return g.validate()


def _build(style, waist, length, waistband, vertices, body, z_waist, clearance, name):
    """The skirt with its folded-cone placement, and its layout: per piece (first vertex, rows' pattern radii,
    row start offsets, beta) for interpolating positions between resolutions."""
    pieces, theta = _pieces(style, _cone_sine(style, waist, length, body, z_waist, clearance))
    rho0 = waist / theta
    area = 0.5 * theta * ((rho0 + length) ** 2 - rho0 ** 2)
    h = np.sqrt(area / (vertices * np.sqrt(3) / 2))
    for _ in range(4):  # adjust the edge length until the count is close (boundaries add vertices)
        s_rows = _rows(length, waistband, h * np.sqrt(3) / 2)
        count = sum(_piece_mesh(rho0, s_rows, beta, h)[0].size for beta, _ in pieces)
        if abs(count - vertices) < 0.02 * vertices:
            break
        h *= np.sqrt(count / vertices)
    R, A, Z = _row_placement(style, s_rows, rho0, theta, body, z_waist, clearance)
    positions, uv, faces, waist_v, hem_v, piece_ends, layout = [], [], [], [], [], [], []
    offset_u = 0.0
    n = 0
    for k, (beta, phi_piece) in enumerate(pieces):
        rho, psi, row, f = _piece_mesh(rho0, s_rows, beta, h)
        half_width = (rho0 + length) * (np.sin(beta) if beta < np.pi / 2 else 1.0)
        centre_u = offset_u + half_width
        offset_u = centre_u + half_width + PIECE_GAP_M
        # uv: the centre line psi = 0 along +v; the waist arc near the apex, the hem arc far from it
        u = centre_u + rho * np.sin(psi)
        v = rho * np.cos(psi)
        phi = _arc_length_azimuth(np.mod(phi_piece + psi * (2 * np.pi / theta) + np.pi, 2 * np.pi) - np.pi,
                                  R[row], A[row])
        r3 = R[row] + A[row] * np.cos(FOLDS * phi)
        positions.append(np.stack([r3 * np.sin(phi), -r3 * np.cos(phi), Z[row]], axis=1))
        uv.append(np.stack([u, v], axis=1))
        faces.append(f + n)
        waist_v.append(np.flatnonzero(s_rows[row] <= waistband + 1e-12) + n)
        hem_v.append(np.flatnonzero(row == len(s_rows) - 1) + n)
        piece_ends.append((n, rho, psi, beta))
        layout.append({"first": n, "rows": rho0 + s_rows, "starts": np.r_[0, np.cumsum(np.bincount(row))],
                       "beta": beta, "rho": rho, "psi": psi})
        n += rho.size
    positions, uv = np.vstack(positions), np.vstack(uv)
    faces = np.vstack(faces)
    # orient counter-clockwise in uv (the zipper's order is clockwise since u grows with psi)
    a, b, c = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    signed = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    faces[signed < 0] = faces[signed < 0][:, [0, 2, 1]]
    seams = _seam_pairs(positions, piece_ends, pieces, theta)
    g = Garment(positions, uv, faces.astype(np.int32), seams, np.concatenate(waist_v), np.concatenate(hem_v),
                name or f"skirt_{style}")
    return g, layout


def _edges_and_cross_pairs(faces):
    """Unique edges (E, 2) and, for every edge shared by two faces, the pair of vertices opposite it."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    opposite = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    key = np.sort(e, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, opposite = key[order], opposite[order]
    same = (key[1:] == key[:-1]).all(axis=1)
    cross = np.stack([opposite[:-1][same], opposite[1:][same]], axis=1)
    return np.unique(key, axis=0), cross


def _relax(g, body, clearance, iterations, positions=None):
    """Position-based relaxation of the 3D placement towards the pattern's edge lengths (Jacobi projections of
    every edge onto its pattern length, and more weakly of every interior edge's cross pair onto its flat
    distance, over-relaxed by RELAX_OMEGA), the waist edge held, seam pairs welded and vertices pushed out of the
    body's clearance every few iterations. Returns the positions."""
    f = g.faces
    edges, cross = _edges_and_cross_pairs(f)
    count = np.maximum(np.bincount(edges.ravel(), minlength=len(g.positions)), 1).astype(np.float64)
    # cross pairs (the two vertices opposite an interior edge) at a weaker weight: folds spread over several
    # triangles instead of creasing (without them 1 % of the dihedral angles exceed 80 degrees)
    weight = np.r_[np.ones(len(edges)), np.full(len(cross), RELAX_BEND_WEIGHT)]
    edges = np.vstack([edges, cross])
    rest = np.linalg.norm(g.uv[edges[:, 0]] - g.uv[edges[:, 1]], axis=1)
    x = (g.positions if positions is None else positions).copy()
    held = g.positions[:, 2] > g.positions[:, 2].max() - 1e-9          # the waist edge
    w = (~held).astype(np.float64)
    n = len(x)
    total = w[edges[:, 0]] + w[edges[:, 1]]
    total[total == 0] = 1
    ka, kb = weight * w[edges[:, 0]] / total, weight * w[edges[:, 1]] / total
    s0, s1 = g.seams[:, 0], g.seams[:, 1]
    for it in range(iterations):
        d = x[edges[:, 1]] - x[edges[:, 0]]
        length = np.sqrt((d * d).sum(axis=1))
        c = ((length - rest) / np.maximum(length, 1e-12))[:, None] * d
        for k in range(3):
            dx = np.bincount(edges[:, 0], ka * c[:, k], n) - np.bincount(edges[:, 1], kb * c[:, k], n)
            x[:, k] += RELAX_OMEGA * dx / count
        mid = 0.5 * (x[s0] + x[s1])
        x[s0], x[s1] = mid, mid
        if it % 5 == 4 or it == iterations - 1:
            gap = body.clearance(x)
            inside = gap < clearance
            if inside.any():   # push out horizontally (both seam copies alike: the same point, the same push)
                r = np.hypot(x[inside, 0], x[inside, 1])
                x[inside, :2] *= ((r + clearance - gap[inside]) / np.maximum(r, 1e-12))[:, None]
    return x


def _interpolate(coarse, coarse_layout, fine, fine_layout):
    """Positions of the fine mesh's vertices from the coarse mesh's: the coarse placement's piecewise-affine map
    from pattern to 3D (barycentric in the coarse triangle holding each fine vertex's uv, searched among the
    triangles of its band of rows), so the fine mesh inherits the coarse placement's strain."""
    out = np.empty((fine.num_vertices, 3))
    row_of = np.empty(coarse.num_vertices, np.int64)
    for c in coarse_layout:
        counts = np.diff(c["starts"])
        row_of[c["first"]:c["first"] + counts.sum()] = np.repeat(np.arange(len(counts)), counts)
    band_of_face = row_of[coarse.faces].min(axis=1)
    piece_of_face = np.searchsorted([c["first"] for c in coarse_layout], coarse.faces[:, 0], side="right") - 1
    for k, (c, f) in enumerate(zip(coarse_layout, fine_layout)):
        rows = c["rows"]
        band = np.clip(np.searchsorted(rows, f["rho"], side="right") - 1, 0, len(rows) - 2)
        idx = f["first"] + np.arange(f["rho"].size)
        for j in np.unique(band):
            pts = fine.uv[idx[band == j]]
            tri = coarse.faces[(band_of_face == j) & (piece_of_face == k)]
            a, b, cc = (coarse.uv[tri[:, m]] for m in range(3))
            v0, v1 = b - a, cc - a
            det = v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0]
            d = pts[:, None, :] - a[None]
            l1 = (d[..., 0] * v1[None, :, 1] - d[..., 1] * v1[None, :, 0]) / det
            l2 = (v0[None, :, 0] * d[..., 1] - v0[None, :, 1] * d[..., 0]) / det
            l0 = 1 - l1 - l2
            best = np.argmax(np.minimum(np.minimum(l0, l1), l2), axis=1)   # the triangle holding it (or nearest)
            w = np.stack([l0, l1, l2], axis=-1)[np.arange(len(pts)), best]
            out[idx[band == j]] = np.einsum("pk,pkd->pd", w, coarse.positions[tri[best]])
    return out


def _relaxed(g, layout, style, waist, length, waistband, vertices, body, z_waist, clearance, name):
    """The circle skirt's placement relaxed towards its pattern: relaxed at RELAX_COARSE_VERTICES (Jacobi
    relaxation needs more iterations the finer the mesh), interpolated to the requested resolution, polished."""
    if vertices <= RELAX_COARSE_VERTICES:
        g.positions = _relax(g, body, clearance, RELAX_ITERATIONS)
        return g
    coarse, coarse_layout = _build(style, waist, length, waistband, RELAX_COARSE_VERTICES, body, z_waist, clearance,
                                   name)
    coarse.positions = _relax(coarse, body, clearance, RELAX_ITERATIONS)
    start = _interpolate(coarse, coarse_layout, g, layout)
    g.positions = _relax(g, body, clearance, RELAX_POLISH_ITERATIONS, positions=start)
    return g


def _seam_pairs(positions, piece_ends, pieces, theta):
    """Pairs of vertices on the pieces' straight edges that meet in 3D (same row, same azimuth)."""
    ends = []  # (piece, row rho, azimuth, vertex)
    for k, (n0, rho, psi, beta) in enumerate(piece_ends):
        for edge in (-beta, beta):
            sel = np.flatnonzero(np.isclose(psi, edge))
            phi = np.mod(pieces[k][1] + edge * (2 * np.pi / theta), 2 * np.pi)
            ends += [(round(float(rho[i]), 9), round(float(phi), 6) % round(2 * np.pi, 6), n0 + i) for i in sel]
    groups = {}
    for rho, phi, vert in ends:
        groups.setdefault((rho, phi), []).append(vert)
    pairs = []
    for key, verts in groups.items():
        if len(verts) != 2:
            raise AssertionError(f"skirt seam: {len(verts)} vertices meet at {key}")  # a bug, not bad input
        pairs.append(sorted(verts))
    pairs = np.array(sorted(pairs), np.int32)
    d = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1)
    if d.max() > 1e-9:
        raise AssertionError(f"skirt seam: pairs {d.max():.3g} m apart")
    return pairs


def triangle_angles(points, faces):
    """(F, 3) interior angles (radians) of triangles of points (V, 2) or (V, 3)."""
    p = np.asarray(points, dtype=np.float64)
    f = np.asarray(faces)
    out = np.empty(f.shape)
    for k in range(3):
        a, b, c = p[f[:, k]], p[f[:, (k + 1) % 3]], p[f[:, (k + 2) % 3]]
        u, w = b - a, c - a
        cos = np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        out[:, k] = np.arccos(np.clip(cos, -1, 1))
    return out


def rest_strain(garment):
    """(F, 3) Green strain (G_uu, G_vv, G_uv) of the 3D placement against the pattern, per face."""
    p, uv, f = garment.positions, garment.uv, garment.faces
    Dm = np.stack([uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]], axis=2)     # (F, 2, 2)
    Ds = np.stack([p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]], axis=2)         # (F, 3, 2)
    F = Ds @ np.linalg.inv(Dm)
    G = 0.5 * (np.transpose(F, (0, 2, 1)) @ F - np.eye(2))
    return np.stack([G[:, 0, 0], G[:, 1, 1], G[:, 0, 1]], axis=1)
