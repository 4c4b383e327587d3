"""The add-on's long jobs as functions of a JobState (bpy-free: the operators gather plain values from bpy and
pass them here; drapelab.ui.jobs runs the returned work on a worker thread or synchronously).

Each job writes its outputs into `out_dir` (the add-on's cache folder: beside the .blend, or in the temp folder
for an unsaved file) atomically, so a cancelled job leaves the previous files as they were.
"""
import os
import re
import threading
import time

import numpy as np

from .. import diagnose as diagnose_module
from .. import infer
from . import figures

__all__ = ["fit_work", "diagnose_work", "simulate_work", "safe_name", "measurement_png"]


def safe_name(text, fallback="fit"):
    """A file-name-safe version of a fabric or preset name."""
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(text or "")).strip("._")
    return name[:60] or fallback


def measurement_png(out_dir, image_path):
    """The measurement picture's file for an image: its name plus a hash of its full path (two folders may hold
    images of the same name)."""
    import hashlib
    key = hashlib.sha1(os.path.abspath(image_path).encode()).hexdigest()[:8]
    return os.path.join(out_dir, "previews", f"measurement_{safe_name(os.path.basename(image_path), 'image')}_{key}.png")


def _fit_config(mesh_level, calibrate):
    config = infer.load_config()
    if mesh_level:
        config["mesh_level"] = int(mesh_level)
        # calibrate on the fit's own mesh when the user chose one (fit.json's calibration mesh is finer)
        config["calibration"] = dict(config.get("calibration") or {}, mesh_level=None)
    if not calibrate:
        config["calibration"] = dict(config.get("calibration") or {}, enabled=False)
    return config


def fit_work(images, density, out_dir, model="bdp", epochs=None, time_budget=None, seed=0, fabric=None,
             effects=None, calibration=None, mesh_level=None, calibrate=True, init=None):
    """Work of a fit job: infer.fit (writes OUT_DIR/presets/<fabric>_<model>.json), then the preview drapes of the
    result (overlay and r(theta) PNGs). Returns {"preset": path, "overlay": png, "rtheta": png, "metrics": ...,
    "training": {...}}. Arguments are checked here, before the worker starts, so bad input is an error at once.
    init: a preset to start from (fit --init), e.g. a diagnosis's refit."""
    if not images:
        raise infer.InputError("images: import at least one Cusick image first")
    infer.check_density(density)
    if epochs is not None and int(epochs) < 1:
        raise infer.InputError(f"epochs: must be >= 1, got {epochs}")
    if time_budget is not None and not float(time_budget) > 0:
        raise infer.InputError(f"time_budget: must be > 0 seconds, got {time_budget}")
    for path in images:
        if not os.path.isfile(path):
            raise infer.InputError(f"images: {path}: no such file")
    if init:
        infer.load_preset(init)  # a missing or broken start is an error before the worker starts
    name = safe_name((fabric or {}).get("name"), "fit")
    preset_path = os.path.join(out_dir, "presets", f"{name}_{model}.json")
    overlay = os.path.join(out_dir, "previews", f"{name}_{model}_overlay.png")
    rtheta = os.path.join(out_dir, "previews", f"{name}_{model}_rtheta.png")
    config = _fit_config(mesh_level, calibrate)
    total_epochs = int(epochs) if epochs is not None else (None if time_budget else int(config["default_epochs"]))

    def work(state):
        os.makedirs(os.path.dirname(preset_path), exist_ok=True)
        os.makedirs(os.path.dirname(overlay), exist_ok=True)
        t0 = time.monotonic()

        def fraction():
            if time_budget:
                return 0.95 * min(1.0, (time.monotonic() - t0) / float(time_budget))
            return None

        def progress(e):
            f = fraction() if total_epochs is None else 0.9 * e["epoch"] / total_epochs
            state.update(f, f"epoch {e['epoch']}" + (f"/{total_epochs}" if total_epochs else "") +
                         f": loss {e['loss']:.4f}, IoU {e['iou']:.3f}, MSE {e['mse']:.4f}",
                         epoch=e["epoch"], loss=e["loss"], iou=e["iou"], mse=e["mse"], data=e["data"], kl=e["kl"])
            state.record(e["loss"])

        def calibration_progress(c):
            state.update(fraction(), f"drape calibration {c['evaluation']}: DC {c['dc']:.3f} (observed "
                                     f"{c['dc_observed']:.3f}), nodes {c['nodes']:.1f} (observed {c['nodes_observed']:.1f})")

        def plan_progress(p):
            state.update(None, f"time budget {p['total_s']:g} s: epochs {p['epochs_s']:.0f} s, calibration "
                               f"{p['calibration_s']:.0f} s")

        state.update(0.0, f"fitting {model} to {len(images)} image(s): set-up and scale search")
        preset = infer.fit(list(images), float(density), model=model, epochs=epochs, time_budget=time_budget,
                           seed=int(seed), out=preset_path, progress=progress, cancel_event=state.cancel,
                           fabric=fabric, calibration_progress=calibration_progress, plan_progress=plan_progress,
                           config=config, calibration=calibration, effects=effects, init=init or None)
        result = {"preset": preset_path, "training": {k: preset["training"].get(k) for k in ("epochs", "seconds",
                                                                                             "final_loss")}}
        state.update(0.96, "draping the fitted preset for the overlay")
        try:
            result["metrics"] = figures.fit_result(preset, images[0], overlay, rtheta, seed=int(seed),
                                                   cancel_event=state.cancel)
            result["overlay"], result["rtheta"] = overlay, rtheta
        except infer.Cancelled:  # the preset is written and valid: keep it, without previews
            result["metrics"] = None
        return result

    return work


