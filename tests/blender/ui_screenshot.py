"""A real Blender window (under Xvfb, not --background): the Drape tab in the 3D view's sidebar while a fit runs.

Run by tests/python/test_addon_ui_screenshot.py as
    xvfb-run -a -s "-screen 0 1920x1200x24" blender --factory-startup --enable-event-simulate \
        --python tests/blender/ui_screenshot.py -- OUT_DIR
Sequence (window-manager timers, so the window draws in between): the splash is switched off before it opens;
the bundled image is imported; the sidebar is opened and turned to the "Drape" tab (Ctrl+wheel over it, the
simulated events Blender's --enable-event-simulate allows: 3.4 has no Python setter for a sidebar's tab); the
fit starts as the UI would start it (INVOKE_DEFAULT: worker thread + modal timer); once epochs report, the
window is captured with screen.screenshot (OUT_DIR/addon_panel_fit_running.png); Esc (a simulated key press over
the 3D view) cancels the fit through the modal operator; a 1-epoch fit then runs to the end and the sidebar, scrolled down to its overlay and r(theta)
plot, is captured (OUT_DIR/addon_panel_fit_done.png); then a 3-draw diagnosis of that preset and Apply Material
on a sphere with its heat map, with the Diagnose, Presets and Garment panels open, scrolled to the top
(OUT_DIR/addon_panel_diagnose_garment.png); Blender quits. Prints "SCREENSHOT <path> ..." per picture
and "UI DONE"; a failure prints "UI FAILED ..." and exits 1.
"""
import os
import sys
import time
import traceback

import bpy

root = os.environ["DRAPELAB_ROOT"]
sys.path[:0] = [os.path.join(root, "addon"), os.environ["DRAPELAB_NATIVE_DIR"]]
OUT_DIR = sys.argv[sys.argv.index("--") + 1] if "--" in sys.argv else os.path.join(root, "build", "test-artifacts")
RUNNING_PNG = os.path.join(OUT_DIR, "addon_panel_fit_running.png")
DONE_PNG = os.path.join(OUT_DIR, "addon_panel_fit_done.png")
SECTIONS_PNG = os.path.join(OUT_DIR, "addon_panel_diagnose_garment.png")
SCROLL_STEPS = 22       # wheel steps that scroll the sidebar from the top down to the finished fit's pictures
IMAGE = os.path.join(root, "assets", "cusick", "fabric_02", "silhouettes", "sample_02_capture_1.jpg")
TABS_AFTER_ITEM = 3     # factory sidebar tabs: Item, Tool, View, then the add-on's Drape
DEADLINE_S = 150.0

bpy.context.preferences.view.show_splash = False
import drapelab  # noqa: E402

drapelab.register()
from drapelab.ui import jobs  # noqa: E402

t0 = time.monotonic()
state = {"step": "sidebar"}


def fail(message):
    print(f"UI FAILED {message}", flush=True)
    jobs.cancel_all(5.0)
    os._exit(1)


def view3d():
    win = bpy.context.window_manager.windows[0]
    for area in win.screen.areas:
        if area.type == 'VIEW_3D':
            regions = {r.type: r for r in area.regions}
            return win, area, regions
    fail("no 3D view in the factory screen")


def tick():
    try:
        return step()
    except Exception:  # noqa: BLE001 - any error must fail the test, not hang Blender
        fail(traceback.format_exc())


