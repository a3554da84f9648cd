"""The BRDF Moments UI, laid out for Blender's default widths: the 3D view's and the Shader
Editor's sidebars (N, tab "BRDF Moments", about 190 px of content in 3.4 at 1920x1080) and
Material Properties (about 270 px).

One main panel (the file, Load, Analyse, the diffuse floor) and sub-panels that fold: Fits,
Chart, Edit, Result, Preview, Export and Details (closed at first: the long text lives there).
Every label goes through a helper that knows the width its cell gets: short labels with icons,
numbers that fit, longer text wrapped at that width (measured with ``blf``, the UI's own
font). The windowed lane switches ``AUDIT`` on and checks each recorded cell against the text
it holds (tests/windowed/drive.py).

In Material Properties the main panel has no header of its own: Blender puts a header panel
that a saved layout has never seen after the panels it already lists (the engine's), while a
header-less one goes in with the header-less panels at the top, under the material's slots.
The sub-panels keep their headers, so every section still folds.

``draw_material`` draws the whole panel into one layout (the headless tests use it)."""

import json
import math
import os

import bpy

from . import icons, lifecycle
from .live import preview_image_name

# --- measuring ------------------------------------------------------------------------------

DEFAULT_WIDTH = 300.0  # content width when there is no region (headless tests)
AUDIT = None  # a list while the windowed lane checks the labels: one dict per text cell
_PANEL = [""]  # the panel being drawn, for the audit


_OSL: list = []


def osl_supported() -> bool:
    """Whether this Blender has OSL (asked once: the question looks for a module on disk)."""
    if not _OSL:
        from .preview.osl import osl_available

        _OSL.append(osl_available()[0])
    return _OSL[0]


_MEMO: dict = {}  # (what, material, its inputs) -> the answer: the panel redraws often, inputs rarely change


def _memo(what, state, inputs, compute):
    key = (what, state.id_data.name, inputs)
    if key not in _MEMO:
        if len(_MEMO) > 64:
            _MEMO.clear()
        _MEMO[key] = compute()
    return _MEMO[key]


def region_of(state):
    """``state.region()``, parsed once per stored region and mode."""
    return _memo("region", state, (hash(state.region_data), state.mode), state.region)


def requested_point(state):
    """``state.requested_point()`` (the region's clamp of the sliders), once per slider setting."""
    inputs = (
        hash(state.region_data),
        hash(state.fit_data),
        state.mode,
        state.mu_slope,
        state.sigma2,
        state.lock,
        state.correlation_a,
        state.strength,
        tuple(state.colour),
        state.grazing_boost,
    )
    return _memo("point", state, inputs, state.requested_point)


def _scale():
    """The interface scale (0 in a headless Blender, which has no window: taken as 1)."""
    return bpy.context.preferences.system.ui_scale or 1.0


def ui_unit():
    """Blender's widget unit in pixels (UI_UNIT_X: 20 at 72 dpi and scale 1)."""
    system = bpy.context.preferences.system
    pixel = getattr(system, "pixel_size", 1.0) or 1.0
    if bpy.app.version >= (4, 0, 0) or not getattr(system, "dpi", 0):
        return int(round(18.0 * _scale())) + 2 * pixel
    return int((20 * system.dpi * pixel + 36) / 72)


def font_size():
    """The UI's label font size in pixels (the style's points at the interface scale)."""
    style = bpy.context.preferences.ui_styles[0]
    points = getattr(getattr(style, "widget_label", None), "points", 11.0)
    return points * _scale()


def text_width(text, size=None):
    """``text``'s width in pixels in the UI font (blf), or an estimate when blf cannot say."""
    try:
        import blf

        try:
            blf.size(0, size or font_size())
        except TypeError:  # Blender before 4.0 also takes a dpi
            blf.size(0, size or font_size(), 72)
        return blf.dimensions(0, text)[0]
    except Exception:  # noqa: BLE001 - no font (a bare headless module): the old estimate
        return 7.0 * len(text)


def content_width(context):
    """The width a panel's layout gets in ``context.region`` (pixels). Measured on Blender 3.4's
    screenshots: the layout keeps 0.4 unit each side inside the region (Properties: 303 px
    region, 287 px of buttons); a sidebar also loses its column of category tabs (1 unit) and,
    with region overlap, 0.4 unit each side around its floating panels (229 px region, 175 px)."""
    region = getattr(context, "region", None) if context is not None else None
    if region is None or region.width <= 1:
        return DEFAULT_WIDTH
    unit = ui_unit()
    width = region.width - 0.8 * unit
    if region.type == "UI":
        width -= 1.8 * unit
    return max(width, 4 * unit)


