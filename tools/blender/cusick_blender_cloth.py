"""A Cusick drape test in Blender's own cloth modifier, measured against real silhouettes.

    blender --background --factory-startup --python-exit-code 1 --python tools/blender/cusick_blender_cloth.py -- \
        (--preset P.json | --blender-preset cotton|denim|leather|rubber|silk) --fabric N --json OUT.json \
        [--level 3] [--frames 150] [--quality Q] [--seed 0] [--bend-calibration F] [--curvature A] [--obj OUT.obj]

The specimen is drapelab's Cusick template circle{level} (30 cm disk, metres), its support region r < 9 cm
pinned (the tester clamps the specimen between two 18 cm disks). The flat start is perturbed by a seeded
sub-millimetre wave (rest shape kept flat through a shape key) so that the folds form as in a real drape
instead of depending on round-off. The bake runs frame by frame; the drape coefficient of the silhouette is
tracked every few frames to report when the drape settles. The final positions are rendered with drapelab's
own orthographic renderer at the dataset's calibration (720 px/m, centre (128, 128)) and compared with every
capture-1 silhouette of fabric N (IoU, pixel MSE, drape coefficient via drapelab.measure).
"""
import argparse
import json
import os
import sys
import time

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.environ.get("DRAPELAB_ROOT") or os.path.normpath(os.path.join(HERE, "..", ".."))
sys.path[:0] = [os.path.join(ROOT, "addon"), os.environ.get("DRAPELAB_NATIVE_DIR") or os.path.join(ROOT, "build", "python")]

import numpy as np  # noqa: E402

from drapelab import blender_cloth, measure, paths, render, sim  # noqa: E402
from drapelab._native import InputError  # noqa: E402

SUPPORT_RADIUS_M = 0.09
PERTURBATION_M = 0.0005  # amplitude of the seeded start wave (well below the 5 mm edges)
TRACK_EVERY = 5          # frames between drape-coefficient samples
SETTLED_DC_CHANGE = 0.01  # settled: DC moves less than this (below the real re-drape sd) over SETTLED_WINDOW frames
SETTLED_WINDOW = 20


def parse(argv):
    p = argparse.ArgumentParser(prog="cusick_blender_cloth.py")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", help="drapelab preset JSON (exported through drapelab.blender_cloth)")
    src.add_argument("--blender-preset", choices=blender_cloth.BLENDER_PRESETS, help="Blender's shipped cloth preset")
    p.add_argument("--fabric", required=True,
                   help="fabric number in the Cusick dataset (1-5, 11-20), or several (1,2,3): the drape is compared "
                        "with each (a Blender preset's drape does not depend on the fabric); the first is the main one")
    p.add_argument("--json", required=True, help="output JSON")
    p.add_argument("--level", type=int, default=3, help="template mesh circle1..5 (default 3, the dataset's)")
    p.add_argument("--frames", type=int, default=150, help="frames to bake (default 150)")
    p.add_argument("--quality", type=int, default=None, help="steps per frame (default: preset's / Blender's 5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bend-calibration", type=float, default=blender_cloth.BEND_CALIBRATION)
    p.add_argument("--curvature", type=float, default=None,
                   help="read the bending table at this curvature measure (1/m); default: the secant stiffness")
    p.add_argument("--obj", help="also write the final drape as OBJ")
    a = p.parse_args(argv)
    if a.frames < 2 or a.level not in (1, 2, 3, 4, 5):
        p.error("--frames must be >= 2 and --level one of 1..5")
    try:
        a.fabrics = [int(v) for v in a.fabric.split(",")]
    except ValueError:
        p.error(f"--fabric: expected a fabric number or numbers separated by commas, got {a.fabric!r}")
    return a


