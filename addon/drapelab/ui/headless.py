"""Helpers of the headless Blender scripts (tools/blender/*.py): their arguments after "--", the add-on registered
once, and operators that raise on anything but {'FINISHED'} so that `blender --background --python-exit-code 1`
exits non-zero on failure (an operator's ERROR report already raises RuntimeError through bpy.ops)."""
import argparse
import sys

import bpy


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
