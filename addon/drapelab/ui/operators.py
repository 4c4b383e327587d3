"""drapelab.* operators: the add-on's actions and the headless API.

Long operators (fit, diagnose, simulate_garment) follow one pattern (_JobOperator): execute() runs the job
synchronously (scripts, `blender --background`: errors through self.report and {'CANCELLED'}); invoke() from the
UI starts it in a worker process (a drapelab.ui.jobs.Task: Blender's Python is not thread safe) and polls it with a
window-manager timer in a modal operator that copies its state into the panel; Esc or drapelab.cancel sets
the job's cancel flag, which the facade checks between simulation steps.
"""
import json
import os

import numpy as np

import bpy
from bpy.props import CollectionProperty, EnumProperty, FloatProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper

from .. import infer, measure
from .._native import InputError, SolverError
from . import figures, jobs, previews, tasks
from . import presets as preset_files
from .properties import MOTIONS, cache_dir, user_presets_dir

POLL_SECONDS = 0.2   # timer interval of the modal poll (cancel latency is the worker's, not this)
ERRORS = (InputError, SolverError, ValueError, OSError, RuntimeError)
NOT_AVAILABLE_SIMULATION = "garment simulation is not available in this build yet"
NOT_AVAILABLE_CLOTH_EXPORT = "Export to Blender Cloth is not available in this build yet"


def settings(context):
    return context.scene.drapelab


def _redraw(context):
    wm = context.window_manager
    for window in wm.windows:
        for area in window.screen.areas:
            if area.type == 'VIEW_3D':
                area.tag_redraw()