# Padding a cell needs beside its text: Blender's text margin (0.4 unit) on each side of a
# button's text, an icon's unit, a drop-down's arrow, a checkbox's box.
PADDING = {"label": 0.5, "button": 0.9, "menu": 1.9, "slider": 1.3, "check": 1.5}


def needed(text, kind="label", icon=False, size=None):
    """Pixels a cell needs to show ``text`` whole."""
    unit = ui_unit()
    return text_width(text, size) + PADDING[kind] * unit + (unit if icon else 0.0)


def _record(text, kind, icon, avail):
    if AUDIT is not None and text:
        AUDIT.append({"panel": _PANEL[0], "text": text, "kind": kind, "icon": bool(icon), "avail": float(avail)})


class Cells:
    """The width of what is being drawn, carried along with the layout: ``w`` pixels."""

    def __init__(self, context, width=None):
        self.context = context
        self.w = float(width if width is not None else content_width(context))

    def part(self, frac):
        out = Cells(self.context, self.w * frac)
        return out


def label(layout, cells, text, icon="NONE"):
    """One label in a cell of width ``cells.w``: recorded for the audit."""
    layout.label(text=text, icon=icon)
    _record(text, "label", icon != "NONE", cells.w)


def fit(cells, variants, kind="label", icon=False):
    """The first of ``variants`` (longest first) that fits the cell; else the last."""
    for text in variants:
        if needed(text, kind, icon) <= cells.w:
            return text
    return variants[-1]


def wrap(text, cells, icon=False):
    """``text`` in lines that fit the cell (measured), words kept whole unless one alone is
    wider than the cell (a long file name), which is then broken where it must be."""
    room = cells.w - needed("", "label", icon)
    lines = []
    for para in filter(None, text.split("\n")):
        line = ""
        for word in para.split(" "):
            trial = f"{line} {word}" if line else word
            if text_width(trial) <= room:
                line = trial
                continue
            if line:
                lines.append(line)
            while text_width(word) > room and len(word) > 1:
                cut = len(word) - 1
                while cut > 1 and text_width(word[:cut]) > room:
                    cut -= 1
                lines.append(word[:cut])
                word = word[cut:]
            line = word
        if line:
            lines.append(line)
    return lines or [""]


def wrapped(layout, text, cells, icon="NONE"):
    """A whole message as several labels, wrapped to the cell's width (labels do not wrap)."""
    col = layout.column(align=True)
    for k, line in enumerate(wrap(text, cells, icon != "NONE")):
        label(col, cells, line, icon if k == 0 else ("BLANK1" if icon != "NONE" else "NONE"))


def button(layout, cells, idname, text, icon="NONE", **props):
    op = layout.operator(idname, text=text, icon=icon)
    for key, value in props.items():
        setattr(op, key, value)
    _record(text, "button", icon != "NONE", cells.w)
    return op


def prop(layout, cells, owner, attr, text=None, kind="slider", icon="NONE", shown=None, **kw):
    """A property with the text it shows (``shown``: name and value, or the menu's item)."""
    kwargs = dict(kw)
    if text is not None:
        kwargs["text"] = text
    if icon != "NONE":
        kwargs["icon"] = icon
    layout.prop(owner, attr, **kwargs)
    _record(shown if shown is not None else (text or ""), kind, icon != "NONE", cells.w)


def _value(owner, attr):
    """A float property's value as Blender shows it (its precision)."""
    rna = owner.bl_rna.properties[attr]
    return f"{getattr(owner, attr):.{getattr(rna, 'precision', 3)}f}"


_ITEM_NAMES: dict = {}  # (type, property) -> {identifier: name}: enum items are fixed once registered


def _item_name(owner, attr):
    key = (type(owner).__name__, attr)
    if key not in _ITEM_NAMES:
        _ITEM_NAMES[key] = {i.identifier: i.name for i in owner.bl_rna.properties[attr].enum_items}
    value = getattr(owner, attr)
    return _ITEM_NAMES[key].get(value, str(value))


def _split(layout, cells, factor):
    split = layout.split(factor=factor, align=True)
    return split, cells.part(factor), cells.part(1.0 - factor)


def _num(v, digits=4):
    return f"{v:.{digits}g}"


# --- the sections -------------------------------------------------------------------------


