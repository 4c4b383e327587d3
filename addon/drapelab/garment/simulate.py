"""Garment simulation: a garment (``mesh.Garment``) with one draw of a fitted material (``material.GarmentMaterial``)
on the moving body (``body.Body`` and a motion), the same cloth model as the Cusick drapes.

The simulated mesh is the garment welded at its seams (``welded_mesh``): every sewn point is one vertex, the
pattern pieces' faces keep their own corners' pattern coordinates (native ``TriangleMesh.corner_uv``), so
stretching is that of the pieces, the seam edges bend like any other edge (their bending table: the geometric
mean of the tables of their two faces' other edges), and the mesh is one manifold surface on which self contact
is well-posed (faces meeting at a seam share vertices and are excluded from contact pairs as neighbours are).
Frames are mapped back to the garment's own vertex order (seam copies get their point's position) for the PC2
and OBJ outputs and the add-on.

The model: per-face stretching and per-bending-edge bending tables sampled from the preset's posterior (oriented by
the garment's uv, i.e. its grain line), the preset's density, gravity; the waistband held by the handle spring to
anchors carried by the pelvis; contact with the body's parts (rigid surfaces of revolution, IPC barrier of reach
``BODY_REACH_M``, native garment/revolved_body.hpp) and self contact (the ``self_contact`` effect: IPC barriers
between non-adjacent point-triangle and edge-edge pairs closer than the fabric's thickness, with friction
``SELF_FRICTION``; contact/pair_contact.hpp), every move of the cloth bounded by continuous collision detection
(no cloth vertex or edge ever enters the body, the cloth never passes through itself). The body moves inside each
step (native ImplicitEuler's contact steps: it advances from its start pose as
far as collision detection on the relative motion allows, carrying the cloth near it along a smooth displacement
field bounded by the self contact's CCD, and the rest between the step's linear solves). The start placement must be free
of self-intersections (an InputError names the first pair) and of the body (vertices and edges). Friction with the
body: IPC's lagged Coulomb potential per vertex and body part, coefficient ``BODY_FRICTION`` (native
garment/body_friction.hpp): the vertex's slip is measured against the body's own motion over the step, so a moving
leg drags the cloth resting on it.

Steps: ``contact_step`` "linearised" (default) takes the Cusick drape's step, the one the presets were fitted
with (one linear solve with the step matrix, another only while collision detection cut the move or the body is
still advancing); "newton" runs IPC's Newton iterations to the incremental potential's minimiser.

Time: ``fps`` frames per second with ``substeps`` implicit steps each; the body and the waist anchors move
continuously (poses at each substep's start and end). Deterministic: the same inputs give the same frames.
Frame 0 is the garment's rest placement; frames 1..frames-1 are simulated.
"""
import os
import time

import numpy as np

from .. import sim
from . import InputError
from .body import Body, make_body, part_transforms
from .material import GarmentMaterial
from .mesh import Garment
from .pc2 import PC2Writer

__all__ = ["drape", "DEFAULT_FPS", "DEFAULT_SUBSTEPS", "CONTACT_STEPS", "DEFAULT_CONTACT_STEP", "BODY_REACH_M", "DEFAULT_THICKNESS_M", "SELF_FRICTION",
           "BODY_FRICTION",
           "hem_radius", "top_band_vertices", "welded_mesh", "WeldedMesh"]