def start_wave(rest, seed):
    """A seeded smooth perturbation of the flat disk: a few angular modes growing with radius (0 on the support)."""
    rng = np.random.default_rng(seed)
    r = np.hypot(rest[:, 0], rest[:, 1])
    th = np.arctan2(rest[:, 1], rest[:, 0])
    ramp = np.clip((r - SUPPORT_RADIUS_M) / (0.15 - SUPPORT_RADIUS_M), 0, 1)
    z = np.zeros(len(rest))
    for k in range(3, 13):
        z += rng.normal() * np.cos(k * th + rng.uniform(0, 2 * np.pi)) / k
    return PERTURBATION_M * ramp * z / max(np.abs(z).max(), 1e-12)


def build_specimen(level, seed):
    model = sim.ClothModel(sim.cusick_specimen(level))
    rest = np.asarray(model.rest_positions, dtype=float)
    faces = np.asarray(model.faces, dtype=np.int64)
    mesh = bpy.data.meshes.new("cusick_specimen")
    start = rest.copy()
    start[:, 2] += start_wave(rest, seed)
    mesh.from_pydata(start.tolist(), [], faces.tolist())
    mesh.update()
    obj = bpy.data.objects.new("cusick_specimen", mesh)
    bpy.context.scene.collection.objects.link(obj)
    # rest shape: the flat disk (shape key), start shape: the perturbed basis
    obj.shape_key_add(name="Basis")
    flat = obj.shape_key_add(name="flat", from_mix=False)
    flat.data.foreach_set("co", rest.ravel().astype(np.float32))
    obj.data.shape_keys.use_relative = True
    pin = obj.vertex_groups.new(name=blender_cloth.PIN_GROUP)
    r = np.hypot(rest[:, 0], rest[:, 1])
    pin.add([int(i) for i in np.flatnonzero(r <= SUPPORT_RADIUS_M + 1e-9)], 1.0, "REPLACE")
    return obj, rest, faces


def apply_settings(obj, args, rest, faces):
    mod = obj.modifiers.new("Cloth", "CLOTH")
    s = mod.settings
    if args.blender_preset:
        values = blender_cloth.blender_preset(args.blender_preset)
        for k, v in values.items():
            setattr(s, k, v)
        s.vertex_group_mass = blender_cloth.PIN_GROUP
        exported = {"blender_preset": args.blender_preset, **values}
    else:
        cs = blender_cloth.cloth_settings(args.preset, mesh=(rest, faces), fps=bpy.context.scene.render.fps,
                                          bend_calibration=args.bend_calibration, curvature=args.curvature,
                                          **({"quality": args.quality} if args.quality else {}))
        for k, v in cs.items():
            if k not in ("collision_settings", "derivation"):
                setattr(s, k, v)
        for k, v in cs["collision_settings"].items():
            setattr(mod.collision_settings, k, v)
        exported = {k: v for k, v in cs.items() if k != "collision_settings"}
    if args.quality:
        s.quality = args.quality
    s.rest_shape_key = obj.data.shape_keys.key_blocks["flat"]
    mod.collision_settings.use_collision = False  # no collider: the support region is pinned
    mod.collision_settings.use_self_collision = False
    return mod, exported


def positions_of(obj):
    dg = bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(dg)
    co = np.empty(len(ev.data.vertices) * 3, dtype=np.float32)
    ev.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def real_silhouettes(fabric):
    root = paths.require_cusick_dataset()
    rows = [r for r in measure.load_manifest(os.path.join(root, "manifest.csv"))
            if r["fabric"] == fabric and r["capture"] == 1]
    if not rows:
        raise InputError(f"--fabric: no capture-1 silhouettes of fabric {fabric} in {root}/manifest.csv")
    out = []
    for r in rows:
        sil = measure.load_silhouette(r["silhouette"], measure.calibration())
        out.append((r, np.asarray(sil.mask, dtype=np.float64)))
    return out


