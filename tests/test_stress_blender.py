"""Stress: bad and degenerate MERL files through the extension's Load MERL operator (bpy wheel).

Blender must keep running: a bad file is an ERROR report and CANCELLED (bpy.ops raises the
report as RuntimeError), the material keeps its previous analysis, and what a valid but
degenerate file puts in the UI (fits, kd, sliders, plot) is finite.
"""

import math
import os
import shutil

import numpy as np
import pytest

from _stress import merl_bytes, sha256, stored_of

pytestmark = pytest.mark.stress

UI_FLOATS = (
    "fit_alpha_b",
    "fit_theta0",
    "fit_theta1",
    "fit_alpha1",
    "fit_m1",
    "fit_mu_slope",
    "fit_sigma2",
    "fit_energy_rmse",
    "fit_mean_rmse",
    "fit_variance_rmse",
    "strength",
    "grazing_boost",
    "mu_slope",
    "sigma2",
    "achieved_mu_slope",
    "achieved_sigma2",
)


@pytest.fixture(scope="module")
def base_raw():
    import samples

    with open(samples.sample_path("ggx_glossy"), "rb") as fh:
        return fh.read()


def _ui_numbers(state):
    vals = [getattr(state, k) for k in UI_FLOATS]
    vals += list(state.kd) + list(state.colour) + list(state.max_albedo)
    return vals


def _assert_ui_finite(bpy, mat):
    state = mat.brdf_moments
    assert all(math.isfinite(v) for v in _ui_numbers(state)), dict(zip(UI_FLOATS, _ui_numbers(state)))
    # the slider ranges hold every fitted value (measured mu goes below -1)
    assert -2.0 <= state.mu_slope <= 0.0 and np.float32(1e-8) <= state.sigma2 <= np.float32(math.pi**2 / 12)
    for text in (state.plot_caption, state.fit_notes, state.edit_warnings):
        assert "nan" not in text.lower().split() and "inf" not in text.lower().split(), text
    img = bpy.data.images.get(f"BRDF Moments plot: {mat.name}")
    if img is not None:
        px = np.array(img.pixels[:])
        assert px.size and np.isfinite(px).all()


