"""Simulation side of drapelab: cloth models, drapes (dynamic rollout or static equilibrium) and their
gradients with respect to the material parameters (bpy-free facade over physics/ and solver/).

Arrays in and out are numpy float64: positions (V, 3) metres, faces (F, 3) int32. Parameters are one flat
vector in the model's layout (``model.layout``), built and taken apart by name::

    from drapelab import sim, tables
    model = sim.ClothModel(sim.cusick_specimen(1))                       # circle1, homogeneous
    params = model.parameters(stretch=tables.COTTON_BLUE.stretch, bend=tables.COTTON_BLUE.bend)
    x = model.simulate(params, steps=100, time_step=0.05)               # (V, 3) final positions
    grads = model.backward(2 * (x - target))                             # {"stretch": (6, 4), "bend": (3, 5), ...}

Blocks (same names in ``parameters(...)``, ``split(...)`` and the gradients of ``backward``):
    stretch           (6, 4) N/m, or (F, 6, 4) per face for heterogeneous models; columns c11, c12, c22, c33
    bend              (3, 5) N m, or (E, 3, 5) per bending edge (``model.bending_edges`` order)
    density           kg/m^2 (float, > 0)
    handle_stiffness  N/m (float, >= 0): the spring holding the vertices on the support disk

Modes: "dynamic" = implicit Euler from the flat rest state (the paper: 100 steps of 0.05 s), gradients by
the adjoint of the whole rollout; "static" = Newton to equilibrium (E minimal), gradients by one adjoint
solve. Long calls release the GIL; ``progress(done, total)`` is called on the calling thread at every step
(or Newton iteration); setting ``cancel_event`` (a threading.Event) from any thread makes the call raise
``Cancelled`` at its next step. Bad input raises ``InputError`` (a ValueError) naming the argument; a
failed solve raises ``SolverError`` (a RuntimeError).
"""
import os
import re
import threading
import warnings

import numpy as np

from . import paths, tables
from ._native import Cancelled, InputError, SolverError, native

__all__ = [
    "InputError", "SolverError", "Cancelled", "ClothModel", "effects", "effect_values", "parse_effects_arg", "cusick_specimen", "cusick_template_path",
    "default_template_dir", "simulate", "backward", "read_obj", "write_obj", "contact_report", "MODES",
    "DEFAULT_DENSITY", "DEFAULT_HANDLE_STIFFNESS", "DEFAULT_SUPPORT_RADIUS", "DEFAULT_TIME_STEP", "DEFAULT_STEPS",
]

MODES = ("dynamic", "static")
CONTACT_STEPS = ("linearised", "newton")  # how a rollout with contact takes its steps (docs/contact.md)
DEFAULT_DENSITY = tables.COTTON_BLUE.density  # kg/m^2
DEFAULT_HANDLE_STIFFNESS = 1e3                # N/m (paper)
DEFAULT_SUPPORT_RADIUS = 0.09                 # m: half the 18 cm Cusick support disk
DEFAULT_GRAVITY = 9.8                         # m/s^2
DEFAULT_TIME_STEP = 0.05                      # s (paper)
DEFAULT_STEPS = 100                           # paper: 5 s of drape
DEFAULT_FORCE_TOLERANCE = 1e-6                # static solve: residual force per vertex weight
DEFAULT_MAX_ITERATIONS = 200                  # static solve: Newton iterations
DEFAULT_MAX_SPEED = 50.0                      # m/s: a faster vertex means the rollout diverged
TEMPLATE_LEVELS = (1, 2, 3, 4, 5)
# Table shapes of the blocks with a table per element; other blocks hold one value per element.
TABLE_SHAPES = {"stretch": tables.STRETCH_SHAPE, "bend": tables.BEND_SHAPE}


# ---------------------------------------------------------------- effects
def effects():
    """The effect registry: a list of {name, explanation, signature, dynamic_only, second_direction, step_parameters,
    step_diagonals, search_grid_spacing, search_grid_reach, parameters: [{name, unit, off, lower, upper, prior_scale, moderate, structural, description}]}
    (the first parameter is the primary one; dynamic_only: the effect acts only over a dynamic rollout's time
    steps, e.g. damping, and a static drape ignores it; second_direction: {parameter: value} under which the
    diagnosis scores the primary again, e.g. a tilt's azimuth turned by 90 degrees; step_parameters: the parameters
    the diagnosis's step test steps, empty for the primary alone; step_diagonals: with two step_parameters, the
    step test also steps along the diagonals of their plane; search_grid_spacing, search_grid_reach: with two
    step_parameters, the diagnosis's refit searches their plane on this grid instead of along its best step, 0 for
    none)."""
    return [dict(e) for e in native.effects()]


