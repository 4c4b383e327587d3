"""Garment operators: Apply Material (per-element stiffness sampled from a preset's posterior, stored as FACE and
EDGE attributes `drapelab_*`) and the viewport heat map of one per-face attribute.

Geometry checks come from drapelab.garment.mesh.garment_from_arrays (its InputError messages): a non-mesh object,
no UV map (the `default_uv` option writes the documented default warp/weft as a UV map), quads or n-gons (the
`triangulate` option triangulates the Blender mesh first, so that each Blender face is one triangle and FACE
attributes map one to one), non-manifold edges, loose vertices.
"""
import bmesh
import bpy
import numpy as np
from bpy.props import BoolProperty, IntProperty, StringProperty

from .. import infer

HEAT_ATTRIBUTE = "drapelab_heat"   # the color attribute the heat map writes (corner domain)
DEFAULT_UV_NAME = "drapelab_warp_weft"
VIRIDIS = np.array([[0.267, 0.005, 0.329], [0.283, 0.141, 0.458], [0.254, 0.265, 0.530], [0.207, 0.372, 0.553],
                    [0.164, 0.471, 0.558], [0.128, 0.567, 0.551], [0.135, 0.659, 0.518], [0.267, 0.749, 0.441],
                    [0.478, 0.821, 0.318], [0.741, 0.873, 0.150], [0.993, 0.906, 0.144]])


def _material_modules():
    try:
        from ..garment import material, mesh
    except ImportError:
        return None
    if not all(hasattr(material, n) for n in ("sample_garment_material", "material_attributes")):
        return None
    return material, mesh


def mesh_arrays(obj):
    """(positions (V, 3) in metres, world space; polygons as a list of index arrays; per-corner uv list or None)."""
    me = obj.data
    n = len(me.vertices)
    co = np.empty(n * 3)
    me.vertices.foreach_get("co", co)
    co = co.reshape(n, 3)
    m = np.array(obj.matrix_world)
    positions = co @ m[:3, :3].T + m[:3, 3]
    loops = np.empty(len(me.loops), np.int64)
    me.loops.foreach_get("vertex_index", loops)
    starts = np.empty(len(me.polygons), np.int64)
    totals = np.empty(len(me.polygons), np.int64)
    me.polygons.foreach_get("loop_start", starts)
    me.polygons.foreach_get("loop_total", totals)
    polys = [loops[s:s + t] for s, t in zip(starts, totals)]
    uv = None
    if me.uv_layers.active is not None:
        data = np.empty(len(me.loops) * 2)
        me.uv_layers.active.data.foreach_get("uv", data)
        data = data.reshape(-1, 2)
        uv = [data[s:s + t] for s, t in zip(starts, totals)]
    return positions, polys, uv


def triangulate(obj):
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bmesh.ops.triangulate(bm, faces=[f for f in bm.faces if len(f.verts) > 3])
    bm.to_mesh(obj.data)
    bm.free()
    obj.data.update()


def write_default_uv(obj, mesh_module):
    positions, polys, _ = mesh_arrays(obj)
    faces = np.array(polys, dtype=np.int64)
    cuv = mesh_module.default_uv(positions, faces)  # (F, 3, 2) metres
    layer = obj.data.uv_layers.new(name=DEFAULT_UV_NAME)
    obj.data.uv_layers.active = layer
    layer.data.foreach_set("uv", np.asarray(cuv, dtype=np.float64).reshape(-1))
    return cuv


def original_vertex_map(garment, positions, faces):
    """For each garment vertex, the Blender vertex it was split from: Garment.source_vertices when the garment
    carries it, else matched through the faces (garment faces follow the Blender faces in order; a split copy
    has exactly its original's position)."""
    source = getattr(garment, "source_vertices", None)
    if source is not None and len(source) == garment.num_vertices:
        return np.asarray(source, np.int64)
    orig = np.full(garment.num_vertices, -1, np.int64)
    gf = np.asarray(garment.faces)
    for c in range(3):
        g = gf[:, c]
        d = np.stack([np.abs(garment.positions[g] - positions[faces[:, k]]).sum(axis=1) for k in range(3)], axis=1)
        orig[g] = faces[np.arange(len(faces)), np.argmin(d, axis=1)]
    return orig


