"""The add-on's long jobs as functions of a JobState (bpy-free: the operators gather plain values from bpy and
pass them here; drapelab.ui.jobs runs the returned work on a worker thread or synchronously).

Each job writes its outputs into `out_dir` (the add-on's cache folder: beside the .blend, or in the temp folder
for an unsaved file) atomically, so a cancelled job leaves the previous files as they were.
"""
import os
import re
import time

from .. import diagnose as diagnose_module
from .. import infer
from . import figures

__all__ = ["fit_work", "diagnose_work", "safe_name", "measurement_png"]


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
             effects=None, calibration=None, mesh_level=None, calibrate=True):
    """Work of a fit job: infer.fit (writes OUT_DIR/presets/<fabric>_<model>.json), then the preview drapes of the
    result (overlay and r(theta) PNGs). Returns {"preset": path, "overlay": png, "rtheta": png, "metrics": ...,
    "training": {...}}. Arguments are checked here, before the worker starts, so bad input is an error at once."""
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
                           config=config, calibration=calibration, effects=effects)
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
