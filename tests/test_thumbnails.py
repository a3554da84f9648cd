"""The preview's thumbnail and the charts are the add-on's own icons (addon/blender/icons.py):
the thumbnail's pixels are the preview image sRGB-encoded, the icons are bounded in number, and
Blender is never asked for an image's own preview (Image.preview stays None), which it would
render in a job thread from a buffer the add-on rewrites and frees."""

import math
import os
import shutil
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.blender

ICONS = "bl_ext.bmtest.brdf_moments.addon.blender.icons"
BYTE = 0.5 / 255 + 1e-6  # Blender keeps an icon's pixels as bytes, rounded to the nearest


def srgb(v):
    """The sRGB transfer function of one linear value (IEC 61966-2-1), clipped to [0, 1]."""
    v = min(max(v, 0.0), 1.0)
    return 12.92 * v if v <= 0.0031308 else 1.055 * v ** (1 / 2.4) - 0.055


def expected_thumbnail(rgba, k):
    """What a thumbnail must hold, pixel by pixel: the mean of each k x k block of the linear,
    premultiplied image, colour divided by alpha, then sRGB-encoded."""
    h, w = rgba.shape[0] // k, rgba.shape[1] // k
    out = np.zeros((h, w, 4))
    for y in range(h):
        for x in range(w):
            block = rgba[y * k : (y + 1) * k, x * k : (x + 1) * k].reshape(-1, 4)
            mean = [sum(float(p[c]) for p in block) / len(block) for c in range(4)]
            a = mean[3]
            out[y, x] = [srgb(mean[c] / a) if a > 0 else 0.0 for c in range(3)] + [min(max(a, 0.0), 1.0)]
    return out


@pytest.fixture
def analysed(fresh, tmp_path, monkeypatch):
    import samples

    monkeypatch.setenv("BRDF_MOMENTS_CACHE", os.environ["BRDF_MOMENTS_CACHE"])
    src = tmp_path / "rough.binary"
    shutil.copy(samples.sample_path("ggx_rough"), src)
    bpy = fresh
    mat = bpy.data.materials.new("Thumb")
    mat.use_fake_user = True
    mat.brdf_moments.source_path = str(src)
    assert bpy.ops.brdf_moments.analyse(material="Thumb") == {"FINISHED"}
    return bpy, mat


def test_the_preview_thumbnail_is_the_preview_image_srgb_encoded(analysed):
    bpy, mat = analysed
    icons = sys.modules[ICONS]
    mat.brdf_moments.sigma2 = min(mat.brdf_moments.fit_sigma2 * 1.5, 0.8)
    assert bpy.ops.brdf_moments.build_preview(material="Thumb", path="BAKED", size=24, samples=4) == {"FINISHED"}
    img = bpy.data.images["BRDF Moments preview: Thumb"]
    w, h = img.size
    buf = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(buf)
    linear = buf.reshape(h, w, 4)[::-1]  # row 0 on top
    want = expected_thumbnail(linear, 1)  # 48 px wide: not reduced
    got = icons.pixels(icons.thumbnail_key("Thumb"))
    assert got is not None and got.shape == want.shape == (24, 48, 4)
    assert np.abs(got - want).max() <= BYTE
    # The image has what tells the encodings apart: lit mid-tones (sRGB lifts them well above
    # linear) and partly covered pixels at the spheres' rims.
    lit = (want[..., 3] > 0.99) & (want[..., 0] > 0.2) & (want[..., 0] < 0.9)
    assert lit.any() and np.abs(want[lit, 0] - np.clip(linear[lit, 0], 0, 1)).max() > 0.1
    assert ((want[..., 3] > 0.01) & (want[..., 3] < 0.99)).any()
    # The panel shows that icon at the top of Edit, above the sliders, and no image's own preview.
    from importlib import import_module

    from tests.test_operators import _Recorder

    log = []
    panel = import_module("bl_ext.bmtest.brdf_moments.addon.blender.panel")
    panel.draw_edit(_Recorder(bpy, log), mat, _Cells())
    shown = [k["icon_value"] for name, _, k in (e for e in log if e[0] == "template_icon")]
    assert shown == [icons.icon_id(icons.thumbnail_key("Thumb"))]
    first_slider = next(i for i, e in enumerate(log) if e[0] == "prop")
    assert next(i for i, e in enumerate(log) if e[0] == "template_icon") < first_slider


class _Cells:
    w = 300.0

    def part(self, frac):
        out = _Cells()
        out.w = self.w * frac
        return out


def test_a_large_preview_is_averaged_down_to_the_thumbnail_width(blender):
    icons = sys.modules[ICONS]
    rng = np.random.default_rng(7)
    h, w = 10, 2 * icons.THUMBNAIL_WIDTH + 13  # k = 3: 217 x 3, the last row and column left out
    alpha = rng.uniform(0.0, 1.0, (h, w, 1))
    alpha[:, :40] = 0.0  # uncovered: no colour
    rgba = np.concatenate([rng.uniform(0.0, 1.5, (h, w, 3)) * alpha, alpha], axis=2).astype(np.float32)
    icons.put_thumbnail("Large", rgba)
    try:
        got = icons.pixels(icons.thumbnail_key("Large"))
        k = math.ceil(w / icons.THUMBNAIL_WIDTH)
        want = expected_thumbnail(rgba, k)
        assert k == 3 and got.shape == want.shape == (3, 217, 4)
        assert np.abs(got - want).max() <= BYTE
    finally:
        icons.drop(lambda key: key == icons.thumbnail_key("Large"))