def write_attributes(obj, attributes, bending_edges, vertex_map):
    """Writes {name: array}: length F arrays as FACE attributes, length E (bending edges) as EDGE attributes, on
    the edges between the bending edges' two (original) vertices. Returns the names written."""
    me = obj.data
    nf, ne_blender = len(me.polygons), len(me.edges)
    edge_of = {}
    ev = np.empty(ne_blender * 2, np.int64)
    me.edges.foreach_get("vertices", ev)
    for i, (a, b) in enumerate(ev.reshape(-1, 2)):
        edge_of[(min(a, b), max(a, b))] = i
    bend_index = None
    if bending_edges is not None and len(bending_edges):
        be = vertex_map[np.asarray(bending_edges, np.int64)]
        bend_index = np.array([edge_of.get((min(a, b), max(a, b)), -1) for a, b in be], np.int64)
    written = []
    for name, values in attributes.items():
        arr = np.asarray(values, dtype=np.float64)
        key = name if name.startswith("drapelab_") else "drapelab_" + name
        if arr.ndim != 1:
            raise ValueError(f"attribute {name}: expected one value per face or bending edge, got shape {arr.shape}")
        if key in me.attributes:
            me.attributes.remove(me.attributes[key])
        if arr.size == nf:
            attr = me.attributes.new(key, 'FLOAT', 'FACE')
            attr.data.foreach_set("value", arr.astype(np.float32))
        elif bend_index is not None and arr.size == bend_index.size:
            full = np.zeros(ne_blender, np.float32)  # boundary edges (no bending) hold 0
            ok = bend_index >= 0
            full[bend_index[ok]] = arr[ok]
            attr = me.attributes.new(key, 'FLOAT', 'EDGE')
            attr.data.foreach_set("value", full)
        else:
            raise ValueError(f"attribute {name}: {arr.size} values for {nf} faces and "
                             f"{0 if bend_index is None else bend_index.size} bending edges")
        written.append(key)
    me.update()
    return written


def stored_material(obj):
    """{"face_stretch_N_m": (F, 6, 4), "edge_bend_N_m": (E, 3, 5)} from the full-table attributes Apply Material
    wrote (drapelab_stretch_00.._23 per face, drapelab_bend_00.._14 per mesh edge), or None when the mesh has
    not all of them."""
    me = obj.data
    stretch_names = [f"drapelab_stretch_{k:02d}" for k in range(24)]
    bend_names = [f"drapelab_bend_{k:02d}" for k in range(15)]
    if not all(n in me.attributes for n in stretch_names + bend_names):
        return None

    def column(name, n):
        out = np.empty(n, np.float32)
        me.attributes[name].data.foreach_get("value", out)
        return out.astype(np.float64)
    nf, ne = len(me.polygons), len(me.edges)
    stretch = np.stack([column(n, nf) for n in stretch_names], axis=1).reshape(nf, 6, 4)
    bend = np.stack([column(n, ne) for n in bend_names], axis=1).reshape(ne, 3, 5)
    # Edges without a drapelab bending table (0): the mesh boundary, and the uv seams where the pattern is cut
    # (the garment model joins its pieces there by seams, not bending). Blender's cloth bends across a welded
    # seam, so they get the element-wise geometric mean of the tables drawn for the other edges.
    missing = ~(bend > 0).all(axis=(1, 2))
    if missing.any() and (~missing).any():
        bend[missing] = np.exp(np.log(bend[~missing]).mean(axis=0))
    return {"face_stretch_N_m": stretch, "edge_bend_N_m": bend}


def colormap(values):
    """RGBA (N, 4) of values scaled to their min..max through viridis (constant values: the middle colour)."""
    v = np.asarray(values, dtype=np.float64)
    lo, hi = float(v.min()), float(v.max())
    t = np.full(v.shape, 0.5) if hi <= lo else (v - lo) / (hi - lo)
    x = t * (len(VIRIDIS) - 1)
    i = np.clip(np.floor(x).astype(int), 0, len(VIRIDIS) - 2)
    w = (x - i)[:, None]
    rgb = VIRIDIS[i] * (1 - w) + VIRIDIS[i + 1] * w
    return np.column_stack([rgb, np.ones(len(v))])


