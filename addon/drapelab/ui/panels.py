"""The sidebar tab "Drape" of the 3D view: Measurement, Fit, Diagnose, Presets, Garment (drawn from
scene.drapelab and, while a job runs, from drapelab.ui.jobs' shared state)."""
import os

import bpy

from . import jobs, previews


class DRAPELAB_UL_images(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row()
        row.label(text=os.path.basename(item.filepath) or "(no file)", icon='IMAGE_DATA')
        row.label(text=f"DC {item.drape_coefficient:.3f}, {item.node_count} nodes")


class _Panel:
    bl_space_type = 'VIEW_3D'
    bl_region_type = 'UI'
    bl_category = "Drape"


def _chars(context):
    """About how many characters of label text fit on one line of the sidebar."""
    region = getattr(context, "region", None)
    width = region.width if region is not None else 300
    return max(18, int(width / (7.0 * context.preferences.view.ui_scale)) - 3)


def _image_scale(context):
    """template_icon scale (units of 20 px) filling the sidebar's width."""
    region = getattr(context, "region", None)
    width = region.width if region is not None else 300
    return max(6.0, (width - 40) / (20.0 * context.preferences.view.ui_scale))


def _job_box(layout, kind, context=None):
    """Progress bar, message, live numbers and Cancel of the job of `kind` while it runs (or its last outcome)."""
    job = jobs.current(kind)
    if job is None:
        return False
    context = context or bpy.context
    width = _chars(context)
    snap = job.state.snapshot()
    if snap["status"] not in (jobs.RUNNING, jobs.FAILED, jobs.CANCELLED):
        return False
    box = layout.box()
    if snap["status"] == jobs.RUNNING:
        label = f"{kind} running, {snap['elapsed']:.0f} s"
        if hasattr(box, "progress"):  # UILayout.progress exists from Blender 4.0
            box.progress(factor=snap["fraction"], type='BAR', text=f"{label}: {100 * snap['fraction']:.0f} %")
        else:
            box.prop(context.window_manager, "drapelab_progress", text=label, slider=True)
        for line in _wrap(snap["message"] or "starting", width):
            box.label(text=line)
        m = snap["metrics"]
        if "loss" in m and "loss" not in snap["message"]:
            col = box.column(align=True)
            col.label(text=f"loss {m['loss']:.4f}")
            col.label(text=f"IoU {m.get('iou', 0):.3f}   MSE {m.get('mse', 0):.4f}")
        if len(snap["history"]) > 1:
            h = snap["history"]
            for line in _wrap("loss history: " + " ".join(f"{v:.3g}" for v in h[-8:]), width):
                box.label(text=line)
        box.operator("drapelab.cancel", icon='CANCEL')
        box.label(text="Esc also cancels", icon='INFO')
        return True
    if snap["status"] == jobs.FAILED:
        for i, line in enumerate(_wrap(f"{kind} failed: {snap['error']}", width)[:6]):
            box.label(text=line, icon='ERROR' if i == 0 else 'NONE')
    elif snap["status"] == jobs.CANCELLED:
        for i, line in enumerate(_wrap(f"{kind} cancelled after {snap['elapsed']:.0f} s; earlier results kept", width)):
            box.label(text=line, icon='CANCEL' if i == 0 else 'NONE')
    return False


class DRAPELAB_PT_measurement(_Panel, bpy.types.Panel):
    bl_label = "Measurement"
    bl_idname = "DRAPELAB_PT_measurement"

    def draw(self, context):
        s = context.scene.drapelab
        layout = self.layout
        layout.operator("drapelab.import_images", icon='FILEBROWSER')
        row = layout.row()
        row.template_list("DRAPELAB_UL_images", "", s, "images", s, "active_image", rows=2)
        row.operator("drapelab.remove_image", text="", icon='X')
        if s.measurement_image:
            previews.draw_image(layout, s.measurement_image, _image_scale(context))
            layout.operator("drapelab.show_image", icon='IMAGE').image = s.measurement_image
        col = layout.column(align=True)
        col.prop(s, "fabric_name")
        col.prop(s, "density", text="Density (kg/m²)")
        col.prop(s, "thickness_mm")
        box = layout.box()
        box.label(text="Calibration")
        box.prop(s, "px_per_m")
        box.operator("drapelab.calibrate_from_disk", icon='PIVOT_BOUNDBOX')
        box.prop(s, "centre_auto")
        if not s.centre_auto:
            r = box.row(align=True)
            r.prop(s, "centre_x")
            r.prop(s, "centre_y")


class DRAPELAB_PT_fit(_Panel, bpy.types.Panel):
    bl_label = "Fit"
    bl_idname = "DRAPELAB_PT_fit"

    def draw(self, context):
        s = context.scene.drapelab
        layout = self.layout
        layout.prop(s, "model", expand=True)
        box = layout.box()
        box.label(text="Effects (fitted with the material)")
        grid = box.column(align=True)
        for name in s.effects.bl_rna.properties.keys():
            if name not in ("rna_type", "name"):
                grid.prop(s.effects, name)
        row = layout.row()
        row.prop(s, "budget_mode", expand=True)
        layout.prop(s, "epochs" if s.budget_mode == 'EPOCHS' else "time_budget")
        row = layout.row()
        row.prop(s, "seed")
        row.prop(s, "mesh_level")
        if s.model == 'BDP':
            layout.prop(s, "calibrate")
        layout.prop(s, "init_path")
        running = _job_box(layout, "fit", context)
        row = layout.row()
        row.enabled = not running and jobs.current() is None
        row.scale_y = 1.4
        row.operator("drapelab.fit", icon='PLAY')
        data = s.metrics()
        if data:
            m, t = data.get("metrics"), data.get("training") or {}
            box = layout.box()
            col = box.column(align=True)
            col.label(text=os.path.basename(s.preset_path), icon='FILE')
            if t.get("epochs") is not None:
                col.label(text=f"{t['epochs']} epochs in {t.get('seconds') or 0:.0f} s")
                if t.get("final_loss") is not None:
                    col.label(text=f"final loss {t['final_loss']:.4f}")
            if m:
                dc, nodes = m["drape_coefficient"], m["node_count"]
                col.label(text=f"IoU {m['iou']:.3f}   MSE {m['mse']:.4f}")
                col.label(text=f"r(θ) rmse {1000 * m['r_theta_rmse_m']:.1f} mm")
                col.label(text=f"DC {dc['predicted']:.3f} (measured {dc['observed']:.3f})")
                col.label(text=f"nodes {nodes['predicted']} (measured {nodes['observed']})")
        scale = _image_scale(context)
        if s.overlay_image:
            previews.draw_image(layout, s.overlay_image, scale)
            layout.operator("drapelab.show_image", text="Overlay in Image Editor", icon='IMAGE').image = s.overlay_image
        if s.rtheta_image:
            previews.draw_image(layout, s.rtheta_image, scale)
            layout.operator("drapelab.show_image", text="r(θ) in Image Editor", icon='IMAGE').image = s.rtheta_image


class DRAPELAB_PT_diagnose(_Panel, bpy.types.Panel):
    bl_label = "Diagnose"
    bl_idname = "DRAPELAB_PT_diagnose"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        from .operators import diagnosis
        s = context.scene.drapelab
        layout = self.layout
        row = layout.row()
        row.prop(s, "diagnose_budget", text="Budget (s)")
        row.prop(s, "diagnose_samples", text="Draws")
        running = _job_box(layout, "diagnose", context)
        row = layout.row()
        row.enabled = not running and jobs.current() is None and bool(s.preset_path)
        row.operator("drapelab.diagnose", icon='VIEWZOOM')
        d = diagnosis(s)
        if d:
            if d.get("verdict"):
                for line in _wrap(d["verdict"], _chars(context)):
                    layout.label(text=line)
            box = layout.box()
            box.label(text="Missing effect? Likeliest first")
            for e in d.get("ranking", []):
                col = box.column(align=True)
                col.label(text=e["effect"].replace("_", " "), icon='DOT')
                r = col.row(align=True)
                p = e.get("p_value")
                r.label(text=(f"p {p:.2g}" if p is not None else "not tested") +
                        (f", gain {e['gain']:.3g}" if e.get("gain") is not None else ""))
                refit = (e.get("refit") or {}).get("preset")
                refit = os.path.join(os.path.dirname(bpy.path.abspath(s.diagnosis_path)), refit) if refit else ""
                op = r.operator("drapelab.add_effect", text="Add", icon='ADD')
                op.effect = e["effect"]
                op.refit = refit  # the next fit starts from the diagnosis's refit (fit --init)
                if refit:  # the diagnosis's refit with this effect, as a preset to use directly
                    op = r.operator("drapelab.load_preset", text="Use refit", icon='IMPORT')
                    op.filepath = refit
            row = layout.row()
            row.enabled = jobs.current() is None
            row.operator("drapelab.fit", text="Refit", icon='FILE_REFRESH')
        if s.history_image:
            layout.label(text="Error across model versions")
            previews.draw_image(layout, s.history_image, _image_scale(context))


def _wrap(text, width):
    words, lines, line = text.split(), [], ""
    for w in words:
        if len(line) + len(w) + 1 > width:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}".strip()
    return lines + [line] if line else lines


