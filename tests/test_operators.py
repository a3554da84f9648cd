"""The extension's operators under the bpy 4.5 wheel (headless: the same code paths as
``blender -b``; the threaded modal path needs a window, which the bpy module has not)."""

import hashlib
import json
import os
import shutil

import numpy as np
import pytest

from addon.core.file.merl import read_merl
from addon.core.fits.curves import fit_material
from addon.core.profiles.compute import compute_profiles

pytestmark = pytest.mark.blender  # the operators in the bpy module


def _sha(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def analysed(fresh, tmp_path, monkeypatch):
    """A material with ggx_rough analysed through the Analyse operator; edits go to tmp."""
    import samples

    monkeypatch.setenv("BRDF_MOMENTS_CACHE", os.environ["BRDF_MOMENTS_CACHE"])  # edits/ lives under it
    src = tmp_path / "rough.binary"
    shutil.copy(samples.sample_path("ggx_rough"), src)
    bpy = fresh
    mat = bpy.data.materials.new("Rough")
    mat.use_fake_user = True
    mat.brdf_moments.source_path = str(src)
    assert bpy.ops.brdf_moments.analyse(material="Rough") == {"FINISHED"}
    return bpy, mat, src


def test_analyse_stores_fits_and_draws_the_plot(analysed):
    bpy, mat, src = analysed
    state = mat.brdf_moments
    want = fit_material(compute_profiles(read_merl(src)))
    assert state.analysed
    assert state.fit_mu_slope == pytest.approx(want["mu_slope"], rel=1e-5)
    img = bpy.data.images["BRDF Moments plot: Rough"]
    px = np.array(img.pixels[:]).reshape(img.size[1], img.size[0], 4)
    background = np.array([0.16, 0.16, 0.16])
    # Curves were drawn: a good share of pixels differ from the background colour.
    drawn = np.abs(px[..., :3] - background).max(axis=-1) > 0.1
    assert 0.01 < drawn.mean() < 0.5
    assert "mean:" in state.plot_caption and "variance:" in state.plot_caption


def test_reset_sliders_returns_to_the_fit(analysed):
    bpy, mat, _ = analysed
    state = mat.brdf_moments
    state.mu_slope, state.sigma2, state.strength = -0.2, 0.3, 2.0
    assert bpy.ops.brdf_moments.reset_sliders(material="Rough") == {"FINISHED"}
    assert state.mu_slope == pytest.approx(min(max(state.fit_mu_slope, -2), 0), abs=1e-6)
    assert state.sigma2 == pytest.approx(state.fit_sigma2, rel=1e-6)
    assert state.strength == 1.0


def test_apply_at_the_fit_is_the_identity_and_leaves_the_source_alone(analysed):
    bpy, mat, src = analysed
    before = _sha(src)
    assert bpy.ops.brdf_moments.apply_edit(material="Rough") == {"FINISHED"}
    state = mat.brdf_moments
    assert os.path.isfile(state.edited_path) and not os.path.samefile(state.edited_path, src)
    np.testing.assert_array_equal(read_merl(state.edited_path).rho, read_merl(src).rho)
    assert _sha(src) == before
    assert state.achieved_mu_slope == pytest.approx(state.fit_mu_slope, abs=1e-6)


def test_apply_edits_from_the_stored_analysis_exactly_as_the_engine_does(analysed):
    """Apply starts from the analysis Analyse stored (it does not analyse the file again): the
    written table is the engine's edit of the file with a fresh analysis, to rounding. Stored
    as float32 (before 12-02) it would differ by ~1e-7."""
    from addon.core.edit import edit, scale_to_albedo

    bpy, mat, src = analysed
    state = mat.brdf_moments
    state.sigma2 = state.fit_sigma2 * 1.5
    assert bpy.ops.brdf_moments.apply_edit(material="Rough") == {"FINISHED"}
    table = read_merl(src)
    prof = compute_profiles(table)
    res = edit(table, state.slider_targets(), prof, fit_material(prof), remeasure=False)
    if state.scale_to_one:
        res = scale_to_albedo(res)
    got = read_merl(state.edited_path)
    np.testing.assert_array_equal(got.valid, res.table.valid)
    np.testing.assert_allclose(got.rho, res.table.rho, rtol=1e-12, atol=1e-300)


def test_apply_refuses_a_file_that_changed_since_it_was_analysed(analysed):
    bpy, mat, src = analysed
    state = mat.brdf_moments
    state.sigma2 = state.fit_sigma2 * 1.5
    before = (state.edited_path, state.profiles_data)
    st = os.stat(src)
    os.utime(src, ns=(st.st_atime_ns, st.st_mtime_ns + 5_000_000_000))
    with pytest.raises(RuntimeError, match="changed since it was analysed"):
        bpy.ops.brdf_moments.apply_edit(material="Rough")
    assert (state.edited_path, state.profiles_data) == before
    assert bpy.ops.brdf_moments.analyse(material="Rough") == {"FINISHED"}  # analysed again: Apply works
    assert bpy.ops.brdf_moments.apply_edit(material="Rough") == {"FINISHED"}


def test_apply_energy_strength_and_export_everything(analysed, tmp_path):
    bpy, mat, src = analysed
    state = mat.brdf_moments
    state.strength = 0.5
    assert bpy.ops.brdf_moments.apply_edit(material="Rough") == {"FINISHED"}
    edited = read_merl(state.edited_path)
    orig = read_merl(src)
    kd = np.asarray(compute_profiles(orig).kd)[:, None]  # the stored copy is float32
    # Energy-only edits are exact: the specular part halves, kd stays.
    on = orig.valid
    np.testing.assert_allclose(
        edited.rho[on], (np.minimum(orig.rho, kd) + 0.5 * np.maximum(orig.rho - kd, 0))[on], rtol=1e-12, atol=1e-15
    )
    assert max(state.max_albedo) > 0 and state.edited_profiles() is not None
    out = tmp_path / "exports"
    out.mkdir()
    for what in ("TABLE", "PROFILES", "PLOTS"):
        assert bpy.ops.brdf_moments.export(what=what, directory=str(out), material="Rough") == {"FINISHED"}
    names = sorted(os.listdir(out))
    assert names == [
        "Rough_edited.binary",
        "Rough_edited_profiles.png",
        "Rough_edited_report.json",
        "Rough_measured_profiles.png",
        "Rough_profiles.json",
    ]
    np.testing.assert_array_equal(read_merl(out / "Rough_edited.binary").rho, edited.rho)
    # The per-view promise beside the table: an energy edit announces the fit and re-measures to it.
    report = json.loads((out / "Rough_edited_report.json").read_text())
    assert report["meets"] and not report["clamped"] and len(report["theta_o"]) == len(report["judged"])
    assert report["announced"]["sigma2"] == pytest.approx(state.fit_sigma2, rel=1e-6)
    for ch in ("r", "g", "b", "avg"):
        got, want = (np.asarray(report[k]["alpha"][ch], float) for k in ("achieved", "target"))
        assert np.nanmax(np.abs(got / want - 1.0)[np.asarray(report["judged"])]) < 1e-4
    data = json.loads((out / "Rough_profiles.json").read_text())
    assert set(data) == {"material", "source", "measured", "edited"}
    assert data["measured"]["avg"]["alpha"] == pytest.approx(state.profiles()["avg"]["alpha"], rel=1e-6)


def test_export_names_stay_inside_the_folder(analysed, tmp_path):
    bpy, mat, _ = analysed
    mat.name = "../../escape"
    out = tmp_path / "inside"
    out.mkdir()
    assert bpy.ops.brdf_moments.export(what="PROFILES", directory=str(out), material=mat.name) == {"FINISHED"}
    files = os.listdir(out)
    assert len(files) == 1 and files[0].endswith("_profiles.json") and "/" not in files[0]
    assert not any(p.name.endswith("_profiles.json") for p in tmp_path.parent.iterdir())


@pytest.mark.parametrize(
    "setup, message",
    [
        ("unanalysed", "load and analyse a MERL file first"),
        ("source gone", "source MERL file is missing"),
    ],
)
def test_apply_errors_are_reports_not_tracebacks(analysed, setup, message):
    bpy, mat, src = analysed
    if setup == "unanalysed":
        mat = bpy.data.materials.new("Empty")
    else:
        os.unlink(src)
    with pytest.raises(RuntimeError) as info:  # bpy.ops turns an ERROR report into RuntimeError
        bpy.ops.brdf_moments.apply_edit(material=mat.name)
    assert message in str(info.value)
    assert "Traceback" not in str(info.value)


def test_export_table_before_apply_is_refused(analysed, tmp_path):
    bpy, mat, _ = analysed
    with pytest.raises(RuntimeError, match="press Apply"):
        bpy.ops.brdf_moments.export(what="TABLE", directory=str(tmp_path), material="Rough")
    assert os.listdir(tmp_path) == ["rough.binary"]


class _Recorder:
    """A stand-in for bpy's UILayout that checks what a panel draws: every property it
    shows must exist on its owner, and every operator it places must be registered."""

    def __init__(self, bpy, log):
        self.bpy, self.log = bpy, log

    def __getattr__(self, name):
        if name in ("row", "column", "box", "grid_flow", "split"):
            return lambda *a, **k: _Recorder(self.bpy, self.log)
        if name == "prop":

            def prop(owner, attr, **_):
                assert attr in owner.bl_rna.properties, attr
                self.log.append(("prop", attr))

            return prop
        if name == "operator":

            def operator(idname, **_):
                group, op = idname.split(".")
                assert hasattr(getattr(self.bpy.ops, group), op) and getattr(getattr(self.bpy.ops, group), op).idname()
                self.log.append(("operator", idname))
                return type("Props", (), {})()

            return operator
        return lambda *a, **k: self.log.append((name, a, k))


def test_panel_draws_every_state_with_real_properties_and_operators(analysed):
    from importlib import import_module

    bpy, mat, _ = analysed
    panel = import_module("bl_ext.bmtest.brdf_moments.addon.blender.panel")
    for step in ("analysed", "edited"):
        if step == "edited":
            mat.brdf_moments.strength = 0.9
            bpy.ops.brdf_moments.apply_edit(material="Rough")
        log = []
        panel.draw_material(_Recorder(bpy, log), mat)
        props = {entry[1] for entry in log if entry[0] == "prop"}
        assert {"mu_slope", "sigma2", "strength", "colour", "grazing_boost", "lock", "mode"} <= props
        ops = {entry[1] for entry in log if entry[0] == "operator"}
        assert {"brdf_moments.apply_edit", "brdf_moments.reset_sliders", "brdf_moments.export"} <= ops
    assert bpy.types.VIEW3D_PT_brdf_moments.bl_category == "BRDF Moments"


def test_every_operator_is_undo_aware(blender):
    import sys

    entry = sys.modules["bl_ext.bmtest.brdf_moments"]  # the extension's entry point gathers them
    for op in entry.operator_classes():
        if op.bl_idname in {"brdf_moments.export", "brdf_moments.show_image"}:
            continue  # writes files / changes what a window shows: nothing in the .blend to undo
        assert "UNDO" in op.bl_options, op.bl_idname


def test_build_preview_baked_renders_original_and_edited(analysed, tmp_path):
    bpy, mat, _ = analysed
    state = mat.brdf_moments
    state.sigma2 = min(state.fit_sigma2 * 1.5, 0.8)
    out = tmp_path / "preview.png"
    assert bpy.ops.brdf_moments.build_preview(
        material="Rough", path="BAKED", size=24, samples=4, render_to=str(out)
    ) == {"FINISHED"}
    scene = bpy.data.scenes["BRDF Moments Preview"]
    spheres = [o for o in scene.objects if o.type == "MESH"]
    assert len(spheres) == 2
    mats = {o.material_slots[0].material.name for o in spheres}
    assert state.preview_material in mats and len(mats) == 2
    img = bpy.data.images.load(str(out))
    assert tuple(img.size) == (48, 24)
    assert [s.name for s in bpy.data.scenes if s.name != "BRDF Moments Preview"]  # the user's scene is kept
    # the panel's image is what the spheres' Emission shows: the baked textures, composed
    shown = bpy.data.images["BRDF Moments preview: Rough"]
    assert tuple(shown.size) == (48, 24) and shown.use_fake_user
    px = np.empty(48 * 24 * 4, np.float32)
    shown.pixels.foreach_get(px)
    px = px.reshape(24, 48, 4)[::-1]
    from addon.core.preview import sphere_layout

    layout = sphere_layout(48, 24, 2)
    mask = layout.interior_mask()
    mask[:11] = False  # rows under the labels (7 px glyphs from row 1, outlined)
    for k, o in enumerate(sorted(spheres, key=lambda o: o.location.x)):
        bake = o.material_slots[0].material.node_tree.nodes["BRDFM Bake"].image
        tex = np.empty(bake.size[0] * bake.size[1] * 4, np.float32)
        bake.pixels.foreach_get(tex)
        tex = tex.reshape(bake.size[1], bake.size[0], 4)[::-1]
        left = layout.lefts[k]
        sub = mask[layout.top : layout.top + layout.diameter, left : left + layout.diameter]
        np.testing.assert_allclose(
            px[layout.top : layout.top + layout.diameter, left : left + layout.diameter][sub, :3],
            tex[sub, :3],
            rtol=1e-5,
            atol=1e-6,
        )


def test_slider_drag_updates_the_osl_preview_without_resynthesis(analysed, tmp_path):
    from addon.blender.preview import osl_available

    bpy, mat, _ = analysed
    if not osl_available()[0]:
        pytest.fail("the bpy wheel's OSL should be reachable in the test harness: " + osl_available()[1])
    state = mat.brdf_moments
    assert bpy.ops.brdf_moments.build_preview(material="Rough", path="OSL", mode="MODEL", size=16) == {"FINISHED"}
    edited = bpy.data.materials[state.preview_material]
    node = edited.node_tree.nodes["BRDFM OSL"]
    tables_before = (
        set(os.listdir(os.path.join(os.environ["BRDF_MOMENTS_CACHE"], "edits")))
        if os.path.isdir(os.path.join(os.environ["BRDF_MOMENTS_CACHE"], "edits"))
        else set()
    )
    state.sigma2 = 0.2
    assert node.inputs["Sigma2"].default_value == pytest.approx(0.2)
    state.mu_slope = -0.6
    assert node.inputs["MuSlope"].default_value == pytest.approx(-0.6)
    state.strength = 0.5
    want = state.model_params(edited=True).alpha_b
    assert tuple(node.inputs["AlphaB"].default_value)[:3] == pytest.approx(want, rel=1e-6)
    edits = os.path.join(os.environ["BRDF_MOMENTS_CACHE"], "edits")
    assert (set(os.listdir(edits)) if os.path.isdir(edits) else set()) == tables_before  # nothing re-synthesized


def test_the_reachable_region_is_stored_drawn_and_is_what_apply_clamps_to(analysed):
    """Analyse stores the material's reachable region (SPEC §3: warp mode's is the material's
    curve under roughness edits, widened by the tilt's reach) and draws it; the panel's 'Apply
    will use' point for sliders outside it is the point Apply then clamps to."""
    from addon.core.edit import reachable_region
    from addon.core.edit.reach import ReachableRegion
    from addon.core.edit.solve import roughness_region

    bpy, mat, src = analysed
    state = mat.brdf_moments
    table = read_merl(src)
    prof = compute_profiles(table)
    fit = fit_material(prof)
    want = roughness_region(table, prof, fit)  # computed here, outside the operator
    got = state.region()
    assert got.curve and len(got.curve["scales"]) == len(want.curve["scales"])
    # the curve passes through the material itself at s = 1
    k = got.curve["scales"].index(1.0)
    assert got.curve["sigma2"][k] == pytest.approx(fit["sigma2"], rel=1e-9)
    assert type(got).__name__ == ReachableRegion.__name__  # the extension's own copy of the class
    np.testing.assert_allclose(got.sigma2, want.sigma2, rtol=1e-12)
    np.testing.assert_allclose(got.mu_min, want.mu_min, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(got.mu_max, want.mu_max, rtol=1e-12, equal_nan=True)
    state.mode = "model"
    assert state.region().to_json() == reachable_region(prof, fit, mode="model").to_json()
    state.mode = "warp"
    img = bpy.data.images["BRDF Moments region: Rough"]
    px = np.array(img.pixels[:]).reshape(img.size[1], img.size[0], 4)[..., :3]
    filled = np.abs(px - np.array([0.16, 0.16, 0.16])).max(axis=-1) > 0.05
    assert 0.05 < filled.mean() < 0.9  # the region is painted, not the whole frame
    # At the fit: inside, nothing to say.
    point = state.requested_point()
    assert point is None or point[0] == point[1]
    # Far below the region's variances: outside; the panel's point is Apply's.
    state.sigma2 = max(got.sigma2_min * 0.2, 1e-6)
    (mu, s2), (mu_c, s2_c) = state.requested_point()
    assert (mu_c, s2_c) != (mu, s2) and s2_c >= got.sigma2_min
    assert bpy.ops.brdf_moments.apply_edit(material="Rough") == {"FINISHED"}
    assert f"clamped to the nearest reachable point ({mu_c:+.3f}, {s2_c:.4g})" in state.edit_warnings
    # A damaged stored region is ignored, never a traceback in the panel.
    state.region_data = '{"warp": {"sigma2": [1, 0]}}'
    assert state.region() is None and state.requested_point() is None


def test_the_whole_panel_fits_the_default_widths_of_this_blender(analysed):
    """Issue 29: every text cell of the whole panel (every section open, after an Apply) fits
    the width its cell gets, measured with blf in the UI font, at the default widths: the
    Properties editor's region in this version's factory startup and a sidebar of 220 px (3.4)
    or 280 px (the later sources' UI_SIDEBAR_PANEL_WIDTH). The window lane checks 3.4 on screen."""
    from importlib import import_module
    from types import SimpleNamespace

    bpy, mat, _ = analysed
    panel = import_module("bl_ext.bmtest.brdf_moments.addon.blender.panel")
    mat.brdf_moments.strength = 0.8
    assert bpy.ops.brdf_moments.apply_edit(material="Rough") == {"FINISHED"}
    props = next(
        r.width
        for a in bpy.data.screens["Layout"].areas
        if a.type == "PROPERTIES"
        for r in a.regions
        if r.type == "WINDOW"
    )
    assert 280 <= props <= 340, props  # the factory layout's Properties editor
    unit = panel.ui_unit()
    for kind, width in (("WINDOW", props), ("UI", 220), ("UI", 280)):
        panel.AUDIT = []
        try:
            log = []
            panel.draw_material(
                _Recorder(bpy, log), mat, SimpleNamespace(region=SimpleNamespace(width=width, type=kind))
            )
            cells = list(panel.AUDIT)
        finally:
            panel.AUDIT = None
        assert len(cells) > 40, len(cells)
        content = width - 0.8 * unit - (1.8 * unit if kind == "UI" else 0)
        assert max(c["avail"] for c in cells) == pytest.approx(content)
        cut = []
        for c in cells:
            need = panel.text_width(c["text"]) + panel.PADDING[c["kind"]] * unit + (unit if c["icon"] else 0)
            if need > c["avail"] + 0.5:
                cut.append((c["text"], c["kind"], round(need), round(c["avail"])))
        assert cut == [], (kind, width, cut)
        texts = {c["text"] for c in cells}
        assert {"Reset", "Apply", "Build Preview", "Edited Table", "Load Set…"} <= texts


def test_the_announced_line_is_one_row_that_fits_the_sidebar(blender):
    """The slider section's read-only line of what Apply will deliver (issue 27 fills
    ``announced_json``): nothing while it is empty or damaged, else one label that fits a
    sidebar of 220 px, with the numbers it was given."""
    import json
    from importlib import import_module
    from types import SimpleNamespace

    bpy = blender
    panel = import_module("bl_ext.bmtest.brdf_moments.addon.blender.panel")
    unit = panel.ui_unit()
    narrow = panel.Cells(SimpleNamespace(region=SimpleNamespace(width=220, type="UI")))
    for raw in ("", "not json", json.dumps({"mu_slope": "x"}), json.dumps({"sigma2": 0.1})):
        log = []
        panel._draw_announced(_Recorder(bpy, log), SimpleNamespace(announced_json=raw), narrow)
        assert [e for e in log if e[0] == "label"] == [], raw
    panel._draw_announced(_Recorder(bpy, []), SimpleNamespace(), narrow)  # no such property yet
    for cells in (narrow, panel.Cells(None)):
        for clamped in (False, True):
            log = []
            doc = {"mu_slope": -0.91234, "sigma2": 0.16129, "out_of_reach": 0.125, "clamped": clamped}
            panel._draw_announced(_Recorder(bpy, log), SimpleNamespace(announced_json=json.dumps(doc)), cells)
            labels = [e[2] for e in log if e[0] == "label"]
            assert len(labels) == 1, labels
            text, icon = labels[0]["text"], labels[0]["icon"]
            assert icon == ("ERROR" if clamped else "FORWARD")
            assert "-0.91" in text and "0.16" in text and "12%" in text.replace(" %", "%"), text
            assert panel.text_width(text) + panel.PADDING["label"] * unit + unit <= cells.w + 0.5, (text, cells.w)
