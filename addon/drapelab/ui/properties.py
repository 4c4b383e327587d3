"""scene.drapelab: the add-on's settings and its last results (one PropertyGroup; no job state: whether a job
runs lives only in drapelab.ui.jobs, so a .blend saved mid-job reopens idle)."""
import json
import os
import tempfile

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty,
                       PointerProperty, StringProperty)

from .. import measure, sim
from . import presets as preset_files

MOTIONS = [("static", "Static", "the dress form stands still"),
           ("walk", "Walk", "walking in place: the legs swing +-25 degrees about the hips, the pelvis sways"),
           ("twirl", "Twirl", "turning about the vertical axis, up to 1 turn/s"),
           ("jump", "Jump", "a 10 cm hop after 6 frames of rest")]
MODELS = [("HOMO", "HOMO", "one bending table for the whole specimen"),
          ("HETER", "HETER", "a bending table per bending edge (point estimate)"),
          ("BDP", "BDP", "Bayesian differentiable physics: a posterior over per-edge tables, drape-calibrated")]


def cache_dir():
    """The add-on's output folder: drapelab_cache beside the saved .blend, else one in the temp folder."""
    if bpy.data.filepath:
        return os.path.join(os.path.dirname(bpy.path.abspath(bpy.data.filepath)), "drapelab_cache")
    return os.path.join(tempfile.gettempdir(), f"drapelab_cache_{os.getpid()}")


def user_presets_dir():
    return bpy.utils.user_resource('SCRIPTS', path=os.path.join("presets", "drapelab"), create=True)


class DRAPELAB_PG_image(bpy.types.PropertyGroup):
    filepath: StringProperty(name="Image", subtype='FILE_PATH')
    drape_coefficient: FloatProperty(name="Drape coefficient", default=0.0)
    node_count: IntProperty(name="Nodes", default=0)


def _effect_group():
    """A PropertyGroup with one toggle per registered effect (read from the native registry at register time)."""
    annotations = {}
    for e in sim.effects():
        params = ", ".join(f"{p['name']}" for p in e["parameters"])
        annotations[e["name"]] = BoolProperty(
            name=e["name"].replace("_", " "), default=False,
            description=f"Fit this effect's strength with the material ({params}): {e['explanation']}")
    return type("DRAPELAB_PG_effects", (bpy.types.PropertyGroup,), {"__annotations__": annotations})


def _show_active_image(settings):
    """The measurement picture follows the image selected in the list (redrawn at the current calibration)."""
    if not 0 <= settings.active_image < len(settings.images):
        return
    from . import figures, previews
    from .tasks import measurement_png
    path = bpy.path.abspath(settings.images[settings.active_image].filepath)
    png = measurement_png(cache_dir(), path)
    try:
        os.makedirs(os.path.dirname(png), exist_ok=True)
        figures.measurement_preview(path, png, settings.calibration())
    except (ValueError, OSError) as e:  # the file changed or vanished since it was imported
        print(f"drapelab: {path}: {e}")
        return
    settings.measurement_image = previews.load(png, "measurement")


_preset_items_cache = []  # Blender keeps only pointers to enum item strings: hold them here


def _preset_items(self, context):
    global _preset_items_cache
    items = []
    for i, e in enumerate(preset_files.list_presets(user_presets_dir())):
        tag = "shipped" if e["source"] == preset_files.SHIPPED else "yours"
        items.append((e["path"], f"{e['name']} ({tag})", e["path"], i))
    _preset_items_cache = items or [("NONE", "no presets", "", 0)]
    return _preset_items_cache


def _is_mesh(self, obj):
    return obj.type == 'MESH'


_heat_items_cache = []


def _heat_items(self, context):
    global _heat_items_cache
    items = [("NONE", "none", "no heat map", 0)]
    obj = self.garment
    if obj is not None and obj.type == 'MESH':
        for a in obj.data.attributes:
            # the summaries (stretch_weft, bend_warp, ...), not the full tables' entries (stretch_00, ...)
            if a.name.startswith("drapelab_") and a.domain in ('FACE', 'EDGE') and a.data_type == 'FLOAT' \
                    and not a.name[-2:].isdigit():
                items.append((a.name, a.name[len("drapelab_"):], f"{a.domain.lower()} attribute {a.name}",
                              len(items)))
    _heat_items_cache = items
    return _heat_items_cache


