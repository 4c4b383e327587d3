"""Images shown in Blender: the PNGs drapelab.ui.figures writes become bpy.data.images (reloaded when the file
changes) whose previews the panels draw; `show_in_image_editor` puts one in an Image Editor (a new window when
the screen has none)."""
import os

import bpy

PREFIX = "drapelab_"


def load(path, name):
    """The Blender image `drapelab_<name>` showing the PNG at `path` (created, or re-pointed and reloaded);
    returns the image's name, or "" when there is no file."""
    if not path or not os.path.isfile(path):
        return ""
    key = PREFIX + name
    img = bpy.data.images.get(key)
    if img is None:
        img = bpy.data.images.load(path, check_existing=False)
        img.name = key
    else:
        img.filepath = path
        img.reload()
    if not bpy.app.background:
        img.preview_ensure()
        try:
            img.preview.reload()
        except AttributeError:  # Blender < 3.0 has no ImagePreview.reload
            pass
    return img.name


def icon(name):
    """The preview icon id of image `name`, or 0."""
    img = bpy.data.images.get(name) if name else None
    if img is None or bpy.app.background:
        return 0
    return img.preview_ensure().icon_id


def show_in_image_editor(context, name):
    """Shows the image in the first Image Editor of the screen, else in a new window turned into an Image Editor.
    Returns the area used, or None (no such image, or no window: --background)."""
    img = bpy.data.images.get(name)
    if img is None or context.window is None:
        return None
    for area in context.screen.areas if context.screen else []:
        if area.type == 'IMAGE_EDITOR':
            area.spaces.active.image = img
            return area
    before = set(context.window_manager.windows[:])
    bpy.ops.wm.window_new()
    new = [w for w in context.window_manager.windows if w not in before]
    if not new:
        return None
    area = max(new[0].screen.areas, key=lambda a: a.width * a.height)
    area.type = 'IMAGE_EDITOR'
    area.spaces.active.image = img
    return area


def draw_image(layout, name, scale=10.0):
    """Draws the image's preview in a panel (nothing in --background, where there is no UI)."""
    ic = icon(name)
    if ic:
        layout.template_icon(icon_value=ic, scale=scale)
    elif name:
        layout.label(text=f"(image {name})")
