"""Helpers of the headless Blender scripts (tools/blender/*.py): their arguments after "--", the add-on registered
once, and operators that raise on anything but {'FINISHED'} so that `blender --background --python-exit-code 1`
exits non-zero on failure (an operator's ERROR report already raises RuntimeError through bpy.ops)."""
import argparse
import sys

import bpy
import numpy as np


def script_args(description, add_arguments):
    """Parses the script's own arguments (those after "--"); add_arguments(parser) declares them."""
    parser = argparse.ArgumentParser(prog="blender --background --python SCRIPT --", description=description)
    add_arguments(parser)
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    return parser.parse_args(argv)


def ensure_registered():
    """Registers the add-on unless Blender already has it (an installed, enabled add-on)."""
    if not hasattr(bpy.types.Scene, "drapelab"):
        import drapelab
        drapelab.register()
    return bpy.context.scene.drapelab


def run(operator, **kwargs):
    """Calls bpy.ops.drapelab.<operator>(**kwargs); RuntimeError unless it returns {'FINISHED'}."""
    result = getattr(bpy.ops.drapelab, operator)(**kwargs)
    if result != {'FINISHED'}:
        raise RuntimeError(f"drapelab.{operator} returned {sorted(result)} (see the messages above)")
    return result


def mesh_object(name, positions, faces, corner_uv=None, smooth=False):
    """A new mesh object `name` linked to the scene: vertices (V, 3), triangles (F, 3), optionally a UV map
    "UVMap" from per-corner uv (F, 3, 2) and smooth shading."""
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(positions).tolist(), [], np.asarray(faces).tolist())
    if corner_uv is not None:
        layer = me.uv_layers.new(name="UVMap")
        layer.data.foreach_set("uv", np.asarray(corner_uv, dtype=np.float64).reshape(-1))
    me.update()
    if smooth:
        for poly in me.polygons:
            poly.use_smooth = True
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj
