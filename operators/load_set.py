"""Load Set: an analysed set's fits.json (``python -m addon analyze FOLDER --out DIR`` writes
DIR/fits.json) onto the material's region plot: each material's (μ̃, σ̃²) as a grey dot, and the
set's correlation fit as the quadratic's a. The file is only read; a bad one changes nothing."""

import json

import bpy
from bpy_extras.io_utils import ImportHelper

from .common import target_material


class BRDFMOMENTS_OT_load_set(bpy.types.Operator, ImportHelper):
    """Show an analysed set's materials (its fits.json, from 'python -m addon analyze') on the region plot"""

    bl_idname = "brdf_moments.load_set"
    bl_label = "Load Set"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def execute(self, context):
        from ..addon.blender.state import region_image
        from ..addon.core.fits.curves import load_set_points

        try:
            mat = target_material(context, self.material)
            if not self.filepath:
                raise ValueError("no fits.json chosen")
            path = bpy.path.abspath(self.filepath)
            points, a = load_set_points(path)  # everything checked before the state changes
        except ValueError as exc:  # UnsafePath is one: a single line naming the file
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        state = mat.brdf_moments
        state.set_data = json.dumps([[n, m, s] for n, m, s in points], separators=(",", ":"), allow_nan=False)
        state.set_path = self.filepath
        if a is not None:
            state.correlation_a = a  # its update redraws the region plot (and moves a locked σ̃²)
        else:
            region_image(mat, later=True)
        corr = f", correlation a {a:.4g}" if a is not None else ", no correlation fit in it"
        self.report({"INFO"}, f"{mat.name}: set of {len(points)} material(s) on the region plot{corr}")
        return {"FINISHED"}