class _JobOperator:
    """Mixin: subclasses define kind, make_work(context) -> work (raising on bad input, before anything runs) and
    finish(context, result) (main thread: the result into the scene)."""
    kind = ""
    _timer = None
    _job = None

    def _start(self, context, synchronous):
        try:
            work = self.make_work(context)
            self._job = jobs.start(self.kind, work, synchronous=synchronous)
        except ERRORS as e:
            self.report({'ERROR'}, f"{self.kind}: {e}")
            return {'CANCELLED'}
        return None

    def _conclude(self, context, state):
        if state.status == jobs.DONE:
            try:
                message = self.finish(context, state.result)
            except ERRORS as e:
                self.report({'ERROR'}, f"{self.kind}: {e}")
                return {'CANCELLED'}
            self.report({'INFO'}, message or f"{self.kind} finished")
            return {'FINISHED'}
        if state.status == jobs.CANCELLED:
            self.report({'WARNING'}, f"{self.kind} cancelled; earlier results kept")
            return {'CANCELLED'}
        self.report({'ERROR'}, f"{self.kind}: {state.error}")
        return {'CANCELLED'}

    def execute(self, context):
        failed = self._start(context, synchronous=True)
        if failed:
            return failed
        return self._conclude(context, self._job.state)

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        failed = self._start(context, synchronous=False)
        if failed:
            return failed
        wm = context.window_manager
        self._timer = wm.event_timer_add(POLL_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        return {'RUNNING_MODAL'}

    def modal(self, context, event):
        if event.type == 'ESC' and event.value == 'PRESS':
            self._job.cancel()
            return {'RUNNING_MODAL'}
        if event.type == 'TIMER':
            _redraw(context)
            self.poll_job(context)
            if self._job.state.done and not self._job.alive:
                context.window_manager.event_timer_remove(self._timer)
                self._timer = None
                return self._conclude(context, self._job.state)
        return {'PASS_THROUGH'}

    def poll_job(self, context):
        """Main thread, every timer tick while the job runs: subclasses show partial results (default: nothing)."""

    def cancel(self, context):  # Blender closes the window or file while the operator is modal
        if self._job is not None:
            self._job.cancel()
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None


# ---------------------------------------------------------------- measurement
def _apply_manifest(s, path):
    """Fills fabric name, density and thickness when the image is one of the bundled or dataset images."""
    from .. import paths
    for folder in (os.path.join(paths.assets_dir(), "cusick"), paths.cusick_dataset_dir()):
        manifest = os.path.join(folder, "manifest.csv") if folder else None
        if not manifest or not os.path.isfile(manifest):
            continue
        for row in measure.load_manifest(manifest):
            if os.path.realpath(row["silhouette"]) == os.path.realpath(path):
                s.fabric_name, s.density = row["name"], row["density_kg_m2"]
                s.thickness_mm = row["thickness_mm"] or s.thickness_mm
                return True
    return False


class DRAPELAB_OT_import_images(bpy.types.Operator, ImportHelper):
    """Import one or more Cusick drape images (the silhouette, centre and scale are detected and shown)"""
    bl_idname = "drapelab.import_images"
    bl_label = "Import Cusick Images"
    bl_options = {'REGISTER', 'UNDO'}

    filter_glob: StringProperty(default="*.jpg;*.jpeg;*.png;*.tif;*.tiff;*.bmp;*.exr", options={'HIDDEN'})
    files: CollectionProperty(type=bpy.types.OperatorFileListElement, options={'HIDDEN', 'SKIP_SAVE'})
    directory: StringProperty(subtype='DIR_PATH', options={'HIDDEN', 'SKIP_SAVE'})

    def selected_paths(self):
        names = [f.name for f in self.files if f.name]
        if names and self.directory:
            return [os.path.join(self.directory, n) for n in names]
        return [self.filepath] if self.filepath else []

    def execute(self, context):
        s = settings(context)
        paths_in = [bpy.path.abspath(p) for p in self.selected_paths()]
        if not paths_in:
            self.report({'ERROR'}, "import_images: no image selected (filepath, or directory and files)")
            return {'CANCELLED'}
        cal = s.calibration()
        measured = []
        for p in paths_in:  # every image is checked before any is added
            try:
                png = tasks.measurement_png(cache_dir(), p)
                os.makedirs(os.path.dirname(png), exist_ok=True)
                m = figures.measurement_preview(p, png, cal)
            except ERRORS as e:
                self.report({'ERROR'}, f"import_images: {e}" if p in str(e) else f"import_images: {p}: {e}")
                return {'CANCELLED'}
            measured.append((p, m, png))
        existing = {bpy.path.abspath(i.filepath) for i in s.images}
        for p, m, png in measured:
            if p in existing:
                item = next(i for i in s.images if bpy.path.abspath(i.filepath) == p)
            else:
                item = s.images.add()
                item.filepath = p
            item.drape_coefficient, item.node_count = m["drape_coefficient"], m["node_count"]
        s.active_image = len(s.images) - 1
        s.measurement_image = previews.load(measured[-1][2], "measurement")
        if _apply_manifest(s, measured[0][0]):
            self.report({'INFO'}, f"{s.fabric_name}: density and thickness from the dataset manifest")
        self.report({'INFO'}, f"imported {len(measured)} image(s): DC "
                              + ", ".join(f"{m['drape_coefficient']:.3f}" for _, m, _ in measured))
        return {'FINISHED'}


class DRAPELAB_OT_calibrate_from_disk(bpy.types.Operator, ImportHelper):
    """Set the scale and centre from a photo of the undraped specimen (a flat disk of known diameter)"""
    bl_idname = "drapelab.calibrate_from_disk"
    bl_label = "Calibrate from Flat Disk"
    bl_options = {'REGISTER', 'UNDO'}

    filter_glob: StringProperty(default="*.jpg;*.jpeg;*.png;*.tif;*.tiff;*.bmp;*.exr", options={'HIDDEN'})
    diameter_mm: FloatProperty(name="Specimen diameter (mm)", default=300.0, min=1.0,
                               description="diameter of the flat specimen (the Cusick test's is 300 mm)")

    def execute(self, context):
        s = settings(context)
        path = bpy.path.abspath(self.filepath)
        try:
            cal = measure.calibrate_from_disk(path, diameter_m=self.diameter_mm / 1000.0)
        except ERRORS as e:
            self.report({'ERROR'}, f"calibrate_from_disk: {e}")
            return {'CANCELLED'}
        s.px_per_m, s.centre_x, s.centre_y, s.centre_auto = cal.px_per_m, cal.cx, cal.cy, False
        self.report({'INFO'}, f"calibration from {os.path.basename(path)}: {cal.px_per_m:.1f} px/m, centre "
                              f"({cal.cx:.1f}, {cal.cy:.1f}) px")
        return {'FINISHED'}


class DRAPELAB_OT_remove_image(bpy.types.Operator):
    """Remove the selected image from the measurements"""
    bl_idname = "drapelab.remove_image"
    bl_label = "Remove Image"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        s = settings(context)
        if not 0 <= s.active_image < len(s.images):
            self.report({'ERROR'}, "remove_image: no image selected")
            return {'CANCELLED'}
        s.images.remove(s.active_image)
        s.active_image = max(0, min(s.active_image, len(s.images) - 1))
        return {'FINISHED'}


# ---------------------------------------------------------------- fit
HISTORY_MAX = 20  # model versions kept in the scene's error history


def _append_history(s, entry, chart=True):
    """Adds a model version's errors to the scene's history and redraws the history chart."""
    h = s.history()
    h.append(entry)
    s.history_json = json.dumps(h[-HISTORY_MAX:])
    if chart:
        png = os.path.join(cache_dir(), "previews", "history.png")
        os.makedirs(os.path.dirname(png), exist_ok=True)
        figures.history_chart(h[-HISTORY_MAX:], png)
        s.history_image = previews.load(png, "history")


class DRAPELAB_OT_fit(_JobOperator, bpy.types.Operator):
    """Fit the fabric's stiffness posterior to the imported images (runs in the background; Esc cancels)"""
    bl_idname = "drapelab.fit"
    bl_label = "Fit"
    bl_options = {'REGISTER', 'UNDO'}
    kind = "fit"

    time_budget: FloatProperty(name="Time budget (s)", default=0.0, min=0.0,
                               description="seconds for the whole fit; 0: the panel's setting")
    epochs: IntProperty(name="Epochs", default=0, min=0, description="epochs to run; 0: the panel's setting")

    def make_work(self, context):
        s = settings(context)
        if self.epochs and self.time_budget:
            raise InputError("give epochs or time_budget, not both")
        epochs, budget = (self.epochs or None), (self.time_budget or None)
        if epochs is None and budget is None:
            epochs, budget = (s.epochs, None) if s.budget_mode == 'EPOCHS' else (None, s.time_budget)
        fabric = {"name": s.fabric_name} if s.fabric_name else {}
        if s.thickness_mm > 0:
            fabric["thickness_mm"] = s.thickness_mm
        return jobs.Task(tasks.fit_work, s.image_paths(), round(s.density, 6), cache_dir(), model=s.model.lower(), epochs=epochs,
                              time_budget=budget, seed=s.seed, fabric=fabric or None,
                              effects=s.enabled_effects() or None, calibration=s.calibration(),
                              mesh_level=s.mesh_level or None, calibrate=s.calibrate,
                              init=bpy.path.abspath(s.init_path) if s.init_path else None)

    def finish(self, context, result):
        s = settings(context)
        s.preset_path = result["preset"]
        s.init_path = ""  # the start was used: the next fit starts afresh unless Add sets it again
        s.metrics_json = json.dumps({"metrics": result.get("metrics"), "training": result.get("training")})
        if result.get("overlay"):
            s.overlay_image = previews.load(result["overlay"], "overlay")
            s.rtheta_image = previews.load(result["rtheta"], "rtheta")
        m = result.get("metrics") or {}
        label = f"{s.fabric_name or 'fit'} {s.model.lower()}" + (
            " + " + ", ".join(s.enabled_effects()) if s.enabled_effects() else "")
        if m:
            _append_history(s, {"model": label, "mse": m["mse"], "iou": m["iou"], "source": "fit preview",
                                "dc_error": abs(m["drape_coefficient"]["predicted"] - m["drape_coefficient"]["observed"])})
        t = result.get("training") or {}
        return (f"fit: wrote {result['preset']} ({t.get('epochs')} epochs)" +
                (f", IoU {m['iou']:.3f}, MSE {m['mse']:.4f}" if m else ""))


class DRAPELAB_OT_cancel(bpy.types.Operator):
    """Cancel the running drapelab job (takes effect at the next simulation step)"""
    bl_idname = "drapelab.cancel"
    bl_label = "Cancel"

    def execute(self, context):
        job = jobs.current()
        if job is None:
            self.report({'WARNING'}, "cancel: no drapelab job is running")
            return {'CANCELLED'}
        job.cancel()
        self.report({'INFO'}, f"cancelling the {job.state.kind} job")
        return {'FINISHED'}


# ---------------------------------------------------------------- diagnose
class DRAPELAB_OT_diagnose(_JobOperator, bpy.types.Operator):
    """Diagnose the current preset against the imported images: where it fails, which effect is missing"""
    bl_idname = "drapelab.diagnose"
    bl_label = "Diagnose"
    bl_options = {'REGISTER', 'UNDO'}
    kind = "diagnose"

    time_budget: FloatProperty(name="Time budget (s)", default=0.0, min=0.0, description="0: the panel's setting")
    samples: IntProperty(name="Draws", default=0, min=0, description="posterior draws; 0: the panel's setting")
    report_dir: StringProperty(name="Report folder", default="", subtype='DIR_PATH',
                               description="where the report goes (index.html, figures, diagnosis.json, refit "
                                           "presets); default: diagnosis/ in the add-on's cache folder")

    def make_work(self, context):
        s = settings(context)
        samples = self.samples or s.diagnose_samples
        if samples < 3:
            raise InputError(f"samples: at least 3 posterior draws, got {samples}")
        return jobs.Task(tasks.diagnose_work, bpy.path.abspath(s.preset_path) if s.preset_path else "", s.image_paths(),
                                   cache_dir(), time_budget=self.time_budget or s.diagnose_budget, samples=samples,
                                   seed=s.seed, history=s.history(),
                                   report_dir=bpy.path.abspath(self.report_dir) if self.report_dir else None)

    def finish(self, context, result):
        s = settings(context)
        s.diagnosis_path = os.path.join(result["report"], "diagnosis.json")
        if result.get("history_png"):
            s.history_image = previews.load(result["history_png"], "history")
        d = result["diagnosis"]
        base = d.get("base")
        if base:  # the chart the job drew already holds this diagnosis's models
            _append_history(s, {"model": f"{s.fabric_name or 'preset'} (diagnose base)", "mse": base["mse"],
                                "iou": base.get("iou"), "dc_error": base.get("dc_error"), "source": "diagnose"},
                            chart=False)
        return d.get("verdict") or "diagnosis written"


def diagnosis(s):
    """The last diagnosis (dict) or None; cached by file modification time (panels draw often)."""
    path = bpy.path.abspath(s.diagnosis_path) if s.diagnosis_path else ""
    try:
        mtime = os.path.getmtime(path)
    except OSError:
        return None
    if _diagnosis_cache.get("key") != (path, mtime):
        try:
            with open(path) as f:
                _diagnosis_cache.update(key=(path, mtime), value=json.load(f))
        except (OSError, ValueError):
            return None
    return _diagnosis_cache.get("value")


_diagnosis_cache = {}


class DRAPELAB_OT_add_effect(bpy.types.Operator):
    """Switch this effect on for the next fit (Refit fits its strength with the material, starting from the
    diagnosis's refit when there is one)"""
    bl_idname = "drapelab.add_effect"
    bl_label = "Add Effect"
    bl_options = {'REGISTER', 'UNDO'}

    effect: StringProperty(name="Effect")
    refit: StringProperty(name="Refit preset", subtype='FILE_PATH',
                          description="the diagnosis's refit with this effect: the next fit starts from it")

    def execute(self, context):
        s = settings(context)
        from .. import sim
        names = [e["name"] for e in sim.effects()]
        if self.effect not in names:
            self.report({'ERROR'}, f"add_effect: unknown effect {self.effect!r} (registered: {', '.join(names)})")
            return {'CANCELLED'}
        refit = bpy.path.abspath(self.refit) if self.refit else ""
        if refit and not os.path.isfile(refit):
            self.report({'ERROR'}, f"add_effect: refit: {refit}: no such file")
            return {'CANCELLED'}
        setattr(s.effects, self.effect, True)
        if refit:
            s.init_path = refit
            self.report({'INFO'}, f"{self.effect} will be fitted by the next fit (Refit), starting from the "
                                  f"diagnosis's refit {os.path.basename(refit)}")
        else:
            self.report({'INFO'}, f"{self.effect} will be fitted by the next fit (Refit)")
        return {'FINISHED'}


# ---------------------------------------------------------------- presets
class DRAPELAB_OT_save_preset(bpy.types.Operator, ExportHelper):
    """Save the current preset: to a JSON file (filepath), or as one of your presets (name)"""
    bl_idname = "drapelab.save_preset"
    bl_label = "Save Preset"
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={'HIDDEN'})
    name: StringProperty(name="Name", default="", description="save as your preset of this name (no filepath)")

    def invoke(self, context, event):
        if self.name:
            return self.execute(context)
        return ExportHelper.invoke(self, context, event)

    def execute(self, context):
        s = settings(context)
        if not s.preset_path:
            self.report({'ERROR'}, "save_preset: no current preset (fit or load one first)")
            return {'CANCELLED'}
        try:
            source = bpy.path.abspath(s.preset_path)
            if self.filepath:
                path = preset_files.write_to(source, bpy.path.abspath(self.filepath))
            elif self.name:
                path = preset_files.save(source, user_presets_dir(), self.name)
            else:
                raise InputError("save_preset: give filepath or name")
        except ERRORS as e:
            self.report({'ERROR'}, f"save_preset: {e}")
            return {'CANCELLED'}
        self.report({'INFO'}, f"saved preset {path}")
        return {'FINISHED'}


