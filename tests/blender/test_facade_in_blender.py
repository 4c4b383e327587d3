"""Headless Blender: the bpy-free facade and the native module load inside Blender's Python, a drape runs,
and its result becomes a Blender mesh. Run by ./drapelab test as
    blender --background --factory-startup --python-exit-code 1 --python tests/blender/test_facade_in_blender.py
"""
import os
import sys

import bpy

root = os.environ["DRAPELAB_ROOT"]  # Blender ignores PYTHONPATH: the launcher exports these
sys.path[:0] = [os.path.join(root, "addon"), os.environ["DRAPELAB_NATIVE_DIR"]]

import numpy as np  # noqa: E402

from drapelab import measure, render, sim, tables  # noqa: E402

model = sim.ClothModel(sim.cusick_specimen(1), density=tables.COTTON_BLUE.density)
params = model.parameters(stretch=tables.COTTON_BLUE.stretch, bend=tables.COTTON_BLUE.bend)
x = model.simulate(params, steps=20)
assert x.shape == (model.num_vertices, 3) and np.isfinite(x).all()
assert x[:, 2].min() < -0.01, "the outer ring should fall under gravity"

mesh = bpy.data.meshes.new("drape")
mesh.from_pydata(x.tolist(), [], model.faces.tolist())
mesh.update()
obj = bpy.data.objects.new("drape", mesh)
bpy.context.scene.collection.objects.link(obj)
assert len(obj.data.vertices) == model.num_vertices
assert len(obj.data.polygons) == len(model.faces)

mask = np.asarray(render.hard_silhouette(render.orthographic_camera(), x, model.faces))
dc = measure.drape_coefficient(mask)
assert 0.0 < dc < 1.0, dc
print(f"PASS test_facade_in_blender: {model.num_vertices} vertices, drape coefficient {dc:.3f} after 1 s")
