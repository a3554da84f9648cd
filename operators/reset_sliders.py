"""Reset sliders: back to the fitted values (an identity edit)."""

import bpy

from .common import material_or_report


class BRDFMOMENTS_OT_reset_sliders(bpy.types.Operator):
    """Set the sliders back to the material's fitted values"""

    bl_idname = "brdf_moments.reset_sliders"
    bl_label = "Reset Sliders"
    bl_options = {"REGISTER", "UNDO"}

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def execute(self, context):
        mat = material_or_report(self, context, analysed=True)
        if mat is None:
            return {"CANCELLED"}
        mat.brdf_moments.reset_sliders()
        return {"FINISHED"}
