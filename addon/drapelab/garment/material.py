"""Per-element material of a garment, drawn from a preset's posterior, and its Blender attributes.

``sample_garment_material(preset, garment, seed, samples)`` draws the garment's per-face stretching tables and
per-bending-edge bending tables exactly as ``infer.evaluate`` drapes a preset: the bending draws are
``infer.preset_bend_samples(preset, E, numpy.random.default_rng(seed), samples)`` (the bdp posterior's per-element
spread log_std, and its drape-calibrated per-draw factor global_log_std; a homo preset gives one table for every
edge; a heter preset's per-element tables when the element count matches, else their mean), the stretching
table is the preset's ``stretch_N_m`` on every face (presets fit bending only: stretching is a fixed table, so
every face carries the same one), the density the preset's. A preset's active effects (fitted on Cusick drapes)
are carried as values in ``GarmentMaterial.effects`` for the simulator to apply or not; they do not change the
tables.

Orientation: the tables are in the pattern's (u, v) frame (u = weft, v = warp), which is the garment's uv, so no
rotation is applied: a garment whose uv +v is the grain line gets warp and weft right on every triangle. A
mesh whose UV map is rotated against the grain rotates the fabric with it.

Attributes (``material_attributes``; the add-on stores them on the Blender mesh, names with the ``drapelab_``
prefix, ``ATTRIBUTE_DOMAINS`` gives FACE or EDGE):
    drapelab_stretch_weft, _warp, _shear   FACE, N/m: c11, c22, c33 of the table's small-strain row (row 0;
                                           stretch.hpp: W = 1/2 eps^T C eps at small strain)
    drapelab_bend_warp, _bias, _weft       EDGE, N m: the table's small-curvature column (column 0) of the rows
                                           beta = 0, 45, 90 degrees (bend.hpp: beta = angle between the fold edge
                                           and the weft). Warp bending (textile usage: the warp yarns curve, the
                                           fold line runs along the weft) is row 0; weft bending row 2.
    drapelab_stretch_00 .. _23             FACE: the whole (6, 4) table, row-major (entry 4 row + column)
    drapelab_bend_00 .. _14                EDGE: the whole (3, 5) table, row-major (entry 5 row + column)
    drapelab_density                       FACE, kg/m^2
EDGE attributes follow ``bending_edges`` (the native model's order); on a Blender mesh whose seams are welded
(``write_garment_obj``), the edge of bending edge (a, b) joins points ``garment.point_index()[[a, b]]``.
"""
import os
from dataclasses import dataclass, field

import numpy as np

from . import InputError
from .mesh import Garment

__all__ = ["GarmentMaterial", "sample_garment_material", "material_attributes", "material_from_attributes",
           "garment_bending_edges", "resolve_preset", "ATTRIBUTE_DOMAINS", "FACE_SUMMARIES", "EDGE_SUMMARIES"]

STRETCH_SHAPE = (6, 4)
BEND_SHAPE = (3, 5)
FACE_SUMMARIES = {"drapelab_stretch_weft": (0, 0), "drapelab_stretch_warp": (0, 2), "drapelab_stretch_shear": (0, 3)}
EDGE_SUMMARIES = {"drapelab_bend_warp": (0, 0), "drapelab_bend_bias": (1, 0), "drapelab_bend_weft": (2, 0)}
STRETCH_ENTRIES = [f"drapelab_stretch_{k:02d}" for k in range(24)]
BEND_ENTRIES = [f"drapelab_bend_{k:02d}" for k in range(15)]
DENSITY = "drapelab_density"
ATTRIBUTE_DOMAINS = {**{n: "FACE" for n in FACE_SUMMARIES}, **{n: "EDGE" for n in EDGE_SUMMARIES},
                     **{n: "FACE" for n in STRETCH_ENTRIES}, **{n: "EDGE" for n in BEND_ENTRIES}, DENSITY: "FACE"}
MAX_SAMPLES = 10000