def effect_values(effects):
    """An effects argument {name: {param: value}} (or None) as a new dict of floats for the native model, which
    checks names and ranges against the registry (InputError naming "effect.param")."""
    if effects is None:
        return {}
    if not isinstance(effects, dict):
        raise InputError(f"effects: expected a dict {{name: {{parameter: value}}}}, got {type(effects).__name__}")
    out = {}
    for name, values in effects.items():
        if values is None:
            values = {}
        if not isinstance(values, dict):
            raise InputError(f"effects: {name}: expected a dict {{parameter: value}}, got {type(values).__name__}")
        out[str(name)] = {str(param): _scalar(value, f"effects: {name}.{param}") for param, value in values.items()}
    return out


EFFECT_BARE_VALUES = ("moderate", "off", None)


def parse_effects_arg(text, bare="moderate", registry=None):
    """The command-line effects syntax as {name: {param: value}} (the ``effects=`` argument of ClothModel).

    text: comma-separated items, each ``NAME`` (switch the effect on), ``NAME=VALUE`` (set its primary
    parameter, the first of its block, in that parameter's unit), ``NAME.PARAM=VALUE`` (set any one) or, only
    with bare=None (``fit``), ``NAME.PARAM`` (fit that one parameter: its value comes back as None, the
    fit's "fitted from its off value"; the effect's parameters not named stay off); spaces around items, names
    and values are ignored; None or "" gives {} (no effect).
    bare: what a named effect's primary parameter is when the text does not set it: "moderate" (the registry's
    moderate strength: ``synth``) or "off" (its off value: ``fit``, which fits it from there); the effect's
    other parameters not set take their off values, so every named effect comes back with its whole block.
    bare=None returns only what the text sets (a bare NAME gives {}; beside some of its parameters set, its other
    parameters come back as None: ``tilt,tilt.azimuth_rad=1`` fits the angle at that azimuth), for callers that
    must tell a value given from one filled in (``fit``: fit_effects.EffectPlan fixes the given values, fits the parameters given
    as None and every parameter of an effect given as {}, and holds the rest of a named effect off).
    registry: the effect list (default ``effects()``). Errors (InputError naming the item): an unknown effect
    or parameter (listing the known ones), a value that is not a finite number, a parameter set (or fitted)
    twice, ``NAME.PARAM`` without a value where nothing is fitted (bare not None) or on a structural parameter
    (it chooses the model's structure and has no gradient: it needs a value). Ranges
    are checked where values meet the model, by the native registry (``ClothModel(effects=...)``).
    """
    if bare not in EFFECT_BARE_VALUES:
        raise InputError(f"bare: expected one of {EFFECT_BARE_VALUES}, got {bare!r}")
    if text is None:
        return {}
    if not isinstance(text, str):
        raise InputError(f"effects: expected text NAME[=VALUE][,NAME.PARAM=VALUE...], got {type(text).__name__}")
    blocks = {e["name"]: e["parameters"] for e in (effects() if registry is None else registry)}
    given = {}
    switched = set()  # effects named bare (NAME alone)
    for item in (s.strip() for s in text.split(",")):
        if not item:
            if text.strip():
                raise InputError(f"effects: empty item in {text!r} (items are separated by single commas)")
            continue
        key, has_value, value = (s.strip() for s in item.partition("="))
        name, has_param, param = (s.strip() for s in key.partition("."))
        if name not in blocks:
            raise InputError(f"effects: unknown effect {name!r} in {item!r} (registered: "
                             f"{', '.join(blocks) or 'none'})")
        names = [q["name"] for q in blocks[name]]
        if has_param and param not in names:
            raise InputError(f"effects: effect {name!r} has no parameter {param!r} in {item!r} "
                             f"(parameters: {', '.join(names)})")
        if has_param and not has_value:
            if bare is not None:
                raise InputError(f"effects: {item!r} names a parameter without a value (write {name}.{param}=VALUE; "
                                 f"a bare {name}.{param} fits it, only in fit --effects)")
            if next(q for q in blocks[name] if q["name"] == param).get("structural"):
                raise InputError(f"effects: {name}.{param} is structural (it has no gradient and cannot be fitted): "
                                 f"write {name}.{param}=VALUE")
        values = given.setdefault(name, {})
        if not has_value and not has_param:
            switched.add(name)
            continue
        param = param if has_param else names[0]
        if param in values:
            raise InputError(f"effects: {name}.{param} is set twice in {text!r}")
        if not has_value:
            values[param] = None  # fitted (bare=None only)
            continue
        try:
            number = float(value)
        except ValueError:
            raise InputError(f"effects: {name}.{param}: expected a number, got {value!r}") from None
        if not np.isfinite(number):
            raise InputError(f"effects: {name}.{param}: must be finite, got {value!r}")
        values[param] = number
    if bare is None:
        # a bare NAME beside some of its parameters set (tilt,tilt.azimuth_rad=1): those are held, the rest fitted
        for name in switched:
            if given[name]:
                for q in blocks[name]:
                    given[name].setdefault(q["name"], None)
        return given
    out = {}
    for name, values in given.items():
        primary = blocks[name][0]
        filled = {q["name"]: float(q["off"]) for q in blocks[name]}
        filled[primary["name"]] = float(primary[bare])
        filled.update(values)
        out[name] = filled
    return out


