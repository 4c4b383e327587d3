"""Headless Blender: the add-on registers and unregisters cleanly (twice), every contract operator exists and runs
on bundled data, bad input is reported, and an unregister stops a running job. Run by ./drapelab test as
    blender --background --factory-startup --python-exit-code 1 --python tests/blender/test_addon_register.py
(about a minute: a 1-epoch homo fit on circle1 and a 3-draw diagnosis of it).
"""
import json
import math
import os
import shutil
import sys
import tempfile
import time

import bpy

root = os.environ["DRAPELAB_ROOT"]  # Blender ignores PYTHONPATH: the launcher exports these
sys.path[:0] = [os.path.join(root, "addon"), os.environ["DRAPELAB_NATIVE_DIR"]]

import numpy as np  # noqa: E402

import drapelab  # noqa: E402

IMAGE = os.path.join(root, "assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
SHIPPED = os.path.join(root, "assets", "presets", "fabric_02_cotton_blue_bdp.json")
CONTRACT = ["import_images", "fit", "cancel", "diagnose", "add_effect", "save_preset", "load_preset",
            "apply_material", "simulate_garment", "export_blender_cloth"]
tmp = tempfile.mkdtemp(prefix="drapelab_addon_test_")
timings = {}


def expect_error(call, fragment):
    """The operator must fail with an ERROR report containing `fragment` (bpy.ops raises RuntimeError for it)."""
    try:
        result = call()
    except RuntimeError as e:
        assert fragment in str(e), f"expected {fragment!r} in the error, got: {e}"
        return str(e)
    raise AssertionError(f"expected an error mentioning {fragment!r}, the operator returned {result}")


def ok(result, what):
    if result != {'FINISHED'}:
        raise AssertionError(f"{what} returned {result}")


# -- register / unregister twice
for _ in range(2):
    drapelab.register()
    assert hasattr(bpy.types.Scene, "drapelab")
    for name in CONTRACT:
        assert hasattr(bpy.types, f"DRAPELAB_OT_{name}"), f"operator drapelab.{name} is not registered"
    assert bpy.types.DRAPELAB_PT_fit.bl_category == "Drape"
    drapelab.unregister()
    assert not hasattr(bpy.types.Scene, "drapelab") and not hasattr(bpy.types, "DRAPELAB_OT_fit")
drapelab.register()

from drapelab import infer, sim  # noqa: E402
from drapelab.ui import jobs, operators, tasks  # noqa: E402

operators.user_presets_dir = lambda: os.path.join(tmp, "user_presets")  # never the tester's own presets
os.makedirs(operators.user_presets_dir())
s = bpy.context.scene.drapelab
assert s.model == "BDP" and {e["name"] for e in sim.effects()} <= set(s.effects.bl_rna.properties.keys())

# -- measurement: an unreadable image is refused and adds nothing; the bundled image fills the fabric
bad = os.path.join(tmp, "broken.jpg")
with open(bad, "wb") as f:
    f.write(b"\xff\xd8 this is not a jpeg")
expect_error(lambda: bpy.ops.drapelab.import_images(filepath=bad), "broken.jpg")
assert len(s.images) == 0
ok(bpy.ops.drapelab.import_images(directory=os.path.dirname(IMAGE) + os.sep,
                                  files=[{"name": os.path.basename(IMAGE)}]), "import_images")
assert len(s.images) == 1 and abs(s.images[0].drape_coefficient - 0.670) < 0.01
assert s.fabric_name == "Cotton Blue" and abs(s.density - 0.192) < 1e-6
img = bpy.data.images[s.measurement_image]
assert img.size[0] > 100 and img.size[1] > 100

# -- the picture follows the selected image; calibration from a flat disk (a draped one is refused)
ok(bpy.ops.drapelab.import_images(filepath=os.path.join(root, "assets", "cusick", "fabric_05", "silhouettes",
                                                        "sample_01_capture_1.jpg")), "import a second image")
assert len(s.images) == 2 and "sample_01" in bpy.data.images[s.measurement_image].filepath
s.active_image = 0
assert "sample_02" in bpy.data.images[s.measurement_image].filepath
ok(bpy.ops.drapelab.remove_image(), "remove_image")
assert len(s.images) == 1 and "sample_01" in s.images[0].filepath
s.active_image = 0
ok(bpy.ops.drapelab.remove_image(), "remove_image")
ok(bpy.ops.drapelab.import_images(filepath=IMAGE), "import_images again")
assert len(s.images) == 1 and s.fabric_name == "Cotton Blue"
expect_error(lambda: bpy.ops.drapelab.calibrate_from_disk(filepath=IMAGE), "not a flat disk")
from drapelab import measure  # noqa: E402

disk_px_per_m, disk_centre = 800.0, (150.0, 140.0)
yy, xx = np.mgrid[0:300, 0:320] + 0.5
flat_disk = np.where(np.hypot(xx - disk_centre[0], yy - disk_centre[1]) <= 0.15 * disk_px_per_m, 0.1, 0.95)
measure.write_image(os.path.join(tmp, "flat.png"), flat_disk)
ok(bpy.ops.drapelab.calibrate_from_disk(filepath=os.path.join(tmp, "flat.png")), "calibrate_from_disk")
assert abs(s.px_per_m - disk_px_per_m) < 0.01 * disk_px_per_m and not s.centre_auto, s.px_per_m
assert abs(s.centre_x - disk_centre[0]) < 1.0 and abs(s.centre_y - disk_centre[1]) < 1.0, (s.centre_x, s.centre_y)
s.px_per_m, s.centre_auto = 720.0, True

# -- fit: arguments checked, then a 1-epoch homo fit on circle1 writes a preset and the previews
expect_error(lambda: bpy.ops.drapelab.fit(epochs=1, time_budget=5.0), "not both")
s.model, s.mesh_level, s.seed = "HOMO", 1, 0
t = time.monotonic()
ok(bpy.ops.drapelab.fit(epochs=1), "fit")
timings["fit"] = time.monotonic() - t
preset = infer.load_preset(s.preset_path)
assert preset["model"] == "homo" and preset["training"]["epochs"] == 1 and preset["fabric"]["name"] == "Cotton Blue"
metrics = json.loads(s.metrics_json)["metrics"]
assert 0.5 < metrics["iou"] <= 1.0, metrics
assert bpy.data.images[s.overlay_image].size[0] > 100 and bpy.data.images[s.rtheta_image].size[0] > 100
assert len(s.history()) == 1 and bpy.data.images[s.history_image].size[0] > 100  # the chart redrawn after a fit
assert jobs.current("fit").state.status == jobs.DONE

# -- presets: export to a file, load it back, save as a user preset by name, refuse a bad file
exported = os.path.join(tmp, "exported.json")
ok(bpy.ops.drapelab.save_preset(filepath=exported), "save_preset")
with open(exported) as f:
    assert json.load(f)["posterior"] == preset["posterior"]
ok(bpy.ops.drapelab.load_preset(filepath=SHIPPED), "load_preset shipped")
assert s.model == "BDP" and s.preset_path == SHIPPED
ok(bpy.ops.drapelab.load_preset(filepath=exported), "load_preset exported")
assert s.preset_path == exported and s.model == "HOMO" and infer.load_preset(s.preset_path) == preset
ok(bpy.ops.drapelab.save_preset(name="my cotton"), "save_preset by name")
assert os.path.isfile(os.path.join(operators.user_presets_dir(), "my_cotton.json"))
not_a_preset = os.path.join(tmp, "not_a_preset.json")
with open(not_a_preset, "w") as f:
    f.write('{"kind": "something else"}')
expect_error(lambda: bpy.ops.drapelab.load_preset(filepath=not_a_preset), "not a drapelab material preset")
assert s.preset_path == exported

# -- diagnose: argument checks, then 3 draws of the circle1 preset with a small budget
expect_error(lambda: bpy.ops.drapelab.diagnose(samples=2), "at least 3")
t = time.monotonic()
ok(bpy.ops.drapelab.diagnose(samples=3, time_budget=40.0), "diagnose")
timings["diagnose"] = time.monotonic() - t
d = operators.diagnosis(s)
assert d is not None and d["draws_used"] >= 1 and len(d["ranking"]) >= 1, d
assert os.path.isfile(os.path.join(os.path.dirname(s.diagnosis_path), "index.html"))
assert s.history_image and len(s.history()) == 2
expect_error(lambda: bpy.ops.drapelab.add_effect(effect="gravity_waves"), "unknown effect")
ok(bpy.ops.drapelab.add_effect(effect=d["ranking"][0]["effect"]), "add_effect")
assert s.enabled_effects() == {d["ranking"][0]["effect"]: None} and s.init_path == ""
# Add with the diagnosis's refit: the next fit starts from it (fit --init), and the start is then cleared
expect_error(lambda: bpy.ops.drapelab.add_effect(effect="tilt", refit=os.path.join(tmp, "missing.json")),
             "no such file")
ok(bpy.ops.drapelab.add_effect(effect=d["ranking"][0]["effect"], refit=SHIPPED), "add_effect with its refit")
assert s.init_path == SHIPPED
ok(bpy.ops.drapelab.fit(epochs=1), "fit from the refit")
continued = infer.load_preset(s.preset_path)
assert continued["training"]["init"]["preset"] == SHIPPED and s.init_path == "", continued["training"].get("init")
assert d["ranking"][0]["effect"] in continued["active_effects"]

# -- cancel with nothing running is a warning, not an error
assert bpy.ops.drapelab.cancel() == {'CANCELLED'}
print(f"PASS test_addon_register: operators, fit ({timings['fit']:.1f} s), presets, diagnose "
      f"({timings['diagnose']:.1f} s)")

# ---------------------------------------------------------------- garments
from drapelab.ui import garment_ops  # noqa: E402

ok(bpy.ops.drapelab.load_preset(filepath=SHIPPED), "load_preset for the garment")
shipped = infer.load_preset(SHIPPED)


def tube(name, uv=True, quads=False, rings=8, segments=24, radius=0.3, height=0.5):
    """An open tube (a skirt-like surface) with a cylindrical UV map (u around, v up) or none."""
    verts = [(radius * math.cos(2 * math.pi * j / segments), radius * math.sin(2 * math.pi * j / segments),
              height * i / (rings - 1)) for i in range(rings) for j in range(segments)]
    faces, uvs = [], []
    for i in range(rings - 1):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            c, d = b + segments, a + segments
            ua, ub = j / segments, (j + 1) / segments
            va, vb = i / (rings - 1), (i + 1) / (rings - 1)
            if quads:
                faces.append((a, b, c, d))
                uvs.append([(ua, va), (ub, va), (ub, vb), (ua, vb)])
            else:
                faces += [(a, b, c), (a, c, d)]
                uvs += [[(ua, va), (ub, va), (ub, vb)], [(ua, va), (ub, vb), (ua, vb)]]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    if uv:
        layer = me.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.array([c for f in uvs for c in f], dtype=np.float64).ravel())
    me.update()
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def activate(obj):
    bpy.context.view_layer.objects.active = obj
    for o in bpy.context.scene.objects:
        o.select_set(o is obj)