def draw_main(layout, mat, cells, title=False):
    """The file, Load and Analyse, the diffuse floor. ``title``: Material Properties, where the
    main panel has no header, names itself; there a material with no file takes two rows."""
    state = mat.brdf_moments
    col = layout.column()
    if not state.source_path:
        split, left, right = _split(col, cells, 0.5)
        label(split, left, "BRDF Moments" if title else "No file", "MATERIAL" if title else "FILE")
        button(split, right, "brdf_moments.load_merl", "Load…", "FILEBROWSER", material=mat.name)
    else:
        if title:
            label(col, cells, "BRDF Moments", "MATERIAL")
        wrapped(col, os.path.basename(bpy.path.abspath(state.source_path)), cells, icon="FILE")
        row = col.row(align=True)
        button(row, cells.part(0.5), "brdf_moments.load_merl", "Load…", "FILEBROWSER", material=mat.name)
        button(row, cells.part(0.5), "brdf_moments.analyse", "Analyse", "FILE_REFRESH", material=mat.name)
    split, left, right = _split(col, cells, 0.4)
    label(split, left, "Floor")
    prop(split, right, state, "floor", text="", kind="menu", shown=_item_name(state, "floor"))
    if not state.analysed and not title:
        wrapped(col, "Load a MERL table or a Neural-BRDF file to analyse it", cells, icon="INFO")


def draw_fits(layout, mat, cells):
    """The fitted μ̃, σ̃², α̃b (4 significant digits) beside their fit errors, the diffuse swatch."""
    state = mat.brdf_moments
    col = layout.column(align=True)
    split, left, right = _split(col, cells, 0.55)
    split.active = False  # the columns' heads
    label(split, left, "Fit")
    label(split, right, "RMSE")
    for left_text, right_text in (
        (f"μ̃ = {state.fit_mu_slope:+.4g}", f"{state.fit_mean_rmse:.3g} rad"),
        (f"σ̃² = {state.fit_sigma2:.4g}", f"{state.fit_variance_rmse:.3g} rad²"),
        (f"α̃b = {state.fit_alpha_b:.4g}", f"{state.fit_energy_rmse:.3g}"),
    ):
        split, left, right = _split(col, cells, 0.55)
        label(split, left, left_text)
        label(split, right, right_text)
    split, left, right = _split(col, cells, 0.55)
    label(split, left, "Diffuse π·kd")
    swatch = split.row()
    swatch.enabled = False
    prop(swatch, right, state, "kd_albedo", text="", kind="label", shown="")
    if state.fit_notes:
        wrapped(layout, state.fit_notes, cells, icon="ERROR")


CHARTS = [
    ("ENERGY", "Energy α", "energy per channel against the view elevation, with the fitted spline"),
    ("MEAN", "Mean μθ", "the lobe's mean angle against the view elevation, with the fitted line μ̃ θo"),
    ("VARIANCE", "Variance σ²", "the lobe's variance against the view elevation, with the fitted constant σ̃²"),
    ("REGION", "Reachable", "what a reciprocal table of this material can show on the (μ̃, σ̃²) plane"),
]


def draw_chart(layout, mat, cells):
    """One chart at a time, chosen above it, drawn at the size the panel shows it."""
    from .state import region_image_name

    wm = bpy.context.window_manager
    kind = getattr(wm, "brdf_moments_chart", "ENERGY")
    row = layout.row(align=True)
    rest = cells.part(1.0)
    rest.w -= ui_unit()
    prop(row, rest, wm, "brdf_moments_chart", text="", kind="menu", shown=dict((k, n) for k, n, _ in CHARTS)[kind])
    name = region_image_name(mat) if kind == "REGION" else f"BRDF Moments plot: {mat.name}"
    img = bpy.data.images.get(name)
    row.operator("brdf_moments.show_image", text="", icon="FULLSCREEN_ENTER").image = img.name if img else ""
    side = int(cells.w) - 8  # Blender draws a preview 4 px inside its button on each side
    icon = chart_icon(mat, kind, side)
    if icon is not None:
        layout.template_icon(icon_value=icon, scale=(side + 8.5) / ui_unit())
    elif chart_failed(mat, kind, side):
        wrapped(layout, "No chart: nothing to draw for this material", cells, icon="INFO")
    else:
        label(layout, cells, "Drawing…", "TIME")


def _draw_announced(layout, state, cells=None):
    """What Apply will deliver for the sliders as they stand, in one row under them: the slope
    and variance it reaches, the share of views out of reach, whether it clamps. Empty until
    the state holds ``announced_json`` (keys mu_slope, sigma2, out_of_reach, clamped)."""
    raw = getattr(state, "announced_json", "")
    if not raw:
        return
    try:
        d = json.loads(raw)
        mu, s2 = float(d["mu_slope"]), float(d["sigma2"])
        out, clamped = float(d.get("out_of_reach", 0.0)), bool(d.get("clamped", False))
    except (ValueError, TypeError, KeyError):
        return
    if not (math.isfinite(mu) and math.isfinite(s2) and math.isfinite(out)):
        return
    cells = cells or Cells(None)
    if d.get("nothing_to_do"):  # clamped back onto the fit: Apply would change no lobe (SPEC §3)
        label(
            layout.row(), cells, fit(cells, ["Nothing to do: clamped to the fit", "Nothing to do"], icon=True), "ERROR"
        )
        return
    pct = 100.0 * min(max(out, 0.0), 1.0)
    icon = "ERROR" if clamped else "FORWARD"
    text = fit(
        cells,
        [
            f"Delivers μ̃ {mu:+.3f}, σ̃² {s2:.4g}, {pct:.0f} % out{', clamped' if clamped else ''}",
            f"μ̃ {mu:+.3f} σ̃² {s2:.3g} · {pct:.0f} % out",
            f"μ̃ {mu:+.2f} σ̃² {s2:.2g} · {pct:.0f}%",
        ],
        icon=True,
    )
    label(layout.row(), cells, text, icon)


