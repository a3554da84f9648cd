"""The BRDF Moments UI: one drawing function, shown in Material Properties and in tabs of their
own in the 3D view's and the Shader Editor's sidebars (N panel, tab "BRDF Moments")."""

import math
import os
import textwrap

import bpy

from .live import preview_image_name


def osl_supported() -> bool:
    from .preview.osl import osl_available

    return osl_available()[0]


def wrapped(layout, text, width_px=None, icon="NONE"):
    """A whole message as several labels, wrapped to the panel's width (labels do not wrap)."""
    chars = max(24, int((width_px or 300) / 7.0))
    first = True
    for para in filter(None, text.split("\n")):
        for line in textwrap.wrap(para, chars) or [""]:
            layout.label(text=line, icon=icon if first else "BLANK1")
            first = False


def _region_width(context):
    region = getattr(context, "region", None) if context is not None else None
    scale = getattr(getattr(context, "preferences", None), "view", None)
    ui = getattr(scale, "ui_scale", 1.0) if scale is not None else 1.0
    return (region.width / max(ui, 0.5) - 40) if region is not None else 300


def _pair(col, left, right):
    """One row of two aligned cells: a value and its own error."""
    row = col.row()
    split = row.split(factor=0.5)
    split.label(text=left)
    split.label(text=right)


def _draw_region(layout, mat, width):
    """What a reciprocal table of this material can show, and (before Apply) whether the sliders
    ask for more: then the point Apply will use instead."""
    from .state import region_image_name

    state = mat.brdf_moments
    region = state.region()
    if region is None:
        return
    col = layout.column(align=True)
    point = state.requested_point()
    s2 = point[0][1] if point else state.sigma2
    lo, hi = region.mu_range(min(max(s2, region.sigma2_min), region.sigma2_max))
    col.label(
        text=f"Reachable: σ̃² {region.sigma2_min:.3g} to {region.sigma2_max:.3g}; μ̃ {lo:+.3f} to {hi:+.3f} at this σ̃²",
        icon="INFO",
    )
    if point and point[0] != point[1]:
        (mu, s2), (mu_c, s2_c) = point
        wrapped(
            col,
            f"The sliders (μ̃ {mu:+.3f}, σ̃² {s2:.4g}) ask for more than a reciprocal table of this "
            f"material shows: Apply will use the nearest reachable point, μ̃ {mu_c:+.3f}, σ̃² {s2_c:.4g}",
            width,
            icon="ERROR",
        )
    # An analysed set's materials on the plot (grey dots): Load Set reads analyze's fits.json.
    row = col.row(align=True)
    if state.set_data:
        count = len(state.set_points())
        name = os.path.basename(bpy.path.abspath(state.set_path)) or "set"
        row.label(text=f"Set: {name} ({count} material{'s' if count != 1 else ''})", icon="OUTLINER_DATA_POINTCLOUD")
    else:
        row.label(text="Set: none (fits.json of 'analyze')", icon="OUTLINER_DATA_POINTCLOUD")
    row.operator("brdf_moments.load_set", text="Load Set…", icon="FILEBROWSER").material = mat.name
    if state.set_data or state.set_path:
        row.operator("brdf_moments.clear_set", text="", icon="X").material = mat.name
    img = bpy.data.images.get(region_image_name(mat))
    if img is not None:
        row = col.row(align=True)
        row.label(text="Region plot")
        row.operator("brdf_moments.show_image", text="Open full size", icon="WINDOW").image = img.name
        if getattr(img, "preview", None) is not None:
            col.template_icon(icon_value=img.preview.icon_id, scale=8.0)