class DRAPELAB_PG_settings(bpy.types.PropertyGroup):
    # Measurement
    images: CollectionProperty(type=DRAPELAB_PG_image)
    active_image: IntProperty(name="Active image", default=0, update=lambda self, context: _show_active_image(self))
    fabric_name: StringProperty(name="Fabric", default="", description="fabric name recorded in the preset")
    density: FloatProperty(name="Area density", default=0.2, min=0.0, soft_min=0.01, soft_max=1.0, precision=3,
                           description="area density of the fabric in kg/m^2 (required by the fit)")
    thickness_mm: FloatProperty(name="Thickness (mm)", default=0.5, min=0.0, soft_max=5.0, precision=3,
                                description="fabric thickness in mm (recorded in the preset)")
    px_per_m: FloatProperty(name="Scale (px/m)", default=float(measure.DATASET_PX_PER_M), min=1.0,
                            description="image scale of the calibrated top view, pixels per metre")
    centre_auto: BoolProperty(name="Centre at image centre", default=True)
    centre_x: FloatProperty(name="Centre x (px)", default=0.0)
    centre_y: FloatProperty(name="Centre y (px)", default=0.0)
    # Fit
    model: EnumProperty(name="Model", items=MODELS, default="BDP")
    effects: PointerProperty(type=bpy.types.PropertyGroup)  # replaced by the registry group at register()
    budget_mode: EnumProperty(name="Budget", items=[("EPOCHS", "Epochs", "run a number of epochs"),
                                                    ("TIME", "Time", "run for a time budget (whole fit)")],
                              default="TIME")
    epochs: IntProperty(name="Epochs", default=25, min=1, soft_max=500)
    time_budget: FloatProperty(name="Time budget (s)", default=300.0, min=1.0, soft_max=3600.0,
                               description="seconds for the whole fit (set-up, epochs, drape calibration)")
    seed: IntProperty(name="Seed", default=0, min=0)
    calibrate: BoolProperty(name="Drape calibration", default=True,
                            description="BDP: end with the drape calibration (needs about 140 s of the budget)")
    mesh_level: IntProperty(name="Mesh level", default=0, min=0, max=5,
                            description="Cusick template mesh circleN for the fit (0: fit.json's)")
    # Results (not job state)
    preset_path: StringProperty(name="Preset", subtype='FILE_PATH', description="the current preset")
    init_path: StringProperty(name="Start from", subtype='FILE_PATH',
                              description="the next fit starts from this preset (fit --init): its material, "
                                          "stretching and effects, e.g. a diagnosis's refit (set by Add); empty: "
                                          "from fit.json's start. Cleared when that fit is done")
    overlay_image: StringProperty(name="Overlay image")
    rtheta_image: StringProperty(name="r(theta) image")
    measurement_image: StringProperty(name="Measurement image")
    metrics_json: StringProperty(name="Metrics", default="")
    # Diagnose
    diagnose_budget: FloatProperty(name="Time budget (s)", default=300.0, min=1.0)
    diagnose_samples: IntProperty(name="Draws", default=16, min=3, max=256)
    diagnosis_path: StringProperty(name="Diagnosis", subtype='FILE_PATH')
    history_image: StringProperty(name="History image")
    history_json: StringProperty(name="History", default="[]")
    # Presets
    preset_choice: EnumProperty(name="Preset", items=_preset_items)
    new_preset_name: StringProperty(name="Name", default="my fabric")
    # Garment
    garment: PointerProperty(name="Garment", type=bpy.types.Object, poll=_is_mesh)
    collider: PointerProperty(name="Collider", type=bpy.types.Object, poll=_is_mesh)
    heat_attribute: EnumProperty(name="Heat map", items=_heat_items)
    frame_start: IntProperty(name="Start", default=1, min=0)
    frame_end: IntProperty(name="End", default=60, min=1)
    motion: EnumProperty(name="Motion", items=MOTIONS, default="static",
                         description="the dress form's motion during Simulate (it gets its own Mesh Cache)")
    body_friction: FloatProperty(name="Body friction", default=0.3, min=0.0, max=2.0, precision=2,
                                 description="Coulomb friction coefficient between the garment and the dress form "
                                             "(0: frictionless)")

    def metrics(self):
        try:
            return json.loads(self.metrics_json) if self.metrics_json else None
        except ValueError:
            return None

    def history(self):
        try:
            return json.loads(self.history_json or "[]")
        except ValueError:
            return []

    def calibration(self):
        centre = None if self.centre_auto else (self.centre_x, self.centre_y)
        return measure.calibration(self.px_per_m, centre)

    def image_paths(self):
        return [bpy.path.abspath(i.filepath) for i in self.images]

    def enabled_effects(self):
        """{name: None} for each toggled effect (infer.fit's form for 'fit this effect')."""
        return {e["name"]: None for e in sim.effects() if getattr(self.effects, e["name"], False)}


_effects_class = None
CLASSES = (DRAPELAB_PG_image,)


def register():
    global _effects_class
    _effects_class = _effect_group()
    for c in CLASSES + (_effects_class,):
        bpy.utils.register_class(c)
    DRAPELAB_PG_settings.__annotations__["effects"] = PointerProperty(type=_effects_class)
    bpy.utils.register_class(DRAPELAB_PG_settings)
    bpy.types.Scene.drapelab = PointerProperty(type=DRAPELAB_PG_settings)


def unregister():
    global _effects_class
    del bpy.types.Scene.drapelab
    bpy.utils.unregister_class(DRAPELAB_PG_settings)
    for c in reversed(CLASSES + (_effects_class,)):
        bpy.utils.unregister_class(c)
    _effects_class = None
