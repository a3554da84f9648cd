"""An analysed set on the region plot (issue 18): ``analyze``'s fits.json read by Load Set, its
materials drawn as grey dots by ``region_plot``; a bad file is one line and changes nothing."""

import hashlib
import json
import math
import os
import shutil

import numpy as np
import pytest

from addon.blender.plot_image import SET_COLOUR, region_plot
from addon.core.edit.reach import ReachableRegion
from addon.core.fits.curves import LAMBERT_VARIANCE

BACKGROUND = np.array([0.16, 0.16, 0.16])
SAMPLES = ("ggx_glossy", "ggx_rough", "phong")


def _layout(width, height):
    """The region plot's frame, from its documented layout (5x7 glyphs, 6 px advance, scale s)."""
    s = max(1, int(round(width / 450)))
    line_h = 9 * s
    return 7 * 6 * s + 10, width - 12 - 1, 3 * line_h + 8, height - 2 * line_h - 14


def _pixel(mu, s2, ranges, width, height):
    x0, x1, top, bottom = _layout(width, height)
    x_lo, x_hi, y_lo, y_hi = ranges
    x = x0 + (mu - x_lo) / (x_hi - x_lo) * (x1 - x0)
    y = bottom - (math.log10(s2) - y_lo) / (y_hi - y_lo) * (bottom - top)
    return int(round(x)), int(round(y))


def _toy_region():
    s2 = np.geomspace(0.01, 0.5, 30)
    return ReachableRegion.from_json(
        {
            "sigma2": list(s2),
            "mu_min": [-1.05] * 30,
            "mu_max": [-0.5] * 30,
            "sigma2_min": 0.01,
            "sigma2_max": 0.5,
            "fitted": [-0.9, 0.45],
        }
    )


# --- the plot alone (numpy, no bpy) ----------------------------------------------------------------


def test_region_plot_draws_set_points_as_grey_dots_where_the_axes_put_them():
    region = _toy_region()
    slider = (-0.9, 0.45)
    base = region_plot(region, slider)
    point = (-0.3, 0.05)  # inside the plot's own ranges: the axes do not move
    with_set = region_plot(region, slider, set_points=[point])
    assert with_set.shape == base.shape and np.isfinite(with_set).all()
    _, _, top, _ = _layout(600, 420)
    changed = np.abs(with_set[..., :3] - base[..., :3]).max(axis=-1) > 1e-6
    # The ranges the plot's documentation gives: the region, the fit, the mirror (-1) and
    # Lambert (0, pi^2/12), 0.05 of padding (log10 on the variance).
    ranges = (-1.05 - 0.05, 0.0 + 0.05, math.log10(0.01) - 0.05, math.log10(LAMBERT_VARIANCE) + 0.05)
    x, y = _pixel(*point, ranges, 600, 420)
    ys, xs = np.nonzero(changed[top:])
    ys = ys + top
    assert len(xs) > 0
    assert np.abs(xs - x).max() <= 3 and np.abs(ys - y).max() <= 3  # only the dot, round the point
    np.testing.assert_allclose(with_set[y, x, :3], 0.9 * np.asarray(SET_COLOUR) + 0.1 * base[y, x, :3], atol=1e-5)
    assert changed[:top].any()  # the legend gained "set (1)"


def test_region_plot_widens_for_the_set_but_leaves_far_outliers_off():
    region = _toy_region()
    base = region_plot(region, None)
    # Five decades below the region and a slope of -9: left off, the axes kept, only the legend changes.
    outliers = region_plot(region, None, set_points=[(-0.8, 1e-7), (-9.0, 0.1), (float("nan"), 0.1), (-0.5, 0.0)])
    _, _, top, _ = _layout(600, 420)
    np.testing.assert_array_equal(outliers[top:], base[top:])
    assert not np.array_equal(outliers[:top], base[:top])
    # A point just left of the plot's range widens the mean-slope axis: it is drawn, in grey.
    wide = region_plot(region, None, set_points=[(-1.4, 0.05)])
    ranges = (-1.4 - 0.05, 0.05, math.log10(0.01) - 0.05, math.log10(LAMBERT_VARIANCE) + 0.05)
    x, y = _pixel(-1.4, 0.05, ranges, 600, 420)
    assert np.abs(wide[y, x, :3] - 0.9 * np.asarray(SET_COLOUR) - 0.1 * BACKGROUND).max() < 1e-5
    assert not np.array_equal(wide[top:], base[top:])


# --- Load Set and Clear Set, in Blender -----------------------------------------------------------


