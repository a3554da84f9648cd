"""Reset sliders: back to the fitted values (an identity edit)."""

import bpy

from .common import analysed_material


class BRDFMOMENTS_OT_reset_sliders(bpy.types.Operator):
    """Set the sliders back to the material's fitted values"""

    bl_idname = "brdf_moments.reset_sliders"
    bl_label = "Reset Sliders"
    bl_options = {"REGISTER", "UNDO"}

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def execute(self, context):
        try:
            mat = analysed_material(context, self.material)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        mat.brdf_moments.reset_sliders()
        return {"FINISHED"}
