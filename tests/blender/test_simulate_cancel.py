"""Headless Blender: drapelab.simulate_garment's bake cancelled mid-way, stopped by its time limit, cancelled before
its first frame, and unregistered while it runs; a moving collider. Run by ./drapelab test as
    blender --background --factory-startup --python-exit-code 1 --python tests/blender/test_simulate_cancel.py

The bake runs as the operator's invoke starts it, in a worker process (operators.simulation_job gathers a jobs.Task
from bpy, jobs.start runs it; the test polls it as the modal operator's timer would), since modal operators never
run under --background. Checked after each stop: the PC2 cache is
valid (its header counts exactly the frames in the file, all complete), holds the frames done, plays in the Mesh
Cache modifier, and the scene is not left half-set (one cache modifier, the mesh itself untouched, no temporary or
side files); a bake stopped before its first simulated frame leaves the previous cache byte for byte.
"""
import glob
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

drapelab.register()
from drapelab.garment import body as body_module, pc2, skirt as skirt_module  # noqa: E402
from drapelab.ui import headless, jobs, operators  # noqa: E402

tmp = tempfile.mkdtemp(prefix="drapelab_bake_test_")
operators.cache_dir = lambda: os.path.join(tmp, "cache")  # the operator module's view of the cache folder
CANCEL_LIMIT_S = 1.0   # the bound for Cancel (checked between substeps)
FRAMES = 60            # far more than any stopped bake reaches


def local_positions(obj, evaluated=True):
    if evaluated:
        me = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
    else:
        me = obj.data
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def wait_for(job, frames_written, timeout=120.0):
    t = time.monotonic()
    while job.state.metrics.get("frames_written", 0) < frames_written:
        assert job.alive, f"the bake ended before {frames_written} frames: {job.state.snapshot()}"
        assert time.monotonic() - t < timeout, f"no frame {frames_written} after {timeout} s"
        time.sleep(0.02)


def check_cache(path, frames, obj):
    """The cache is complete and consistent: its header counts `frames`, the file holds exactly those, it plays."""
    h = pc2.read_pc2_header(path)
    assert h["num_samples"] == frames, (h, frames)
    assert h["num_points"] == len(obj.data.vertices)
    assert h["file_size"] == pc2.HEADER_SIZE + frames * h["num_points"] * 12, h
    x = pc2.read_pc2(path)
    assert np.isfinite(x).all()
    mods = [m for m in obj.modifiers if m.type == 'MESH_CACHE']
    assert len(mods) == 1 and mods[0].name == "drapelab cache" and mods[0].filepath == path, [m.name for m in mods]
    bpy.context.scene.frame_set(int(mods[0].frame_start) + frames - 1)
    played = local_positions(obj)
    assert np.abs(played - x[-1]).max() < 1e-5, np.abs(played - x[-1]).max()
    return x


def leftovers():
    return sorted(os.path.basename(p) for p in glob.glob(os.path.join(tmp, "cache", ".*")) +
                  glob.glob(os.path.join(tmp, "cache", "*simulator_order*")))


# the demo scene: the bundled dress form and a small circle skirt on it (welded seams, pattern as UV map)
for obj in list(bpy.data.objects):
    bpy.data.objects.remove(obj)
body = body_module.make_body()
g = skirt_module.make_skirt("circle", vertices=500, body=body)
body_obj = headless.mesh_object("body", body.positions, body.faces)
point = g.point_index()
points = np.zeros((int(point.max()) + 1, 3))
points[point] = g.positions
skirt = headless.mesh_object("skirt", points, point[g.faces], g.uv[g.faces])
bpy.context.view_layer.objects.active = skirt
skirt.select_set(True)
assert bpy.ops.drapelab.apply_material(preset="fabric_02_cotton_blue_bdp") == {'FINISHED'}
s = bpy.context.scene.drapelab
s.garment, s.collider = skirt, body_obj
rest = local_positions(skirt, evaluated=False)
path = os.path.join(tmp, "cache", "skirt.pc2")

# -- 1. a bake cancelled after a few frames: the frames done are kept, the cache is valid and plays, also mid-bake
work, target = operators.simulation_job(bpy.context, skirt, body_obj, 1, FRAMES)
job = jobs.start("simulate", work)
assert isinstance(job, jobs.ProcessJob)
wait_for(job, 2)
h = pc2.read_pc2_header(path)  # mid-bake: the cache is already at its path, complete frames only
assert 2 <= h["num_samples"] and h["file_size"] >= pc2.HEADER_SIZE + h["num_samples"] * h["num_points"] * 12
assert operators.attach_while_baking(target, job.state)  # what the modal poll does: playback during the bake
bpy.context.scene.frame_set(2)
assert np.abs(local_positions(skirt) - pc2.read_pc2(path)[1]).max() < 1e-5
wait_for(job, 4)
job.cancel()
assert job.join(CANCEL_LIMIT_S + 5.0)
cancel_s = job.state.finished - job.state.cancel_requested_at
assert job.state.status == jobs.DONE, job.state.snapshot()
result = job.state.result
assert result["cancelled"] and not result["stopped_by_time_limit"]
assert 4 <= result["frames_written"] == result["frames"] < FRAMES, result
message = operators.finish_simulation(target, result)
assert "cancelled, frames done kept" in message, message
baked = check_cache(path, result["frames_written"], skirt)
assert np.abs(baked[0] - rest).max() < 1e-5                     # frame 0: the rest placement
assert np.abs(baked[-1] - rest).max() > 1e-4                    # the skirt moved
assert np.abs(local_positions(skirt, evaluated=False) - rest).max() == 0.0  # the mesh itself untouched
assert not leftovers(), leftovers()
assert cancel_s < CANCEL_LIMIT_S, cancel_s
print(f"cancel mid-bake after {result['frames_written']} frames: the worker stopped {1000 * cancel_s:.0f} ms "
      f"after the cancel ({result['seconds_per_frame']:.2f} s/frame)")

