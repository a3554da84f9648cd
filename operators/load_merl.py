"""Load: a file browser for MERL .binary files and Neural-BRDF weights (.npz, .h5, a folder of
.npy); for a weights set the artist picks the material from a list. Analysed at once."""

import os

import bpy
from bpy_extras.io_utils import ImportHelper

from ..addon.blender.jobs import BackgroundJob
from .common import analysis_work, store_analysis, target_material

# Blender keeps only pointers to dynamic enum strings: the items must outlive the callback.
_ITEMS_CACHE = {}


def _network_items(self, context):
    from ..addon.core.file.nbrdf import chooser_materials

    path = bpy.path.abspath(self.filepath) if self.filepath else ""
    try:
        key = (path, os.stat(path).st_mtime_ns) if path and os.path.exists(path) else (path, 0)
    except OSError:
        key = (path, 0)
    items = _ITEMS_CACHE.get(key)
    if items is None:
        names = chooser_materials(path)
        items = [(n, n, f"measured material {n} of this weights file") for n in names]
        if len(names) != 1:
            # No silent default for a set: the first entry asks for a choice.
            items.insert(0, ("NONE", "(choose a material)" if names else "(a MERL file: none)", ""))
        _ITEMS_CACHE.clear()
        _ITEMS_CACHE[key] = items
    return items


class BRDFMOMENTS_OT_load_merl(BackgroundJob, bpy.types.Operator, ImportHelper):
    """Load a measured BRDF (MERL .binary, or a Neural-BRDF network) into the material and analyse it"""

    bl_idname = "brdf_moments.load_merl"
    bl_label = "Load MERL"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Analysing"

    filename_ext = ".binary"
    filter_glob: bpy.props.StringProperty(default="*.binary;*.npz;*.h5;*.hdf5;*.npy", options={"HIDDEN"})
    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")
    network: bpy.props.EnumProperty(
        name="Measured material",
        items=_network_items,
        description="for a Neural-BRDF weights file (.npz, .h5) or folder of .npy files: which of its materials",
    )

    def _spec(self):
        from ..addon.core.file.nbrdf import chooser_materials, source_spec

        path = bpy.path.abspath(self.filepath) if self.filepath else ""
        names = chooser_materials(path)
        choice = self.network if self.network in names else None
        if len(names) > 1 and choice is None:
            raise ValueError(
                f"{path}: holds {len(names)} measured materials; pick one in the "
                f"'Measured material' list (e.g. {', '.join(names[:3])})"
            )
        return source_spec(path, choice)

    def invoke(self, context, event):
        # The file browser first; Blender then calls execute, which runs the analysis.
        return ImportHelper.invoke(self, context, event)

    def execute(self, context):
        win = context.window_manager.windows if context.window_manager else None
        if win and not bpy.app.background:
            # In the UI the analysis runs as the Analyse operator: threaded, with progress.
            try:
                mat = target_material(context, self.material)
                spec = self._spec()
            except ValueError as exc:
                self.report({"ERROR"}, str(exc))
                return {"CANCELLED"}
            try:
                analysis_work(spec, mat.brdf_moments.floor)  # checks the file now: the report, not a traceback
                # The material keeps its path and analysis until the job lands (Esc keeps both).
                bpy.ops.brdf_moments.analyse("INVOKE_DEFAULT", material=mat.name, filepath=spec)
            except (ValueError, RuntimeError) as exc:  # bpy.ops raises RuntimeError on an ERROR report
                text = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
                self.report({"ERROR"}, text.removeprefix("Error: "))
                return {"CANCELLED"}
            return {"FINISHED"}
        return BackgroundJob.execute(self, context)

    def start(self, context):
        mat = target_material(context, self.material)
        self._mat_name = mat.name
        self._source = self._spec()
        return analysis_work(self._source, mat.brdf_moments.floor)

    def finish(self, context, result):
        self.report({"INFO"}, store_analysis(bpy.data.materials[self._mat_name], self._source, result))
