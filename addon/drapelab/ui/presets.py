"""Preset files for the add-on's preset menu (bpy-free: the bpy side passes the user folder, which is
bpy.utils.user_resource('SCRIPTS', path="presets/drapelab", create=True)).

Shipped presets are read-only (assets/presets inside the add-on or the clone); the user's own live in the user
folder. Every preset written or imported is validated first (infer.validate_preset) and written atomically.
"""
import json
import os

from .. import infer, paths
from .tasks import safe_name

__all__ = ["shipped_dir", "list_presets", "resolve", "save", "import_file", "delete", "SHIPPED", "USER"]

SHIPPED, USER = "SHIPPED", "USER"


def shipped_dir():
    return os.path.join(paths.assets_dir(), "presets")


def _entries(folder, source):
    out = []
    if folder and os.path.isdir(folder):
        for name in sorted(os.listdir(folder)):
            if name.endswith(".json") and not name.startswith("."):
                out.append({"name": name[:-5], "path": os.path.join(folder, name), "source": source})
    return out


def list_presets(user_dir):
    """[{name, path, source}] of the shipped presets, then the user's (a user preset may share a shipped name)."""
    return _entries(shipped_dir(), SHIPPED) + _entries(user_dir, USER)


def resolve(name_or_path, user_dir):
    """A preset path from a path (existing file) or a preset name (user presets first, then shipped; a name may
    carry .json; a unique prefix such as "fabric_05" will do). InputError listing the known names when nothing
    or more than one matches."""
    text = os.fspath(name_or_path or "")
    if not text:
        raise infer.InputError("preset: give a preset name or a path to a preset JSON file")
    if os.path.isfile(text):
        return os.path.abspath(text)
    stem = text[:-5] if text.endswith(".json") else text
    entries = list_presets(user_dir)
    for source in (USER, SHIPPED):
        for e in entries:
            if e["source"] == source and e["name"] == stem:
                return e["path"]
    prefixed = {e["name"]: e["path"] for e in entries if e["name"].startswith(stem)}
    if len(prefixed) == 1:  # a unique prefix, such as "fabric_05"
        return next(iter(prefixed.values()))
    names = ", ".join(sorted({e["name"] for e in entries}))
    what = f"{text!r} is the start of several" if prefixed else f"no preset file or name {text!r}"
    raise infer.InputError(f"preset: {what} (known: {names})")


def save(preset, folder, name):
    """Validates `preset` (a dict or a path) and writes it as FOLDER/<name>.json; returns the path."""
    data = infer.load_preset(preset) if isinstance(preset, (str, os.PathLike)) else infer.validate_preset(preset)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, safe_name(name, "preset") + ".json")
    infer.write_preset(path, data)
    return path


def write_to(preset, path):
    """Validates `preset` (dict or path) and writes it to `path` (export)."""
    data = infer.load_preset(preset) if isinstance(preset, (str, os.PathLike)) else infer.validate_preset(preset)
    if not path.endswith(".json"):
        raise infer.InputError(f"filepath: {path}: a preset file name ends in .json")
    infer.write_preset(path, data)
    return path


def import_file(path, user_dir):
    """Copies a preset JSON file (validated) into the user folder under its own file name; returns the new path."""
    data = infer.load_preset(path)
    stem = os.path.splitext(os.path.basename(path))[0]
    return save(data, user_dir, stem)


def delete(path, user_dir):
    """Deletes a user preset; shipped presets and files outside the user folder are refused."""
    real, folder = os.path.realpath(path), os.path.realpath(user_dir)
    if os.path.dirname(real) != folder:
        raise infer.InputError(f"preset: {path} is not one of your presets (shipped presets cannot be deleted)")
    if not os.path.isfile(real):
        raise infer.InputError(f"preset: {path}: no such file")
    os.remove(real)


def summary(path):
    """One-line description of a preset file for the UI (fabric, model, density), or the error."""
    try:
        with open(path) as f:
            p = json.load(f)
        name = (p.get("fabric") or {}).get("name") or os.path.basename(path)
        return f"{name}: {p.get('model')}, {p.get('density_kg_m2')} kg/m^2"
    except (OSError, ValueError) as e:
        return f"{os.path.basename(path)}: unreadable ({e})"