class DRAPELAB_PT_presets(_Panel, bpy.types.Panel):
    bl_label = "Presets"
    bl_idname = "DRAPELAB_PT_presets"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        s = context.scene.drapelab
        layout = self.layout
        layout.prop(s, "preset_choice", text="")
        row = layout.row(align=True)
        row.operator("drapelab.load_preset_choice", icon='IMPORT')
        row.operator("drapelab.delete_preset", text="Delete", icon='TRASH')
        box = layout.box()
        box.label(text=f"Current: {os.path.basename(s.preset_path) or 'none'}")
        row = box.row(align=True)
        row.prop(s, "new_preset_name", text="")
        op = row.operator("drapelab.save_preset", text="Save as mine", icon='ADD')
        op.name = s.new_preset_name
        op.filepath = ""
        row = layout.row(align=True)
        row.operator("drapelab.import_preset", text="Import JSON", icon='IMPORT')
        row.operator("drapelab.save_preset", text="Export JSON", icon='EXPORT').name = ""
        layout.operator("drapelab.load_preset", text="Load from file", icon='FILEBROWSER')


class DRAPELAB_PT_garment(_Panel, bpy.types.Panel):
    bl_label = "Garment"
    bl_idname = "DRAPELAB_PT_garment"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        s = context.scene.drapelab
        layout = self.layout
        layout.prop(s, "garment")
        layout.prop(s, "collider")
        layout.operator("drapelab.apply_material", icon='MATERIAL')
        layout.prop(s, "heat_attribute")
        layout.operator("drapelab.show_heat_map", icon='COLOR')
        _job_box(layout, "simulate", context)
        row = layout.row(align=True)
        row.prop(s, "frame_start")
        row.prop(s, "frame_end")
        layout.prop(s, "motion")
        layout.prop(s, "body_friction")
        op = layout.operator("drapelab.simulate_garment", icon='PHYSICS')
        op.frame_start, op.frame_end, op.motion = s.frame_start, s.frame_end, s.motion
        op.body_friction = s.body_friction
        op.collider = s.collider.name if s.collider else ""
        layout.operator("drapelab.export_blender_cloth", icon='MOD_CLOTH')


CLASSES = (DRAPELAB_UL_images, DRAPELAB_PT_measurement, DRAPELAB_PT_fit, DRAPELAB_PT_diagnose, DRAPELAB_PT_presets,
           DRAPELAB_PT_garment)


def register():
    # a read-only slider for the progress bar (UILayout.progress arrives in Blender 4.0)
    bpy.types.WindowManager.drapelab_progress = bpy.props.FloatProperty(
        name="Progress", min=0.0, max=100.0, subtype='PERCENTAGE', precision=0, get=_progress_value)
    for c in CLASSES:
        bpy.utils.register_class(c)


def _progress_value(self):
    job = jobs.current()
    return 100.0 * job.state.fraction if job is not None else 0.0


def unregister():
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
    del bpy.types.WindowManager.drapelab_progress
