"""The BRDF Moments UI: one drawing function, shown in Material Properties and in the 3D
view's sidebar (N panel, tab "BRDF Moments")."""

import math

import bpy


def draw_material(layout, mat):
    state = mat.brdf_moments
    row = layout.row(align=True)
    row.prop(state, "source_path", text="")
    op = row.operator("brdf_moments.load_merl", text="", icon="FILEBROWSER")
    op.material = mat.name
    layout.prop(state, "floor")
    if not state.analysed:
        row = layout.row()
        row.enabled = bool(state.source_path)
        row.operator("brdf_moments.analyse", icon="PLAY").material = mat.name
        layout.label(text="Load a MERL file (.binary) to analyse it", icon="INFO")
        return
    layout.prop(state, "kd", text="Diffuse kd")

    box = layout.box()
    box.label(text="Fits (paper Sec. 3.4, θo 0-85°)", icon="GRAPH")
    grid = box.grid_flow(columns=2, align=True)
    grid.label(text=f"μ̃ = {state.fit_mu_slope:+.3f}")
    grid.label(text=f"RMSE {state.fit_mean_rmse:.3g} rad")
    grid.label(text=f"σ̃² = {state.fit_sigma2:.4f}")
    grid.label(text=f"RMSE {state.fit_variance_rmse:.3g} rad²")
    grid.label(text=f"α̃b = {state.fit_alpha_b:.4g}")
    grid.label(text=f"RMSE {state.fit_energy_rmse:.3g}")
    box.label(text=f"energy knots θ0 {math.degrees(state.fit_theta0):.1f}°, θ1 {math.degrees(state.fit_theta1):.1f}°")
    if state.fit_notes:
        box.label(text=state.fit_notes, icon="ERROR")

    img = bpy.data.images.get(f"BRDF Moments plot: {mat.name}")
    if img is not None and getattr(img, "preview", None) is not None:
        plot = layout.box()
        plot.template_icon(icon_value=img.preview.icon_id, scale=14.0)
        col = plot.column(align=True)
        for line in filter(None, state.plot_caption.split("\n")):
            col.label(text=line)
        col.label(text="θo 0-90° (grid 15°); solid measured, dashed edited, thin fit")

    sliders = layout.box()
    sliders.label(text="Sliders", icon="MODIFIER")
    col = sliders.column()
    col.prop(state, "strength")
    col.prop(state, "colour")
    col.prop(state, "grazing_boost")
    col.prop(state, "mu_slope")
    row = col.row()
    row.enabled = not state.lock
    row.prop(state, "sigma2")
    row = col.row(align=True)
    row.prop(state, "lock")
    sub = row.row()
    sub.enabled = state.lock
    sub.prop(state, "correlation_a", text="a")
    col.row().prop(state, "mode", expand=True)
    col.prop(state, "scale_to_one")
    row = sliders.row(align=True)
    row.operator("brdf_moments.reset_sliders", icon="LOOP_BACK").material = mat.name
    row.operator("brdf_moments.apply_edit", icon="FILE_REFRESH").material = mat.name

    if state.edited_path:
        res = layout.box()
        res.label(text="Last edit", icon="CHECKMARK")
        res.label(text=f"reached μ̃ {state.achieved_mu_slope:+.3f}, σ̃² {state.achieved_sigma2:.4f}")
        res.label(text="largest albedo " + ", ".join(f"{v:.3f}" for v in state.max_albedo),
                  icon="ERROR" if max(state.max_albedo) > 1.0 else "NONE")
        for warning in filter(None, state.edit_warnings.split("\n")):
            res.label(text=warning, icon="ERROR")
    row = layout.row(align=True)
    for what, icon in (("TABLE", "EXPORT"), ("PROFILES", "TEXT"), ("PLOTS", "IMAGE_DATA")):
        op = row.operator("brdf_moments.export", text=what.title(), icon=icon)
        op.what, op.material = what, mat.name
    prev = layout.box()
    prev.label(text="Preview: original | edited", icon="SHADING_RENDERED")
    row = prev.row(align=True)
    row.prop(state, "preview_path", expand=True)
    if state.preview_path != "BAKED":
        prev.row().prop(state, "preview_mode", expand=True)
    prev.prop(state, "preview_env")
    prev.prop(state, "preview_size")
    op = prev.operator("brdf_moments.build_preview", icon="SHADING_RENDERED")
    op.material, op.use_panel_settings = mat.name, True


class MATERIAL_PT_brdf_moments(bpy.types.Panel):
    bl_label = "BRDF Moments"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return context.material is not None

    def draw(self, context):
        draw_material(self.layout, context.material)


class VIEW3D_PT_brdf_moments(bpy.types.Panel):
    bl_label = "BRDF Moments"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BRDF Moments"

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.active_material is not None

    def draw(self, context):
        draw_material(self.layout, context.object.active_material)


CLASSES = (MATERIAL_PT_brdf_moments, VIEW3D_PT_brdf_moments)