BAD = [
    ("empty", lambda raw: b"", "too short"),
    ("header only", lambda raw: raw[:12], "truncated"),
    ("padded", lambda raw: raw + b"\0\0\0\0", "oversized"),
    ("wrong header", lambda raw: merl_bytes(stored_of(raw), (90, 90, 360)), "wrong header"),
    ("random bytes", lambda raw: np.random.default_rng(3).bytes(5000), "wrong header"),
    ("NaN", lambda raw: raw[: 12 + 8 * 777] + np.array([np.nan]).tobytes() + raw[12 + 8 * 778 :], "non-finite"),
    ("all missing", lambda raw: merl_bytes(np.full((3, (len(raw) - 12) // 24), -1.0)), "no measured cells"),
    ("huge", lambda raw: merl_bytes(np.abs(stored_of(raw)) * 1e31), "above 1e+30"),
]


def _loaded(bpy, tmp_path, sample, material):
    """A copy of ``sample`` in ``tmp_path`` loaded into a new material: (the material, the copy)."""
    import samples

    path = tmp_path / f"{sample}.binary"
    shutil.copy(samples.sample_path(sample), path)
    mat = bpy.data.materials.new(material)
    assert bpy.ops.brdf_moments.load_merl(filepath=str(path), material=material) == {"FINISHED"}
    return mat, path


def test_bad_files_are_cancelled_with_a_report_and_keep_the_previous_analysis(fresh, tmp_path, base_raw, stress_log):
    bpy = fresh
    mat, good = _loaded(bpy, tmp_path, "gold", "M")
    state = mat.brdf_moments
    before = (state.source_path, state.fit_mu_slope, state.fit_sigma2, state.profiles_data)
    for name, build, fault in BAD:
        path = tmp_path / f"bad {name}.binary"
        path.write_bytes(build(base_raw))
        digest = sha256(path)
        with pytest.raises(RuntimeError) as info:  # an ERROR report: the operator returned CANCELLED
            bpy.ops.brdf_moments.load_merl(filepath=str(path), material="M")
        msg = str(info.value)
        assert str(path) in msg and fault in msg and "Traceback" not in msg, msg
        assert (state.source_path, state.fit_mu_slope, state.fit_sigma2, state.profiles_data) == before
        assert sha256(path) == digest
        stress_log.record("Blender: Load MERL on bad files", "error", f"{name}: {fault}")
    # A folder is a source only when it holds Neural-BRDF .npy weights; this one holds none.
    for name, filepath, fault in [
        ("folder", str(tmp_path), "a folder with no network weights"),
        ("missing", str(tmp_path / "gone.binary"), "no such file"),
        ("no file", "", "no MERL file chosen"),
    ]:
        with pytest.raises(RuntimeError, match=fault):
            bpy.ops.brdf_moments.load_merl(filepath=filepath, material="M")
        assert state.profiles_data == before[3]
        stress_log.record("Blender: Load MERL on bad files", "error", f"{name}: {fault}")
    with pytest.raises(RuntimeError, match="no material named"):
        bpy.ops.brdf_moments.load_merl(filepath=str(good), material="Nope")
    # Still alive and working.
    assert bpy.ops.brdf_moments.load_merl(filepath=str(good), material="M") == {"FINISHED"}
    _assert_ui_finite(bpy, mat)


DEGENERATE = [
    ("green zero", lambda s: s[1].__setitem__(s[1] >= 0, 0.0)),
    ("green missing", lambda s: s[1].fill(-1.0)),
    ("all zero", lambda s: s.__setitem__(s >= 0, 0.0)),
    ("red at 1e-300", lambda s: s[0].__setitem__(s[0] >= 0, s[0][s[0] >= 0] * 1e-300)),
    ("one cell left", lambda s: (s.fill(-1.0), s.__setitem__((slice(None), 1234567), 1.0))),
]


@pytest.mark.parametrize("name, change", DEGENERATE, ids=[d[0] for d in DEGENERATE])
def test_degenerate_files_load_with_finite_values_in_the_ui(fresh, tmp_path, base_raw, stress_log, name, change):
    bpy = fresh
    stored = stored_of(base_raw)
    change(stored)
    path = tmp_path / f"{name.replace(' ', '_')}.binary"
    path.write_bytes(merl_bytes(stored))
    digest = sha256(path)
    mat = bpy.data.materials.new("D")
    assert bpy.ops.brdf_moments.load_merl(filepath=str(path), material="D") == {"FINISHED"}
    assert mat.brdf_moments.analysed
    _assert_ui_finite(bpy, mat)
    assert sha256(path) == digest
    stress_log.record("Blender: Load MERL on degenerate files", "clamped", name)


def test_apply_at_the_slider_limits_never_breaks_blender(fresh, tmp_path, stress_log):
    import samples

    bpy = fresh
    digest = sha256(samples.sample_path("ggx_glossy"))  # the copy's bytes before anything read it
    mat, src = _loaded(bpy, tmp_path, "ggx_glossy", "G")
    state = mat.brdf_moments
    # Property limits clamp what a drag can set: these are the extremes a user can reach.
    state.mu_slope, state.sigma2, state.mode = 5.0, -1.0, "model"
    assert state.mu_slope == 0.0 and state.sigma2 == pytest.approx(1e-8)
    try:
        outcome = bpy.ops.brdf_moments.apply_edit(material="G")
    except RuntimeError as exc:  # a clear ERROR report, and the material is as it was
        assert "Traceback" not in str(exc) and str(exc).strip()
        assert state.edited_path == ""
        outcome = "error"
    else:
        assert outcome == {"FINISHED"} and os.path.isfile(state.edited_path)
    _assert_ui_finite(bpy, mat)
    assert sha256(src) == digest
    stress_log.record(
        "Blender: Apply at the slider limits",
        "error" if outcome == "error" else "clamped",
        "model, mu 0, sigma2 at its minimum",
    )


@pytest.mark.parametrize(
    "prop, value, label",
    [
        ("grazing_boost", 1e30, "Grazing boost"),  # a float32 property: 1e308 would read inf
        ("strength", -1.0, "Strength"),
        ("sigma2", float("nan"), "Variance"),
        ("mu_slope", 5.0, "Mean slope"),
    ],
)
def test_apply_with_a_stored_slider_beyond_its_range_is_one_error_line(fresh, tmp_path, stress_log, prop, value, label):
    """A slider value the property's limits never let a drag set, but a file from another
    version or a script writing the stored value can hold: the engine refuses it (declared
    ranges, core/limits.py), and Apply reports one ERROR line naming the slider and cancels."""
    bpy = fresh
    mat, _ = _loaded(bpy, tmp_path, "ggx_glossy", "R")
    state = mat.brdf_moments
    state[prop] = value  # the stored value itself: the RNA min/max clamp only what is set through them
    held = getattr(state, prop)
    assert held == pytest.approx(value, rel=1e-6) or (math.isnan(value) and math.isnan(held)), (prop, held)
    with pytest.raises(RuntimeError) as err:
        bpy.ops.brdf_moments.apply_edit(material="R")
    msg = str(err.value).strip()
    assert "Traceback" not in msg and len(msg.splitlines()) == 1, msg
    assert label in msg and ("at most" in msg or "at least" in msg or "finite" in msg), msg
    assert state.edited_path == "" and not mat.get("brdfm_kind")  # nothing applied
    stress_log.record("Blender: Apply at the slider limits", "error", f"stored {prop}={value!r}")
