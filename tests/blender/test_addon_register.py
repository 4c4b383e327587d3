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
assert len(s.history()) == 1
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
assert s.enabled_effects() == {d["ranking"][0]["effect"]: None}

# -- cancel with nothing running is a warning, not an error
assert bpy.ops.drapelab.cancel() == {'CANCELLED'}
print(f"PASS test_addon_register: operators, fit ({timings['fit']:.1f} s), presets, diagnose "
      f"({timings['diagnose']:.1f} s)")