DEFAULT_FPS = 24
DEFAULT_SUBSTEPS = 4          # implicit steps per frame (1/96 s at 24 fps)
# Each implicit step: "linearised" (default) is the Cusick drape's step (the one the presets were fitted with):
# one linear solve with the step matrix, moves bounded by collision detection, another solve only while a move was
# cut or the body is still advancing; "newton" minimises IPC's incremental potential to FORCE_TOLERANCE (about
# 30 linear solves per step, several times slower; see docs/garments.md "Step kinds").
CONTACT_STEPS = ("linearised", "newton")
DEFAULT_CONTACT_STEP = "linearised"
# Linearised moves with self-contact couplings are solved by CG to this relative residual (inexact Newton: an
# animation that is not differentiated; the Cusick fits' recorded rollouts solve to 1e-10).
DIRECTION_TOLERANCE = 1e-3
BODY_REACH_M = 2e-3           # the body barrier acts within 2 mm of its surface
BARRIER_WEIGHT_SCALE = 1.0    # barrier stiffness in vertex weights x reach (as self_contact; disk_contact: 5)
GRAVITY = 9.8                 # m/s^2
HOLD_STIFFNESS = 1e3          # N/m: the waistband's attachment spring (the Cusick handle's value)
SEAM_STIFFNESS = 1e3          # N/m per seam pair
# Newton iterations of each step end when every residual force is below this fraction of the vertex's weight:
# an animation needs far less than a fit's adjoint (1e-6).
FORCE_TOLERANCE = 1e-2
WAIST_BAND_M = 0.03           # a garment without named waist vertices: those within this of its top
DEFAULT_THICKNESS_M = 1e-3    # self contact's reach when the material does not know its fabric's thickness
SELF_FRICTION = 0.3           # Coulomb coefficient between layers (the self_contact effect's moderate value)
BODY_FRICTION = 0.3           # Coulomb coefficient between the cloth and the body (woven fabric on a covered form)
MAX_SUBSTEP_SPLITS = 3        # a failing frame is redone with 2x, 4x, 8x the substeps before drape() gives up
MAX_SEAM_GAP_M = 1e-3         # seam copies further apart than this at the start are an error (no silent welding)


class Cancelled(Exception):
    """Raised inside the frame loop when cancel_event is set (drape() returns what was done)."""


class _Crossed(Exception):
    """A frame ended with the cloth through itself (it is done again with finer substeps)."""


class WeldedMesh:
    """The garment as the simulator sees it: seams welded (module doc). ``point`` (V,) maps each garment vertex to
    its simulated vertex; ``positions`` (P, 3), ``faces`` (F, 3) (the garment's faces, same order), ``corner_uv``
    (3F, 2) pattern coordinates per face corner, ``uv`` (P, 2) one copy's (only read where corner_uv is not)."""

    def __init__(self, garment):
        point = np.asarray(garment.point_index(), dtype=np.int64)
        n = int(point.max()) + 1
        counts = np.bincount(point, minlength=n).astype(float)
        positions = np.zeros((n, 3))
        np.add.at(positions, point, garment.positions)
        positions /= counts[:, None]
        gap = np.linalg.norm(garment.positions - positions[point], axis=1)
        if gap.max() > MAX_SEAM_GAP_M / 2:
            i = int(np.argmax(gap))
            raise InputError(f"garment: seam copies of point {int(point[i])} (vertex {i}) are "
                             f"{2 * gap[i] * 1000:.2f} mm apart or more; a garment starts sewn (its seam vertices "
                             "in pairs at one place)")
        faces = point[garment.faces]
        repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
        if repeated.any():
            f = int(np.argmax(repeated))
            raise InputError(f"garment: face {f} {garment.faces[f].tolist()} has two vertices sewn into one point "
                             "(a seam pairs vertices of one face)")
        uv = np.zeros((n, 2))
        uv[point] = garment.uv
        self.point = point
        self.positions = positions
        self.faces = np.ascontiguousarray(faces, dtype=np.int32)
        self.uv = uv
        self.corner_uv = np.ascontiguousarray(garment.uv[garment.faces].reshape(-1, 2))
        try:
            self.native = sim.native.TriangleMesh(self.positions, self.faces, self.uv, self.corner_uv)
        except (ValueError, RuntimeError) as e:  # native InputError (non-manifold after welding, ...)
            raise InputError(f"garment: its seams welded, the mesh is not a valid cloth: {e}") from None
        self.bending_edges = np.asarray(sim.native.bending_edges(self.native), dtype=np.int64)

    @property
    def num_vertices(self):
        return int(self.positions.shape[0])

    def to_garment(self, x):
        """(V, 3) garment-order positions of simulated positions x (P, 3)."""
        return np.asarray(x).reshape(-1, 3)[self.point]

    def bend_tables(self, material):
        """(E', 3, 5) bending tables on the welded mesh's bending edges from the material's (on the garment's):
        an edge inside a piece keeps its table; a seam edge (a bending edge only once welded) gets the geometric
        mean of the tables of its two faces' other bending edges."""
        key = lambda a, b: (min(a, b), max(a, b))
        own = {}
        for k, (a, b) in enumerate(np.asarray(material.bending_edges).reshape(-1, 2)):
            own.setdefault(key(int(self.point[a]), int(self.point[b])), k)
        bend = np.asarray(material.bend, dtype=float)
        out = np.empty((len(self.bending_edges),) + bend.shape[1:])
        seam = []
        for e, (a, b, c, d) in enumerate(self.bending_edges):
            k = own.get(key(int(a), int(b)))
            if k is None:
                seam.append(e)
            else:
                out[e] = bend[k]
        fallback = np.exp(np.log(bend).mean(axis=0))
        for e in seam:
            a, b, c, d = (int(v) for v in self.bending_edges[e])
            near = [own[q] for q in (key(a, c), key(b, c), key(a, d), key(b, d)) if q in own]
            out[e] = np.exp(np.log(bend[near]).mean(axis=0)) if near else fallback
        self.seam_edges = np.asarray(seam, dtype=np.int64)
        return out