def draw_material(layout, mat, context=None):
    state = mat.brdf_moments
    width = _region_width(context)
    col = layout.column(align=True)
    name = os.path.basename(bpy.path.abspath(state.source_path)) if state.source_path else "no file"
    row = col.row(align=True)
    row.label(text=name, icon="FILE")
    op = row.operator("brdf_moments.load_merl", text="Load MERL…", icon="FILEBROWSER")
    op.material = mat.name
    if state.source_path:
        sub = row.row(align=True)
        sub.operator(
            "brdf_moments.analyse", text="Analyse again" if state.analysed else "Analyse", icon="FILE_REFRESH"
        ).material = mat.name
    layout.prop(state, "floor")
    if not state.analysed:
        layout.label(text="Load a MERL file (.binary) to analyse it", icon="INFO")
        return

    # kd: read-only numbers and the diffuse albedo's swatch
    row = layout.row(align=True)
    split = row.split(factor=0.75)
    split.label(text="kd  " + "  ".join(f"{v:.4g}" for v in state.kd))
    swatch = split.row()
    swatch.enabled = False
    swatch.prop(state, "kd_albedo", text="")

    box = layout.box()
    box.label(text="Fits (paper Sec. 3.4, θo 0-85°)", icon="GRAPH")
    col = box.column(align=True)
    _pair(col, f"μ̃ = {state.fit_mu_slope:+.4g}", f"RMSE {state.fit_mean_rmse:.3g} rad")
    _pair(col, f"σ̃² = {state.fit_sigma2:.4g}", f"RMSE {state.fit_variance_rmse:.3g} rad²")
    _pair(col, f"α̃b = {state.fit_alpha_b:.4g}", f"RMSE {state.fit_energy_rmse:.3g}")
    col.label(text=f"energy knots θ0 {math.degrees(state.fit_theta0):.1f}°, θ1 {math.degrees(state.fit_theta1):.1f}°")
    if state.fit_notes:
        wrapped(box.column(align=True), state.fit_notes, width, icon="ERROR")

    img = bpy.data.images.get(f"BRDF Moments plot: {mat.name}")
    plot = layout.box()
    row = plot.row(align=True)
    row.label(text="Profiles", icon="IMAGE_DATA")
    row.operator("brdf_moments.show_image", text="Open full size", icon="WINDOW").image = (
        img.name if img is not None else ""
    )
    if img is not None and getattr(img, "preview", None) is not None:
        plot.template_icon(icon_value=img.preview.icon_id, scale=10.0)

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
    row = col.row(align=True)
    row.label(text="Material shader")
    osl = osl_supported()
    if osl:
        row.prop(state, "artist_shader", text="")
    else:  # no OSL in this Blender: the approximations
        row.prop(state, "artist_shader", text="")
    if state.artist_shader in {"AUTO", "OSL", "LOBES"}:
        row = col.row(align=True)
        row.label(text="Table texture")
        row.prop(state, "texture_storage", text="")
    _draw_region(sliders, mat, width)
    row = sliders.row(align=True)
    row.operator("brdf_moments.reset_sliders", icon="LOOP_BACK").material = mat.name
    row.operator("brdf_moments.apply_edit", icon="CHECKMARK").material = mat.name

    if state.edited_path:
        res = layout.box()
        res.label(text="Last edit", icon="CHECKMARK")
        res.label(text=f"reached μ̃ {state.achieved_mu_slope:+.4g}, σ̃² {state.achieved_sigma2:.4g}")
        fid = state.fidelity()
        if fid is not None:
            from ..core.edit.fidelity import describe

            wrapped(res.column(align=True), describe(fid), width, icon="NONE" if fid["meets"] else "INFO")
        res.label(
            text="largest albedo " + ", ".join(f"{v:.3f}" for v in state.max_albedo),
            icon="ERROR" if max(state.max_albedo) > 1.0 else "NONE",
        )
        for warning in filter(None, state.edit_warnings.split("\n")):
            wrapped(res.column(align=True), warning, width, icon="ERROR")
    from .material import is_applied

    if is_applied(mat):
        res = layout.box()
        used = state.artist_shader_used
        fit = state.principled_fit() if used == "principled" else None
        lobes = state.lobes_fit() if used == "lobes" else None
        col = res.column(align=True)
        if lobes is not None:
            wrapped(
                col,
                f"'{mat.name}' renders {lobes.n_lobes} GGX lobes and a diffuse lobe fitted to the edited table, "
                f"their colours following the view angle: an approximation, BRDF error {100 * lobes.error:.1f} % "
                f"(cosine-weighted), albedo within {100 * lobes.albedo_error:.1f} %",
                width,
                icon="INFO",
            )
        elif fit is not None:
            wrapped(
                col,
                f"'{mat.name}' renders a Principled BSDF fitted to the edited table: an approximation, "
                f"BRDF error {100 * fit.error:.1f} % (cosine-weighted), albedo within "
                f"{100 * fit.albedo_error:.1f} %",
                width,
                icon="INFO",
            )
        elif used == "osl":
            wrapped(
                col,
                f"'{mat.name}' renders the edited table (OSL tabulated shader, Cycles with OSL)",
                width,
                icon="INFO",
            )
        else:
            wrapped(col, f"'{mat.name}' renders an earlier edit", width, icon="INFO")
        res.operator("brdf_moments.restore_material", icon="LOOP_BACK").material = mat.name
    row = layout.row(align=True)
    row.label(text="Export")
    for what, icon in (("TABLE", "EXPORT"), ("PROFILES", "TEXT"), ("PLOTS", "IMAGE_DATA")):
        op = row.operator("brdf_moments.export", text=what.title(), icon=icon)
        op.what, op.material = what, mat.name
    prev = layout.box()
    prev.label(text="Preview: original | edited", icon="SHADING_RENDERED")
    col = prev.column()
    if osl_supported():
        col.row().prop(state, "preview_path", expand=True)
    else:
        col.label(text="Baked path (this Blender has no OSL)")
    col.prop(state, "preview_mode", text="Shows")
    if state.preview_mode == "MODEL":
        col.label(text="a sketch of the fits, not the material", icon="ERROR")
    col.prop(state, "preview_env")
    col.prop(state, "preview_size")
    row = prev.row(align=True)
    op = row.operator("brdf_moments.build_preview", icon="RENDER_STILL")
    op.material, op.use_panel_settings = mat.name, True
    pimg = bpy.data.images.get(preview_image_name(mat))
    if pimg is not None:
        row.operator("brdf_moments.show_image", text="Open full size", icon="WINDOW").image = pimg.name
        if getattr(pimg, "preview", None) is not None:
            prev.template_icon(icon_value=pimg.preview.icon_id, scale=12.0)