def _sha(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture(scope="module")
def set_fits(tmp_path_factory):
    """A real fits.json: the headless analyze on three samples."""
    import samples
    from addon.tools.analyze import analyze

    root = tmp_path_factory.mktemp("set")
    folder = root / "in"
    folder.mkdir()
    for name in SAMPLES:
        shutil.copy(samples.sample_path(name), folder / f"{name}.binary")
    problems = analyze([str(folder)], str(root / "out"), workers=1, plots=False, log=lambda *_: None)
    assert problems == []
    path = root / "out" / "fits.json"
    return str(path), json.loads(path.read_text())


@pytest.fixture
def analysed(fresh, tmp_path):
    import samples

    bpy = fresh
    src = tmp_path / "rough.binary"
    shutil.copy(samples.sample_path("ggx_rough"), src)
    mat = bpy.data.materials.new("Rough")
    mat.use_fake_user = True
    mat.brdf_moments.source_path = str(src)
    assert bpy.ops.brdf_moments.analyse(material="Rough") == {"FINISHED"}
    return bpy, mat


def _region_pixels(bpy, mat):
    img = bpy.data.images[f"BRDF Moments region: {mat.name}"]
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[::-1]  # row 0 on top, as region_plot draws


def _snapshot(mat):
    state = mat.brdf_moments
    out = {}
    for prop in state.bl_rna.properties:
        if prop.identifier == "rna_type":
            continue
        value = getattr(state, prop.identifier)
        out[prop.identifier] = tuple(value) if hasattr(value, "__len__") and not isinstance(value, str) else value
    return out


def test_load_set_stores_the_files_points_and_correlation_and_draws_them(analysed, set_fits):
    bpy, mat = analysed
    path, doc = set_fits
    before = _sha(path)
    state = mat.brdf_moments
    assert bpy.ops.brdf_moments.load_set(material="Rough", filepath=path) == {"FINISHED"}
    assert _sha(path) == before  # only read
    want = [(n, f["mu_slope"], f["sigma2"]) for n, f in doc["materials"].items()]
    assert len(want) == 3 and state.set_points() == want  # the file's values, exactly
    assert state.set_path == path
    assert state.correlation_a == pytest.approx(doc["correlation"]["a"], rel=1e-6)  # a float property
    # Each set point is a grey dot where the plot's axes put it (ranges from the plot's
    # documented rule: the region, fit, mirror, Lambert and the set, 0.05 of padding).
    region = state.region()
    mu_b, _ = region.boundary()
    mus = [*mu_b[np.isfinite(mu_b)], region.fitted[0], -1.0, 0.0, state.mu_slope]
    s2s = [*region.sigma2, region.fitted[1], LAMBERT_VARIANCE, state.sigma2]
    x_lo, x_hi = min(mus) - 0.05, max(mus) + 0.05
    y_lo, y_hi = math.log10(min(s2s)) - 0.05, math.log10(max(s2s)) + 0.05
    # A set may widen the axes by half the mean-slope span and one decade of variance each way;
    # points beyond are left off (and counted in the legend).
    span = x_hi - x_lo
    shown = [
        (n, m, v)
        for n, m, v in want
        if x_lo - 0.5 * span <= m <= x_hi + 0.5 * span and y_lo - 1.0 <= math.log10(v) <= y_hi + 1.0
    ]
    assert any(n != "ggx_rough" for n, _, _ in shown)  # a dot other than the material itself is checked
    mus += [m for _, m, _ in shown]
    s2s += [v for _, _, v in shown]
    ranges = (min(mus) - 0.05, max(mus) + 0.05, math.log10(min(s2s)) - 0.05, math.log10(max(s2s)) + 0.05)
    px = _region_pixels(bpy, mat)
    h, w = px.shape[:2]
    for name, mu, s2 in shown:
        if name == "ggx_rough":
            continue  # the material itself: its set dot is under the fit's marker
        x, y = _pixel(mu, s2, ranges, w, h)
        assert np.abs(px[y, x, :3] - np.asarray(SET_COLOUR)).max() < 0.08, (name, px[y, x])
    # The panel names the file and offers Clear.
    from importlib import import_module

    from test_operators import _Recorder

    panel = import_module("bl_ext.bmtest.brdf_moments.addon.blender.panel")
    log = []
    panel.draw_material(_Recorder(bpy, log), mat)
    ops = {entry[1] for entry in log if entry[0] == "operator"}
    assert {"brdf_moments.load_set", "brdf_moments.clear_set"} <= ops
    labels = [entry[2].get("text", "") for entry in log if entry[0] == "label"]
    assert any("fits.json (3 materials)" in t for t in labels), labels
    # Clear: no set, the correlation a stays; the plot loses the dots.
    assert bpy.ops.brdf_moments.clear_set(material="Rough") == {"FINISHED"}
    assert state.set_data == "" and state.set_path == "" and state.set_points() == []
    assert state.correlation_a == pytest.approx(doc["correlation"]["a"], rel=1e-6)
    assert not np.array_equal(_region_pixels(bpy, mat), px)
    assert _sha(path) == before


def _bad_files(tmp, good):
    def write(name, text):
        p = tmp / name
        p.write_text(text)
        return str(p)

    many = {"materials": {f"m{i}": {"mu_slope": -0.5, "sigma2": 0.1} for i in range(5001)}}
    big = tmp / "big.json"
    with open(big, "w") as fh:
        fh.write(json.dumps(good)[:-1] + " " * (11 << 20) + "}")
    nan = json.dumps(good).replace(str(good["materials"]["phong"]["sigma2"]), "NaN")
    inf = json.dumps(good).replace(str(good["materials"]["phong"]["sigma2"]), "1e999")
    return {
        "missing file": (str(tmp / "nope.json"), "No such file"),
        "a folder": (str(tmp), "is a directory"),
        "not JSON": (write("text.json", "materials: none\n"), "not valid fits JSON"),
        "wrong schema": (write("list.json", '{"materials": [1, 2]}'), "no 'materials' object"),
        "profiles JSON": (write("prof.json", '{"theta_o": [0.0], "kd": [0, 0, 0]}'), "no 'materials' object"),
        "fit not a number": (
            write("str.json", '{"materials": {"x": {"mu_slope": "-0.5", "sigma2": 0.1}}}'),
            "mu_slope is str, not a number",
        ),
        "no fits in it": (
            write("none.json", '{"materials": {"x": {"mu_slope": null, "sigma2": null}}}'),
            "no material",
        ),
        "NaN": (write("nan.json", nan), "NaN is not a number JSON allows"),
        "inf": (write("inf.json", inf), "not a finite number"),
        "bad correlation": (
            write("corr.json", json.dumps({**good, "correlation": {"a": True}})),
            "correlation a is bool",
        ),
        "too many materials": (write("many.json", json.dumps(many)), "5001 materials, the limit is 5000"),
        "too large": (str(big), "too large"),
    }


def test_bad_set_files_are_one_line_errors_and_change_nothing(analysed, set_fits, tmp_path):
    bpy, mat = analysed
    path, doc = set_fits
    # A set already loaded: a bad file must keep it, and the correlation a, as they were.
    assert bpy.ops.brdf_moments.load_set(material="Rough", filepath=path) == {"FINISHED"}
    mat.brdf_moments.correlation_a = -0.25
    before, pixels = _snapshot(mat), _region_pixels(bpy, mat).copy()
    for case, (bad, message) in _bad_files(tmp_path, doc).items():
        sha = _sha(bad) if os.path.isfile(bad) else None
        with pytest.raises(RuntimeError) as info:  # bpy.ops turns an ERROR report into RuntimeError
            bpy.ops.brdf_moments.load_set(material="Rough", filepath=bad)
        text = str(info.value).strip()
        assert message in text, (case, text)
        assert "Traceback" not in text and len(text.splitlines()) == 1, (case, text)
        assert _snapshot(mat) == before, case
        np.testing.assert_array_equal(_region_pixels(bpy, mat), pixels)
        assert sha is None or _sha(bad) == sha, case  # never written to
    with pytest.raises(RuntimeError, match="no fits.json chosen"):
        bpy.ops.brdf_moments.load_set(material="Rough", filepath="")
    assert _snapshot(mat) == before


def test_a_set_without_a_correlation_keeps_a_and_a_damaged_stored_set_is_not_drawn(analysed, set_fits, tmp_path):
    bpy, mat = analysed
    _, doc = set_fits
    one = tmp_path / "one.json"
    one.write_text(json.dumps({"materials": {"phong": doc["materials"]["phong"]}}))  # analyze of one file
    state = mat.brdf_moments
    state.correlation_a = -0.3
    assert bpy.ops.brdf_moments.load_set(material="Rough", filepath=str(one)) == {"FINISHED"}
    assert state.correlation_a == pytest.approx(-0.3) and len(state.set_points()) == 1
    # Damaged in the .blend: no dots, no traceback in the panel or the plot.
    import sys

    ext_state = sys.modules["bl_ext.bmtest.brdf_moments.addon.blender.state"]
    for damaged in ('[["x", "y"]]', "{", '{"a": 1}', '[["x", 1, "nan"]]'):
        state.set_data = damaged
        assert state.set_points() == []
        assert ext_state.region_image(mat) is not None
