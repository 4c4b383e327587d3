"""drapelab: digitise real fabrics from Cusick drape tests (bpy-free facade over the native core).

Inside Blender this package is also the add-on: register()/unregister() import drapelab.ui (the only part that
imports bpy) when they are called, so importing drapelab (the CLI, scripts, tests) never needs bpy.
"""
__version__ = "0.1.0"

bl_info = {
    "name": "drapelab",
    "author": "drapelab",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "View3D > Sidebar > Drape",
    "description": "Fabric digitisation from Cusick drape images: fit, diagnose, presets, garments",
    "doc_url": "",
    "category": "Physics",
}


def register():
    from . import ui
    ui.register()


def unregister():
    from . import ui
    ui.unregister()