# ---------------------------------------------------------------- meshes
def contact_report(faces, positions, obstacle=None, search_radius=0.0, max_listed=8):
    """Contact diagnostics of a state (native contact/diagnostics.hpp): ``{"min_distance_m", "search_radius_m",
    "intersecting_pairs", "first_pairs"}``. faces (F, 3); positions (V, 3) or flat 3V (m); obstacle: None or
    (positions (W, 3), faces (G, 3)), a mesh whose pairs with the cloth count too (its faces numbered after the
    cloth's in first_pairs). min_distance_m is the smallest distance between primitives sharing no vertex within
    search_radius (0: the mean edge length), +inf when none is that close; intersecting_pairs counts the triangle
    pairs sharing no vertex that cross."""
    f = np.ascontiguousarray(faces, dtype=np.int32)
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"contact_report: faces must be (F, 3), got {f.shape}")
    x = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1)
    kwargs = {}
    if obstacle is not None:
        op, of = obstacle
        kwargs = {"obstacle_positions": np.ascontiguousarray(op, dtype=np.float64).reshape(-1, 3),
                  "obstacle_faces": np.ascontiguousarray(of, dtype=np.int32).reshape(-1, 3)}
    r = native.contact_report(f, x, search_radius=float(search_radius), max_listed=int(max_listed), **kwargs)
    r["first_pairs"] = [tuple(p) for p in r["first_pairs"]]
    return r


def default_template_dir():
    """The bundled Cusick template meshes (``paths.template_dir()``: assets/cusick/template_meshes)."""
    return paths.template_dir()


def _level(level):
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or int(level) not in TEMPLATE_LEVELS:
        raise InputError(f"level: expected one of {TEMPLATE_LEVELS} (circle1..circle5), got {level!r}")
    return int(level)


def cusick_template_path(level, template_dir=None):
    """Path of circle{level}.obj in the template folder (default: the bundled one) when present, else None."""
    folder = default_template_dir() if template_dir is None else os.fspath(template_dir)
    path = os.path.join(folder, f"circle{_level(level)}.obj")
    return path if os.path.isfile(path) else None


def cusick_specimen(level=3, *, vertices=None, template_dir=None):
    """The flat 30 cm Cusick specimen (z = 0, centred, u = x weft, v = y warp) as a TriangleMesh.

    level 1..5: the Cusick template circle{level}.obj (297, 1205, 2699, 4766, 7496 vertices) from
    ``template_dir`` (default: the bundled ``default_template_dir()``); a missing file is an InputError.
    vertices=N (instead of level): a generated disk of about N (>= 7) vertices.
    """
    if vertices is not None:
        if isinstance(vertices, bool) or not isinstance(vertices, (int, np.integer)) or vertices < 7:
            raise InputError(f"vertices: expected an integer >= 7, got {vertices!r}")
        return native.make_cusick_specimen(int(vertices))
    level = _level(level)
    folder = default_template_dir() if template_dir is None else os.fspath(template_dir)
    return native.load_cusick_template(level, folder)


def read_obj(path):
    """A TriangleMesh from an OBJ file; its rest pattern (u, v) is the (x, y) of the vertices (flat meshes)."""
    return native.read_obj(os.fspath(path))


