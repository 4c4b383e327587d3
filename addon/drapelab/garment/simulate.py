"""Garment simulation: a garment (``mesh.Garment``) with one draw of a fitted material (``material.GarmentMaterial``)
on the moving body (``body.Body`` and a motion), the same cloth model as the Cusick drapes.

The model: per-face stretching and per-bending-edge bending tables sampled from the preset's posterior (oriented by
the garment's uv, i.e. its grain line), the preset's density, gravity; the waistband held by the handle spring to
anchors carried by the pelvis; seam pairs held together (physics/seam.hpp); contact with the body's parts (rigid
surfaces of revolution, IPC barrier of reach ``BODY_REACH_M``, native garment/revolved_body.hpp), so every step is an
IPC step (Newton on the incremental potential, bounded by collision detection: no cloth vertex ever enters the
body). Not yet: self contact (issue 19), friction with the body, cloth edges against the body (vertices only).

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
from .mesh import Garment, self_intersections
from .pc2 import PC2Writer

__all__ = ["drape", "DEFAULT_FPS", "DEFAULT_SUBSTEPS", "BODY_REACH_M", "hem_radius", "top_band_vertices"]

DEFAULT_FPS = 24
DEFAULT_SUBSTEPS = 2          # implicit steps per frame (1/48 s at 24 fps)
BODY_REACH_M = 2e-3           # the body barrier acts within 2 mm of its surface
BARRIER_WEIGHT_SCALE = 1.0    # barrier stiffness in units of each vertex's weight x reach (as disk_contact)
GRAVITY = 9.8                 # m/s^2
HOLD_STIFFNESS = 1e3          # N/m: the waistband's attachment spring (the Cusick handle's value)
SEAM_STIFFNESS = 1e3          # N/m per seam pair
# Newton iterations of each step end when every residual force is below this fraction of the vertex's weight:
# an animation needs far less than a fit's adjoint (1e-6).
FORCE_TOLERANCE = 1e-2
WAIST_BAND_M = 0.03           # a garment without named waist vertices: those within this of its top


class Cancelled(Exception):
    """Raised inside the frame loop when cancel_event is set (drape() returns what was done)."""


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


def build_model(garment, material, body):
    """The native model of the garment with its body contact: (ClothModel, parameters, contact term)."""
    positions, uv, faces = garment.to_native_mesh_arrays()
    model = sim.ClothModel((positions, faces, uv), heterogeneous=True, density=material.density,
                           handle_stiffness=HOLD_STIFFNESS, held_vertices=np.asarray(garment.waist_vertices),
                           seams=np.asarray(garment.seams).reshape(-1, 2), seam_stiffness=SEAM_STIFFNESS)
    params = material.native_parameters(model)
    weights = np.asarray(model.native.masses(params)) * GRAVITY
    kappa = BARRIER_WEIGHT_SCALE * weights * BODY_REACH_M
    parts = [(np.asarray(o, float), np.asarray(s, float), np.asarray(r, float)) for o, s, r in body.profiles]
    contact = model.native.add_body_contact(parts, kappa, BODY_REACH_M)
    return model, params, contact


def drape(garment, material, body=None, motion="static", frames=48, fps=DEFAULT_FPS, substeps=DEFAULT_SUBSTEPS,
          progress=None, cancel_event=None, pc2_path=None, keep_frames=True):
    """Simulates the garment on the body for ``frames`` frames (module doc). Returns a dict: ``positions``
    (frames done, V, 3) float32 when keep_frames, ``first`` and ``last`` (V, 3), and the stats ``vertices``,
    ``frames`` (done), ``seconds_per_frame``, ``max_body_penetration_m`` (deepest cloth vertex inside the body over
    all frames, 0 when none), ``min_body_clearance_m``, ``self_intersections_final`` (intersecting face pairs of the
    last frame), ``hem_radius_m`` (last frame, from the pelvis axis), ``cancelled``, ``newton_iterations``.
    ``pc2_path``: the frames are appended to a PC2 cache as they finish (playback can start during the bake; a
    reader never sees a partial frame). ``progress(frame_done, frames)``; ``cancel_event`` (threading.Event)
    stops between substeps keeping the frames done. A step that fails raises SolverError naming the frame."""
    body = make_body() if body is None else body
    _check(garment, material, body, frames, fps, substeps)
    model, params, contact = build_model(garment, material, body)
    positions, _, _ = garment.to_native_mesh_arrays()
    waist = np.asarray(model.handle_vertices)
    waist_rest = np.asarray(positions)[waist]
    h = 1.0 / (fps * substeps)
    times = np.arange((frames - 1) * substeps + 1) * h
    transforms = part_transforms(body, motion, times, fps)  # (T, parts, 4, 4)
    x = np.asarray(positions, dtype=float).copy()
    v = np.zeros_like(x)
    clearance0 = np.asarray(contact.clearance(x.ravel()))
    if clearance0.min() <= 0:
        worst = int(np.argmin(clearance0))
        raise InputError(f"garment: {int((clearance0 <= 0).sum())} vertices start inside the body (deepest: vertex "
                         f"{worst}, {-clearance0[worst] * 1000:.1f} mm); move or scale the garment")
    kept = [x.astype(np.float32)] if keep_frames else []
    writer = PC2Writer(pc2_path, len(x), start_frame=1, sample_rate=1.0) if pc2_path else None
    penetration, clearance_min = 0.0, float(clearance0.min())
    done, cancelled, iterations = 1, False, 0
    t_start = time.perf_counter()
    try:
        if writer:
            writer.write_frame(x)
        for frame in range(1, frames):
            for j in range(substeps):
                if cancel_event is not None and cancel_event.is_set():
                    raise Cancelled()
                k = (frame - 1) * substeps + j
                start, end = transforms[k, 0], transforms[k + 1, 0]
                a0 = waist_rest @ start[:3, :3].T + start[:3, 3]
                a1 = waist_rest @ end[:3, :3].T + end[:3, 3]
                model.set_handle_anchors(a1)
                # The waistband moves with the pelvis: it starts the step with its anchors' velocity, so the inertial
                # prediction already carries it (a lagging waist would start each step 10^3 weights out of balance
                # and cost Newton iterations); its offset from the anchors (the held waistband's strain) stays.
                v[waist] = (a1 - a0) / h
                contact.set_poses(list(transforms[k]), list(transforms[k + 1]))
                try:
                    x = model.simulate(params, steps=1, time_step=h, record=False, positions0=x, velocities0=v,
                                       contact_force_tolerance=FORCE_TOLERANCE, contact_step="newton")
                except sim.SolverError as e:
                    raise sim.SolverError(f"garment: frame {frame} substep {j}: {e}") from None
                v = model.velocities.copy()
                iterations += int(model.last_result.get("timing", {}).get("newton_iterations", 0))
            c = np.asarray(contact.clearance(x.ravel()))
            clearance_min = min(clearance_min, float(c.min()))
            penetration = max(penetration, float(max(0.0, -c.min())))
            if writer:
                writer.write_frame(x)
            if keep_frames:
                kept.append(x.astype(np.float32))
            done += 1
            if progress:
                progress(done, frames)
    except Cancelled:
        cancelled = True
    finally:
        if writer:
            writer.close()
    seconds = time.perf_counter() - t_start
    pelvis_last = transforms[(done - 1) * substeps, 0]
    first = np.asarray(positions, dtype=float)
    return {"positions": np.stack(kept) if keep_frames else None, "first": first, "last": x,
            "vertices": int(len(x)), "frames": int(done), "fps": float(fps), "substeps": int(substeps),
            "seconds_per_frame": seconds / max(1, done - 1), "max_body_penetration_m": penetration,
            "min_body_clearance_m": clearance_min,
            "self_intersections_final": int(len(self_intersections(x, garment.faces))),
            "hem_radius_m": hem_radius(x, garment, pelvis_last[:2, 3]), "cancelled": cancelled,
            "newton_iterations": iterations, "motion": motion}