class DRAPELAB_OT_load_preset(bpy.types.Operator, ImportHelper):
    """Load a preset JSON file (validated) as the current preset"""
    bl_idname = "drapelab.load_preset"
    bl_label = "Load Preset"
    bl_options = {'REGISTER', 'UNDO'}
    filter_glob: StringProperty(default="*.json", options={'HIDDEN'})

    def execute(self, context):
        s = settings(context)
        try:
            path = preset_files.resolve(bpy.path.abspath(self.filepath) if self.filepath else "", user_presets_dir())
            p = infer.load_preset(path)
        except ERRORS as e:
            self.report({'ERROR'}, f"load_preset: {e}")
            return {'CANCELLED'}
        s.preset_path = path
        s.fabric_name = (p.get("fabric") or {}).get("name") or s.fabric_name
        s.density = p["density_kg_m2"]
        s.model = p["model"].upper()
        s.metrics_json = json.dumps({"metrics": None, "training": {k: (p.get("training") or {}).get(k)
                                                                   for k in ("epochs", "seconds", "final_loss")},
                                     "preset_metrics": p.get("metrics")})
        s.overlay_image = s.rtheta_image = ""
        self.report({'INFO'}, f"loaded preset {path}: {preset_files.summary(path)}")
        return {'FINISHED'}