def test_the_icons_are_bounded_and_the_least_recently_used_goes(blender):
    icons = sys.modules[ICONS]
    icons.drop()
    gone = []
    px = np.full((8, 8, 4), 0.5, np.float32)
    n = icons.MAX_ICONS
    try:
        for i in range(n):
            icons.put(f"test|{i}", px, signature=i, on_evict=gone.append)
        assert icons.icon_id("test|0") is not None  # used: now the most recent
        for i in range(n, n + 5):
            icons.put(f"test|{i}", px, signature=i, on_evict=gone.append)
            assert len(icons.keys()) == n and len(icons._COLLECTION[0]) == n  # Blender's collection too
        assert gone == [f"test|{i}" for i in range(1, 6)]
        assert icons.icon_id("test|1") is None and icons.signature("test|1") is None
        assert icons.signature("test|0") == 0 and icons.icon_id("test|0") is not None
        # a thumbnail shares the bound with the charts
        icons.put_thumbnail("Bound", np.ones((4, 4, 4), np.float32))
        assert len(icons._COLLECTION[0]) == n and gone[-1] == "test|6"
    finally:
        icons.drop()


def test_blender_is_never_asked_for_an_images_preview(analysed):
    """Analyse (the plots), a slider move (the region plot, the live preview's image), Build
    Preview, the panel drawn: none of the add-on's images has a preview of Blender's."""
    from importlib import import_module

    from tests.test_operators import _Recorder

    bpy, mat = analysed
    live = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.live"]
    state = mat.brdf_moments
    assert bpy.ops.brdf_moments.build_preview(material="Thumb", path="BAKED", size=16, samples=4) == {"FINISHED"}
    state.sigma2 = min(state.fit_sigma2 * 1.3, 0.8)
    assert live.update_now(mat) is not None
    import_module("bl_ext.bmtest.brdf_moments.addon.blender.panel").draw_material(_Recorder(bpy, []), mat)
    ours = [img for img in bpy.data.images if img.name.startswith("BRDF Moments")]
    assert {"BRDF Moments plot: Thumb", "BRDF Moments preview: Thumb"} <= {img.name for img in ours}
    assert [img.name for img in ours if img.preview is not None] == []


def test_the_preview_image_is_in_the_saved_file(analysed, tmp_path):
    """A generated image's pixels are not saved with the file: reopened, the preview's measured
    sphere was black (only the edited one was redrawn live). The preview is packed and reads
    back exactly, premultiplied; so is a plot (8-bit)."""
    bpy, mat = analysed
    live = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.live"]
    images = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.images"]
    rng = np.random.default_rng(11)
    alpha = rng.uniform(0.0, 1.0, (24, 48, 1))
    rgba = np.concatenate([rng.uniform(0.0, 4.0, (24, 48, 3)) * alpha, alpha], axis=2).astype(np.float32)
    live.write_preview_image(mat, rgba)
    plot = (rng.integers(0, 256, (20, 30, 4)) / 255.0).astype(np.float32)
    plot[..., 3] = 1.0
    images.keep_image("BRDF Moments test plot", plot)
    path = str(tmp_path / "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    got = live.read_preview_image(bpy.data.materials["Thumb"])
    np.testing.assert_array_equal(got, rgba)
    img = bpy.data.images["BRDF Moments test plot"]
    buf = np.empty(30 * 20 * 4, np.float32)
    img.pixels.foreach_get(buf)
    assert np.abs(buf.reshape(20, 30, 4)[::-1] - plot).max() < 1e-6


def test_sphere_labels_stay_in_their_cells_and_leave_nothing_behind(blender):
    """A label wider than its sphere's cell loses words from the end; redrawn shorter, the
    longer one's pixels are gone; the other sphere's cell is never touched."""
    from addon.core.preview import sphere_layout

    font = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.plot_font"]
    lay = sphere_layout(128, 64, 2)
    rng = np.random.default_rng(3)
    img = rng.uniform(0.2, 0.8, (64, 128, 4)).astype(np.float32)
    left_cell = img[:, :64].copy()
    images = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.images"]
    images.label_image(img, lay, [None, "σ²×1.30 μ+0.05 refined"])
    np.testing.assert_array_equal(img[:, :64], left_cell)
    inked = img[: lay.top, 64:, 0] == 1.0  # white text pixels in the margin above sphere 1
    cols = np.flatnonzero(inked.any(axis=0))
    assert cols.size and cols.max() - cols.min() < 64  # the words that fit: within the cell
    assert font.text_width("σ²×1.30") <= 64 < font.text_width("σ²×1.30 μ+0.05")  # so one word is left
    assert cols.max() - cols.min() < font.text_width("σ²×1.30")
    images.label_image(img, lay, [None, "σ²×1.30"])
    np.testing.assert_array_equal(img[:, :64], left_cell)
    w = font.text_width("σ²×1.30")
    x = min(max(lay.lefts[1] + (lay.diameter - w) // 2, 64), 128 - w)
    margin = img[: lay.top, 64:].copy()
    margin[:, x - 1 - 64 : x + w + 1 - 64] = 0.0  # the new label's box
    assert np.all(margin == 0.0)  # nothing of the longer label is left in the margin
