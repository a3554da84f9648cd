"""Load a MERL file into the active material: read, analyse, fit, store."""

import bpy
from bpy_extras.io_utils import ImportHelper


def target_material(context, name=""):
    if name:
        return bpy.data.materials.get(name)
    mat = getattr(context, "material", None)
    if mat is None and context.object is not None:
        mat = context.object.active_material
    return mat


class BRDFMOMENTS_OT_load_merl(bpy.types.Operator, ImportHelper):
    """Load a measured BRDF (MERL .binary) and analyse its moment profiles"""

    bl_idname = "brdf_moments.load_merl"
    bl_label = "Load MERL"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".binary"
    filter_glob: bpy.props.StringProperty(default="*.binary", options={"HIDDEN"})
    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def execute(self, context):
        from ..addon.core.fits import fit_material
        from ..addon.core.merl import MerlError, read_merl
        from ..addon.core.profiles import compute_profiles

        mat = target_material(context, self.material)
        if mat is None:
            self.report({"ERROR"}, "No material to load into: select an object with a material")
            return {"CANCELLED"}
        try:
            table = read_merl(self.filepath)
            prof = compute_profiles(table)
            fit = fit_material(prof)
        except MerlError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except (OSError, ValueError, MemoryError) as exc:
            self.report({"ERROR"}, f"{self.filepath}: {exc}")
            return {"CANCELLED"}
        state = mat.brdf_moments
        state.source_path = self.filepath
        state.store_analysis(prof, fit)
        self.report({"INFO"}, f"Analysed {table.name}: μ̃ {state.fit_mu_slope:+.3f}, σ̃² {state.fit_sigma2:.4f}")
        return {"FINISHED"}