@dataclass
class GarmentMaterial:
    """One draw of a garment's material: stretch (F, 6, 4) N/m per face, bend (E, 3, 5) N m per bending edge,
    bending_edges (E, 2) int32 (a, b) in the native model's order (bending_stencils (E, 4): a, b and the two
    opposite vertices), density kg/m^2, face_scalars {name: (F,)}, edge_scalars {name: (E,)}."""
    stretch: np.ndarray
    bend: np.ndarray
    bending_edges: np.ndarray
    density: float
    face_scalars: dict = field(default_factory=dict)
    edge_scalars: dict = field(default_factory=dict)
    bending_stencils: np.ndarray = None
    preset_name: str = ""
    seed: int = 0
    sample: int = 0
    effects: dict = field(default_factory=dict)  # the preset's active effects {name: {param: value}} (their means)
    thickness_m: float = None  # the fabric's thickness (preset fabric.thickness_mm), m; None: not known

    def native_parameters(self, model):
        """The parameter vector of a heterogeneous ``sim.ClothModel`` of this garment (same faces and edges)."""
        return model.parameters(stretch=self.stretch, bend=self.bend, density=self.density)


def _summaries(stretch, bend):
    faces = {n: np.ascontiguousarray(stretch[:, r, c]) for n, (r, c) in FACE_SUMMARIES.items()}
    edges = {n: np.ascontiguousarray(bend[:, r, c]) for n, (r, c) in EDGE_SUMMARIES.items()}
    return faces, edges


def resolve_preset(preset):
    """A validated preset dict from a dict, a JSON path, or a shipped preset's name (``assets/presets``: the
    file name without .json, or a unique prefix such as "fabric_05"). Returns (preset, name)."""
    from .. import infer, paths
    if isinstance(preset, dict):
        return infer.validate_preset(preset), str((preset.get("fabric") or {}).get("name", "preset"))
    if not isinstance(preset, (str, os.PathLike)):
        raise InputError(f"preset: expected a preset dict, a JSON path or a shipped preset name, got {type(preset).__name__}")
    path = os.fspath(preset)
    if not os.path.exists(path):
        folder = os.path.join(paths.assets_dir(), "presets")
        names = sorted(f[:-5] for f in os.listdir(folder) if f.endswith(".json")) if os.path.isdir(folder) else []
        matches = [n for n in names if n == path] or [n for n in names if n.startswith(path)]
        if len(matches) != 1:
            raise InputError(f"preset: {path!r} is neither a file nor {'a unique' if matches else 'a'} shipped preset "
                             f"name (shipped: {', '.join(names) or 'none'})")
        path = os.path.join(folder, matches[0] + ".json")
    return infer.load_preset(path), os.path.splitext(os.path.basename(path))[0]


def garment_bending_edges(garment):
    """(E, 4) int32 bending stencils (a, b, c, d) of the garment in the native model's order."""
    from .._native import native
    p, uv, f = garment.to_native_mesh_arrays()
    return np.asarray(native.bending_edges(native.TriangleMesh(p, f, uv)), dtype=np.int32)


def sample_garment_material(preset, garment, seed=0, samples=1):
    """``samples`` GarmentMaterial draws for the garment from the preset's posterior (see the module docstring),
    deterministic per (seed, samples): the same stream as ``evaluate --seed S --samples K`` (so draw i depends
    on K too: the per-draw factor is drawn after all the per-element noise)."""
    from .. import fit_effects, infer
    if not isinstance(garment, Garment):
        raise InputError(f"garment: expected a Garment, got {type(garment).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed: expected an integer >= 0, got {seed!r}")
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or not 1 <= samples <= MAX_SAMPLES:
        raise InputError(f"samples: expected an integer in [1, {MAX_SAMPLES}], got {samples!r}")
    garment.validate()
    preset, name = resolve_preset(preset)
    stencils = garment_bending_edges(garment)
    E, F = stencils.shape[0], garment.num_faces
    draws = infer.preset_bend_samples(preset, E, np.random.default_rng(int(seed)), int(samples))
    stretch = np.broadcast_to(np.asarray(preset["stretch_N_m"], np.float64), (F,) + STRETCH_SHAPE)
    thickness = _thickness_m(preset)
    out = []
    for i in range(int(samples)):
        s = np.array(stretch)
        b = np.ascontiguousarray(draws[i], dtype=np.float64)
        if not (np.isfinite(b).all() and (b > 0).all()):  # log-normal draws: only an absurd preset gets here
            raise InputError(f"preset {name}: draw {i} has a non-finite or non-positive bending entry")
        fs, es = _summaries(s, b)
        out.append(GarmentMaterial(s, b, stencils[:, :2].copy(), float(preset["density_kg_m2"]), fs, es,
                                   stencils.copy(), name, int(seed), i,
                                   fit_effects.active_effect_values(preset.get("active_effects")), thickness))
    return out