def draw_edit(layout, mat, cells):
    """The spheres (measured, edited live), the sliders, what Apply will use, the reachable
    region, Reset and Apply."""
    state = mat.brdf_moments
    col = layout.column()
    # The spheres are the artist's feedback while the sliders move: right above them, in sight
    # whenever the sliders are (the Preview section below holds how they are rendered).
    _draw_spheres(col, mat, cells)
    for attr in ("strength", "grazing_boost", "mu_slope"):
        rna = state.bl_rna.properties[attr]
        prop(col, cells, state, attr, shown=f"{rna.name}  {_value(state, attr)}")
    split, left, right = _split(col, cells, 0.45)
    label(split, left, "Colour")
    prop(split, right, state, "colour", text="", kind="label", shown="")
    row = col.row()
    row.enabled = not state.lock
    prop(row, cells, state, "sigma2", shown=f"{state.bl_rna.properties['sigma2'].name}  {_value(state, 'sigma2')}")
    _draw_announced(col, state, cells)
    prop(col, cells, state, "lock", kind="check", shown=state.bl_rna.properties["lock"].name)
    row = col.row()
    row.enabled = state.lock
    prop(
        row,
        cells,
        state,
        "correlation_a",
        text="Correlation a",
        shown=f"Correlation a  {_value(state, 'correlation_a')}",
    )
    row = col.row(align=True)
    for item in state.bl_rna.properties["mode"].enum_items:
        _record(item.name, "button", False, cells.w / 2)
    row.prop(state, "mode", expand=True)
    prop(col, cells, state, "scale_to_one", kind="check", shown=state.bl_rna.properties["scale_to_one"].name)
    row = col.row(align=True)
    icon_cell, rest = cells.part(0.0), cells.part(1.0)
    icon_cell.w, rest.w = ui_unit(), cells.w - ui_unit()
    row.label(text="", icon="NODE_MATERIAL")
    # Every Blender has a choice: OSL where it runs, the two approximations everywhere.
    prop(row, rest, state, "artist_shader", text="", kind="menu", shown=_item_name(state, "artist_shader"))
    if state.artist_shader in {"AUTO", "OSL", "LOBES"}:
        row = col.row(align=True)
        row.label(text="", icon="PACKAGE")
        prop(row, rest, state, "texture_storage", text="", kind="menu", shown=_item_name(state, "texture_storage"))
    _draw_region(layout, mat, cells)
    row = layout.row(align=True)
    button(row, cells.part(0.5), "brdf_moments.reset_sliders", "Reset", "LOOP_BACK", material=mat.name)
    button(row, cells.part(0.5), "brdf_moments.apply_edit", "Apply", "CHECKMARK", material=mat.name)


def _draw_region(layout, mat, cells):
    """What a reciprocal table of this material can show, and (before Apply) whether the
    sliders ask for more: then the point Apply will use instead."""
    state = mat.brdf_moments
    region = region_of(state)
    if region is None:
        return
    col = layout.column(align=True)
    point = requested_point(state)
    s2 = point[0][1] if point else state.sigma2
    lo, hi = region.mu_range(min(max(s2, region.sigma2_min), region.sigma2_max))
    label(col, cells, "Reachable", "INFO")
    s2_range = f"{region.sigma2_min:.3g} – {region.sigma2_max:.3g}"
    s2_text = fit(cells, [f"σ̃² {s2_range}", f"σ̃² {region.sigma2_min:.2g} – {region.sigma2_max:.2g}"], icon=True)
    label(col, cells, s2_text, "BLANK1")  # under the heading's text
    mu_texts = [f"μ̃ {lo:+.3f} – {hi:+.3f} at this σ̃²", f"μ̃ {lo:+.3f} – {hi:+.3f}", f"μ̃ {lo:+.2f} – {hi:+.2f}"]
    label(col, cells, fit(cells, mu_texts, icon=True), "BLANK1")
    if point and point[0] != point[1]:
        (mu, s2), (mu_c, s2_c) = point
        wrapped(
            col,
            f"The sliders (μ̃ {mu:+.3f}, σ̃² {s2:.4g}) ask for more than a reciprocal table of this "
            f"material shows: Apply will use the nearest reachable point, μ̃ {mu_c:+.3f}, σ̃² {s2_c:.4g}",
            cells,
            icon="ERROR",
        )
    # An analysed set's materials on the region chart (grey dots): Load Set reads analyze's fits.json.
    if state.set_data:
        count = len(state.set_points())
        name = os.path.basename(bpy.path.abspath(state.set_path)) or "set"
        wrapped(col, f"Set: {name} ({count} material{'s' if count != 1 else ''})", cells, "OUTLINER_DATA_POINTCLOUD")
    row = col.row(align=True)
    clear = bool(state.set_data or state.set_path)
    load = cells.part(1.0)
    load.w -= ui_unit() if clear else 0.0
    button(row, load, "brdf_moments.load_set", "Load Set…", "FILEBROWSER", material=mat.name)
    if clear:
        row.operator("brdf_moments.clear_set", text="", icon="X").material = mat.name


