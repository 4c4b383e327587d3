"""Garments for drapelab (bpy-free, numpy only): garment meshes with their flat patterns (``mesh``), a
parametric skirt generator (``skirt``), a lower body with kinematic motions (``body``), per-element material
sampled from a preset's posterior (``material``) and the PC2 point cache Blender's Mesh Cache modifier plays
(``pc2``). All lengths in metres; z is up; the body faces -y (Blender's front view looks along +y).

Bad input raises ``InputError`` (a ValueError) naming the problem and its first offending index.
"""
try:  # the project's error type when the compiled core is there (always, in the add-on and the CLI)
    from .._native import InputError
except ImportError:  # pragma: no cover - the pure-numpy pieces still work without the compiled core
    class InputError(ValueError):
        """Bad input (a ValueError) naming the argument and the first offending index."""

__all__ = ["InputError"]