def _thickness_m(preset):
    """The preset's fabric thickness in metres (fabric.thickness_mm), None when absent or not a positive number."""
    t = (preset.get("fabric") or {}).get("thickness_mm")
    try:
        t = float(t)
    except (TypeError, ValueError):
        return None
    return t * 1e-3 if np.isfinite(t) and t > 0 else None


def material_attributes(material):
    """{name: (F,) or (E,) float64} of every per-element value the add-on stores as Blender attributes
    (ATTRIBUTE_DOMAINS gives each one's domain, FACE or EDGE)."""
    if not isinstance(material, GarmentMaterial):
        raise InputError(f"material: expected a GarmentMaterial, got {type(material).__name__}")
    out = {}
    out.update({k: np.array(v, np.float64) for k, v in material.face_scalars.items()})
    out.update({k: np.array(v, np.float64) for k, v in material.edge_scalars.items()})
    s = material.stretch.reshape(-1, 24)
    b = material.bend.reshape(-1, 15)
    out.update({n: np.ascontiguousarray(s[:, k]) for k, n in enumerate(STRETCH_ENTRIES)})
    out.update({n: np.ascontiguousarray(b[:, k]) for k, n in enumerate(BEND_ENTRIES)})
    out[DENSITY] = np.full(s.shape[0], material.density)
    return out


def material_from_attributes(attributes, garment):
    """The GarmentMaterial stored in Blender attributes (``material_attributes``' names) on this garment: the
    tables from drapelab_stretch_00.._23 and drapelab_bend_00.._14, the summaries recomputed from them.
    Errors (InputError) name a missing attribute, a wrong length, a non-finite or negative value."""
    if not isinstance(garment, Garment):
        raise InputError(f"garment: expected a Garment, got {type(garment).__name__}")
    if not hasattr(attributes, "get"):
        raise InputError(f"attributes: expected a mapping name -> array, got {type(attributes).__name__}")
    stencils = garment_bending_edges(garment)
    F, E = garment.num_faces, stencils.shape[0]

    def column(name, n):
        if name not in attributes:
            raise InputError(f"attributes: {name} is missing (apply the material again)")
        try:
            a = np.asarray(attributes[name], dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise InputError(f"attributes: {name} is not an array of numbers") from None
        if a.shape != (n,):
            what = "faces" if ATTRIBUTE_DOMAINS[name] == "FACE" else "bending edges"
            raise InputError(f"attributes: {name} has {a.size} values, the garment has {n} {what}")
        bad = ~np.isfinite(a)
        if bad.any():
            raise InputError(f"attributes: {name} has a non-finite value at element {int(np.argmax(bad))}")
        return a
    stretch = np.stack([column(n, F) for n in STRETCH_ENTRIES], axis=1).reshape((F,) + STRETCH_SHAPE)
    bend = np.stack([column(n, E) for n in BEND_ENTRIES], axis=1).reshape((E,) + BEND_SHAPE)
    neg = np.delete(stretch, 1, axis=2) < 0          # c12, a Poisson coupling, may be negative
    if neg.any():
        raise InputError(f"attributes: negative stretching stiffness on face {int(np.argwhere(neg)[0][0])}")
    if (bend <= 0).any():
        raise InputError(f"attributes: non-positive bending stiffness on bending edge {int(np.argwhere(bend <= 0)[0][0])}")
    density = column(DENSITY, F)
    if not (density > 0).all() or np.ptp(density) > 1e-12 * density.max():
        raise InputError("attributes: drapelab_density must be one positive value on every face")
    fs, es = _summaries(stretch, bend)
    return GarmentMaterial(stretch, bend, stencils[:, :2].copy(), float(density[0]), fs, es, stencils.copy())