def welded_mesh(garment):
    """The garment's simulated mesh, its seams welded (``WeldedMesh``)."""
    return WeldedMesh(garment)


def top_band_vertices(positions, band_m=WAIST_BAND_M):
    """Indices of the vertices within band_m of the highest one: the waistband of a garment that does not name it
    (an OBJ, a Blender mesh)."""
    z = np.asarray(positions, dtype=float).reshape(-1, 3)[:, 2]
    return np.flatnonzero(z > z.max() - band_m).astype(np.int32)


def hem_radius(positions, garment, centre_xy=(0.0, 0.0)):
    """Mean horizontal distance (m) of the hem vertices from the vertical axis through centre_xy."""
    x = np.asarray(positions, dtype=float).reshape(-1, 3)[np.asarray(garment.hem_vertices)]
    return float(np.hypot(x[:, 0] - centre_xy[0], x[:, 1] - centre_xy[1]).mean())


def _check(garment, material, body, frames, fps, substeps):
    if not isinstance(garment, Garment):
        raise InputError(f"garment: expected a Garment, got {type(garment).__name__}")
    if not isinstance(material, GarmentMaterial):
        raise InputError(f"material: expected a GarmentMaterial (material.sample_garment_material), got "
                         f"{type(material).__name__}")
    if body is not None and not isinstance(body, Body):
        raise InputError(f"body: expected a Body (body.make_body), got {type(body).__name__}")
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 2:
        raise InputError(f"frames: expected an integer >= 2, got {frames!r}")
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise InputError(f"substeps: expected a positive integer, got {substeps!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps: must be > 0, got {fps!r}")
    if len(garment.waist_vertices) == 0:
        raise InputError("garment: no waist vertices to attach to the body")
    if material.stretch.shape[0] != len(garment.faces):
        raise InputError(f"material: {material.stretch.shape[0]} stretch tables for {len(garment.faces)} faces "
                         "(sample it for this garment)")


