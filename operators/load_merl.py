"""Load MERL: a file browser filtered to .binary; the chosen file is analysed at once."""

import bpy
from bpy_extras.io_utils import ImportHelper

from ..addon.jobs import BackgroundJob
from .common import analysis_work, store_analysis, target_material


class BRDFMOMENTS_OT_load_merl(BackgroundJob, bpy.types.Operator, ImportHelper):
    """Load a measured BRDF (MERL .binary) into the material and analyse its moment profiles"""

    bl_idname = "brdf_moments.load_merl"
    bl_label = "Load MERL"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Analysing"

    filename_ext = ".binary"
    filter_glob: bpy.props.StringProperty(default="*.binary", options={"HIDDEN"})
    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def invoke(self, context, event):
        # The file browser first; Blender then calls execute, which runs the analysis.
        return ImportHelper.invoke(self, context, event)

    def execute(self, context):
        win = context.window_manager.windows if context.window_manager else None
        if win and not bpy.app.background:
            # In the UI the analysis runs as the Analyse operator: threaded, with progress.
            try:
                mat = target_material(context, self.material)
            except ValueError as exc:
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
            try:
                analysis_work(self.filepath)  # checks the file now: the report, not a traceback
                # The material keeps its path and analysis until the job lands (Esc keeps both).
                bpy.ops.brdf_moments.analyse("INVOKE_DEFAULT", material=mat.name, filepath=self.filepath)
            except (ValueError, RuntimeError) as exc:  # bpy.ops raises RuntimeError on an ERROR report
                text = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
                self.report({"ERROR"}, text.removeprefix("Error: "))
                return {"CANCELLED"}
            return {"FINISHED"}
        return BackgroundJob.execute(self, context)

    def start(self, context):
        self._mat_name = target_material(context, self.material).name
        return analysis_work(self.filepath)

    def finish(self, context, result):
        self.report({"INFO"}, store_analysis(bpy.data.materials[self._mat_name], self.filepath, result))