class DRAPELAB_OT_load_preset_choice(bpy.types.Operator):
    """Load the preset chosen in the menu"""
    bl_idname = "drapelab.load_preset_choice"
    bl_label = "Load"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        choice = settings(context).preset_choice
        if not choice or choice == "NONE":
            self.report({'ERROR'}, "load: no preset chosen")
            return {'CANCELLED'}
        return bpy.ops.drapelab.load_preset(filepath=choice)


class DRAPELAB_OT_delete_preset(bpy.types.Operator):
    """Delete the chosen preset (yours only; shipped presets stay)"""
    bl_idname = "drapelab.delete_preset"
    bl_label = "Delete Preset"
    filepath: StringProperty(name="Preset file", default="", description="default: the menu's choice")

    def invoke(self, context, event):
        return context.window_manager.invoke_confirm(self, event)

    def execute(self, context):
        path = self.filepath or settings(context).preset_choice
        try:
            preset_files.delete(path, user_presets_dir())
        except ERRORS as e:
            self.report({'ERROR'}, f"delete_preset: {e}")
            return {'CANCELLED'}
        self.report({'INFO'}, f"deleted {path}")
        return {'FINISHED'}


class DRAPELAB_OT_import_preset(bpy.types.Operator, ImportHelper):
    """Import a preset JSON file into your presets"""
    bl_idname = "drapelab.import_preset"
    bl_label = "Import Preset"
    filter_glob: StringProperty(default="*.json", options={'HIDDEN'})

    def execute(self, context):
        try:
            path = preset_files.import_file(bpy.path.abspath(self.filepath), user_presets_dir())
        except ERRORS as e:
            self.report({'ERROR'}, f"import_preset: {e}")
            return {'CANCELLED'}
        self.report({'INFO'}, f"imported as {path}")
        return {'FINISHED'}


