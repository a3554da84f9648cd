"""Export: the edited MERL table, the profiles as JSON, or the plots as PNG, into a folder.

File names come from the material's name through ``safe_export_path``, so they cannot
leave the chosen folder; every file is written atomically."""

import json
import os

import bpy

from .common import analysed_material


def _write_json(data, path):
    from ..addon.core.file.atomic import atomic_path

    with atomic_path(path, ".json") as tmp, open(tmp, "w") as fh:
        json.dump(data, fh, allow_nan=False)
        fh.write("\n")


def _write_png(mat, path, edited):
    """The profile figure with matplotlib where it exists, else the panel's own image."""
    import importlib.util

    from ..addon.core.file.atomic import atomic_path

    state = mat.brdf_moments
    prof = state.edited_profiles() if edited else state.profiles()
    if importlib.util.find_spec("matplotlib") is not None:
        from ..addon.tools.plots import plot_profiles

        if edited:
            # The edited table's profiles (what the edit announced is measured on this table)
            # over the measured ones they came from.
            title = f"{mat.name}: edited (thin, per channel; announced = this table's) over measured (grey)"
            plot_profiles(prof, path, title=title, measured=state.profiles())
        else:
            plot_profiles(prof, path, title=f"{mat.name} (measured)")
        return
    # Blender builds whose Python has no matplotlib (Debian's): the panel's own chart.
    from ..addon.blender.state import plot_image

    img = plot_image(mat, edited=state.edited_profiles() if edited else False)
    with atomic_path(path, ".png") as tmp:
        img.filepath_raw = tmp
        img.file_format = "PNG"
        img.save()
        img.filepath_raw = ""


class BRDFMOMENTS_OT_export(bpy.types.Operator):
    """Export the edited MERL table, the profiles (JSON) or the plots (PNG) to a folder"""

    bl_idname = "brdf_moments.export"
    bl_label = "Export"
    bl_options = {"REGISTER"}

    what: bpy.props.EnumProperty(
        name="What",
        items=[
            ("TABLE", "Edited MERL table", "the re-synthesized table (.binary)"),
            (
                "PROFILES",
                "Profiles JSON",
                "measured (and edited) moment profiles, as 'python -m addon profiles' writes",
            ),
            ("PLOTS", "Plots PNG", "the profile figures, measured and edited"),
        ],
        default="TABLE",
    )
    directory: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH")
    filter_folder: bpy.props.BoolProperty(default=True, options={"HIDDEN"})
    material: bpy.props.StringProperty(name="Material", description="source material (default: active)")

    def invoke(self, context, event):
        if bpy.app.background or self.directory:
            return self.execute(context)
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        from ..addon.core.file.safeio import run_scope

        try:
            with run_scope():
                written = self._export(context)
        except (OSError, ValueError, ArithmeticError) as exc:
            self.report({"ERROR"}, str(exc).splitlines()[0])
            return {"CANCELLED"}
        self.report({"INFO"}, "Exported " + ", ".join(written))
        return {"FINISHED"}

    def _export(self, context):
        from ..addon.core.file.cachefs import check_sealed
        from ..addon.core.file.merl import read_merl, write_merl
        from ..addon.core.file.names import distinct_name, safe_export_path

        mat = analysed_material(context, self.material)
        state = mat.brdf_moments
        folder = bpy.path.abspath(self.directory) if self.directory else ""
        if not folder or not os.path.isdir(folder):
            raise ValueError(f"{folder or 'no folder'}: choose an existing folder to export into")
        written = []
        base = distinct_name(mat.name)  # materials 'a/b' and 'a_b' never share a file
        if self.what == "TABLE":
            if not state.edited_path or not os.path.isfile(state.edited_path):
                raise ValueError(f"{mat.name}: nothing to export yet; press Apply to re-synthesize the table")
            from ..addon.core.file.sources import source_file

            dest = safe_export_path(folder, f"{base}_edited", ".binary")
            check_sealed(state.edited_path, "edited table (Apply's cache)")
            write_merl(read_merl(state.edited_path), dest, source=source_file(bpy.path.abspath(state.source_path)))
            written.append(dest)
            if state.edit_report:
                # The per-view promise beside the table (what `edit --report` writes), so anyone
                # can check the edit without the extension.
                dest = safe_export_path(folder, f"{base}_edited_report", ".json")
                _write_json(json.loads(state.edit_report), dest)
                written.append(dest)
        elif self.what == "PROFILES":
            data = {"material": mat.name, "source": state.source_path, "measured": state.profiles().to_json()}
            edited = state.edited_profiles()
            if edited is not None:
                data["edited"] = edited.to_json()
            dest = safe_export_path(folder, f"{base}_profiles", ".json")
            _write_json(data, dest)
            written.append(dest)
        else:
            for edited in (False, True):
                if edited and state.edited_profiles() is None:
                    continue
                dest = safe_export_path(folder, f"{base}_{'edited' if edited else 'measured'}_profiles", ".png")
                _write_png(mat, dest, edited)
                written.append(dest)
        return written