def show_heat_map(context, obj, attribute):
    """Writes the face attribute through the colormap into the corner color attribute HEAT_ATTRIBUTE, makes it the
    active color and sets solid viewport shading to show attribute colours. Returns (min, max)."""
    me = obj.data
    if attribute not in me.attributes or me.attributes[attribute].domain not in ('FACE', 'EDGE'):
        raise ValueError(f"heat map: {obj.name} has no face or edge attribute {attribute!r} (Apply Material first)")
    totals = np.empty(len(me.polygons), np.int64)
    me.polygons.foreach_get("loop_total", totals)
    if me.attributes[attribute].domain == 'FACE':
        vals = np.empty(len(me.polygons), np.float32)
        me.attributes[attribute].data.foreach_get("value", vals)
    else:  # per bending edge: each face shows the mean of its interior edges (boundary edges hold 0)
        edge_vals = np.empty(len(me.edges), np.float32)
        me.attributes[attribute].data.foreach_get("value", edge_vals)
        loop_edges = np.empty(len(me.loops), np.int64)
        me.loops.foreach_get("edge_index", loop_edges)
        face_of_loop = np.repeat(np.arange(len(me.polygons)), totals)
        v = edge_vals[loop_edges]
        used = v > 0
        sums = np.bincount(face_of_loop, weights=np.where(used, v, 0.0), minlength=len(me.polygons))
        counts = np.bincount(face_of_loop, weights=used.astype(float), minlength=len(me.polygons))
        vals = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        vals = np.where(np.isnan(vals), np.nanmean(vals) if np.isfinite(vals).any() else 0.0, vals)
    rgba = colormap(vals)
    corner = np.repeat(rgba, totals, axis=0)
    if HEAT_ATTRIBUTE in me.color_attributes:
        me.color_attributes.remove(me.color_attributes[HEAT_ATTRIBUTE])
    col = me.color_attributes.new(HEAT_ATTRIBUTE, 'FLOAT_COLOR', 'CORNER')
    col.data.foreach_set("color", corner.astype(np.float32).reshape(-1))
    me.color_attributes.active_color = col
    me.update()
    for area in context.screen.areas if context.screen else []:
        if area.type == 'VIEW_3D':
            shading = area.spaces.active.shading
            shading.type = 'SOLID'
            shading.color_type = 'VERTEX'
    return float(vals.min()), float(vals.max())


class DRAPELAB_OT_apply_material(bpy.types.Operator):
    """Sample per-triangle stiffness from the preset's posterior onto the active mesh (face/edge attributes)"""
    bl_idname = "drapelab.apply_material"
    bl_label = "Apply Material"
    bl_options = {'REGISTER', 'UNDO'}

    preset: StringProperty(name="Preset", default="", description="preset name or path (default: the current)")
    seed: IntProperty(name="Seed", default=0, min=0)
    triangulate: BoolProperty(name="Triangulate", default=False,
                              description="triangulate quads and n-gons of the mesh first")
    default_uv: BoolProperty(name="Default warp/weft", default=False,
                             description="without a UV map: add the default cylindrical warp/weft UV map (warp up)")

    def execute(self, context):
        from .operators import _preset_argument
        mods = _material_modules()
        if mods is None:
            self.report({'ERROR'}, "apply_material: garment materials are not available in this build yet")
            return {'CANCELLED'}
        material, mesh_module = mods
        obj = context.active_object
        if obj is None:
            self.report({'ERROR'}, "apply_material: no active object; select the garment mesh")
            return {'CANCELLED'}
        if obj.type != 'MESH':
            self.report({'ERROR'}, f"apply_material: {obj.name} is not a mesh (its type is {obj.type}); select "
                                   "the garment mesh")
            return {'CANCELLED'}
        try:
            preset_path = _preset_argument(context, self.preset)
            preset = infer.load_preset(preset_path)
            positions, polys, uv = mesh_arrays(obj)
            sizes = {len(p) for p in polys}
            if sizes - {3}:
                if not self.triangulate:
                    n = sum(len(p) != 3 for p in polys)
                    raise ValueError(f"{obj.name}: {n} faces are quads or n-gons; run Apply Material with "
                                     "Triangulate on (or triangulate the mesh)")
                triangulate(obj)
                positions, polys, uv = mesh_arrays(obj)
            faces = np.array(polys, dtype=np.int64).reshape(-1, 3)
            if uv is None:
                if not self.default_uv:
                    raise ValueError(f"{obj.name}: no UV map: the warp/weft directions come from the UV map; run "
                                     "Apply Material with Default warp/weft on (cylindrical, warp up) or unwrap it")
                write_default_uv(obj, mesh_module)
                positions, polys, uv = mesh_arrays(obj)
            garment = mesh_module.garment_from_arrays(positions, faces, corner_uv=np.array(uv), name=obj.name)
            sampled = material.sample_garment_material(preset, garment, seed=self.seed, samples=1)[0]
            attributes = material.material_attributes(sampled)
            vmap = original_vertex_map(garment, positions, faces)
            written = write_attributes(obj, attributes, getattr(sampled, "bending_edges", None), vmap)
        except (ValueError, OSError, RuntimeError) as e:
            self.report({'ERROR'}, f"apply_material: {e}")
            return {'CANCELLED'}
        s = context.scene.drapelab
        s.garment = obj
        obj["drapelab_preset"] = (preset.get("fabric") or {}).get("name") or preset["model"]
        obj["drapelab_preset_path"] = preset_path  # Simulate draws the same material from it
        summaries = [n for n in written if not n[-2:].isdigit()]
        self.report({'INFO'}, f"{obj.name}: wrote {len(written)} attributes ({', '.join(summaries)} and the full "
                              "tables drapelab_stretch_00.._23, drapelab_bend_00.._14)")
        return {'FINISHED'}


