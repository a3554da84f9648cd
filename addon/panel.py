"""The BRDF Moments panel in Material Properties."""

import bpy


class MATERIAL_PT_brdf_moments(bpy.types.Panel):
    bl_label = "BRDF Moments"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return context.material is not None

    def draw(self, context):
        layout = self.layout
        state = context.material.brdf_moments
        row = layout.row()
        row.prop(state, "source_path", text="")
        row.operator("brdf_moments.load_merl", text="", icon="FILEBROWSER")
        if not state.analysed:
            layout.label(text="Load a MERL file to analyse it", icon="INFO")
            return
        col = layout.column(align=True)
        col.prop(state, "kd", text="Diffuse kd")
        box = layout.box()
        box.label(text="Fits (paper Sec. 3.4)")
        grid = box.grid_flow(columns=2, align=True)
        grid.label(text=f"μ̃ = {state.fit_mu_slope:+.3f}")
        grid.label(text=f"RMSE {state.fit_mean_rmse:.3g} rad")
        grid.label(text=f"σ̃² = {state.fit_sigma2:.4f}")
        grid.label(text=f"RMSE {state.fit_variance_rmse:.3g} rad²")
        grid.label(text=f"α̃b = {state.fit_alpha_b:.4g}")
        grid.label(text=f"RMSE {state.fit_energy_rmse:.3g}")
        if state.fit_notes:
            box.label(text=state.fit_notes, icon="ERROR")
        sliders = layout.column()
        sliders.prop(state, "strength")
        sliders.prop(state, "colour")
        sliders.prop(state, "grazing_boost")
        sliders.prop(state, "mu_slope")
        sliders.prop(state, "sigma2")
        sliders.prop(state, "mode", expand=True)
