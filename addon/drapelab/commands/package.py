"""`drapelab package [--out ZIP]`: the Blender add-on as a zip that Preferences > Add-ons > Install accepts.

The zip holds one top folder `drapelab/`: the Python package (facade, CLI, ui/, garment/, config/), the compiled
core (drapelab_native*.so, loaded from the package folder by drapelab._native) and the bundled assets
(assets/: the template meshes, the demo images and manifest, the shipped presets, their README with the data's
citation) as drapelab/assets, which drapelab.paths finds inside an installed add-on. The compiled module links
against Debian's shared libraries (OpenImageIO, SuiteSparse, OpenBLAS): a machine that installs the zip needs
them (docs/addon.md). Written atomically (temporary file, then rename). Default: build/addon/drapelab-VERSION.zip.
"""
import os
import zipfile

TOP = "drapelab"
SKIP_DIRS = {"__pycache__"}
SKIP_SUFFIXES = (".pyc", ".pyo", ".ckpt")


def register(subparsers):
    p = subparsers.add_parser("package", help="write the Blender add-on zip (Preferences > Add-ons > Install)",
                              description=__doc__.split("\n\n", 1)[1])
    p.add_argument("--out", default=None, metavar="ZIP",
                   help="the zip to write (its folder must exist); default build/addon/drapelab-VERSION.zip")
    p.set_defaults(func=run)


def native_module_file():
    """The compiled module's file (the one this process loaded: the build's, or the installed package's)."""
    from .._native import native
    path = getattr(native, "__file__", None)
    if not path or not os.path.isfile(path):
        raise OSError("package: the compiled module drapelab_native has no file to copy (run ./drapelab build)")
    return path


def package_files():
    """[(absolute source path, path inside the zip)] of everything the add-on needs, sorted."""
    from .. import paths
    package_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    files = []
    for base, target in ((package_dir, TOP), (paths.assets_dir(), f"{TOP}/assets")):
        if not os.path.isdir(base):
            raise OSError(f"package: {base} is missing")
        for folder, dirs, names in os.walk(base):
            dirs[:] = sorted(d for d in dirs if d not in SKIP_DIRS and not d.startswith(".")
                             and not (folder == package_dir and d == "assets"))
            for name in sorted(names):
                if name.startswith(".") or name.endswith(SKIP_SUFFIXES) or name.startswith("drapelab_native"):
                    continue
                src = os.path.join(folder, name)
                files.append((src, f"{target}/{os.path.relpath(src, base).replace(os.sep, '/')}"))
    so = native_module_file()
    files.append((so, f"{TOP}/{os.path.basename(so)}"))
    return sorted(files, key=lambda f: f[1])


def default_zip_path():
    from .. import __version__, paths
    return os.path.join(paths.repository_root(), "build", "addon", f"drapelab-{__version__}.zip")


def write_zip(out=None):
    """Writes the add-on zip; returns (path, number of files, bytes)."""
    from .. import measure
    path = out or default_zip_path()
    if out is None:
        os.makedirs(os.path.dirname(path), exist_ok=True)
    if not path.endswith(".zip"):
        raise OSError(f"{path}: the add-on package is a .zip file")
    files = package_files()

    def write(tmp):
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for src, arc in files:
                z.write(src, arc)
    measure._atomic_write(path, "add-on zip", ".zip", write)
    return path, len(files), os.path.getsize(path)


def run(args):
    path, count, size = write_zip(args.out)
    print(f"wrote {path}: {count} files, {size / 1e6:.1f} MB (install: Blender > Preferences > Add-ons > Install, "
          "or ./drapelab install-addon)")
    return 0
