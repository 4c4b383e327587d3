"""Locates and imports the compiled core `drapelab_native`.

Where it is looked for, in order: already importable (on sys.path); $DRAPELAB_NATIVE_DIR (the launcher sets it
to build/python); this package's own folder (an installed add-on ships the .so beside this file: see
drapelab.commands.package); the clone's build/python. A file in the package folder is loaded by its path, so
the package folder never goes on sys.path (its module names, such as `measure`, would shadow others there).
"""
import glob
import importlib
import importlib.machinery
import importlib.util
import os
import sys

MODULE = "drapelab_native"
PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))


def _from_file(path):
    loader = importlib.machinery.ExtensionFileLoader(MODULE, path)
    spec = importlib.util.spec_from_file_location(MODULE, path, loader=loader)
    module = importlib.util.module_from_spec(spec)
    sys.modules[MODULE] = module
    try:
        loader.exec_module(module)
    except BaseException:
        sys.modules.pop(MODULE, None)
        raise
    return module


def packaged_module_files(folder=PACKAGE_DIR):
    """The compiled modules in `folder` that this Python can load (its extension suffixes)."""
    return [p for suffix in importlib.machinery.EXTENSION_SUFFIXES
            for p in sorted(glob.glob(os.path.join(folder, MODULE + suffix)))]


def load():
    if MODULE in sys.modules:
        return sys.modules[MODULE]
    try:
        return importlib.import_module(MODULE)
    except ImportError:
        pass
    errors = []
    env = os.environ.get("DRAPELAB_NATIVE_DIR", "")
    if env and os.path.isdir(env):
        if env not in sys.path:
            sys.path.insert(0, env)
        try:
            return importlib.import_module(MODULE)
        except ImportError as e:
            errors.append(f"{env}: {e}")
    for path in packaged_module_files():
        try:
            return _from_file(path)
        except ImportError as e:
            errors.append(f"{path}: {e}")
    build = os.path.normpath(os.path.join(PACKAGE_DIR, "..", "..", "build", "python"))
    if os.path.isdir(build):
        if build not in sys.path:
            sys.path.insert(0, build)
        try:
            return importlib.import_module(MODULE)
        except ImportError as e:
            errors.append(f"{build}: {e}")
    searched = [p for p in (env, PACKAGE_DIR, build) if p]
    raise ImportError("drapelab: the native module is not built; run ./drapelab build (searched "
                      f"{searched}{': ' + '; '.join(errors) if errors else ''})")


native = load()
InputError = native.InputError
SolverError = native.SolverError
Cancelled = native.Cancelled