# -- 2. a bake stopped before its first simulated frame: the previous cache stays byte for byte, and on the object
with open(path, "rb") as f:
    before = f.read()
work, target = operators.simulation_job(bpy.context, skirt, body_obj, 1, FRAMES)
job = jobs.Job("simulate", work)
job.state.cancel.set()
state = job.run_sync()
assert state.status == jobs.DONE and state.result["frames_written"] == 0, state.snapshot()
assert "nothing changed" in operators.finish_simulation(target, state.result)
with open(path, "rb") as f:
    assert f.read() == before
check_cache(path, result["frames_written"], skirt)
assert not leftovers(), leftovers()

# -- 3. the operator's time limit (as a script uses it): stops the bake keeping the frames done
t = time.monotonic()
assert bpy.ops.drapelab.simulate_garment(frame_start=1, frame_end=FRAMES, time_limit=2.0) == {'FINISHED'}
limited_s = time.monotonic() - t
n = pc2.read_pc2_header(path)["num_samples"]
assert 2 <= n < FRAMES, n
check_cache(path, n, skirt)
assert not leftovers(), leftovers()
print(f"time limit 2 s: {n} frames, the operator returned after {limited_s:.1f} s (material sampling included)")

# -- 4. a moving collider: the dress form walks, through its own Mesh Cache in step with the garment's
assert bpy.ops.drapelab.simulate_garment(frame_start=1, frame_end=4, motion="walk") == {'FINISHED'}
check_cache(path, 4, skirt)
body_path = os.path.join(tmp, "cache", "body_walk.pc2")
walked = check_cache(body_path, 4, body_obj)
expected = body_module.body_frames(body, "walk", 4)
assert np.abs(walked - expected).max() < 1e-5, np.abs(walked - expected).max()
assert np.abs(expected[3] - expected[0]).max() > 0.01  # the legs moved
# the panel's body friction reaches the simulator (0: frictionless; default 0.3)
assert abs(s.body_friction - 0.3) < 1e-6, s.body_friction
work, target = operators.simulation_job(bpy.context, skirt, body_obj, 1, 3, body_friction=0.0)
state = jobs.Job("simulate", work).run_sync()
assert state.status == jobs.DONE and state.result["body_friction"] == 0.0, state.snapshot()
operators.finish_simulation(target, state.result)
# a static bake puts the dress form back at rest
assert bpy.ops.drapelab.simulate_garment(frame_start=1, frame_end=3) == {'FINISHED'}
assert body_obj.modifiers.get("drapelab cache") is None
check_cache(path, 3, skirt)
expect = None
try:
    bpy.ops.drapelab.simulate_garment(frame_start=1, frame_end=3, motion="fly")
except TypeError as e:  # an enum property refuses an unknown value before the operator runs
    expect = str(e)
assert expect and "fly" in expect, expect

# -- 5. unregister while a bake runs stops the worker; the cache keeps the frames done, valid
work, target = operators.simulation_job(bpy.context, skirt, body_obj, 1, FRAMES)
job = jobs.start("simulate", work)
wait_for(job, 3)
t = time.monotonic()
drapelab.unregister()
stopped_s = time.monotonic() - t
assert not job.alive and job.state.status in (jobs.DONE, jobs.CANCELLED), job.state.snapshot()
assert job.state.result["cancelled"], job.state.result
n = job.state.result["frames_written"]
h = pc2.read_pc2_header(path)
assert 3 <= n == h["num_samples"] < FRAMES and h["file_size"] == pc2.HEADER_SIZE + n * h["num_points"] * 12, (n, h)
assert np.isfinite(pc2.read_pc2(path)).all()
assert not leftovers(), leftovers()
assert stopped_s < 2.0, stopped_s
shutil.rmtree(tmp, ignore_errors=True)
print(f"PASS test_simulate_cancel: cancel mid-bake kept {result['frames_written']} valid frames (worker stopped in "
      f"{1000 * cancel_s:.0f} ms), a bake stopped before its first frame left the previous cache as it was, the time "
      f"limit, a walking collider, unregister stopped a bake in {1000 * stopped_s:.0f} ms")
