"""Restore: the artist's own shader back in place of the edit (the node tree as it was)."""

import bpy

from .common import material_or_report


class BRDFMOMENTS_OT_restore_material(bpy.types.Operator):
    """Put the material's original shader back (removes the BRDF Moments edit node)"""

    bl_idname = "brdf_moments.restore_material"
    bl_label = "Restore Original Shader"
    bl_options = {"REGISTER", "UNDO"}

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def execute(self, context):
        from ..addon.blender.material import restore

        mat = material_or_report(self, context)
        if mat is None:
            return {"CANCELLED"}
        if not restore(mat):
            self.report({"INFO"}, f"{mat.name}: the shader is already the original")
            return {"CANCELLED"}
        mat.brdf_moments.artist_shader_used = ""
        self.report({"INFO"}, f"{mat.name}: original shader restored")
        return {"FINISHED"}
