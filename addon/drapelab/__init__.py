"""drapelab: digitise real fabrics from Cusick drape tests (bpy-free facade over the native core).

The Blender UI lives in drapelab.ui (added with the add-on issue) and is the only part importing bpy.
"""
__version__ = "0.1.0"

bl_info = {
    "name": "drapelab",
    "author": "drapelab",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "View3D > Sidebar > Drape",
    "description": "Fabric digitisation from Cusick drape images",
    "category": "Physics",
}
