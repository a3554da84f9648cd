"""Bound the approximation: the least BRDF error any mix of Blender's closures reaches on the
applied edit's table, beside the approximation's own (a background job: 6 s and more)."""

import os

import bpy

from ..addon.blender import material as artist
from ..addon.blender.jobs import BackgroundJob
from .common import analysed_material


class BRDFMOMENTS_OT_node_bound(BackgroundJob, bpy.types.Operator):
    """The least BRDF error any mix of Blender's closures reaches on the applied edit's table
    (core.material.node_bound), stated beside the approximation's own error (Esc cancels)"""

    bl_idname = "brdf_moments.node_bound"
    bl_label = "Bound"
    bl_options = {"REGISTER", "UNDO"}  # it writes the bound into the material's state
    job_label = "Bounding the approximation"

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def start(self, context):
        from ..addon.core.material.lobes import shadowing_for

        mat = analysed_material(context, self.material)
        state = mat.brdf_moments
        if state.artist_shader_used not in ("lobes", "principled") or not state.edited_path:
            raise ValueError(f"{mat.name}: no approximation applied to bound")
        path, shadowing = state.edited_path, shadowing_for(bpy.app.version)
        if not os.path.exists(path):
            raise ValueError(f"{path}: the edited table is missing; Apply again")
        self._mat_name, self._path = mat.name, path

        def work(report_progress):
            from ..addon.core.file.merl import read_merl
            from ..addon.core.material.node_bound import node_bound

            report_progress(1, 3)
            return node_bound(read_merl(path), shadowing=shadowing)

        return work

    def finish(self, context, bound):
        mat = bpy.data.materials.get(self._mat_name)
        if mat is None or mat.brdf_moments.edited_path != self._path:
            return  # applied again meanwhile: that Apply starts its own
        artist.set_bound(mat, float(bound))
        self.report(
            {"INFO"}, f"{mat.name}: the least error any mix of Blender's closures reaches is {100 * bound:.1f} %"
        )