class DRAPELAB_OT_show_image(bpy.types.Operator):
    """Show this picture in an Image Editor of the screen"""
    bl_idname = "drapelab.show_image"
    bl_label = "Show in Image Editor"
    image: StringProperty(name="Image")

    def execute(self, context):
        if bpy.data.images.get(self.image) is None:
            self.report({'ERROR'}, f"show_image: no image {self.image!r}")
            return {'CANCELLED'}
        if previews.show_in_image_editor(context, self.image) is None:
            self.report({'WARNING'}, "show_image: no window to show it in (background mode)")
            return {'CANCELLED'}
        return {'FINISHED'}


# ---------------------------------------------------------------- garment
def _cloth_export_module():
    try:
        from . import cloth_export
    except ImportError:
        return None
    return cloth_export if hasattr(cloth_export, "apply_cloth_settings") else None


def _simulate_function():
    try:
        from ..garment import simulate
    except ImportError:
        return None
    return getattr(simulate, "drape", None)


def _preset_argument(context, preset):
    s = settings(context)
    if preset:
        return preset_files.resolve(preset, user_presets_dir())
    if s.preset_path:
        return bpy.path.abspath(s.preset_path)
    raise InputError("no preset: give preset (a name or path), or fit or load one first")


def simulation_job(context, obj, collider, frame_start, frame_end, preset="", seed=0, time_limit=0.0,
                   motion="static", body_friction=0.3):
    """What simulate_garment runs, checked and gathered from bpy on the main thread: (work, target). `work` is a
    jobs.Task of drapelab.ui.tasks.simulate_work (bpy-free, picklable: jobs.start runs it in a worker process,
    run_sync on this thread); `target` is what finish_simulation and attach_while_baking need (plain names and
    paths). Bad input raises before anything is written."""
    if frame_end <= frame_start:
        raise InputError(f"frame_end ({frame_end}) must be after frame_start ({frame_start})")
    if motion not in [m[0] for m in MOTIONS]:
        raise InputError(f"motion {motion!r}: expected one of {', '.join(m[0] for m in MOTIONS)}")
    if _simulate_function() is None:
        raise InputError(NOT_AVAILABLE_SIMULATION)
    s = settings(context)
    if obj is None or obj.type != 'MESH':
        raise InputError("pick the garment mesh (Garment field or the active object)")
    from .garment_ops import garment_for_simulation
    garment, source, body = garment_for_simulation(obj, collider)
    if not preset and not s.preset_path and obj.get("drapelab_preset_path"):
        p = infer.load_preset(obj["drapelab_preset_path"])  # the preset Apply Material used
    else:
        p = infer.load_preset(_preset_argument(context, preset))
    from ..garment import material
    mat = material.sample_garment_material(p, garment, seed=seed, samples=1)[0]
    os.makedirs(cache_dir(), exist_ok=True)
    path = os.path.join(cache_dir(), f"{bpy.path.clean_name(obj.name)}.pc2")
    collider_path = os.path.join(cache_dir(), f"{bpy.path.clean_name(collider.name)}_{motion}.pc2")
    if os.path.abspath(collider_path) == os.path.abspath(path):
        raise InputError(f"the garment and the collider must be two objects ({obj.name})")
    work = jobs.Task(tasks.simulate_work, garment, mat, body, source, garment.blender_positions,
                     np.linalg.inv(np.array(obj.matrix_world)), path, frame_end - frame_start + 1, motion=motion,
                     time_limit=time_limit or None, collider_path=collider_path,
                     collider_world_to_local=np.linalg.inv(np.array(collider.matrix_world)),
                     body_friction=body_friction)
    target = {"object": obj.name, "path": path, "frame_start": frame_start, "collider": collider.name,
              "collider_path": collider_path, "motion": motion, "attached": False}
    return work, target