def _figure(word, value):
    """'error 13.3 %' with no-break spaces: a wrapped line never parts a figure from its word or
    its unit (the sidebar's default width wraps the error and the bound, issue 37.4)."""
    return f"{word}\u00a0{100 * value:.1f}\u00a0%"


def _renders(mat):
    """What the material renders since Apply: (short line, whole sentence), or None."""
    from .material import is_applied

    if not is_applied(mat):
        return None
    state = mat.brdf_moments
    used = state.artist_shader_used
    lobes = state.lobes_fit() if used == "lobes" else None
    if lobes is not None:
        bound = f", {_figure('bound', lobes.bound)}" if lobes.bound is not None else ""
        return (
            f"Renders lobes ≈ ({_figure('error', lobes.error)}{bound})",
            f"'{mat.name}' renders {lobes.n_lobes} lobes ({lobes.describe()})"
            + (" and a diffuse lobe" if lobes.has_diffuse else "")
            + " fitted to the "
            f"edited table, their colours{' and stretch' if lobes.anisotropic else ''} following the view angle: "
            f"an approximation, BRDF error {100 * lobes.error:.1f} % (cosine-weighted, as Cycles renders it"
            f"), albedo within {100 * lobes.albedo_error:.1f} %"
            + (
                f"; the least error any mix of Blender's closures reaches on this table is {100 * lobes.bound:.1f} %"
                if lobes.bound is not None
                else ""
            ),
        )
    shader = state.principled_fit() if used == "principled" else None
    if shader is not None:
        bound = state.principled_bound()
        said = f", {_figure('bound', bound)}" if bound is not None else ""
        return (
            f"Renders Principled ≈ ({_figure('error', shader.error)}{said})",
            f"'{mat.name}' renders a Principled BSDF fitted to the edited table: an approximation, "
            f"BRDF error {100 * shader.error:.1f} % (cosine-weighted), albedo within "
            f"{100 * shader.albedo_error:.1f} %"
            + (
                f"; the least error any mix of Blender's closures reaches on this table is {100 * bound:.1f} %"
                if bound is not None
                else ""
            ),
        )
    if used == "osl":
        return (
            "Renders the edited table (OSL)",
            f"'{mat.name}' renders the edited table (OSL tabulated shader, Cycles with OSL)",
        )
    return "Renders an earlier edit", f"'{mat.name}' renders an earlier edit"


def draw_result(layout, mat, cells):
    """The last Apply, short: what it reached, whether each view meets its target, the albedo,
    its warnings, what the material renders (the long forms are in Details)."""
    state = mat.brdf_moments
    col = layout.column(align=True)
    if state.edited_path:
        split, left, right = _split(col, cells, 0.5)
        label(split, left, f"μ̃ {state.achieved_mu_slope:+.4g}", "CHECKMARK")
        label(split, right, f"σ̃² {state.achieved_sigma2:.4g}")
        fid = state.fidelity()
        if fid is not None:
            text = "Per-view targets met" if fid["meets"] else "Per-view targets missed (Details)"
            wrapped(col, text, cells, icon="NONE" if fid["meets"] else "INFO")
        wrapped(
            col,
            "Largest albedo " + ", ".join(f"{v:.3f}" for v in state.max_albedo),
            cells,
            icon="ERROR" if max(state.max_albedo) > 1.0 else "NONE",
        )
        for warning in filter(None, state.edit_warnings.split("\n")):
            wrapped(col, warning, cells, icon="ERROR")
    renders = _renders(mat)
    if renders is not None:
        wrapped(col, renders[0], cells, icon="INFO")
        if "bound" not in renders[0] and state.artist_shader_used in ("lobes", "principled"):
            # its own background job (6 s and more), after Apply
            button(
                layout,
                cells,
                "brdf_moments.node_bound",
                "Find the Bound",
                "DRIVER_DISTANCE",
                material=mat.name,
            )
        button(layout, cells, "brdf_moments.restore_material", "Restore Shader", "LOOP_BACK", material=mat.name)


