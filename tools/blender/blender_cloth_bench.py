"""Timing anchor for garments: Blender's own cloth modifier on a skirt over a moving body, seconds per frame.

    blender --background --factory-startup --python-exit-code 1 --python tools/blender/blender_cloth_bench.py -- \
        --json OUT.json [--garment skirt|GARMENT.obj] [--vertices 6000] [--style circle] \
        [--body default|BODY.obj] [--body-pc2 BODY.pc2] [--motion walk] [--frames 48] [--preset P.json] \
        [--quality 5] [--no-self-collision]

Blender cloth at its default settings (quality 5 steps per frame, Blender's default material), or with the
settings exported from --preset (drapelab.blender_cloth), collisions with the body and self-collision on, the
waist pinned (the garment's waist vertices; for a foreign OBJ without them, the vertices within 3 cm of its top).
The body is a mesh whose vertex animation plays from a PC2 cache through a Mesh Cache modifier, with a Collision
modifier after it. Default garment and body: drapelab.garment's make_skirt and make_body, the body's motion
written to a PC2 by drapelab.garment.pc2, and the garment object following the pelvis (its keyed transform), so
the pinned waist moves with the hips. A foreign body OBJ + PC2 has no pelvis: its garment's waist stays put.
Frames are evaluated one by one (what a bake does); the JSON holds seconds per frame (mean over all frames and
over the frames after the first, which includes building the cloth), the mesh sizes and the hem radius.
"""
import argparse
import os
import sys
import tempfile
import time

import bpy
import mathutils

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.environ.get("DRAPELAB_ROOT") or os.path.normpath(os.path.join(HERE, "..", ".."))
sys.path[:0] = [os.path.join(ROOT, "addon"), os.environ.get("DRAPELAB_NATIVE_DIR") or os.path.join(ROOT, "build", "python")]

import numpy as np  # noqa: E402

from drapelab import blender_cloth, measure  # noqa: E402
from drapelab._native import InputError  # noqa: E402
from drapelab.garment import body as garment_body, mesh as garment_mesh, pc2, skirt  # noqa: E402

PIN_TOP_M = 0.03  # a foreign garment: vertices within this of its highest point are the waist


def parse(argv):
    p = argparse.ArgumentParser(prog="blender_cloth_bench.py")
    p.add_argument("--json", required=True)
    p.add_argument("--garment", default="skirt", help="'skirt' (drapelab.garment.make_skirt) or a garment OBJ")
    p.add_argument("--vertices", type=int, default=6000, help="skirt vertices (default 6000)")
    p.add_argument("--style", default="circle", help="skirt style (circle, flared, aline)")
    p.add_argument("--body", default="default", help="'default' (make_body) or a body OBJ (then --body-pc2)")
    p.add_argument("--body-pc2", help="the body's vertex animation (PC2, the body OBJ's vertex order)")
    p.add_argument("--motion", default="walk", choices=garment_body.MOTIONS, help="default body's motion")
    p.add_argument("--frames", type=int, default=48)
    p.add_argument("--preset", help="drapelab preset: Blender cloth with its exported settings (default: Blender's)")
    p.add_argument("--quality", type=int, default=blender_cloth.DEFAULT_QUALITY)
    p.add_argument("--no-self-collision", action="store_true")
    a = p.parse_args(argv)
    if a.frames < 2:
        p.error("--frames must be >= 2")
    if a.body != "default" and not a.body_pc2:
        p.error("--body OBJ needs --body-pc2 (its animation)")
    return a


def read_obj_triangles(path):
    """Vertices (V, 3) and triangles (F, 3) of an OBJ (polygons fanned); errors name the file."""
    v, f = [], []
    try:
        with open(path) as fh:
            for n, line in enumerate(fh, 1):
                t = line.split()
                if not t:
                    continue
                if t[0] == "v":
                    v.append([float(c) for c in t[1:4]])
                elif t[0] == "f":
                    idx = [int(c.split("/")[0]) for c in t[1:]]
                    idx = [i - 1 if i > 0 else len(v) + i for i in idx]
                    f += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
    except OSError as e:
        raise InputError(f"{path}: cannot read OBJ: {e.strerror}") from None
    except (ValueError, IndexError):
        raise InputError(f"{path}: line {n}: not a valid OBJ vertex or face") from None
    v, f = np.asarray(v, dtype=float), np.asarray(f, dtype=np.int64)
    if len(v) < 3 or len(f) < 1 or f.min() < 0 or f.max() >= len(v):
        raise InputError(f"{path}: needs vertices and faces with valid indices")
    return v, f


def mesh_object(name, positions, faces):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.asarray(positions, dtype=float).tolist(), [], np.asarray(faces).tolist())
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def make_garment(args, body):
    """(positions, faces, waist, hem vertex indices) of the welded garment (seam copies merged: one connected
    mesh); a foreign OBJ's hem: the vertices within PIN_TOP_M of its lowest point."""
    if args.garment == "skirt":
        g = skirt.make_skirt(args.style, vertices=args.vertices, body=body)
    else:
        try:
            g = garment_mesh.read_garment_obj(args.garment, triangulate=True)
        except InputError:
            x, f = read_obj_triangles(args.garment)
            top = np.flatnonzero(x[:, 2] >= x[:, 2].max() - PIN_TOP_M)
            return x, f, top, np.flatnonzero(x[:, 2] <= x[:, 2].min() + PIN_TOP_M)
    point = g.point_index()
    pos = np.zeros((int(point.max()) + 1, 3))
    pos[point] = g.positions
    waist = np.unique(point[g.waist_vertices]) if g.waist_vertices.size else \
        np.flatnonzero(pos[:, 2] >= pos[:, 2].max() - PIN_TOP_M)
    hem = np.unique(point[g.hem_vertices]) if g.hem_vertices.size else \
        np.flatnonzero(pos[:, 2] <= pos[:, 2].min() + PIN_TOP_M)
    return pos, point[g.faces], waist, hem


