"""Analyse: moment profiles and fits of the material's MERL file, off the main thread."""

import bpy

from ..addon.blender.jobs import BackgroundJob
from .common import analysis_work, store_analysis, target_material


class BRDFMOMENTS_OT_analyse(BackgroundJob, bpy.types.Operator):
    """Compute the moment profiles and fits of the material's MERL file (Esc cancels)"""

    bl_idname = "brdf_moments.analyse"
    bl_label = "Analyse"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Analysing"

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")
    filepath: bpy.props.StringProperty(
        name="MERL file",
        subtype="FILE_PATH",
        options={"HIDDEN", "SKIP_SAVE"},
        description="analyse this file instead of the material's (Load uses it): the material takes the path only "
        "once the analysis is done, so a cancelled or failed Load leaves it as it was",
    )

    def start(self, context):
        mat = target_material(context, self.material)
        self._mat_name, self._path = mat.name, self.filepath or mat.brdf_moments.source_path
        return analysis_work(self._path, mat.brdf_moments.floor)

    def finish(self, context, result):
        self.report({"INFO"}, store_analysis(bpy.data.materials[self._mat_name], self._path, result))
