"""Analyse: moment profiles and fits of the material's MERL file, off the main thread."""

import bpy

from ..addon.jobs import BackgroundJob
from .common import analysis_work, store_analysis, target_material


class BRDFMOMENTS_OT_analyse(BackgroundJob, bpy.types.Operator):
    """Compute the moment profiles and fits of the material's MERL file (Esc cancels)"""

    bl_idname = "brdf_moments.analyse"
    bl_label = "Analyse"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Analysing"

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def start(self, context):
        mat = target_material(context, self.material)
        self._mat_name, self._path = mat.name, mat.brdf_moments.source_path
        return analysis_work(self._path)

    def finish(self, context, result):
        mat = bpy.data.materials[self._mat_name]
        name = store_analysis(mat, self._path, result)
        state = mat.brdf_moments
        self.report({"INFO"}, f"Analysed {name}: μ̃ {state.fit_mu_slope:+.3f}, σ̃² {state.fit_sigma2:.4f}")