def diagnose_work(preset, images, out_dir, time_budget=None, samples=None, seed=0, candidates=None,
                  history=None, report_dir=None):
    """Work of a diagnose job: diagnose.diagnose writing its report into `report_dir` (default
    OUT_DIR/diagnosis), then the error-history
    chart (the given `history` entries of earlier model versions, then the diagnosis's) as
    OUT_DIR/previews/history.png. Returns {"report": dir, "diagnosis": dict, "history_png": path}."""
    if not images:
        raise infer.InputError("images: import at least one Cusick image first")
    if not preset:
        raise infer.InputError("preset: fit or load a preset first")
    p = infer.load_preset(preset)  # an unreadable preset is an error before the worker starts
    if time_budget is not None and not float(time_budget) > 0:
        raise infer.InputError(f"time_budget: must be > 0 seconds, got {time_budget}")
    if samples is not None and int(samples) < diagnose_module.MIN_SAMPLES:
        raise infer.InputError(f"samples: at least {diagnose_module.MIN_SAMPLES}, got {samples}")
    report = report_dir or os.path.join(out_dir, "diagnosis")
    chart = os.path.join(out_dir, "previews", "history.png")
    k = int(samples or diagnose_module.DEFAULT_SAMPLES)

    def work(state):
        os.makedirs(os.path.dirname(chart), exist_ok=True)
        t0 = time.monotonic()

        def progress(e):
            f = None
            if time_budget:
                f = min(0.95, (time.monotonic() - t0) / float(time_budget))
            elif e.get("stage") == "draws" and "done" in e:
                f = 0.5 * e["done"] / max(1, k)
            state.update(f, e.get("message", ""))

        result = diagnose_module.diagnose(p, list(images), candidates=candidates, time_budget=time_budget,
                                          samples=k, seed=int(seed), out_dir=report, progress=progress,
                                          cancel_event=state.cancel)
        entries = list(history or []) + [e for e in result.get("history", []) if e not in (history or [])]
        out = {"report": report, "diagnosis": result, "history_png": None}
        if any(e.get("mse") is not None for e in entries):
            figures.history_chart(entries, chart)
            out["history_png"] = chart
        if result.get("cancelled"):
            state.update(None, "diagnosis cancelled: the report holds what was done")
        return out

    return work


def _read_pc2_frame(f, frame, num_points):
    """Frame `frame` of an open PC2 file, (num_points, 3) float64 (the frame must be complete: its writer counted
    it in the header before the caller asked)."""
    from ..garment.pc2 import HEADER_SIZE
    size = num_points * 12
    f.seek(HEADER_SIZE + frame * size)
    data = f.read(size)
    if len(data) != size:
        raise OSError(f"{f.name}: frame {frame} is not complete in the simulator's cache")
    return np.frombuffer(data, dtype="<f4").reshape(num_points, 3).astype(np.float64)


