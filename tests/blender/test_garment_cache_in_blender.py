"""Headless Blender: a generated skirt written by drapelab.garment.mesh.write_garment_obj imports into Blender with
its UV map (welded seams, uv in metres), and a PC2 cache written by drapelab.garment.pc2 plays on it through the
Mesh Cache modifier, frame by frame. Run by ./drapelab test as
    blender --background --factory-startup --python-exit-code 1 --python tests/blender/test_garment_cache_in_blender.py
"""
import os
import sys
import tempfile

import bpy

root = os.environ["DRAPELAB_ROOT"]  # Blender ignores PYTHONPATH: the launcher exports these
sys.path[:0] = [os.path.join(root, "addon"), os.environ["DRAPELAB_NATIVE_DIR"]]

import numpy as np  # noqa: E402

from drapelab.garment import body, mesh, pc2, skirt  # noqa: E402

folder = tempfile.mkdtemp(prefix="drapelab_garment_")
g = skirt.make_skirt("aline", vertices=800)
obj_path = os.path.join(folder, "skirt.obj")
mesh.write_garment_obj(obj_path, g)

bpy.ops.object.select_all(action="SELECT")
bpy.ops.object.delete()
bpy.ops.wm.obj_import(filepath=obj_path, forward_axis="Y", up_axis="Z")
obj = bpy.context.selected_objects[0]
me = obj.data
point = g.point_index()
n_points = int(point.max()) + 1
assert len(me.vertices) == n_points, (len(me.vertices), n_points)
co = np.empty(n_points * 3)
me.vertices.foreach_get("co", co)
co = co.reshape(-1, 3)
expected = np.zeros((n_points, 3))
expected[point] = g.positions
assert np.abs(co - expected).max() < 1e-6, np.abs(co - expected).max()     # the file's vertex order, no axis swap
assert me.uv_layers.active is not None, "the OBJ's vt did not become a UV map"
uv = np.empty(len(me.loops) * 2)
me.uv_layers.active.data.foreach_get("uv", uv)
loops = np.empty(len(me.loops), np.int64)
me.loops.foreach_get("vertex_index", loops)
# every loop's uv is one of its point's pattern copies (metres)
uv = uv.reshape(-1, 2)
copies = {}
for v, p in enumerate(point):
    copies.setdefault(int(p), []).append(g.uv[v])
worst = max(min(np.abs(uv[k] - c).max() for c in copies[int(loops[k])]) for k in range(len(loops)))
assert worst < 1e-5, worst

# the Mesh Cache modifier plays a PC2 written frame by frame (points in the mesh's vertex order)
motion = body.pelvis_transforms("twirl", 6)
cache = os.path.join(folder, "skirt.pc2")
with pc2.PC2Writer(cache, n_points, start_frame=1) as writer:
    for T in motion:
        writer.write_frame(expected @ T[:3, :3].T + T[:3, 3])
mod = obj.modifiers.new("drapelab cache", "MESH_CACHE")
mod.cache_format = "PC2"
mod.filepath = cache
mod.time_mode = "FRAME"
mod.play_mode = "SCENE"
mod.frame_start = 1.0
mod.interpolation = "NONE"
scene = bpy.context.scene
worst = 0.0
for k in (0, 3, 5):
    scene.frame_set(1 + k)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    got = np.empty(n_points * 3)
    evaluated.data.vertices.foreach_get("co", got)
    want = expected @ motion[k][:3, :3].T + motion[k][:3, 3]
    worst = max(worst, float(np.abs(got.reshape(-1, 3) - want).max()))
assert worst < 1e-5, worst
assert np.abs(motion[5][:3, :3] - np.eye(3)).max() > 1e-3, "the twirl should have turned the skirt by frame 5"
print(f"PASS test_garment_cache_in_blender: {n_points} points with UVs imported; PC2 of {len(motion)} frames "
      f"played by the Mesh Cache modifier (max error {worst:.1e} m)")