def compare(mask, reals):
    """IoU, pixel MSE against each real silhouette, and the real drape coefficients."""
    per = [{"sample": r["sample"], "iou": float(measure.iou(mask, real)), "mse": float(measure.pixel_mse(mask, real)),
            "dc_real": float(measure.drape_coefficient(real))} for r, real in reals]
    ious, mses, dcs = ([p[k] for p in per] for k in ("iou", "mse", "dc_real"))
    return {"dc_real_mean": float(np.mean(dcs)), "dc_real_min": float(np.min(dcs)), "dc_real_max": float(np.max(dcs)),
            "iou_mean": float(np.mean(ious)), "iou_best": float(np.max(ious)),
            "mse_mean": float(np.mean(mses)), "mse_best": float(np.min(mses)), "per_sample": per}


def main(argv):
    args = parse(argv)
    scene = bpy.context.scene
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o, do_unlink=True)
    reals = {n: real_silhouettes(n) for n in args.fabrics}
    obj, rest, faces = build_specimen(args.level, args.seed)
    mod, exported = apply_settings(obj, args, rest, faces)
    scene.frame_start, scene.frame_end = 1, args.frames
    mod.point_cache.frame_start, mod.point_cache.frame_end = 1, args.frames
    camera = render.orthographic_camera()
    trace = []
    t0 = time.perf_counter()
    t_last = t0
    for f in range(1, args.frames + 1):
        scene.frame_set(f)
        if f % TRACK_EVERY == 0 or f == args.frames:
            t_now = time.perf_counter()
            x = positions_of(obj)
            if not np.all(np.isfinite(x)):
                raise RuntimeError(f"Blender cloth produced NaN or infinity at frame {f}")
            mask = np.asarray(render.hard_silhouette(camera, x, faces), dtype=np.float64)
            trace.append({"frame": f, "dc": float(measure.drape_coefficient(mask)),
                          "min_z_m": float(x[:, 2].min()), "bake_seconds": t_now - t_last})
            t_last = time.perf_counter()
    bake_s = time.perf_counter() - t0
    x = positions_of(obj)
    mask = np.asarray(render.hard_silhouette(camera, x, faces), dtype=np.float64)
    dc = float(measure.drape_coefficient(mask))
    settled = None
    for i, t in enumerate(trace):
        later = [u["dc"] for u in trace[i:] if u["frame"] <= t["frame"] + SETTLED_WINDOW]
        if t["frame"] + SETTLED_WINDOW <= args.frames and max(later) - min(later) < SETTLED_DC_CHANGE \
                and all(abs(u["dc"] - dc) < 2 * SETTLED_DC_CHANGE for u in trace[i:]):
            settled = t["frame"]
            break
    fabrics = {str(n): compare(mask, reals[n]) for n in args.fabrics}
    main_fabric = fabrics[str(args.fabrics[0])]
    nodes = measure.analyse_nodes(measure.r_theta(mask, measure.calibration()))
    result = {
        "source": {"preset": args.preset, "blender_preset": args.blender_preset},
        "fabric": args.fabrics[0], "level": args.level, "vertices": int(len(rest)), "frames": args.frames,
        "quality": int(mod.settings.quality), "seed": args.seed,
        "settings": exported,
        "bake_seconds": bake_s, "seconds_per_frame": bake_s / args.frames,
        "settled_frame": settled,
        "dc": dc, "nodes": int(nodes.count),
        **{k: v for k, v in main_fabric.items() if k != "per_sample"},
        "dc_error": dc - main_fabric["dc_real_mean"],
        "per_sample": main_fabric["per_sample"], "fabrics": fabrics, "trace": trace,
    }
    if args.obj:
        sim.write_obj(args.obj, x, faces.astype(np.int32))
    measure.write_json(args.json, result)
    for n, m in fabrics.items():
        print(f"fabric {n} {args.blender_preset or os.path.basename(args.preset)}: DC {dc:.3f} "
              f"(real {m['dc_real_mean']:.3f}), IoU mean {m['iou_mean']:.3f} best {m['iou_best']:.3f}, MSE mean "
              f"{m['mse_mean']:.4f}, settled at frame {settled}, {bake_s / args.frames:.3f} s/frame")


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    try:
        main(argv)
    except (InputError, FileNotFoundError) as e:
        print(f"cusick_blender_cloth: error: {e}", file=sys.stderr)
        sys.exit(2)