def draw_preview(layout, mat, cells):
    """How the spheres (shown in Edit, above the sliders) are rendered, and Build Preview."""
    state = mat.brdf_moments
    col = layout.column()
    if osl_supported():
        row = col.row()
        for key in ("AUTO", "OSL", "BAKED"):
            _record(key.title(), "button", False, cells.w / 3)
        row.prop(state, "preview_path", expand=True)
    else:
        label(col, cells, "Baked (no OSL here)", "INFO")
    prop(col, cells, state, "preview_mode", text="", kind="menu", shown=_item_name(state, "preview_mode"))
    if state.preview_mode == "MODEL":
        wrapped(col, "a sketch of the fits, not the material", cells, icon="ERROR")
    row = col.row(align=True)
    rest = cells.part(1.0)
    rest.w -= ui_unit()
    row.label(text="", icon="WORLD")
    prop(row, rest, state, "preview_env", text="", kind="label", shown="")
    prop(col, cells, state, "preview_size", shown=f"Size  {state.preview_size} px")
    row = col.row(align=True)
    pimg = bpy.data.images.get(preview_image_name(mat))
    build = cells.part(1.0)
    build.w -= ui_unit() if pimg is not None else 0.0
    op = button(row, build, "brdf_moments.build_preview", "Build Preview", "RENDER_STILL")
    op.material, op.use_panel_settings = mat.name, True
    if pimg is not None:
        row.operator("brdf_moments.show_image", text="", icon="FULLSCREEN_ENTER").image = pimg.name


def _draw_spheres(col, mat, cells):
    """The preview's thumbnail at the panel's width, once Build Preview has made one."""
    if bpy.data.images.get(preview_image_name(mat)) is None:
        return
    thumb = thumbnail_icon(mat)
    if thumb is not None:
        col.template_icon(icon_value=thumb, scale=(int(cells.w) + 0.5) / ui_unit())


def draw_export(layout, mat, cells):
    col = layout.column(align=True)
    for what, text, icon in (
        ("TABLE", "Edited Table", "EXPORT"),
        ("PROFILES", "Profiles", "TEXT"),
        ("PLOTS", "Plots", "IMAGE_DATA"),
    ):
        button(col, cells, "brdf_moments.export", text, icon, what=what, material=mat.name)


def draw_details(layout, mat, cells):
    """The long form: the numbers the other sections round or leave out."""
    state = mat.brdf_moments
    col = layout.column(align=True)
    wrapped(col, "kd " + ", ".join(f"{v:.4g}" for v in state.kd), cells)
    wrapped(col, "Fits: paper Sec. 3.4, over θo 0–85°", cells)
    wrapped(
        col,
        f"Energy knots θ0 {math.degrees(state.fit_theta0):.1f}°, θ1 {math.degrees(state.fit_theta1):.1f}°",
        cells,
    )
    for line in filter(None, state.plot_caption.split("\n")):
        wrapped(col, "Chart " + line, cells)
    fid = state.fidelity() if state.edited_path else None
    if fid is not None:
        from ..core.edit.fidelity import describe

        wrapped(col, describe(fid), cells)
    renders = _renders(mat)
    if renders is not None:
        wrapped(col, renders[1], cells)
    if state.source_path:
        wrapped(col, state.source_path, cells, icon="FILE")
    if state.edited_path:
        wrapped(col, "Edited: " + state.edited_path, cells, icon="FILE_BLEND")


SECTIONS = (
    ("fits", "Fits", draw_fits, set()),
    ("chart", "Chart", draw_chart, set()),
    ("edit", "Edit", draw_edit, set()),  # the spheres on top: in sight beside the sliders
    ("preview", "Preview", draw_preview, set()),
    ("result", "Result", draw_result, set()),
    ("export", "Export", draw_export, {"DEFAULT_CLOSED"}),
    ("details", "Details", draw_details, {"DEFAULT_CLOSED"}),
)


def _section_shown(key, mat):
    from .material import is_applied

    state = mat.brdf_moments
    if not state.analysed:
        return False
    if key == "result":
        return bool(state.edited_path) or is_applied(mat)
    return True