def attach_while_baking(target, state):
    """Main thread, during a bake: once the new cache holds a frame, puts it (and the moving collider's) on the
    objects, so the timeline plays the frames done while the rest bake (the Mesh Cache modifier rereads the
    file's header as it grows). Returns True once attached."""
    if target["attached"] or not state.metrics.get("frames_written"):
        return target["attached"]
    _attach(target)
    target["attached"] = True
    return True


def _attach(target):
    from .garment_ops import attach_mesh_cache
    obj, collider = bpy.data.objects.get(target["object"]), bpy.data.objects.get(target["collider"])
    if obj is None:
        raise InputError(f"{target['object']}: the garment object was removed during the bake")
    attach_mesh_cache(obj, target["path"], frame_start=target["frame_start"])
    if collider is not None:
        if target["motion"] != "static":
            attach_mesh_cache(collider, target["collider_path"], frame_start=target["frame_start"])
        elif collider.modifiers.get("drapelab cache") is not None:  # a static bake: the collider stands still
            collider.modifiers.remove(collider.modifiers["drapelab cache"])


def finish_simulation(target, result):
    """Main thread, after the bake: the caches onto the objects (nothing changes when no frame was simulated: the
    previous cache, if any, stays on the object). Returns the report."""
    if result["frames_written"] == 0:
        return ("simulate: stopped before the first frame was simulated; nothing changed (the previous cache, if "
                "any, is kept)")
    _attach(target)
    target["attached"] = True
    how = ""
    if result["stopped_by_time_limit"]:
        how = " - stopped at the time limit, frames done kept"
    elif result["cancelled"]:
        how = " - cancelled, frames done kept"
    return (f"simulate: {result['frames_written']} frames ({result['motion']}) into "
            f"{os.path.basename(result['path'])} ({result['seconds_per_frame']:.2f} s/frame, body penetration "
            f"{result['max_body_penetration_m'] * 1000:.2f} mm, hem radius {result['hem_radius_m'] * 1000:.0f} mm)"
            f"{how}")


