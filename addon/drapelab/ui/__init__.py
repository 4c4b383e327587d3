"""The Blender side of drapelab (the only sub-package importing bpy, and only from register()).

properties (scene.drapelab), operators (drapelab.*), panels (View3D sidebar tab "Drape"), previews (images
shown in Blender); jobs, tasks, figures and presets are bpy-free (worker threads and the pictures they make).
"""
_registered = False


def _stop_jobs_before_load(*_args):
    """load_pre handler: opening another file stops a running job (its result belongs to the file it started in)
    and forgets the finished ones, so the new file's panel starts idle."""
    from . import jobs
    jobs.cancel_all(timeout=10.0)
    jobs.forget_finished()


def register():
    global _registered
    if _registered:
        return
    import bpy
    from bpy.app.handlers import persistent
    from . import operators, panels, properties
    properties.register()
    operators.register()
    panels.register()
    global _load_handler
    _load_handler = persistent(_stop_jobs_before_load)
    bpy.app.handlers.load_pre.append(_load_handler)
    _registered = True


_load_handler = None


def unregister():
    """Stops any running job (sets its cancel flag and joins the worker) before removing the classes."""
    global _registered, _load_handler
    from . import jobs
    stuck = jobs.cancel_all(timeout=10.0)
    if stuck:
        print(f"drapelab: the {', '.join(stuck)} worker did not stop within 10 s")
    jobs.forget_finished()
    if not _registered:
        return
    import bpy
    from . import operators, panels, properties
    if _load_handler in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_load_handler)
    _load_handler = None
    panels.unregister()
    operators.unregister()
    properties.unregister()
    _registered = False
