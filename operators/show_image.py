"""Show an image (the profile plot, the preview render) at full size in an Image Editor,
without touching the artist's layout: an Image Editor already open is reused, else a
separate window opens (the one Blender opens for renders)."""

import bpy


def image_editors():
    wm = bpy.context.window_manager
    for win in wm.windows if wm is not None else ():
        for area in win.screen.areas:
            if area.type == "IMAGE_EDITOR":
                yield win, area


class BRDFMOMENTS_OT_show_image(bpy.types.Operator):
    """Open the image at full size in an Image Editor (a separate window if none is open)"""

    bl_idname = "brdf_moments.show_image"
    bl_label = "Show Image"
    bl_options = {"REGISTER"}

    image: bpy.props.StringProperty(name="Image")

    def execute(self, context):
        img = bpy.data.images.get(self.image)
        if img is None:
            self.report({"ERROR"}, f"no image named {self.image!r}: analyse or build the preview first")
            return {"CANCELLED"}
        if bpy.app.background or context.window is None:
            self.report({"INFO"}, f"{img.name}: no window to show it in")
            return {"CANCELLED"}
        found = next(image_editors(), None)
        if found is None:
            prefs = context.preferences.view
            saved = prefs.render_display_type
            try:
                prefs.render_display_type = "WINDOW"  # a window of its own, whatever the preference
                bpy.ops.render.view_show("INVOKE_DEFAULT")
            finally:
                prefs.render_display_type = saved
            found = next(image_editors(), None)
        if found is None:
            self.report({"WARNING"}, "could not open an Image Editor")
            return {"CANCELLED"}
        win, area = found
        area.spaces.active.image = img
        area.tag_redraw()
        return {"FINISHED"}
