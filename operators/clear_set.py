"""Clear Set: the region plot without the loaded set's materials (the correlation a stays)."""

import bpy

from .common import material_or_report


class BRDFMOMENTS_OT_clear_set(bpy.types.Operator):
    """Remove the loaded set's materials from the region plot (the correlation a is kept)"""

    bl_idname = "brdf_moments.clear_set"
    bl_label = "Clear Set"
    bl_options = {"REGISTER", "UNDO"}

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def execute(self, context):
        from ..addon.blender.state import region_image

        mat = material_or_report(self, context)
        if mat is None:
            return {"CANCELLED"}
        state = mat.brdf_moments
        if not state.set_data and not state.set_path:
            self.report({"INFO"}, f"{mat.name}: no set loaded")
            return {"CANCELLED"}
        state.set_data = state.set_path = ""
        region_image(mat, later=True)
        return {"FINISHED"}