empty = bpy.data.objects.new("not a mesh", None)
bpy.context.scene.collection.objects.link(empty)
activate(empty)
expect_error(lambda: bpy.ops.drapelab.apply_material(), "not a mesh")
quad_tube = tube("quad skirt", quads=True)
activate(quad_tube)
expect_error(lambda: bpy.ops.drapelab.apply_material(), "quads or n-gons")
ok(bpy.ops.drapelab.apply_material(triangulate=True), "apply_material triangulate")
assert all(len(p.vertices) == 3 for p in quad_tube.data.polygons)
bare = tube("no uv skirt", uv=False)
activate(bare)
expect_error(lambda: bpy.ops.drapelab.apply_material(), "no UV map")
ok(bpy.ops.drapelab.apply_material(default_uv=True), "apply_material default uv")
assert garment_ops.DEFAULT_UV_NAME in bare.data.uv_layers

# bad geometry is named before anything runs: three faces on one edge, a vertex in no face
def flat(name, verts, faces):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    layer = me.uv_layers.new(name="UVMap")
    layer.data.foreach_set("uv", np.array([verts[i][:2] for f in faces for i in f], dtype=np.float64).ravel())
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


fin = flat("fin", [(0, 0, 0), (1, 0, 0), (0.5, 1, 0), (0.5, -1, 0), (0.5, 0.2, 1)], [(0, 1, 2), (1, 0, 3), (0, 1, 4)])
activate(fin)
expect_error(lambda: bpy.ops.drapelab.apply_material(), "non-manifold edge")
loose = flat("loose", [(0, 0, 0), (1, 0, 0), (0, 1, 0), (3, 3, 0)], [(0, 1, 2)])
activate(loose)
expect_error(lambda: bpy.ops.drapelab.apply_material(), "loose vertex 3")
assert not [a for a in fin.data.attributes if a.name.startswith("drapelab_")]