def draw_material(layout, mat, context=None):
    """The whole panel in one layout: the main part, then every section under its name."""
    cells = Cells(context)
    draw_main(layout, mat, cells)
    for key, title, draw, _ in SECTIONS:
        if key == "chart" and context is None:
            continue  # a chart is drawn for a region's width; headless there is none
        if _section_shown(key, mat):
            label(layout, cells, title)
            draw(layout.column(), mat, cells)


# --- the charts' pictures and the preview's thumbnail ----------------------------------------
# Each chart is drawn for the panel at the size it is shown (Blender's own thumbnail of an image
# is 128 px, which made the charts unreadable), in a thread, into an icon of the add-on's own
# (icons.py, which also holds the preview's thumbnail); the panel shows the last picture until
# the new one is in.

_WANTED: dict = {}  # icon key -> the signature being drawn
_DONE: list = []  # (key, signature, pixels or None: it could not be drawn) from the threads
_FAILED: dict = {}  # icon key -> the signature that could not be drawn (damaged data, no region)
_THUMBS_PENDING: set = set()  # materials whose thumbnail is being made from their image


def _signature(mat, kind, side):
    state = mat.brdf_moments
    base = (kind, side, hash(state.profiles_data), hash(state.fit_data))
    if kind == "REGION":
        return (
            *base,
            hash(state.region_data),
            state.mode,
            state.mu_slope,
            state.sigma2,
            state.lock,
            state.correlation_a,
            hash(state.set_data),
        )
    return (*base, hash(state.edited_profiles_data))


def chart_icon(mat, kind, side):
    """The icon id of ``mat``'s ``kind`` chart at ``side`` pixels, asking for it to be drawn
    when what it shows changed; None before the first picture is in."""
    if bpy.app.background or side < 32:
        return None
    key = icons.chart_key(mat.name, kind, side)  # one per width: the sidebar and Properties show it at once
    sig = _signature(mat, kind, side)
    if _FAILED.get(key) == sig:
        return None
    if icons.signature(key) != sig and _WANTED.get(key) != sig:
        _WANTED[key] = sig
        name = mat.name
        from .lifecycle import register_timer  # unregister stops it (lifecycle.shutdown)

        register_timer(lambda: _start_chart(name, kind, side, key, sig), first_interval=0.0)
    return icons.icon_id(key)


def chart_failed(mat, kind, side):
    return _FAILED.get(icons.chart_key(mat.name, kind, side)) == _signature(mat, kind, side)


def charts_pending() -> bool:
    """True while a chart asked for is neither in nor found impossible to draw."""
    return any(sig not in (icons.signature(k), _FAILED.get(k)) for k, sig in _WANTED.items())


def chart_sizes() -> list:
    """(width, height) of every chart picture held."""
    return [size for key, size in zip(icons.keys(), icons.sizes()) if key.startswith("chart|")]


def _start_chart(name, kind, side, key, sig):
    """On the main thread: the data, read from the material; the drawing, in a thread."""

    from . import plot_image

    mat = bpy.data.materials.get(name)
    if mat is None or _WANTED.get(key) != sig:
        if _WANTED.get(key) == sig:
            _WANTED.pop(key)  # its material is gone: nothing will come
        return None
    state = mat.brdf_moments
    try:
        if kind == "REGION":
            region = region_of(state)
            if region is None:
                _FAILED[key] = sig
                return None
            point = requested_point(state)
            slider, used = point if point else ((state.mu_slope, state.sigma2), None)
            corr = state.correlation_a
            points = [(m, s) for _, m, s in state.set_points()] or None
            raw, fit_, targets = state.profiles_data, state.fit(), state.slider_targets()

            def draw():
                from .state import horizon_curve, unpack_profiles

                prof = unpack_profiles(raw) if raw else None
                horizon = horizon_curve(prof, fit_, targets, region, used or slider)
                return plot_image.region_plot(
                    region, slider, used, corr, side, side, points, compact=True, horizon=horizon
                )

        else:
            # Only the stored text here: decoding the profiles takes 0.1-0.2 s on this machine's
            # loaded main thread, so it is done in the thread with the drawing.
            raw, raw_edited, fit_ = state.profiles_data, state.edited_profiles_data, state.fit()

            def draw():
                from .state import unpack_profiles

                prof = unpack_profiles(raw)
                edited = unpack_profiles(raw_edited) if raw_edited else None
                return plot_image.profile_chart(prof, fit_, edited, kind.lower(), side)

    except ValueError:  # damaged stored data: the panel says so elsewhere
        _FAILED[key] = sig
        return None

    def run():  # numpy only: no bpy in this thread
        try:
            px = draw()
        except Exception as exc:  # noqa: BLE001 - a failed drawing keeps the last picture
            print(f"BRDF Moments: drawing the {kind.lower()} chart: {type(exc).__name__}: {exc}")
            px = None
        _DONE.append((key, sig, px))

    from .lifecycle import register_timer, start_thread

    start_thread(run, "brdf_moments: chart")
    register_timer(_place_charts, first_interval=0.02)
    return None