class DRAPELAB_OT_show_heat_map(bpy.types.Operator):
    """Colour the garment in the viewport by the chosen per-face stiffness attribute"""
    bl_idname = "drapelab.show_heat_map"
    bl_label = "Show Heat Map"
    bl_options = {'REGISTER', 'UNDO'}

    attribute: StringProperty(name="Attribute", default="", description="face attribute (default: the panel's)")

    def execute(self, context):
        s = context.scene.drapelab
        obj = s.garment or context.active_object
        name = self.attribute or s.heat_attribute
        if obj is None or obj.type != 'MESH':
            self.report({'ERROR'}, "heat map: pick the garment mesh first")
            return {'CANCELLED'}
        if not name or name == "NONE":
            self.report({'ERROR'}, "heat map: choose an attribute (Apply Material writes them)")
            return {'CANCELLED'}
        try:
            lo, hi = show_heat_map(context, obj, name)
        except ValueError as e:
            self.report({'ERROR'}, str(e))
            return {'CANCELLED'}
        self.report({'INFO'}, f"{name}: {lo:.4g} (dark) .. {hi:.4g} (yellow)")
        return {'FINISHED'}


CLASSES = (DRAPELAB_OT_apply_material, DRAPELAB_OT_show_heat_map)


def garment_for_simulation(obj, collider):
    """(Garment, source vertex of each garment vertex, Body) for simulate_garment: the mesh in world space with its
    UV map (triangles only), its waistband (simulate.top_band_vertices) and hem (the bottom band), and the bundled
    dress form, which the collider must be (other bodies are not supported by the simulator yet)."""
    from ..garment import body as body_module, mesh as mesh_module
    if collider is None:
        raise ValueError("pick the collider (the dress form made by drapelab.garment.body.make_body)")
    body = body_module.make_body()
    if collider.type != 'MESH' or len(collider.data.vertices) != len(body.positions):
        raise ValueError(f"{collider.name}: the collider must be the bundled dress form "
                         f"(drapelab.garment.body.make_body); other bodies are not supported yet")
    bpos, _, _ = mesh_arrays(collider)
    if np.abs(bpos - body.positions).max() > 1e-4:
        raise ValueError(f"{collider.name}: the collider must be the bundled dress form, unmoved (its vertices "
                         "differ from drapelab.garment.body.make_body's)")
    positions, polys, uv = mesh_arrays(obj)
    if any(len(p) != 3 for p in polys):
        raise ValueError(f"{obj.name}: quads or n-gons: triangulate it (Apply Material with Triangulate on)")
    if uv is None:
        raise ValueError(f"{obj.name}: no UV map (run Apply Material with Default warp/weft on, or unwrap it)")
    faces = np.array(polys, dtype=np.int64).reshape(-1, 3)
    garment = mesh_module.garment_from_arrays(positions, faces, corner_uv=np.array(uv), name=obj.name)
    source = original_vertex_map(garment, positions, faces)
    from ..garment.simulate import WAIST_BAND_M, top_band_vertices
    garment.waist_vertices = top_band_vertices(garment.positions)
    # the hem (the simulator's hem radius statistic): the vertices within the same band of the lowest one
    z = np.asarray(garment.positions)[:, 2]
    garment.hem_vertices = np.flatnonzero(z < z.min() + WAIST_BAND_M).astype(np.int32)
    garment.blender_positions = positions
    return garment, source, body


def attach_mesh_cache(obj, path, frame_start=1):
    """Plays the PC2 file on `obj` (whose vertex order and count it must match) through a Mesh Cache modifier named
    "drapelab cache" (created or re-pointed): sample k is shown at scene frame frame_start + k. The positions in
    the file are the object's local coordinates."""
    from ..garment import pc2
    count = pc2.read_pc2_header(path)["num_points"]
    if count != len(obj.data.vertices):
        raise ValueError(f"{path}: the cache has {count} points, {obj.name} has {len(obj.data.vertices)} vertices")
    mod = obj.modifiers.get("drapelab cache") or obj.modifiers.new("drapelab cache", 'MESH_CACHE')
    mod.cache_format = 'PC2'
    mod.filepath = path
    mod.time_mode = 'FRAME'
    mod.play_mode = 'SCENE'
    mod.frame_start = float(frame_start)
    mod.frame_scale = 1.0
    mod.interpolation = 'LINEAR'
    return mod