def write_obj(path, positions, faces):
    """Writes an OBJ (positions (V, 3), faces (F, 3)) atomically."""
    from . import measure
    measure.check_output_path(path, "OBJ")
    positions = _float_array(positions, "positions", ndim=2)
    if positions.shape[1] != 3:
        raise InputError(f"positions: expected shape (V, 3), got {positions.shape}")
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise InputError(f"faces: expected an integer array of shape (F, 3), got {faces.dtype} {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= positions.shape[0]):
        raise InputError(f"faces: vertex indices must lie in [0, {positions.shape[0]})")
    native.write_obj(os.fspath(path), positions, np.ascontiguousarray(faces, dtype=np.int32))


def _mesh_arg(mesh_or_path):
    if isinstance(mesh_or_path, native.TriangleMesh):
        return mesh_or_path
    if isinstance(mesh_or_path, (str, os.PathLike)):
        return read_obj(mesh_or_path)
    if isinstance(mesh_or_path, (tuple, list)) and len(mesh_or_path) in (2, 3):
        positions = _float_array(mesh_or_path[0], "mesh positions", ndim=2)
        faces = np.asarray(mesh_or_path[1])
        if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
            raise InputError(f"mesh faces: expected an integer array of shape (F, 3), got {faces.dtype} {faces.shape}")
        uv = None if len(mesh_or_path) == 2 else _float_array(mesh_or_path[2], "mesh uv", ndim=2)
        return native.TriangleMesh(positions, np.ascontiguousarray(faces, dtype=np.int32), uv)
    raise InputError("mesh_or_path: expected a TriangleMesh, an OBJ path or (positions, faces[, uv]), "
                     f"got {type(mesh_or_path).__name__}")


# ---------------------------------------------------------------- argument checks
def _index_list(value, name):
    a = np.asarray(value)
    if a.ndim != 1 or (a.size and not np.issubdtype(a.dtype, np.integer)):
        raise InputError(f"{name}: expected a list of vertex indices, got {a.dtype} of shape {a.shape}")
    return [int(v) for v in a]


def _float_array(value, name, ndim=None):
    try:
        arr = np.asarray(value)
    except Exception as e:  # ragged lists and the like
        raise InputError(f"{name}: not an array ({e})") from None
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    if ndim is not None and arr.ndim != ndim:
        raise InputError(f"{name}: expected a {ndim}-dimensional array, got shape {arr.shape}")
    arr = np.asarray(arr, dtype=np.float64, order="C")  # (ascontiguousarray would make 0-d arrays 1-d)
    if not np.isfinite(arr).all():
        index = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise InputError(f"{name}: non-finite value {arr[index] if index else arr} at index {list(index)}")
    return arr


def _scalar(value, name, minimum=None, strictly=False, unit=""):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number, got {value!r}") from None
    if not np.isfinite(v):
        raise InputError(f"{name}: must be finite, got {v}")
    if minimum is not None and (v <= minimum if strictly else v < minimum):
        raise InputError(f"{name}: must be {'>' if strictly else '>='} {minimum:g}{' ' + unit if unit else ''}, got {v:g}")
    return v


def _positive_int(value, name):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise InputError(f"{name}: expected a positive integer, got {value!r}")
    return int(value)


# ---------------------------------------------------------------- progress and cancel
def _progress_sink(progress, cancel_event, what):
    """A native.Progress forwarding to progress(done, total) and cancelling when cancel_event is set."""
    if progress is not None and not callable(progress):
        raise InputError(f"progress: expected a callable progress(done, total), got {type(progress).__name__}")
    if cancel_event is not None and not hasattr(cancel_event, "is_set"):
        raise InputError(f"cancel_event: expected a threading.Event, got {type(cancel_event).__name__}")
    if cancel_event is not None and cancel_event.is_set():
        raise Cancelled(f"{what}: cancelled before it started")
    if progress is None and cancel_event is None:
        return None
    sink = None

    def callback(done, total):
        if progress is not None:
            progress(done, total)
        if cancel_event is not None and cancel_event.is_set():
            sink.cancel()

    sink = native.Progress(callback)
    return sink


# ---------------------------------------------------------------- the model
class ClothModel:
    """A cloth model (mesh, rest frame, masses, stretch + bend + gravity + handle) and its solvers.

    mesh_or_path: a TriangleMesh (e.g. ``cusick_specimen(3)``), an OBJ path (a flat mesh: the rest pattern is
    its (x, y)), or (positions, faces[, uv]) with uv the rest pattern (default (x, y)).
    heterogeneous: one stretch table per face and one bend table per bending edge (else one shared table).
    density (kg/m^2), handle_stiffness (N/m), support_radius (m): defaults of ``parameters()`` and the
    handled region (vertices with rest radius below support_radius are held at their rest positions).
    Garments: held_vertices (indices) replaces that region (their anchors move with ``set_handle_anchors``);
    seams (S, 2) pairs of vertices held together by zero-length springs of seam_stiffness N/m.

    One model runs one simulation at a time; ``backward`` differentiates its last ``simulate``.
    """

    def __init__(self, mesh_or_path, heterogeneous=False, density=DEFAULT_DENSITY,
                 handle_stiffness=DEFAULT_HANDLE_STIFFNESS, support_radius=DEFAULT_SUPPORT_RADIUS,
                 gravity=DEFAULT_GRAVITY, effects=None, held_vertices=None, seams=None, seam_stiffness=1e3,
                 px_per_m=720.0):
        mesh = _mesh_arg(mesh_or_path)
        held = [] if held_vertices is None else _index_list(held_vertices, "held_vertices")
        seam_pairs = [] if seams is None or len(seams) == 0 else np.asarray(seams)
        if len(seam_pairs) and (seam_pairs.ndim != 2 or seam_pairs.shape[1] != 2):
            raise InputError(f"seams: expected (S, 2) vertex pairs, got shape {seam_pairs.shape}")
        seam_pairs = [tuple(int(v) for v in pair) for pair in np.asarray(seam_pairs, dtype=np.int64).reshape(-1, 2)]
        seam_stiffness = _scalar(seam_stiffness, "seam_stiffness", 0.0, strictly=True, unit="N/m")
        density = _scalar(density, "density", 0.0, strictly=True, unit="kg/m^2")
        handle_stiffness = _scalar(handle_stiffness, "handle_stiffness", 0.0, unit="N/m")
        support_radius = _scalar(support_radius, "support_radius", 0.0, strictly=True, unit="m")
        gravity = _scalar(gravity, "gravity", 0.0, unit="m/s^2")
        px_per_m = _scalar(px_per_m, "px_per_m", 0.0, strictly=True, unit="px/m")
        self._native = native.Model(mesh, heterogeneous=bool(heterogeneous), support_radius=support_radius,
                                    gravity=gravity, density=density, handle_stiffness=handle_stiffness,
                                    effects=effect_values(effects), held_vertices=held, seams=seam_pairs,
                                    seam_stiffness=seam_stiffness, px_per_m=px_per_m)
        self._blocks = {b["name"]: b for b in self._native.layout}
        self._mesh = self._native.mesh
        self._dynamic = None
        self._static = None
        self._last = None  # mode of the last successful simulate
        self._lock = threading.Lock()
        self.last_result = {}

    @property
    def velocities(self):
        """(V, 3) velocities at the end of the last dynamic rollout (m/s), to continue it in the next call."""
        if self._dynamic is None:
            raise InputError("velocities: run a dynamic simulate(...) first")
        return np.asarray(self._dynamic.velocities).reshape(-1, 3)

    def set_handle_anchors(self, anchors):
        """Moves the held vertices' anchors (H, 3) metres, in ``handle_vertices`` order (a kinematic attachment:
        a garment's waistband following the body between simulate calls)."""
        a = _float_array(anchors, "anchors", ndim=2)
        if a.shape != (len(self.handle_vertices), 3):
            raise InputError(f"anchors: expected ({len(self.handle_vertices)}, 3), got {a.shape}")
        with self._lock:
            self._native.set_handle_anchors(a)

    # -- description
    @property
    def native(self):
        """The native Model (for other facades; users need not touch it)."""
        return self._native

    @property
    def num_vertices(self):
        return self._native.num_vertices

    @property
    def num_faces(self):
        return self._native.num_faces

    @property
    def num_bending_edges(self):
        return self._native.num_bending_edges

    @property
    def num_parameters(self):
        return self._native.num_parameters

    @property
    def active_effects(self):
        """Names of the model's active effects (registry order); their parameters are blocks "name.param"."""
        return list(self._native.active_effects)

    @property
    def heterogeneous(self):
        return self._native.heterogeneous

    @property
    def support_radius(self):
        return self._native.support_radius

    @property
    def faces(self):
        """(F, 3) int32, counter-clockwise in the rest pattern (the model's orientation)."""
        return np.array(self._mesh.faces, dtype=np.int32)

    @property
    def rest_positions(self):
        """(V, 3) metres."""
        return np.array(self._mesh.positions)

    @property
    def uv(self):
        """(V, 2) rest pattern coordinates, metres (u = weft, v = warp)."""
        return np.array(self._mesh.uv)

    @property
    def bending_edges(self):
        """(E, 4) int32 rows (a, b, c, d): edge a-b, c and d opposite; the bend block's element order."""
        return np.array(self._native.bending_edges, dtype=np.int32)

    @property
    def handle_vertices(self):
        """Indices of the vertices held by the handle (rest radius < support_radius)."""
        return np.array(self._native.handle_vertices, dtype=np.int64)

    @property
    def layout(self):
        """Parameter blocks: list of dicts {name, unit, offset, size, entries_per_element, shared}."""
        return [dict(b) for b in self._native.layout]

    def block_shape(self, name):
        """Shape of a block as returned by ``split``: e.g. (6, 4) or (F, 6, 4) for stretch, () for scalars."""
        b = self._block(name)
        table = TABLE_SHAPES.get(name, (b["entries_per_element"],) if b["entries_per_element"] > 1 else ())
        return table if b["shared"] else (b["size"] // b["entries_per_element"],) + table

    def _block(self, name):
        if name not in self._blocks:
            raise InputError(f"unknown parameter block {name!r}; blocks: {', '.join(self._blocks)}")
        return self._blocks[name]

    def masses(self, params):
        """Lumped vertex masses (V,) in kg."""
        return np.asarray(self._native.masses(self._params(params)))

    def __repr__(self):
        return (f"ClothModel({self.num_vertices} vertices, {self.num_faces} faces, {self.num_bending_edges} bending "
                f"edges, {'heterogeneous' if self.heterogeneous else 'homogeneous'})")

    # -- parameters
    def parameters(self, material=None, stretch=None, bend=None, density=None, handle_stiffness=None, effects=None):
        """A flat parameter vector (new array).

        Starts from the model's defaults (Cotton Blue tables, the model's density and handle stiffness), then
        a ``tables.MaterialPreset`` (its stretch, bend and density), then the given blocks: stretch (6, 4)
        on every face or (F, 6, 4) per face (heterogeneous models), bend (3, 5) or (E, 3, 5), density
        (kg/m^2, > 0), handle_stiffness (N/m, >= 0), effects {name: {param: value}} of active effects.
        """
        p = np.array(self._native.default_parameters())
        if material is not None:
            if not isinstance(material, tables.MaterialPreset):
                material = tables.preset(material)
            stretch = material.stretch if stretch is None else stretch
            bend = material.bend if bend is None else bend
            density = material.density if density is None else density
        for name, value in (("stretch", stretch), ("bend", bend)):
            if value is not None:
                self._set_block(p, name, value)
        if density is not None:
            self._set_block(p, "density", _scalar(density, "density", 0.0, strictly=True, unit="kg/m^2"))
        if handle_stiffness is not None:
            self._set_block(p, "handle_stiffness", _scalar(handle_stiffness, "handle_stiffness", 0.0, unit="N/m"))
        for name, values in effect_values(effects).items():
            if name not in self.active_effects:
                raise InputError(f"effects: {name!r} is not active in this model (active: "
                                 f"{', '.join(self.active_effects) or 'none'}); build the model with effects=")
            for param, value in values.items():
                p[self._block(f"{name}.{param}")["offset"]] = value
        self._native.validate_parameters(p)
        return p

    def _set_block(self, p, name, value):
        b = self._block(name)
        arr = _float_array(value, name)
        table = self.block_shape(name) if b["shared"] else self.block_shape(name)[1:]
        per_element = self.block_shape(name)
        if arr.shape == tuple(table):
            self._check_signs(name, arr.reshape((1,) + tuple(table)), shared=True)
            p[b["offset"]:b["offset"] + b["size"]] = np.tile(arr.ravel(), b["size"] // b["entries_per_element"])
        elif not b["shared"] and arr.shape == tuple(per_element):
            self._check_signs(name, arr, shared=False)
            p[b["offset"]:b["offset"] + b["size"]] = arr.ravel()
        else:
            allowed = f"{tuple(table)}" + ("" if b["shared"] else f" or {tuple(per_element)}")
            note = " (the model is homogeneous: one shared table)" if b["shared"] and arr.ndim == len(table) + 1 else ""
            raise InputError(f"{name}: expected shape {allowed}, got {arr.shape}{note}")

    @staticmethod
    def _check_signs(name, arr, shared):
        # c12 (Poisson coupling, column 1 of stretch) may be negative; every other stiffness may not.
        mask = arr < 0
        if name == "stretch":
            mask[..., 1] = False
        if mask.any():
            index = tuple(int(i) for i in np.argwhere(mask)[0])
            if name == "stretch":
                where_text = (f"row {index[-2]} {tables.STRETCH_COLUMNS[index[-1]]}"
                              + ("" if shared else f" of face {index[0]}"))
            elif name == "bend":
                where_text = f"row {index[-2]} column {index[-1]}" + ("" if shared else f" of edge {index[0]}")
            else:
                where_text = f"entry {list(index[1:]) if shared else list(index)}"
            raise InputError(f"{name}: stiffness must be >= 0, got {arr[index]:g} at {where_text}")

    def _params(self, params, name="params"):
        if isinstance(params, dict):
            params = self.parameters(**{k: v for k, v in params.items()})
        arr = _float_array(params, name, ndim=1)
        if arr.shape[0] != self.num_parameters:
            raise InputError(f"{name}: expected {self.num_parameters} values (the model's layout), got {arr.shape[0]}")
        try:
            self._native.validate_parameters(arr)
        except InputError as e:
            raise InputError(f"{name}: {e}") from None
        return arr

    def split(self, params):
        """dict block name -> value: arrays shaped like the tables (see block_shape), floats for scalars.

        Works for parameter vectors and for gradients (same layout; gradients are not sign-checked).
        """
        arr = _float_array(params, "params", ndim=1)
        if arr.shape[0] != self.num_parameters:
            raise InputError(f"params: expected {self.num_parameters} values (the model's layout), got {arr.shape[0]}")
        out = {}
        for name, b in self._blocks.items():
            shape = self.block_shape(name)
            values = arr[b["offset"]:b["offset"] + b["size"]]
            out[name] = float(values[0]) if shape == () else values.reshape(shape).copy()
        return out

    def join(self, blocks):
        """Inverse of split for a dict of every block (no sign checks; use ``parameters`` for materials)."""
        p = np.zeros(self.num_parameters)
        missing = set(self._blocks) - set(blocks)
        if missing:
            raise InputError(f"blocks: missing {', '.join(sorted(missing))}")
        for name, value in blocks.items():
            b = self._block(name)
            arr = _float_array(value, name)
            if arr.shape != tuple(self.block_shape(name)):
                raise InputError(f"{name}: expected shape {self.block_shape(name)}, got {arr.shape}")
            p[b["offset"]:b["offset"] + b["size"]] = arr.ravel()
        return p

    # -- energy
    def _positions(self, positions, name="positions"):
        arr = _float_array(positions, name, ndim=2)
        if arr.shape != (self.num_vertices, 3):
            raise InputError(f"{name}: expected shape ({self.num_vertices}, 3), got {arr.shape}")
        return arr

    def energy(self, positions, params):
        """Total energy E(x; p) in J of positions (V, 3)."""
        return self._native.energy(self._positions(positions).ravel(), self._params(params))

    def gradient(self, positions, params):
        """dE/dx (V, 3) in N."""
        g = self._native.gradient(self._positions(positions).ravel(), self._params(params))
        return np.asarray(g).reshape(-1, 3)

    # -- observation (the measurement model: effects' position transforms before the silhouette render)
    @property
    def has_observation(self):
        """True when an active effect transforms positions before the render (offset, camera)."""
        return bool(self._native.has_observation)

    def observe(self, positions, params):
        """The positions (V, 3) the silhouette renderer sees: ``positions`` through the active effects' transforms
        (offset: the tester's frame; camera: scale, centre offset, perspective); a copy when none is active."""
        x = self._positions(positions)
        if not self.has_observation:
            return x.copy()
        return np.asarray(self._native.observe(x.ravel(), self._params(params))).reshape(-1, 3)

    def observe_backward(self, positions, params, dL_dobserved, flat=False):
        """(dL/dpositions (V, 3), dL/dparams) of a loss of ``observe(positions, params)`` given its gradient
        (V, 3); dL/dparams as a ``split`` dict (or the flat vector): the transforms' direct parameter gradient."""
        x = self._positions(positions)
        g = self._positions(dL_dobserved, "dL_dobserved")
        p = self._params(params)
        gx, gp = self._native.observe_backward(x.ravel(), p, g.ravel())
        gp = np.asarray(gp)
        return np.asarray(gx).reshape(-1, 3), (gp if flat else self.split(gp))

    # -- simulation
    def simulate(self, params, mode="dynamic", steps=DEFAULT_STEPS, time_step=DEFAULT_TIME_STEP, progress=None,
                 cancel_event=None, force_tolerance=DEFAULT_FORCE_TOLERANCE, max_iterations=DEFAULT_MAX_ITERATIONS,
                 max_speed=DEFAULT_MAX_SPEED, record=True, positions0=None, velocities0=None, factor_memory_mb=None,
                 contact_force_tolerance=None, contact_step=None, contact_direction_tolerance=None):
        """Drapes the cloth from its flat rest state; returns the final positions (V, 3).

        mode "dynamic": ``steps`` implicit Euler steps of ``time_step`` seconds (record=False skips what
        backward needs, saving memory). mode "static": Newton to equilibrium, every vertex's residual force
        below force_tolerance times its weight, within max_iterations; a dynamic-only effect (damping) is ignored
        there, with a warning and ``last_result['ignored_effects']``. Details in ``last_result``.
        positions0 (V, 3): start here instead of the flat rest state (e.g. to warm-start a static solve);
        velocities0 (V, 3): initial velocities of a dynamic rollout (default at rest).
        factor_memory_mb: memory (MB) for the per-step factorisations kept for backward (default 1024);
        steps beyond it are refactorised during backward (same result, slower).
        contact_step: with a contact effect (or a garment's body), "linearised" (default): each step is the
        linearised implicit step with the contact terms included, its moves cut by collision detection (another
        iteration while a move was cut); "newton": each step minimises IPC's incremental potential, its Newton
        iterations ending when each residual force is below contact_force_tolerance of the vertex's weight
        (default 1e-6). contact_direction_tolerance: the relative residual to which a linearised move with
        self-contact couplings is solved (default 1e-10; above it only with record=False, e.g. 1e-3 for an
        animation that is not differentiated). See docs/contact.md.
        A dynamic rollout that diverges (a vertex faster than max_speed m/s, or a non-finite or indefinite step)
        raises SolverError naming the step, with the state before that step attached: ``e.step`` (0-based, the
        number of steps completed), ``e.positions`` and ``e.velocities`` (V, 3), all finite.
        """
        if mode not in MODES:
            raise InputError(f"mode: expected one of {MODES}, got {mode!r}")
        p = self._params(params)
        if mode == "dynamic":
            steps = _positive_int(steps, "steps")
            time_step = _scalar(time_step, "time_step", 0.0, strictly=True, unit="s")
            max_speed = _scalar(max_speed, "max_speed", 0.0, strictly=True, unit="m/s")
            memory = {} if factor_memory_mb is None else {
                "factor_memory_mb": _scalar(factor_memory_mb, "factor_memory_mb", 0.0, unit="MB")}
            if contact_step is not None:
                if contact_step not in CONTACT_STEPS:
                    raise InputError(f"contact_step: expected one of {CONTACT_STEPS}, got {contact_step!r}")
                memory["contact_step"] = contact_step
            if contact_direction_tolerance is not None:
                memory["contact_direction_tolerance"] = _scalar(contact_direction_tolerance,
                                                                "contact_direction_tolerance", 0.0, strictly=True)
            if contact_force_tolerance is not None:
                memory["contact_force_tolerance"] = _scalar(contact_force_tolerance, "contact_force_tolerance", 0.0,
                                                            strictly=True)
        else:
            force_tolerance = _scalar(force_tolerance, "force_tolerance", 0.0, strictly=True)
            max_iterations = _positive_int(max_iterations, "max_iterations")
        x0 = None if positions0 is None else self._positions(positions0, "positions0").ravel()
        v0 = None if velocities0 is None else self._positions(velocities0, "velocities0").ravel()
        if v0 is not None and mode != "dynamic":
            raise InputError("velocities0: only a dynamic rollout has initial velocities")
        sink = _progress_sink(progress, cancel_event, "simulate")
        with self._lock:
            self._last = None
            if mode == "dynamic":
                if self._dynamic is None:
                    self._dynamic = native.ImplicitEuler(self._native)
                try:
                    x = self._dynamic.forward(p, time_step=time_step, steps=steps, max_speed=max_speed,
                                              record=bool(record), progress=sink, x0=x0, v0=v0, **memory)
                except SolverError as e:
                    # The rollout stops before the failing step: its state is the last finite one.
                    match = re.match(r"rollout: step (\d+) ", str(e))
                    e.step = int(match.group(1)) if match else None
                    e.positions = np.asarray(self._dynamic.positions).reshape(-1, 3)
                    e.velocities = np.asarray(self._dynamic.velocities).reshape(-1, 3)
                    raise
                self.last_result = {"mode": mode, "steps": steps, "time_step": time_step, "recorded": bool(record),
                                    "timing": dict(self._dynamic.timing)}
            else:
                if self._static is None:
                    self._static = native.StaticSolver(self._native)
                r = self._static.solve(p, force_tolerance=force_tolerance, max_iterations=max_iterations,
                                       progress=sink, x0=x0)
                x = r["positions"]
                self.last_result = {"mode": mode, "iterations": int(r["iterations"]), "residual": float(r["residual"])}
                ignored = [e["name"] for e in effects() if e["dynamic_only"] and e["name"] in self.active_effects]
                if ignored:  # e.g. damping: a static equilibrium does not depend on it (CONVENTIONS.md)
                    self.last_result["ignored_effects"] = ignored
                    warnings.warn(f"simulate: {', '.join(ignored)} has no effect on a static drape (it acts only "
                                  f"over a dynamic rollout's time steps); the static equilibrium ignores it",
                                  stacklevel=2)
            self._last = mode if (mode == "static" or record) else None
        return np.asarray(x).reshape(-1, 3)

    def backward(self, dL_dpositions, flat=False, progress=None, cancel_event=None, alternatives=None):
        """Gradient of a loss L(final positions) with respect to the parameters of the last ``simulate``.

        dL_dpositions: (V, 3). Returns a dict block name -> gradient shaped like ``split`` (or the flat
        vector when flat=True).

        alternatives: parameter vectors (flat, as ``parameters`` gives them) at which the dynamic rollout's step
        map is the same function of the state as at the simulated parameters: a direction parameter whose
        amplitude is off (a tilt's azimuth at zero angle). That is the caller's promise; only the density is
        checked. Then returns a list: the gradient at the simulated parameters, then one per alternative, all from
        the one adjoint (the terms that read a differing parameter are evaluated at both; dynamic mode without
        contact only).
        """
        g = self._positions(dL_dpositions, "dL_dpositions").ravel()
        alts = None
        if alternatives is not None:
            alts = [self._params(q, "alternatives") for q in alternatives]
        sink = _progress_sink(progress, cancel_event, "backward")
        with self._lock:
            if self._last is None:
                raise InputError("backward: run simulate(...) first (dynamic mode with record=True)")
            if self._last == "dynamic":
                out = self._dynamic.backward(g, progress=sink, alternatives=alts)
                gp = out["parameters"]
                if "timing" in self.last_result:  # with the backward's split (backward_*)
                    self.last_result["timing"] = dict(self._dynamic.timing)
            elif alts is not None:
                raise InputError("backward: alternatives need a dynamic rollout (the static adjoint has none)")
            else:
                gp = self._static.adjoint(g)
        shape = (lambda v: np.asarray(v)) if flat else (lambda v: self.split(np.asarray(v)))
        if alts is None:
            return shape(gp)
        return [shape(gp)] + [shape(v) for v in out["alternatives"]]


def simulate(model, params, mode="dynamic", steps=DEFAULT_STEPS, time_step=DEFAULT_TIME_STEP, progress=None,
             cancel_event=None, **options):
    """``model.simulate(...)``: final positions (V, 3) of a drape (see ClothModel.simulate)."""
    if not isinstance(model, ClothModel):
        raise InputError(f"model: expected a ClothModel, got {type(model).__name__}")
    return model.simulate(params, mode=mode, steps=steps, time_step=time_step, progress=progress,
                          cancel_event=cancel_event, **options)


def backward(model, dL_dpositions, flat=False, progress=None, cancel_event=None):
    """``model.backward(...)``: parameter gradients of the model's last simulate (see ClothModel.backward)."""
    if not isinstance(model, ClothModel):
        raise InputError(f"model: expected a ClothModel, got {type(model).__name__}")
    return model.backward(dL_dpositions, flat=flat, progress=progress, cancel_event=cancel_event)