skirt = tube("skirt")
activate(skirt)
ok(bpy.ops.drapelab.apply_material(preset="fabric_02_cotton_blue_bdp", seed=3), "apply_material")
attrs = skirt.data.attributes
F = len(skirt.data.polygons)
weft = np.empty(F, np.float32)
attrs["drapelab_stretch_weft"].data.foreach_get("value", weft)
assert attrs["drapelab_stretch_weft"].domain == 'FACE'
assert np.allclose(weft, shipped["stretch_N_m"][0][0], rtol=1e-6)  # presets fit bending only: one table
bend = np.empty(len(skirt.data.edges), np.float32)
assert attrs["drapelab_bend_warp"].domain == 'EDGE'
attrs["drapelab_bend_warp"].data.foreach_get("value", bend)
interior = bend > 0
n_interior = int(interior.sum())
# the open tube: every edge bends but the two boundary rings and the 7 edges of the uv seam (u = 1 -> 0), where the
# pattern is cut into a sheet (its two sides are held by the garment simulator's seams, not by bending)
assert n_interior == len(skirt.data.edges) - 2 * 24 - 7, (n_interior, len(skirt.data.edges))
post = shipped["posterior"]["bend"]
log_b = np.log(bend[interior])
sd = post["log_std"][0][0]
g = post.get("global_log_std", 0.0)
# draws from the posterior: per-edge log spread = log_std, the draw's common factor ~ N(0, g)
assert abs(log_b.std() - sd) < 0.25 * sd + 1e-3, (log_b.std(), sd)
assert abs(log_b.mean() - post["log_mean"][0][0]) < 4 * g + 4 * sd / math.sqrt(n_interior) + 1e-6, \
    (log_b.mean(), post["log_mean"][0][0], g)
