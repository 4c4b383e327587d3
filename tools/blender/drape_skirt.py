"""Headless: a preset on the bundled skirt, rendered (Cycles on CPU, denoising off: Debian's Blender renders headless
only with Cycles). Builds the demo scene by script: the parametric lower body and skirt of drapelab.garment (body
and skirt generators), a camera and a sun; applies the preset with drapelab.apply_material (per-triangle stretching,
per-edge bending drawn from the posterior), colours the skirt by one stiffness component (the heat map) and renders
a PNG. The drape itself (drapelab.simulate_garment) runs when this build has the garment simulator; until then
the script says so and renders the skirt at its rest placement with the heat map.

    blender --background --factory-startup --python-exit-code 1 --python tools/blender/drape_skirt.py -- \
        --preset fabric_02_cotton_blue_bdp --out out/skirt.png [--style circle] [--vertices 4000] \
        [--heat bend_warp] [--samples 32] [--size 800x800] [--seed 0] [--frames 48] [--motion static] \
        [--time-limit SECONDS] [--blend out/skirt.blend]

--blend saves the scene there before the bake, so the bake's PC2 caches go beside it (drapelab_cache/) and the
saved file plays the drape. --time-limit bounds the whole Blender run (from Blender's start): the bake stops
early, keeping the frames done, so that the render still fits (RENDER_RESERVE_S); the render shows the last frame
done.
"""
import math
import os
import sys
import time