def build_model(garment, material, body, thickness_m=None, friction=SELF_FRICTION, welded=None, body_edges=True,
                body_friction=BODY_FRICTION):
    """The native model of the garment (welded at its seams) with its body contact and self contact:
    (ClothModel, parameters, body contact term, WeldedMesh). thickness_m: self contact's reach (None: the
    material's fabric thickness, else DEFAULT_THICKNESS_M; 0: no self contact). body_edges=False keeps only the
    cloth's vertices off the body (its edges may cut it between them: for states saved before the edge term);
    body_friction: Coulomb coefficient with the body (0: none)."""
    welded = WeldedMesh(garment) if welded is None else welded
    thickness = self_contact_thickness(material, thickness_m)
    effects = {"self_contact": {"thickness_m": thickness, "friction": friction}} if thickness > 0 else None
    held = np.unique(welded.point[np.asarray(garment.waist_vertices)])
    model = sim.ClothModel(welded.native, heterogeneous=True, density=material.density,
                           handle_stiffness=HOLD_STIFFNESS, held_vertices=held, effects=effects)
    params = model.parameters(stretch=material.stretch, bend=welded.bend_tables(material), density=material.density,
                              effects=effects)
    weights = np.asarray(model.native.masses(params)) * GRAVITY
    kappa = BARRIER_WEIGHT_SCALE * weights * BODY_REACH_M
    parts = [(np.asarray(o, float), np.asarray(s, float), np.asarray(r, float)) for o, s, r in body.profiles]
    contact = model.native.add_body_contact(parts, kappa, BODY_REACH_M, edges=bool(body_edges),
                                            friction=float(body_friction))
    return model, params, contact, welded


def self_contact_thickness(material, thickness_m=None):
    """Self contact's reach (m): thickness_m if given (0: off), else the material's fabric thickness, else
    DEFAULT_THICKNESS_M."""
    if thickness_m is None:
        t = getattr(material, "thickness_m", None)
        return float(t) if t else DEFAULT_THICKNESS_M
    if isinstance(thickness_m, bool) or not isinstance(thickness_m, (int, float, np.integer, np.floating)) or \
            not (np.isfinite(thickness_m) and 0 <= thickness_m <= 0.01):
        raise InputError(f"thickness_m: expected a thickness in [0, 0.01] m (0: no self contact), got {thickness_m!r}")
    return float(thickness_m)