class DRAPELAB_OT_simulate_garment(_JobOperator, bpy.types.Operator):
    """Bake the garment's drape on the collider into a PC2 cache played by a Mesh Cache modifier, frame by frame
    (Esc cancels, keeping the frames done)"""
    bl_idname = "drapelab.simulate_garment"
    bl_label = "Simulate"
    bl_options = {'REGISTER', 'UNDO'}
    kind = "simulate"

    frame_start: IntProperty(name="Start", default=1, min=0)
    frame_end: IntProperty(name="End", default=60, min=1)
    collider: StringProperty(name="Collider", default="", description="collider object name (default: the panel's)")
    preset: StringProperty(name="Preset", default="", description="preset name or path (default: the current)")
    seed: IntProperty(name="Seed", default=0, min=0, description="the material draw (as Apply Material's)")
    motion: EnumProperty(name="Motion", items=MOTIONS, default="static",
                         description="the dress form's motion (a moving collider gets its own Mesh Cache)")
    time_limit: FloatProperty(name="Time limit (s)", default=0.0, min=0.0,
                              description="stop the bake after this many seconds, keeping the frames done (0: none)")
    body_friction: FloatProperty(name="Body friction", default=0.3, min=0.0, max=2.0,
                                 description="Coulomb friction coefficient between the garment and the dress form")

    def make_work(self, context):
        if self.collider and self.collider not in bpy.data.objects:
            raise InputError(f"no object named {self.collider!r}")
        s = settings(context)
        collider = bpy.data.objects[self.collider] if self.collider else s.collider
        work, self._target = simulation_job(context, s.garment or context.active_object, collider, self.frame_start,
                                            self.frame_end, preset=self.preset, seed=self.seed,
                                            time_limit=self.time_limit, motion=self.motion,
                                            body_friction=self.body_friction)
        return work

    def poll_job(self, context):
        try:
            attach_while_baking(self._target, self._job.state)
        except ERRORS as e:  # shown when the bake ends; the bake goes on
            print(f"drapelab: simulate: the cache could not be shown during the bake: {e}")

    def finish(self, context, result):
        return finish_simulation(self._target, result)


