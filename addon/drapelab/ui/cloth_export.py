"""Export to Blender Cloth (bpy only): a drapelab preset as the settings of Blender's own cloth modifier.

The numbers come from the bpy-free drapelab.blender_cloth (derivation: docs/lab/blender-cloth.md); this module
only reads the object's mesh and writes the modifier and its vertex groups. Called by the operator
drapelab.export_blender_cloth and by tools/blender scripts.
"""
import bpy  # noqa: F401  (this module only runs inside Blender)
import numpy as np

from .. import blender_cloth
from .._native import InputError

__all__ = ["apply_cloth_settings", "mesh_arrays"]


def mesh_arrays(obj):
    """World-space rest positions (V, 3) and triangles (F, 3) of a mesh object (Blender's cloth runs in world
    space on the mesh's triangulation), and whether every polygon already is a triangle."""
    if obj is None or getattr(obj, "type", None) != "MESH":
        raise InputError(f"object: Export to Blender Cloth needs a mesh object, got "
                         f"{getattr(obj, 'type', type(obj).__name__)} {getattr(obj, 'name', '')!r}".rstrip())
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise InputError(f"{obj.name}: the mesh has no faces (Blender's cloth needs a surface)")
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    m = np.array(obj.matrix_world)
    x = co @ m[:3, :3].T + m[:3, 3]
    mesh.calc_loop_triangles()
    tri = np.empty(len(mesh.loop_triangles) * 3, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", tri)
    sizes = np.empty(len(mesh.polygons), dtype=np.int64)
    mesh.polygons.foreach_get("loop_total", sizes)
    return x, tri.reshape(-1, 3), bool(np.all(sizes == 3))


def _cloth_modifier(obj):
    for mod in obj.modifiers:
        if mod.type == "CLOTH":
            return mod
    return obj.modifiers.new("Cloth", "CLOTH")


def _write_group(obj, name, weights):
    group = obj.vertex_groups.get(name) or obj.vertex_groups.new(name=name)
    # one add() call per distinct weight value keeps this fast on big meshes
    w = np.round(np.asarray(weights, dtype=float), 4)
    for value in np.unique(w):
        group.add([int(i) for i in np.flatnonzero(w == value)], float(value), "REPLACE")
    return group


def _hinge_values(obj, x, tri, edge_values):
    """Per-mesh-edge values (E,) or (E, 3, 5) in mesh_statistics' hinge order."""
    mesh = obj.data
    values = np.asarray(edge_values, dtype=float)
    if values.shape[0] != len(mesh.edges):
        raise InputError(f"material edge_bend_N_m: expected one value per mesh edge ({len(mesh.edges)}), "
                         f"got {values.shape[0]}")
    ev = np.empty(len(mesh.edges) * 2, dtype=np.int64)
    mesh.edges.foreach_get("vertices", ev)
    ev = np.sort(ev.reshape(-1, 2), axis=1)
    index = {(int(a), int(b)): i for i, (a, b) in enumerate(ev)}
    hinges = blender_cloth.mesh_statistics(x, tri)["hinge_edges"]
    return values[[index[(int(a), int(b))] for a, b in hinges]]


def apply_cloth_settings(obj, preset, material=None, *, quality=blender_cloth.DEFAULT_QUALITY, pin_group=None,
                         self_collision=None, **mapping):
    """Adds (or updates) the Cloth modifier of mesh object `obj` with the settings of `preset` (a preset dict or
    a path) on this mesh, and returns the modifier.

    material (optional): a per-element material on this (triangle) mesh, {"face_stretch_N_m": (F, 6, 4) or
    (F, 4) per polygon, "edge_bend_N_m": (E, 3, 5) or (E,) per mesh edge (values on boundary edges are
    ignored)}; each given field becomes a vertex group (drapelab_tension, drapelab_bending) with the
    modifier's base and *_stiffness_max values as its range. pin_group: the vertex group pinned (kept: the
    modifier's current one when None). self_collision: turn Blender's self collision on/off (None: unchanged).
    mapping: further options of ``blender_cloth.cloth_settings`` (curvature, bend_calibration,
    collision_distance_m).
    """
    x, tri, all_triangles = mesh_arrays(obj)
    mod = _cloth_modifier(obj)
    current_pin = mod.settings.vertex_group_mass
    pin = current_pin if pin_group is None else pin_group
    if pin and pin not in obj.vertex_groups:
        raise InputError(f"{obj.name}: no vertex group {pin!r} to pin")
    values = blender_cloth.cloth_settings(preset, quality, mesh=(x, tri), fps=bpy.context.scene.render.fps,
                                          pin_group=pin, **mapping)
    groups = {}
    if material is not None:
        if not isinstance(material, dict) or not set(material) <= {"face_stretch_N_m", "edge_bend_N_m"}:
            raise InputError("material: expected {'face_stretch_N_m': per polygon, 'edge_bend_N_m': per mesh edge}")
        if not all_triangles:
            raise InputError(f"{obj.name}: a per-element material needs a triangle mesh (triangulate it first)")
        stretch = material.get("face_stretch_N_m")
        bend = material.get("edge_bend_N_m")
        if bend is not None:
            bend = _hinge_values(obj, x, tri, bend)
            if bend.ndim == 3:  # tables: read as the scalar was (at its curvature, or scaled to the secant)
                d = values["derivation"]
                median = np.exp(np.asarray(blender_cloth._preset_arg(preset)["posterior"]["bend"]["log_mean"]))
                at = blender_cloth._bend_at(median, d["bend_curvature_per_m"]) if d["bend_reading"] == "secant" else None
                bend = blender_cloth._bend_at(bend, d["bend_curvature_per_m"])
                if at is not None:
                    bend = bend * (d["bend_stiffness_N_m"] / at)
        groups = blender_cloth.vertex_group_weights(
            x, tri, face_stretch_N_m=stretch, hinge_bend_N_m=bend,
            bend_calibration=values["derivation"]["bend_calibration"])
    s = mod.settings
    for key, value in values.items():
        if key not in ("collision_settings", "derivation"):
            setattr(s, key, value)
    for key, value in values["collision_settings"].items():
        setattr(mod.collision_settings, key, value)
    if self_collision is not None:
        mod.collision_settings.use_self_collision = bool(self_collision)
    prefix = {"tension": ("tension", "compression"), "bending": ("bending",)}
    for field, group in groups.items():
        _write_group(obj, group["group"], group["weights"])
        for p in prefix[field]:
            setattr(s, f"{p}_stiffness", group["min"])
            setattr(s, f"{p}_stiffness_max", group["max"])
        if field == "tension":
            s.vertex_group_structural_stiffness = group["group"]
        else:
            s.vertex_group_bending = group["group"]
    return mod