class MATERIAL_PT_brdf_moments(bpy.types.Panel):
    bl_label = "BRDF Moments"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    # Registered types are sorted by this; a Properties editor that already lists its panels
    # (any saved layout) appends a new one at the end: the tabs in the 3D view's and the
    # Shader Editor's sidebars are where it is always at the top.
    bl_order = -100

    @classmethod
    def poll(cls, context):
        return context.material is not None

    def draw(self, context):
        draw_material(self.layout, context.material, context)


class VIEW3D_PT_brdf_moments(bpy.types.Panel):
    bl_label = "BRDF Moments"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BRDF Moments"

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.active_material is not None

    def draw(self, context):
        draw_material(self.layout, context.object.active_material, context)


class NODE_PT_brdf_moments(bpy.types.Panel):
    """The same panel in the Shader Editor's sidebar: a tab of its own, next to the material's nodes."""

    bl_label = "BRDF Moments"
    bl_space_type = "NODE_EDITOR"
    bl_region_type = "UI"
    bl_category = "BRDF Moments"

    @classmethod
    def poll(cls, context):
        space = context.space_data
        obj = context.object
        return (
            getattr(space, "tree_type", "") == "ShaderNodeTree" and obj is not None and obj.active_material is not None
        )

    def draw(self, context):
        draw_material(self.layout, context.object.active_material, context)


CLASSES = (MATERIAL_PT_brdf_moments, VIEW3D_PT_brdf_moments, NODE_PT_brdf_moments)