def step():
    if time.monotonic() - t0 > DEADLINE_S:
        fail(f"timed out in step {state['step']}")
    win, area, regions = view3d()
    s = bpy.context.scene.drapelab
    if state.get("printed") != state["step"]:  # where a crash happened, in the log
        print(f"STEP {state['step']} at {time.monotonic() - t0:.1f} s", flush=True)
        state["printed"] = state["step"]
    if state["step"] == "sidebar":
        with bpy.context.temp_override(window=win, area=area):
            assert bpy.ops.drapelab.import_images(filepath=IMAGE) == {'FINISHED'}
        s.model, s.mesh_level, s.budget_mode, s.epochs, s.calibrate = "HOMO", 1, "EPOCHS", 300, False
        area.spaces.active.show_region_ui = True
        state["step"] = "tab"
        return 1.0
    if state["step"] == "tab":
        ui = regions['UI']
        x, y = ui.x + ui.width // 2, ui.y + ui.height - 40  # over the first panel (window y grows upwards)
        win.event_simulate('MOUSEMOVE', 'NOTHING', x=x, y=y)
        for _ in range(TABS_AFTER_ITEM):
            win.event_simulate('WHEELDOWNMOUSE', 'PRESS', x=x, y=y, ctrl=True)
        state["step"] = "fit"
        return 1.0
    if state["step"] == "fit":
        with bpy.context.temp_override(window=win, area=area, region=regions['WINDOW']):
            result = bpy.ops.drapelab.fit('INVOKE_DEFAULT')
        if result != {'RUNNING_MODAL'}:
            fail(f"the fit did not start in the background: {result}")
        state["step"] = "wait_epoch"
        return 0.5
    if state["step"] == "wait_epoch":
        snap = jobs.current("fit").state.snapshot()
        if snap["status"] != jobs.RUNNING:
            fail(f"the fit ended before the screenshot: {snap['status']} {snap['error']}")
        if snap["metrics"].get("epoch", 0) >= 2:
            state["step"] = "shot"
            return 0.6  # a poll of the modal operator and a redraw after the epoch
        return 0.5
    if state["step"] == "shot":
        snap = jobs.current("fit").state.snapshot()
        os.makedirs(OUT_DIR, exist_ok=True)
        with bpy.context.temp_override(window=win, area=area):
            bpy.ops.screen.screenshot(filepath=RUNNING_PNG)
        print(f"SCREENSHOT {RUNNING_PNG} job={snap['status']} message={snap['message']}", flush=True)
        # Esc, as a user would press it over the 3D view: the modal operator must cancel the job
        win.event_simulate('MOUSEMOVE', 'NOTHING', x=area.x + area.width // 3, y=area.y + area.height // 2)
        win.event_simulate('ESC', 'PRESS')
        win.event_simulate('ESC', 'RELEASE')
        state["step"] = "stop"
        state["cancelled_at"] = time.monotonic()
        return 0.2
    if state["step"] == "stop":
        job = jobs.current("fit")
        if job.alive:
            if time.monotonic() - state["cancelled_at"] > 5.0:
                fail("the fit did not stop within 5 s of Esc")
            return 0.2
        st = job.state
        print(f"CANCELLED job={st.status}: the worker stopped {st.finished - st.cancel_requested_at:.3f} s after "
              f"Esc", flush=True)
        s.epochs = 1  # a short fit that finishes: the panel then shows its overlay, r(theta) plot and metrics
        with bpy.context.temp_override(window=win, area=area, region=regions['WINDOW']):
            result = bpy.ops.drapelab.fit('INVOKE_DEFAULT')
        if result != {'RUNNING_MODAL'}:
            fail(f"the second fit did not start: {result}")
        state["step"] = "wait_done"
        return 0.5
    if state["step"] == "wait_done":
        job = jobs.current("fit")
        if job.alive or not s.overlay_image:  # the modal operator copies the result in on its next poll
            if job.state.status in (jobs.FAILED, jobs.CANCELLED):
                fail(f"the second fit ended {job.state.status}: {job.state.error}")
            return 0.5
        ui = regions['UI']
        x, y = ui.x + ui.width // 2, ui.y + ui.height // 2
        win.event_simulate('MOUSEMOVE', 'NOTHING', x=x, y=y)
        for _ in range(SCROLL_STEPS):
            win.event_simulate('WHEELDOWNMOUSE', 'PRESS', x=x, y=y)
        state["step"] = "shot_done"
        return 3.0  # the image previews render in the background
    if state["step"] == "shot_done":
        with bpy.context.temp_override(window=win, area=area):
            bpy.ops.screen.screenshot(filepath=DONE_PNG)
        print(f"SCREENSHOT {DONE_PNG} job={jobs.current('fit').state.status}", flush=True)
        # the other sections drawn with content: a short diagnosis of the fitted preset (synchronous: execute), a
        # garment with Apply Material's attributes; the closed-by-default panels re-registered open
        cube = bpy.data.objects.get("Cube")
        if cube is not None:
            bpy.data.objects.remove(cube)
        with bpy.context.temp_override(window=win, area=area, region=regions['WINDOW']):
            assert bpy.ops.drapelab.diagnose(samples=3, time_budget=30.0) == {'FINISHED'}
            bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=1.0)
            assert bpy.ops.drapelab.apply_material(triangulate=True, preset="fabric_02_cotton_blue_bdp") == {'FINISHED'}
            s.heat_attribute = "drapelab_bend_warp"
            assert bpy.ops.drapelab.show_heat_map() == {'FINISHED'}
        # Blender keeps a panel's open/closed state per panel id and 3.4 has no Python setter for it: the closed
        # panels are registered again under new ids (same draw code), which open by default; Measurement and Fit
        # are closed the same way so that the others come to the top
        # Show in Image Editor: the factory Layout screen has none, so the overlay opens in a new window
        windows = len(bpy.context.window_manager.windows)
        with bpy.context.temp_override(window=win, area=area, region=regions['WINDOW']):
            assert bpy.ops.drapelab.show_image(image=s.overlay_image) == {'FINISHED'}
        shown = [a.spaces.active.image.name for w in bpy.context.window_manager.windows for a in w.screen.areas
                 if a.type == 'IMAGE_EDITOR' and a.spaces.active.image is not None]
        if len(bpy.context.window_manager.windows) != windows + 1 or s.overlay_image not in shown:
            fail(f"Show in Image Editor did not open the overlay in a new window ({shown})")
        print(f"IMAGE EDITOR shows {shown}", flush=True)
        from drapelab.ui import panels
        for cls in panels.CLASSES[1:]:
            bpy.utils.unregister_class(cls)
        for cls in panels.CLASSES[1:]:
            shown = cls in (panels.DRAPELAB_PT_diagnose, panels.DRAPELAB_PT_presets, panels.DRAPELAB_PT_garment)
            bpy.utils.register_class(type(cls.__name__ + "_shot", (cls,), {
                "bl_idname": cls.bl_idname + "_shot", "bl_options": set() if shown else {'DEFAULT_CLOSED'}}))
        ui = regions['UI']
        x, y = ui.x + ui.width // 2, ui.y + ui.height // 2
        for _ in range(3 * SCROLL_STEPS):  # back to the top of the sidebar
            win.event_simulate('WHEELUPMOUSE', 'PRESS', x=x, y=y)
        state["step"] = "shot_sections"
        return 5.0  # the history chart's preview renders in the background
    if state["step"] == "shot_sections":
        with bpy.context.temp_override(window=win, area=area):
            bpy.ops.screen.screenshot(filepath=SECTIONS_PNG)
        print(f"SCREENSHOT {SECTIONS_PNG}", flush=True)
        print("UI DONE", flush=True)
        bpy.ops.wm.quit_blender()
        return None


bpy.app.timers.register(tick, first_interval=2.0)