def simulate_work(garment, material, body, source, rest_positions, world_to_local, path, frames, motion="static",
                  time_limit=None, collider_path=None, collider_world_to_local=None, body_friction=0.3):
    """Work of a garment bake (drapelab.simulate_garment): garment.simulate.drape of `garment` with
    `material` on `body` for `frames` frames, written to the PC2 cache `path` in the Blender mesh's vertex order
    (`source[i]`: the Blender vertex of garment vertex i; `rest_positions` (V, 3) world: the Blender vertices,
    which split seam copies share) and its local coordinates (`world_to_local` 4x4), frame by frame as the
    simulator finishes each, so that playback can start during the bake.

    The cache at `path` is replaced only once the first simulated frame (frame 1; frame 0 is the rest placement)
    is complete (garment.pc2.PC2Writer: an existing cache stays playable until then, and a reader never sees a
    partial frame); a bake cancelled or failing before that leaves the previous cache as it was. Cancel
    (state.cancel, checked between substeps) and `time_limit` (seconds from the start of the work) stop the bake
    keeping the frames done. A moving `motion` also writes the body's frames to `collider_path` (the collider's
    vertex order is the Body's; `collider_world_to_local` its local coordinates) so the collider moves with it.
    `body_friction`: Coulomb coefficient between the garment and the body (drape's).
    Returns {"frames": frames simulated (with frame 0), "frames_written": frames in the cache, "cancelled",
    "stopped_by_time_limit", "seconds_per_frame", "max_body_penetration_m", "hem_radius_m", "body_friction", "path",
    "collider_path"}. The
    arguments are plain values and numpy arrays (picklable: the work can be rebuilt in a worker process)."""
    from ..garment.pc2 import PC2Writer
    if isinstance(frames, bool) or int(frames) != frames or frames < 2:
        raise infer.InputError(f"frames: at least 2, got {frames}")
    if time_limit is not None and not float(time_limit) > 0:
        raise infer.InputError(f"time_limit: must be > 0 seconds, got {time_limit}")
    folder = os.path.dirname(os.path.abspath(path))
    rest = np.asarray(rest_positions, dtype=np.float64)
    source = np.asarray(source, dtype=np.int64)
    m = np.asarray(world_to_local, dtype=np.float64)
    moving = motion != "static"
    if moving and collider_path is None:
        raise infer.InputError(f"motion {motion}: the collider's cache path is needed")

    def local(x, matrix):
        return x @ matrix[:3, :3].T + matrix[:3, 3]

    def work(state):
        from ..garment.simulate import drape
        os.makedirs(folder, exist_ok=True)
        base = os.path.splitext(os.path.abspath(path))[0]
        side = base + ".simulator_order.pc2"  # the simulator's own frames (its vertex order), removed at the end
        stopped = []
        timer = None
        if time_limit:
            def stop():
                stopped.append(True)
                state.cancel.set()
            timer = threading.Timer(float(time_limit), stop)
            timer.daemon = True
            timer.start()
        writer = collider_writer = collider_frames = None
        handle = []

        def copy_frames(done):
            """Copies the simulator's frames up to `done` (complete in the side cache) into the Blender cache (and
            the body's frames into the collider's, in step)."""
            if done < 2:
                return  # nothing simulated yet: the previous cache stays
            if not handle:
                handle.append(open(side, "rb"))
            while writer.frames_written < done:
                k = writer.frames_written
                x = _read_pc2_frame(handle[0], k, garment.num_vertices)
                out = rest.copy()
                out[source] = x
                if collider_writer is not None:
                    collider_writer.write_frame(collider_frames[k])
                writer.write_frame(local(out, m))

        def progress(done, total):
            copy_frames(done)
            state.update(0.99 * done / total, f"frame {done}/{total}", frames_done=done,
                         frames_written=writer.frames_written)

        try:
            writer = PC2Writer(path, len(rest), start_frame=1, sample_rate=1.0)
            if moving:
                from ..garment.body import body_frames
                collider_frames = local(body_frames(body, motion, int(frames)),
                                        np.asarray(collider_world_to_local, dtype=np.float64))
                collider_writer = PC2Writer(collider_path, len(body.positions), start_frame=1, sample_rate=1.0)
            state.update(0.0, f"baking {frames} frames ({motion})")
            r = drape(garment, material, body=body, motion=motion, frames=int(frames), cancel_event=state.cancel,
                      progress=progress, pc2_path=side, keep_frames=False, body_friction=body_friction)
            copy_frames(r["frames"])
        finally:
            if timer is not None:
                timer.cancel()
            for f in handle:
                f.close()
            for w in (writer, collider_writer):
                if w is not None:
                    w.close()
            try:
                os.unlink(side)
            except OSError:
                pass
        return {"frames": r["frames"], "frames_written": writer.frames_written, "cancelled": r["cancelled"],
                "stopped_by_time_limit": bool(stopped), "seconds_per_frame": r["seconds_per_frame"],
                "max_body_penetration_m": r["max_body_penetration_m"], "hem_radius_m": r["hem_radius_m"],
                "body_friction": r["body_friction"], "path": path,
                "collider_path": collider_path if moving else None, "motion": motion}

    return work