def _process_age():
    """Seconds since this process (Blender) started, from /proc on Linux (0 elsewhere): --time-limit counts
    Blender's own start-up, which comes before this script runs."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = float(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0


T0 = time.monotonic() - _process_age()

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))
if os.path.isdir(os.path.join(REPO, "addon", "drapelab")):
    sys.path.insert(0, os.path.join(REPO, "addon"))
    os.environ.setdefault("DRAPELAB_NATIVE_DIR", os.path.join(REPO, "build", "python"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from drapelab.ui import headless  # noqa: E402

CAMERA_LOCATION = (0.0, -2.0, 0.9)      # in front of the body (it faces -y), a little above hip height
CAMERA_TARGET = (0.0, 0.0, 0.68)
WORLD_COLOUR = (0.85, 0.85, 0.85, 1.0)
CAMERA_LENS_MM = 50.0
SUN_ROTATION_DEG = (50.0, 10.0, 30.0)
BODY_COLOUR = (0.55, 0.55, 0.58, 1.0)
RENDER_RESERVE_S = 8.0  # --time-limit: kept for the scene, the render and saving (measured 1-3 s: 400x400, 8 samples)


def arguments(p):
    p.add_argument("--preset", default="fabric_02_cotton_blue_bdp", help="preset file or shipped/user preset name")
    p.add_argument("--out", required=True, metavar="PNG")
    p.add_argument("--style", default="circle", choices=["circle", "flared", "aline"])
    p.add_argument("--vertices", type=int, default=4000)
    p.add_argument("--heat", default="bend_warp", help="stiffness component shown (drapelab_<name> attribute)")
    p.add_argument("--samples", type=int, default=32, help="Cycles samples")
    p.add_argument("--size", default="800x800", metavar="WxH")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frames", type=int, default=48, help="frames of the drape (when the simulator exists)")
    p.add_argument("--motion", default="static", choices=["static", "walk", "twirl", "jump"],
                   help="the dress form's motion during the drape")
    p.add_argument("--time-limit", type=float, default=0.0, metavar="SECONDS",
                   help="the whole script's time (0: none): the bake stops early, keeping the frames done")
    p.add_argument("--blend", default=None, metavar="FILE.blend", help="also save the scene")


def material(name, colour=None, attribute=None):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = 0.8
    if attribute:
        node = mat.node_tree.nodes.new("ShaderNodeAttribute")
        node.attribute_name = attribute
        mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        bsdf.inputs["Base Color"].default_value = colour
    return mat


def look_at(obj, target):
    from mathutils import Vector
    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat('-Z', 'Y').to_euler()


def main():
    args = headless.script_args(__doc__.split("\n\n")[0], arguments)
    width, height = (int(v) for v in args.size.lower().split("x"))
    for obj in list(bpy.data.objects):  # the factory scene's cube, camera and light
        bpy.data.objects.remove(obj)
    s = headless.ensure_registered()
    from drapelab.garment import body as body_module, skirt as skirt_module
    from drapelab.ui import garment_ops, operators, presets
    preset_path = presets.resolve(args.preset, operators.user_presets_dir())

    body = body_module.make_body()
    garment = skirt_module.make_skirt(args.style, vertices=args.vertices, body=body)
    body_obj = headless.mesh_object("body", body.positions, body.faces, smooth=True)
    body_obj.data.materials.append(material("body", BODY_COLOUR))
    # the skirt as Blender sees a sewn garment: seam copies welded into one point, the pattern as its UV map
    point = garment.point_index()
    points = np.zeros((int(point.max()) + 1, 3))
    points[point] = garment.positions
    skirt = headless.mesh_object("skirt", points, point[garment.faces], garment.uv[garment.faces], smooth=True)
    bpy.context.view_layer.objects.active = skirt
    skirt.select_set(True)
    headless.run("apply_material", preset=preset_path, seed=args.seed)
    s.garment, s.collider = skirt, body_obj
    headless.run("show_heat_map", attribute=f"drapelab_{args.heat}")
    skirt.data.materials.append(material("skirt heat map", attribute=garment_ops.HEAT_ATTRIBUTE))

    draped = False
    if args.blend:  # saved first, so that the bake's caches go beside it and the saved file plays them
        bpy.context.preferences.filepaths.save_version = 0  # no FILE.blend1 backup when it is saved again
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend))
    bake_limit = args.time_limit - (time.monotonic() - T0) - RENDER_RESERVE_S if args.time_limit else 0.0
    if operators._simulate_function() is not None and args.time_limit and bake_limit < 1.0:
        print(f"drape_skirt: no time left for the bake within --time-limit {args.time_limit:g} s: rendering the "
              "skirt at its rest placement", flush=True)
    elif operators._simulate_function() is not None:
        headless.run("simulate_garment", frame_start=1, frame_end=args.frames, collider=body_obj.name,
                     motion=args.motion, time_limit=max(0.0, bake_limit))
        from drapelab.garment import pc2
        draped = pc2.read_pc2_header(skirt.modifiers["drapelab cache"].filepath)["num_samples"]
        bpy.context.scene.frame_set(draped)
    else:
        print(f"drape_skirt: {operators.NOT_AVAILABLE_SIMULATION}: rendering the skirt at its rest placement "
              "with the stiffness heat map", flush=True)

    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    bpy.context.scene.collection.objects.link(cam)
    cam.location = CAMERA_LOCATION
    cam.data.lens = CAMERA_LENS_MM
    look_at(cam, CAMERA_TARGET)
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", 'SUN'))
    sun.data.energy = 3.0
    sun.rotation_euler = tuple(math.radians(a) for a in SUN_ROTATION_DEG)
    bpy.context.scene.collection.objects.link(sun)
    scene = bpy.context.scene
    scene.camera = cam
    scene.world = scene.world or bpy.data.worlds.new("world")
    scene.world.use_nodes = True
    background = scene.world.node_tree.nodes.get("Background")
    background.inputs["Color"].default_value = WORLD_COLOUR
    background.inputs["Strength"].default_value = 1.0
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.samples = args.samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = 'PNG'
    out = os.path.abspath(args.out)
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True)
    if not os.path.isfile(out):
        raise RuntimeError(f"drape_skirt: the render was not written to {out}")
    if args.blend:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend))
    what = f"draped, {draped} of {args.frames} frames, {args.motion}" if draped else "rest placement"
    print(f"drape_skirt: wrote {out} ({what}, heat map drapelab_{args.heat}, {len(skirt.data.vertices)} skirt "
          f"vertices, {time.monotonic() - T0:.1f} s)", flush=True)


main()
