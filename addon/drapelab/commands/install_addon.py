"""`drapelab install-addon [--blender PATH] [--zip ZIP]`: install the add-on into the user's Blender and enable it.

The launcher builds first; this command writes the add-on zip (`drapelab package`; or installs the --zip given),
then runs Blender in the background (without --factory-startup, so the user's preferences are loaded and kept)
to ask it for the user's add-on folder (bpy.utils.user_resource('SCRIPTS', path="addons"); usually
~/.config/blender/3.4/scripts/addons, or $BLENDER_USER_SCRIPTS/addons), unpack the zip there (a previous
drapelab folder is replaced only once the new one is complete), enable the add-on (addon_utils.enable with
default_set) and save the preferences. The same Blender then imports the installed package with
DRAPELAB_NATIVE_DIR unset, so the compiled module it loads is the one inside the add-on, and reports where
everything is. Exit status 2 with Blender's message when any step fails.
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile

MARKER = "DRAPELAB_INSTALL "
BLENDER_TIMEOUT_S = 300

# Runs inside Blender: argv after "--" is [zip path]. Prints MARKER + JSON on success, raises otherwise.
INSTALL_SCRIPT = r'''
import json, os, shutil, sys, tempfile, zipfile
import addon_utils, bpy
zip_path = sys.argv[sys.argv.index("--") + 1]
addons = bpy.utils.user_resource('SCRIPTS', path="addons", create=True)
os.makedirs(addons, exist_ok=True)
target = os.path.join(addons, "drapelab")
if "drapelab" in {m.__name__ for m in addon_utils.modules()}:
    addon_utils.disable("drapelab", default_set=False)
stage = tempfile.mkdtemp(prefix=".drapelab_install_", dir=addons)
try:
    with zipfile.ZipFile(zip_path) as z:
        bad = [n for n in z.namelist() if not n.startswith("drapelab/") or ".." in n.split("/")]
        if bad:
            raise RuntimeError(f"{zip_path}: not a drapelab add-on zip (entry {bad[0]!r} outside drapelab/)")
        z.extractall(stage)
    old = None
    if os.path.exists(target):
        old = target + ".old"
        shutil.rmtree(old, ignore_errors=True)
        os.replace(target, old)
    os.replace(os.path.join(stage, "drapelab"), target)
    if old:
        shutil.rmtree(old, ignore_errors=True)
finally:
    shutil.rmtree(stage, ignore_errors=True)
for name in [m for m in sys.modules if m == "drapelab" or m.startswith("drapelab.") or m == "drapelab_native"]:
    del sys.modules[name]
bpy.utils.refresh_script_paths()  # the add-on folder may not have existed when Blender started
addon_utils.modules_refresh()
module = addon_utils.enable("drapelab", default_set=True, handle_error=None)
if module is None:
    raise RuntimeError("Blender could not enable the add-on drapelab (see the messages above)")
bpy.ops.wm.save_userpref()
import drapelab, drapelab._native as native
loaded, enabled = addon_utils.check("drapelab")
print("DRAPELAB_INSTALL " + json.dumps({"addons": addons, "package": os.path.dirname(drapelab.__file__),
      "native": native.native.__file__, "enabled": bool(enabled and loaded),
      "panel": hasattr(bpy.types, "DRAPELAB_PT_fit"), "userpref": bpy.utils.user_resource('CONFIG')}))
'''


def register(subparsers):
    p = subparsers.add_parser("install-addon", help="install the Blender add-on for this user and enable it",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--blender", default="blender", metavar="PATH", help="the Blender executable (default: blender)")
    p.add_argument("--zip", default=None, metavar="ZIP", help="install this add-on zip (default: package one now)")
    p.set_defaults(func=run)


def blender_environment():
    """The environment for the installing Blender: DRAPELAB_NATIVE_DIR and PYTHONPATH removed, so the installed
    package must load its own compiled module."""
    env = dict(os.environ)
    for key in ("DRAPELAB_NATIVE_DIR", "PYTHONPATH", "DRAPELAB_ROOT"):
        env.pop(key, None)
    return env


def find_blender(blender):
    exe = shutil.which(blender) or (blender if os.path.isfile(blender) and os.access(blender, os.X_OK) else None)
    if exe is None:
        raise OSError(f"--blender: {blender}: no such executable")
    return exe


def install(zip_path, blender="blender"):
    """Installs and enables the zip in the user's Blender; returns the report dict (see INSTALL_SCRIPT)."""
    exe = find_blender(blender)
    with tempfile.NamedTemporaryFile("w", suffix=".py", prefix="drapelab_install_", delete=False) as f:
        f.write(INSTALL_SCRIPT)
        script = f.name
    try:
        done = subprocess.run([exe, "--background", "--python-exit-code", "1", "--python", script, "--",
                               os.path.abspath(zip_path)], env=blender_environment(), capture_output=True, text=True,
                              timeout=BLENDER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise OSError(f"install-addon: Blender did not finish within {BLENDER_TIMEOUT_S} s") from None
    finally:
        os.unlink(script)
    lines = [l for l in done.stdout.splitlines() if l.startswith(MARKER)]
    if done.returncode != 0 or not lines:
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-15:])
        raise OSError(f"install-addon: Blender failed (exit {done.returncode}):\n{tail}")
    report = json.loads(lines[-1][len(MARKER):])
    if not (report["enabled"] and report["panel"]):
        raise OSError(f"install-addon: installed into {report['package']} but Blender did not enable it: {report}")
    if not os.path.realpath(report["native"]).startswith(os.path.realpath(report["package"]) + os.sep):
        raise OSError(f"install-addon: the installed add-on loaded the compiled module from {report['native']}, "
                      f"not from inside {report['package']}")
    return report


def run(args):
    from . import package
    find_blender(args.blender)  # before packaging
    if args.zip:
        if not os.path.isfile(args.zip):
            raise OSError(f"--zip: {args.zip}: no such file")
        zip_path = args.zip
    else:
        zip_path, count, size = package.write_zip()
        print(f"packaged {zip_path} ({count} files, {size / 1e6:.1f} MB)", file=sys.stderr)
    report = install(zip_path, args.blender)
    print(f"installed drapelab into {report['package']} and enabled it (preferences saved in {report['userpref']});"
          f" compiled module {os.path.basename(report['native'])} loaded from the add-on. In Blender: 3D view > "
          "sidebar (N) > Drape")
    return 0