def _evicted(key):
    """A chart's icon went (the bound): drawn again when the panel shows it next."""
    _WANTED.pop(key, None)


def _place_charts():
    placed = False
    while _DONE:
        key, sig, px = _DONE.pop(0)
        if _WANTED.get(key) != sig:
            continue
        if px is None:
            _FAILED[key] = sig
            continue
        icons.put(key, px, signature=sig, on_evict=_evicted)
        placed = True
    if placed:
        icons.redraw()
    return 0.05 if charts_pending() else None


def thumbnail_icon(mat):
    """The icon id of ``mat``'s preview thumbnail; None while there is none, and then (in a
    window) it is made from the preview image by a timer: after a file is opened, or when the
    icons' bound dropped it."""
    found = icons.icon_id(icons.thumbnail_key(mat.name))
    if found is None and not bpy.app.background and mat.name not in _THUMBS_PENDING:
        _THUMBS_PENDING.add(mat.name)
        name = mat.name

        def make():
            _THUMBS_PENDING.discard(name)
            m = bpy.data.materials.get(name)
            if m is not None:
                from .live import read_preview_image

                rgba = read_preview_image(m)
                if rgba is not None:
                    icons.put_thumbnail(name, rgba)
            return None

        from .lifecycle import register_timer

        register_timer(make, first_interval=0.0)
    return found


@lifecycle.on_file_load
def file_loading():
    """Before another file is opened: the pictures held describe this file's materials (a
    material of the same name there may hold other data), so they all go, and nothing drawn
    for this file is placed in the next."""
    _WANTED.clear()
    _DONE.clear()
    _FAILED.clear()
    _THUMBS_PENDING.clear()
    _MEMO.clear()
    icons.drop()


def attach():
    bpy.types.WindowManager.brdf_moments_chart = bpy.props.EnumProperty(
        name="Chart", description="which chart the panel shows", items=CHARTS, default="ENERGY"
    )


def detach():
    if bpy.app.timers.is_registered(_place_charts):
        bpy.app.timers.unregister(_place_charts)
    icons.close()
    _WANTED.clear()
    _FAILED.clear()
    _THUMBS_PENDING.clear()
    _MEMO.clear()
    _ITEM_NAMES.clear()
    _DONE.clear()
    if hasattr(bpy.types.WindowManager, "brdf_moments_chart"):
        del bpy.types.WindowManager.brdf_moments_chart


# --- the panel classes ------------------------------------------------------------------------


def _material(context):
    if context.space_data is not None and context.space_data.type == "PROPERTIES":
        return context.material
    obj = context.object
    return obj.active_material if obj is not None else None


class _Main:
    bl_label = "BRDF Moments"

    def draw(self, context):
        _PANEL[0] = self.bl_idname
        draw_main(self.layout, _material(context), Cells(context), title="HIDE_HEADER" in self.bl_options)


class MATERIAL_PT_brdf_moments(_Main, bpy.types.Panel):
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    bl_options = {"HIDE_HEADER"}  # at the top, under the material's slots (module docstring)

    @classmethod
    def poll(cls, context):
        return context.material is not None


class VIEW3D_PT_brdf_moments(_Main, bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BRDF Moments"

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.active_material is not None


class NODE_PT_brdf_moments(_Main, bpy.types.Panel):
    """The same panel in the Shader Editor's sidebar: a tab of its own, next to the material's nodes."""

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


def _section_class(parent, key, title, draw, options):
    def poll(cls, context):
        mat = _material(context) if parent.poll(context) else None
        return mat is not None and _section_shown(key, mat)

    def draw_panel(self, context):
        _PANEL[0] = self.bl_idname
        draw(self.layout, _material(context), Cells(context))

    prefix = parent.__name__.split("_PT_")[0]
    attrs = {
        "bl_label": title,
        "bl_idname": f"{prefix}_PT_brdf_moments_{key}",
        "bl_space_type": parent.bl_space_type,
        "bl_region_type": parent.bl_region_type,
        "bl_parent_id": parent.__name__,
        "bl_options": set(options),
        "poll": classmethod(poll),
        "draw": draw_panel,
    }
    for name in ("bl_context", "bl_category"):
        if name in parent.__dict__:
            attrs[name] = parent.__dict__[name]
    return type(attrs["bl_idname"], (bpy.types.Panel,), attrs)


MAIN = (MATERIAL_PT_brdf_moments, VIEW3D_PT_brdf_moments, NODE_PT_brdf_moments)
CLASSES = (*MAIN, *(_section_class(p, *s) for p in MAIN for s in SECTIONS))