s.garment = skirt
ok(bpy.ops.drapelab.show_heat_map(attribute="drapelab_bend_warp"), "heat map")
heat = skirt.data.color_attributes[garment_ops.HEAT_ATTRIBUTE]
colours = np.empty(len(skirt.data.loops) * 4, np.float32)
heat.data.foreach_get("color", colours)
assert colours.reshape(-1, 4)[:, :3].std(axis=0).max() > 0.05, "the heat map should vary over the faces"

# -- Export to Blender Cloth: the modifier, with Apply Material's field as vertex groups
ok(bpy.ops.drapelab.export_blender_cloth(), "export_blender_cloth")
assert any(m.type == 'CLOTH' for m in skirt.modifiers)
assert {"drapelab_tension", "drapelab_bending"} <= set(skirt.vertex_groups.keys()), skirt.vertex_groups.keys()

# -- simulate: no garment simulator in this build yet, said clearly
try:
    from drapelab.garment import simulate as _sim  # noqa: F401
    has_simulator = hasattr(_sim, "drape")
except ImportError:
    has_simulator = False
if not has_simulator:
    expect_error(lambda: bpy.ops.drapelab.simulate_garment(frame_start=1, frame_end=5),
                 "garment simulation is not available in this build yet")
expect_error(lambda: bpy.ops.drapelab.simulate_garment(frame_start=5, frame_end=5), "must be after")
if has_simulator:  # a collider that is not the bundled dress form is refused before anything runs
    expect_error(lambda: bpy.ops.drapelab.simulate_garment(frame_start=1, frame_end=3, collider=skirt.name),
                 "bundled dress form")