class DRAPELAB_OT_export_blender_cloth(bpy.types.Operator):
    """Set up Blender's own Cloth modifier on the active mesh with settings calibrated from the preset"""
    bl_idname = "drapelab.export_blender_cloth"
    bl_label = "Export to Blender Cloth"
    bl_options = {'REGISTER', 'UNDO'}

    preset: StringProperty(name="Preset", default="", description="preset name or path (default: the current)")

    def execute(self, context):
        module = _cloth_export_module()
        if module is None:
            self.report({'ERROR'}, f"export_blender_cloth: {NOT_AVAILABLE_CLOTH_EXPORT}")
            return {'CANCELLED'}
        obj = context.active_object
        if obj is None or obj.type != 'MESH':
            self.report({'ERROR'}, "export_blender_cloth: select a mesh object (the garment) first")
            return {'CANCELLED'}
        try:
            path = _preset_argument(context, self.preset)
            from .garment_ops import stored_material
            material = stored_material(obj)  # Apply Material's per-element field, when the mesh carries it
            module.apply_cloth_settings(obj, infer.load_preset(path), material)
        except ERRORS as e:
            self.report({'ERROR'}, f"export_blender_cloth: {e}")
            return {'CANCELLED'}
        self.report({'INFO'}, f"{obj.name}: Blender Cloth settings from {os.path.basename(path)}" +
                    (" with the per-element stiffness as vertex groups" if material else ""))
        return {'FINISHED'}


CLASSES = (DRAPELAB_OT_import_images, DRAPELAB_OT_calibrate_from_disk, DRAPELAB_OT_remove_image, DRAPELAB_OT_fit, DRAPELAB_OT_cancel,
           DRAPELAB_OT_diagnose, DRAPELAB_OT_add_effect, DRAPELAB_OT_save_preset, DRAPELAB_OT_load_preset,
           DRAPELAB_OT_load_preset_choice, DRAPELAB_OT_delete_preset, DRAPELAB_OT_import_preset,
           DRAPELAB_OT_show_image, DRAPELAB_OT_simulate_garment, DRAPELAB_OT_export_blender_cloth)


def register():
    from . import garment_ops
    for c in CLASSES + garment_ops.CLASSES:
        bpy.utils.register_class(c)


def unregister():
    from . import garment_ops
    for c in reversed(CLASSES + garment_ops.CLASSES):
        bpy.utils.unregister_class(c)
