"""Build Preview: original and edited spheres side by side under an HDRI, in their own
scene ("BRDF Moments Preview"), through the OSL shader or the baked path."""

import os

import bpy

from .common import analysed_material

SCENE = "BRDF Moments Preview"


class BRDFMOMENTS_OT_build_preview(bpy.types.Operator):
    """Render original and edited on spheres: OSL (live sliders in moment-model mode) or baked"""

    bl_idname = "brdf_moments.build_preview"
    bl_label = "Build Preview"
    bl_options = {"REGISTER", "UNDO"}

    material: bpy.props.StringProperty(name="Material", description="source material (default: active)")
    path: bpy.props.EnumProperty(name="Path", default="AUTO", items=[
        ("AUTO", "Auto", "OSL where this Cycles has it, else baked"), ("OSL", "OSL", ""), ("BAKED", "Baked", "")])
    mode: bpy.props.EnumProperty(name="OSL mode", default="MODEL", items=[
        ("MODEL", "Moment model", ""), ("TABULATED", "Tabulated", "")])
    env: bpy.props.StringProperty(name="Environment", description="bundled HDRI name or file (empty: default)")
    size: bpy.props.IntProperty(name="Size", default=256, min=16, max=4096,
                                description="sphere size in pixels; the render is two spheres wide")
    samples: bpy.props.IntProperty(name="Samples", default=16, min=1, max=4096)
    render_to: bpy.props.StringProperty(name="Render to", subtype="FILE_PATH",
                                        description="also render a still here (.png display-referred, .exr linear)")
    use_panel_settings: bpy.props.BoolProperty(default=False, options={"HIDDEN"})

    def execute(self, context):
        try:
            info = self._build(context)
        except (OSError, ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            return {"CANCELLED"}
        self.report({"INFO"}, info)
        return {"FINISHED"}

    def _build(self, context):
        from ..addon.core.merl import read_merl
        from ..addon.core.nbrdf import read_table, source_exists
        from ..addon.preview import build_preview, render_still

        mat = analysed_material(context, self.material)
        state = mat.brdf_moments
        if self.use_panel_settings:
            self.path, self.mode, self.env, self.size = (state.preview_path, state.preview_mode, state.preview_env,
                                                         state.preview_size)
        path, mode = self.path.lower(), self.mode.lower()
        source = bpy.path.abspath(state.source_path)
        live = mode == "model" and path in ("osl", "auto")
        if source_exists(source):
            original = read_table(source)  # a MERL file, or FILE:NAME of a network
        elif live or path == "baked":
            original = state.model_params()  # the .blend outlived its MERL file: the fitted model stands in
        else:
            raise ValueError(f"{source}: the source MERL file is missing; load it again for a tabulated preview")
        # The edited sphere: the re-synthesized table if Apply made one, else the sliders'
        # moment model (what the OSL model path renders live anyway).
        if state.edited_path and os.path.isfile(state.edited_path) and not live:
            edited = read_merl(state.edited_path)
        else:
            edited = state.model_params(edited=True)
        scene = bpy.data.scenes.get(SCENE) or bpy.data.scenes.new(SCENE)
        info = build_preview(scene, original, edited, path=path, mode=mode, env=self.env or None,
                             size=(2 * self.size, self.size),
                             samples=self.samples,
                             profiles=[state.profiles() if original is not None and hasattr(original, "rho") else None,
                                       state.edited_profiles() if hasattr(edited, "rho") else None])
        state.preview_material = info.materials[-1]
        if context.window is not None and not bpy.app.background:
            context.window.scene = scene  # show it; the user's own scene is untouched
        text = f"Preview ({info.path}{', ' + info.mode if info.path == 'osl' else ''}) in scene '{SCENE}'"
        if self.render_to:
            out = bpy.path.abspath(self.render_to)
            render_still(scene, out)
            text += f", rendered to {out}"
        return text + "".join(f"; {n}" for n in info.notes)