# -- a PC2 cache written frame by frame plays back through the Mesh Cache modifier
from drapelab.garment import pc2  # noqa: E402

plate = tube("cached", rings=2, segments=6)
rest = np.array([v.co[:] for v in plate.data.vertices])
cache = os.path.join(tmp, "cached.pc2")
with pc2.PC2Writer(cache, len(rest), start_frame=1) as w:
    for k in range(4):
        w.write_frame(rest + np.array([0.0, 0.0, 0.1 * k]))
garment_ops.attach_mesh_cache(plate, cache, frame_start=1)
for frame, k in ((1, 0), (3, 2), (4, 3)):
    bpy.context.scene.frame_set(frame)
    evaluated = plate.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    z = np.array([v.co.z for v in evaluated.vertices])
    assert np.allclose(z, rest[:, 2] + 0.1 * k, atol=1e-6), (frame, z[:3], rest[:3, 2])
try:
    garment_ops.attach_mesh_cache(skirt, cache)
    raise AssertionError("a cache of another vertex count must be refused")
except ValueError as e:
    assert "6" in str(e) or "12" in str(e)

# ---------------------------------------------------------------- jobs: cancel, a .blend saved mid-job, unregister
def long_fit():
    return tasks.fit_work(s.image_paths(), 0.192, os.path.join(tmp, "job"), model="homo", epochs=200, mesh_level=2,
                          calibrate=False)


job = jobs.start("fit", long_fit())
time.sleep(1.0)
assert job.alive
expect_error(lambda: bpy.ops.drapelab.fit(epochs=1), "job is running")  # one long job at a time
ok(bpy.ops.drapelab.cancel(), "cancel")
assert job.join(2.0) and job.state.status == jobs.CANCELLED
print(f"cancel: the worker stopped {1000 * (job.state.finished - job.state.cancel_requested_at):.0f} ms after "
      "drapelab.cancel")

job = jobs.start("fit", long_fit())
time.sleep(1.0)
mid_job = os.path.join(tmp, "saved_mid_job.blend")
bpy.ops.wm.save_as_mainfile(filepath=mid_job, copy=True)
t = time.monotonic()
drapelab.unregister()
stopped = time.monotonic() - t
assert not job.alive and job.state.status == jobs.CANCELLED, job.state.status
assert stopped < 2.0, stopped
assert not hasattr(bpy.types.Scene, "drapelab")
# the file saved while the fit ran reopens idle: its settings and results are there, no job runs, a fit can start;
# opening it while another fit runs stops that fit (its result belongs to the file it started in)
drapelab.register()
job = jobs.start("fit", long_fit())
time.sleep(1.0)
assert job.alive
bpy.ops.wm.open_mainfile(filepath=mid_job)
assert not job.alive and job.state.status == jobs.CANCELLED and jobs.current("fit") is None
s = bpy.context.scene.drapelab
assert s.preset_path == SHIPPED and len(s.images) == 1 and not jobs.running_jobs()
drapelab.unregister()
assert not [h for h in bpy.app.handlers.load_pre if "drapelab" in getattr(h, "__module__", "")]
shutil.rmtree(tmp, ignore_errors=True)
shutil.rmtree(operators.cache_dir(), ignore_errors=True)  # the unsaved file's cache in the temp folder
print(f"PASS test_addon_register: garment attributes from the posterior, heat map, cloth export, PC2 playback, "
      f"unregister stopped a running fit in {1000 * stopped:.0f} ms")
