"""Locates and imports the compiled core `drapelab_native` (built into build/python by ./drapelab)."""
import importlib
import os
import sys


def load():
    try:
        return importlib.import_module("drapelab_native")
    except ImportError:
        pass
    here = os.path.dirname(os.path.abspath(__file__))
    candidates = [os.environ.get("DRAPELAB_NATIVE_DIR", ""), here,
                  os.path.join(here, "..", "..", "build", "python")]
    for c in candidates:
        if c and os.path.isdir(c) and c not in sys.path:
            sys.path.insert(0, c)
    try:
        return importlib.import_module("drapelab_native")
    except ImportError as e:
        raise ImportError("drapelab: the native module is not built; run ./drapelab build "
                          f"(searched {candidates}): {e}") from e


native = load()
InputError = native.InputError
SolverError = native.SolverError
Cancelled = native.Cancelled
