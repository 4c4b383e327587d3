"""`drapelab package` and `drapelab install-addon`: the zip's layout, Blender's own installer (Preferences > Add-ons >
Install) accepting it, and install-addon into a temporary user config from which a fresh Blender finds the add-on
enabled and runs it with the compiled module and assets inside the add-on (no DRAPELAB_NATIVE_DIR)."""
import json
import os
import shutil
import subprocess
import sys
import zipfile

import pytest

from fit_support import ROOT

from drapelab.commands import package

BLENDER = shutil.which("blender")
pytestmark = pytest.mark.skipif(BLENDER is None, reason="needs Blender (Debian package blender)")

CHECK_SCRIPT = r'''
import json, os, sys
import addon_utils, bpy
loaded, enabled = addon_utils.check("drapelab")
import drapelab, drapelab._native as native, drapelab.paths as paths
image = os.path.join(paths.assets_dir(), "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
result = bpy.ops.drapelab.import_images(filepath=image) if hasattr(bpy.types, "DRAPELAB_OT_import_images") else None
s = bpy.context.scene.drapelab
print("CHECK " + json.dumps({"loaded": loaded, "enabled": enabled, "package": os.path.dirname(drapelab.__file__),
      "native": native.native.__file__, "assets": paths.assets_dir(), "import": sorted(result or []),
      "dc": s.images[0].drape_coefficient if len(s.images) else None, "fabric": s.fabric_name}))
'''

INSTALLER_SCRIPT = r'''
import sys, addon_utils, bpy
zip_path = sys.argv[sys.argv.index("--") + 1]
assert bpy.ops.preferences.addon_install(filepath=zip_path) == {'FINISHED'}
assert bpy.ops.preferences.addon_enable(module="drapelab") == {'FINISHED'}
'''


def user_env(home):
    env = {k: v for k, v in os.environ.items() if k not in ("DRAPELAB_NATIVE_DIR", "PYTHONPATH", "DRAPELAB_ROOT")}
    env.update(HOME=str(home), BLENDER_USER_CONFIG=str(home / "config"), BLENDER_USER_SCRIPTS=str(home / "scripts"))
    return env


def blender_check(home, tmp_path):
    script = tmp_path / "check.py"
    script.write_text(CHECK_SCRIPT)
    done = subprocess.run([BLENDER, "--background", "--python-exit-code", "1", "--python", str(script)],
                          env=user_env(home), capture_output=True, text=True, timeout=300)
    lines = [l for l in done.stdout.splitlines() if l.startswith("CHECK ")]
    assert done.returncode == 0 and lines, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads(lines[-1][len("CHECK "):])


@pytest.fixture(scope="module")
def addon_zip(tmp_path_factory):
    path, count, size = package.write_zip(str(tmp_path_factory.mktemp("zip") / "drapelab.zip"))
    return path


def test_zip_layout(addon_zip):
    names = zipfile.ZipFile(addon_zip).namelist()
    assert all(n.startswith("drapelab/") for n in names)
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    need = ["drapelab/__init__.py", "drapelab/_native.py", "drapelab/ui/__init__.py", "drapelab/ui/operators.py",
            "drapelab/ui/panels.py", "drapelab/config/fit.json", "drapelab/assets/README.md",
            "drapelab/assets/cusick/manifest.csv", "drapelab/assets/cusick/fabric_02/silhouettes/sample_02_capture_1.jpg",
            "drapelab/garment/mesh.py"] + [f"drapelab/assets/cusick/template_meshes/circle{k}.obj" for k in range(1, 6)]
    assert not [n for n in need if n not in names], [n for n in need if n not in names]
    assert [n for n in names if n.startswith("drapelab/drapelab_native") and n.endswith(".so")]
    shipped = sorted(os.listdir(os.path.join(ROOT, "assets", "presets")))
    assert sorted(n.rsplit("/", 1)[1] for n in names if n.startswith("drapelab/assets/presets/")) == shipped
    init = zipfile.ZipFile(addon_zip).read("drapelab/__init__.py").decode()
    assert "bl_info" in init and "def register" in init


def test_blenders_own_installer_accepts_the_zip(addon_zip, tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    script = tmp_path / "installer.py"
    script.write_text(INSTALLER_SCRIPT)
    done = subprocess.run([BLENDER, "--background", "--factory-startup", "--python-exit-code", "1", "--python",
                           str(script), "--", addon_zip], env=user_env(home), capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert (home / "scripts" / "addons" / "drapelab" / "ui" / "panels.py").is_file()


def test_install_addon_into_a_temporary_user_config(addon_zip, tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    env = dict(user_env(home), PYTHONPATH=f"{ROOT}/addon:{ROOT}/build/python")
    done = subprocess.run([sys.executable, "-m", "drapelab.cli", "install-addon", "--blender", BLENDER,
                           "--zip", addon_zip], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "enabled it" in done.stdout
    package_dir = home / "scripts" / "addons" / "drapelab"
    assert (package_dir / "__init__.py").is_file() and (home / "config" / "userpref.blend").is_file()
    # a fresh Blender (the user's preferences, not factory settings) has it enabled and runs it from there
    check = blender_check(home, tmp_path)
    assert check["loaded"] and check["enabled"], check
    assert os.path.realpath(check["package"]) == os.path.realpath(package_dir)
    assert os.path.realpath(check["native"]).startswith(os.path.realpath(package_dir) + os.sep)
    assert os.path.realpath(check["assets"]) == os.path.realpath(package_dir / "assets")
    assert check["import"] == ["FINISHED"] and abs(check["dc"] - 0.670) < 0.01 and check["fabric"] == "Cotton Blue"
    # installing again replaces the add-on in place
    done = subprocess.run([sys.executable, "-m", "drapelab.cli", "install-addon", "--blender", BLENDER,
                           "--zip", addon_zip], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    assert not [p for p in os.listdir(package_dir.parent) if p != "drapelab"]


def test_install_addon_refuses_a_missing_blender_or_zip(tmp_path):
    env = dict(user_env(tmp_path), PYTHONPATH=f"{ROOT}/addon:{ROOT}/build/python")
    for args, message in ((["--blender", str(tmp_path / "no-blender")], "no such executable"),
                          (["--zip", str(tmp_path / "missing.zip")], "no such file")):
        done = subprocess.run([sys.executable, "-m", "drapelab.cli", "install-addon", *args], env=env,
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 2 and message in done.stderr, done.stderr