def main(argv):
    args = parse(argv)
    measure.check_output_path(args.json, "JSON")
    scene = bpy.context.scene
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o, do_unlink=True)
    scene.frame_start, scene.frame_end = 1, args.frames
    tmp = tempfile.mkdtemp(prefix="drapelab_bench_")
    pelvis = None
    if args.body == "default":
        body = garment_body.make_body()
        body_x, body_f = body.positions, body.faces
        body_pc2 = os.path.join(tmp, "body.pc2")
        pc2.write_pc2(body_pc2, garment_body.body_frames(body, args.motion, args.frames, fps=scene.render.fps))
        pelvis = garment_body.pelvis_transforms(args.motion, args.frames, fps=scene.render.fps)
    else:
        body = None
        body_x, body_f = read_obj_triangles(args.body)
        body_pc2 = args.body_pc2
        n_points = pc2.read_pc2_header(body_pc2)["num_points"]
        if n_points != len(body_x):
            raise InputError(f"{body_pc2}: {n_points} points per frame, the body OBJ has {len(body_x)} vertices")
    body_obj = mesh_object("body", body_x, body_f)
    cache = body_obj.modifiers.new("MeshCache", "MESH_CACHE")
    cache.cache_format = "PC2"
    cache.filepath = body_pc2
    cache.frame_start = 1.0
    body_obj.modifiers.new("Collision", "COLLISION")

    gx, gf, waist, hem = make_garment(args, body)
    garment = mesh_object("garment", gx, gf)
    pin = garment.vertex_groups.new(name=blender_cloth.PIN_GROUP)
    pin.add([int(i) for i in waist], 1.0, "REPLACE")
    if pelvis is not None:  # the garment (and so its pinned waist) follows the hips
        for f, m in enumerate(pelvis, start=1):
            garment.matrix_world = mathutils.Matrix([list(r) for r in m])
            garment.keyframe_insert("location", frame=f)
            garment.keyframe_insert("rotation_euler", frame=f)

    mod = garment.modifiers.new("Cloth", "CLOTH")
    if args.preset:
        values = blender_cloth.cloth_settings(args.preset, args.quality, mesh=(gx, gf), fps=scene.render.fps,
                                              pin_group=blender_cloth.PIN_GROUP)
        for k, v in values.items():
            if k not in ("collision_settings", "derivation"):
                setattr(mod.settings, k, v)
        for k, v in values["collision_settings"].items():
            setattr(mod.collision_settings, k, v)
        source = args.preset
    else:
        mod.settings.quality = args.quality
        mod.settings.vertex_group_mass = blender_cloth.PIN_GROUP
        source = "blender-default"
    mod.collision_settings.use_collision = True
    mod.collision_settings.use_self_collision = not args.no_self_collision
    mod.point_cache.frame_start, mod.point_cache.frame_end = 1, args.frames

    times = []
    cpu0 = time.process_time()
    for f in range(1, args.frames + 1):
        t = time.perf_counter()
        scene.frame_set(f)
        dg = bpy.context.evaluated_depsgraph_get()
        ev = garment.evaluated_get(dg)  # make sure the cloth of this frame is computed
        n = len(ev.data.vertices)
        times.append(time.perf_counter() - t)
    cpu = time.process_time() - cpu0
    co = np.empty(n * 3)
    ev.data.vertices.foreach_get("co", co)
    m = np.array(ev.matrix_world)
    x = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    if not np.all(np.isfinite(x)):
        raise RuntimeError("Blender cloth produced NaN or infinity")
    result = {
        "tool": "blender_cloth_bench", "blender": bpy.app.version_string,
        "settings": source, "quality": int(mod.settings.quality),
        "self_collision": bool(mod.collision_settings.use_self_collision), "collision": True,
        "garment": args.garment, "garment_vertices": int(len(gx)), "garment_faces": int(len(gf)),
        "pinned_vertices": int(len(waist)),
        "body": args.body, "body_vertices": int(len(body_x)), "motion": args.motion if args.body == "default" else None,
        "frames": args.frames, "fps": scene.render.fps,
        "seconds_total": float(sum(times)),
        "seconds_per_frame": float(np.mean(times)),
        "seconds_per_frame_after_first": float(np.mean(times[1:])),
        "seconds_first_frame": float(times[0]),
        "seconds_per_frame_max": float(np.max(times)),
        # CPU seconds of this process (all threads) per frame: the load-independent figure on a shared machine
        "cpu_seconds_per_frame": float(cpu / args.frames),
        "hem_radius_m": float(np.mean(np.hypot(x[hem, 0], x[hem, 1]))),  # from the world z axis, last frame
        "threads": bpy.context.scene.render.threads,
    }
    measure.write_json(args.json, result)
    print(f"blender_cloth_bench: {len(gx)} garment vertices, {args.frames} frames, "
          f"{result['seconds_per_frame']:.3f} s/frame ({source}, quality {result['quality']}, self-collision "
          f"{result['self_collision']})")


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    try:
        main(argv)
    except (InputError, FileNotFoundError) as e:
        print(f"blender_cloth_bench: error: {e}", file=sys.stderr)
        sys.exit(2)