def drape(garment, material, body=None, motion="static", frames=48, fps=DEFAULT_FPS, substeps=DEFAULT_SUBSTEPS,
          progress=None, cancel_event=None, pc2_path=None, keep_frames=True, thickness_m=None,
          self_friction=SELF_FRICTION, force_tolerance=FORCE_TOLERANCE, contact_step=DEFAULT_CONTACT_STEP,
          body_friction=BODY_FRICTION):
    """Simulates the garment on the body for ``frames`` frames (module doc). Returns a dict: ``positions``
    (frames done, V, 3) float32 when keep_frames, ``first`` and ``last`` (V, 3), and the stats ``vertices``
    (the garment's), ``simulated_vertices`` (seams welded), ``frames`` (done), ``seconds_per_frame``,
    ``max_body_penetration_m`` (deepest cloth point inside the body over all frames: every vertex and every point
    of every edge, 0 when none), ``min_body_clearance_m`` (the same points' least clearance), ``self_intersections_final`` (intersecting face pairs of the last frame),
    ``hem_radius_m`` (last frame, from the pelvis axis), ``self_contact_thickness_m``, ``cancelled``,
    ``newton_iterations`` (linear solves of all steps), ``contact_step``, ``solver`` (factorisations, CG iterations and
    seconds in assembly + factorisation, solves and collision detection), ``retried_frames`` and ``retries`` (each frame
    redone with finer substeps: frame, substeps, error). All positions are in the garment's vertex order.
    ``thickness_m``: self contact's reach (None: the material's fabric thickness, else DEFAULT_THICKNESS_M; 0: no
    self contact); ``self_friction``: Coulomb coefficient between layers; ``body_friction``: between the cloth and
    the body (0: frictionless); ``contact_step``: "linearised" (default:
    one linear solve per step, more only while collision detection cuts a move or the body is still advancing) or
    "newton" (IPC's Newton iterations, ending when every residual force is below ``force_tolerance`` of its
    vertex's weight).
    ``pc2_path``: the frames are appended to a PC2 cache as they finish (playback can start during the bake; a
    reader never sees a partial frame). ``progress(frame_done, frames)``; ``cancel_event`` (threading.Event)
    stops between substeps keeping the frames done. A step that fails raises SolverError naming the frame."""
    body = make_body() if body is None else body
    _check(garment, material, body, frames, fps, substeps)
    if contact_step not in CONTACT_STEPS:
        raise InputError(f"contact_step: expected one of {CONTACT_STEPS}, got {contact_step!r}")
    step_options = ({"contact_step": "newton", "contact_force_tolerance": force_tolerance} if contact_step == "newton"
                    else {"contact_step": "linearised", "contact_direction_tolerance": DIRECTION_TOLERANCE})
    if not (isinstance(self_friction, (int, float, np.integer, np.floating)) and not isinstance(self_friction, bool)
            and 0 <= self_friction <= 2):
        raise InputError(f"self_friction: expected a coefficient in [0, 2], got {self_friction!r}")
    if not (isinstance(body_friction, (int, float, np.integer, np.floating)) and not isinstance(body_friction, bool)
            and 0 <= body_friction <= 2):
        raise InputError(f"body_friction: expected a coefficient in [0, 2], got {body_friction!r}")
    welded = WeldedMesh(garment)
    thickness = self_contact_thickness(material, thickness_m)
    crossing = sim.contact_report(welded.faces, welded.positions, max_listed=1)["first_pairs"]
    if crossing:
        a, b = crossing[0]
        raise InputError(f"garment: its start placement intersects itself (faces {a} and {b}, and perhaps others): "
                         "self contact needs an intersection-free start; fix the placement (sim.contact_report "
                         "lists the pairs)")
    model, params, contact, _ = build_model(garment, material, body, thickness, self_friction, welded,
                                            body_friction=body_friction)
    waist = np.asarray(model.handle_vertices)
    waist_rest = welded.positions[waist]
    x = welded.positions.copy()
    v = np.zeros_like(x)
    clearance0 = np.asarray(contact.clearance(x.ravel()))
    if clearance0.min() <= 0:
        worst = int(np.argmax(welded.point == int(np.argmin(clearance0))))
        raise InputError(f"garment: {int((clearance0 <= 0).sum())} vertices start inside the body (deepest: vertex "
                         f"{worst}, {-clearance0.min() * 1000:.1f} mm); move or scale the garment")
    edge_clearance0 = np.asarray(contact.edge_clearance(x.ravel()))
    if len(edge_clearance0) and edge_clearance0.min() <= 0:
        a, b = (int(np.argmax(welded.point == int(i))) for i in contact.edges[int(np.argmin(edge_clearance0))])
        raise InputError(f"garment: {int((edge_clearance0 <= 0).sum())} edges start through the body (deepest: the "
                         f"edge between vertices {a} and {b}, {-edge_clearance0.min() * 1000:.1f} mm inside); move or "
                         "scale the garment, or refine it")
    clearance0 = np.concatenate([clearance0, edge_clearance0])
    kept = [welded.to_garment(x).astype(np.float32)] if keep_frames else []
    writer = PC2Writer(pc2_path, garment.num_vertices, start_frame=1, sample_rate=1.0) if pc2_path else None
    penetration, clearance_min = 0.0, float(clearance0.min())
    done, cancelled = 1, False
    counters = {"iterations": 0, "retried_frames": 0}
    retries = []
    solver = {"factorizations": 0, "cg_iterations": 0, "assemble_and_factorize_s": 0.0, "solve_s": 0.0,
              "collision_s": 0.0}

    def run_frame(frame, x, v, n):
        """The frame's n substeps from (x, v); raises SolverError (or _Crossed) if a step fails."""
        times = (frame - 1 + np.arange(n + 1) / n) / fps
        transforms = part_transforms(body, motion, times, fps)
        h = 1.0 / (fps * n)
        v = v.copy()
        for j in range(n):
            if cancel_event is not None and cancel_event.is_set():
                raise Cancelled()
            start, end = transforms[j, 0], transforms[j + 1, 0]
            a0 = waist_rest @ start[:3, :3].T + start[:3, 3]
            a1 = waist_rest @ end[:3, :3].T + end[:3, 3]
            model.set_handle_anchors(a1)
            # The waistband moves with the pelvis: it starts the step with its anchors' velocity, so the inertial
            # prediction already carries it (a lagging waist would start each step 10^3 weights out of balance
            # and cost Newton iterations); its offset from the anchors (the held waistband's strain) stays.
            v[waist] = (a1 - a0) / h
            contact.set_poses(list(transforms[j]), list(transforms[j + 1]))
            x = model.simulate(params, steps=1, time_step=h, record=False, positions0=x, velocities0=v,
                               **step_options)
            v = model.velocities.copy()
            timing = model.last_result.get("timing", {})
            counters["iterations"] += int(timing.get("newton_iterations", 0))
            solver["factorizations"] += int(timing.get("factorizations", 0))
            solver["assemble_and_factorize_s"] += float(timing.get("factorize", 0))
            solver["solve_s"] += float(timing.get("solve", 0))
            solver["collision_s"] += float(timing.get("collision", 0))
            solver["cg_iterations"] += int(timing.get("cg_iterations", 0))
        if thickness > 0:
            crossing = sim.contact_report(welded.faces, x, max_listed=1)["first_pairs"]
            if crossing:
                raise _Crossed(f"faces {crossing[0][0]} and {crossing[0][1]} intersect at its end")
        return x, v

    t_start = time.perf_counter()
    try:
        if writer:
            writer.write_frame(welded.to_garment(x))
        for frame in range(1, frames):
            # A frame whose step fails (e.g. cloth pinched so that the body cannot reach its end pose within the
            # step's Newton iterations), or that ends with the cloth through itself (a safety net: every move of
            # the cloth, the body's carry included, is bounded by collision detection), is done again from its
            # start with twice the substeps (smaller body moves), up to MAX_SUBSTEP_SPLITS times.
            n, error = substeps, None
            for attempt in range(MAX_SUBSTEP_SPLITS + 1):
                try:
                    x_next, v_next = run_frame(frame, x, v, n)
                    error = None
                    break
                except (sim.SolverError, _Crossed) as e:
                    error = e
                    counters["retried_frames"] += int(attempt == 0)
                    retries.append({"frame": frame, "substeps": n, "error": str(e)})
                    n *= 2
            if error is not None:
                raise sim.SolverError(f"garment: frame {frame} failed with up to {n // 2} substeps: {error}")
            x, v = x_next, v_next
            c = np.concatenate([np.asarray(contact.clearance(x.ravel())), np.asarray(contact.edge_clearance(x.ravel()))])
            clearance_min = min(clearance_min, float(c.min()))
            penetration = max(penetration, float(max(0.0, -c.min())))
            if writer:
                writer.write_frame(welded.to_garment(x))
            if keep_frames:
                kept.append(welded.to_garment(x).astype(np.float32))
            done += 1
            if progress:
                progress(done, frames)
    except Cancelled:
        cancelled = True
    finally:
        if writer:
            writer.close()
    iterations = counters["iterations"]
    seconds = time.perf_counter() - t_start
    pelvis_last = part_transforms(body, motion, np.array([(done - 1) / fps]), fps)[0, 0]
    last = welded.to_garment(x)
    return {"positions": np.stack(kept) if keep_frames else None, "first": np.array(garment.positions, dtype=float),
            "last": last, "vertices": int(garment.num_vertices), "simulated_vertices": welded.num_vertices,
            "frames": int(done), "fps": float(fps), "substeps": int(substeps),
            "seconds_per_frame": seconds / max(1, done - 1), "max_body_penetration_m": penetration,
            "min_body_clearance_m": clearance_min,
            "self_intersections_final": int(sim.contact_report(welded.faces, x, max_listed=0)["intersecting_pairs"]),
            "hem_radius_m": hem_radius(last, garment, pelvis_last[:2, 3]), "self_contact_thickness_m": thickness,
            "body_friction": float(body_friction),
            "cancelled": cancelled, "newton_iterations": iterations, "contact_step": contact_step, "solver": solver,
            "retried_frames": counters["retried_frames"],
            "retries": retries,
            "motion": motion}
