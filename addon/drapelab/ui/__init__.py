"""The Blender side of drapelab (the only sub-package importing bpy, and only from register()).

properties (scene.drapelab), operators (drapelab.*), panels (View3D sidebar tab "Drape"), previews (images
shown in Blender); jobs, tasks and figures are bpy-free (worker threads and the pictures they make).
"""
_registered = False


def register():
    global _registered
    if _registered:
        return
    from . import operators, panels, properties
    properties.register()
    operators.register()
    panels.register()
    _registered = True


def unregister():
    """Stops any running job (sets its cancel flag and joins the worker) before removing the classes."""
    global _registered
    from . import jobs
    stuck = jobs.cancel_all(timeout=10.0)
    if stuck:
        print(f"drapelab: the {', '.join(stuck)} worker did not stop within 10 s")
    jobs.forget_finished()
    if not _registered:
        return
    from . import operators, panels, properties
    panels.unregister()
    operators.unregister()
    properties.unregister()
    _registered = False
