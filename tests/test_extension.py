"""The Blender side under the bpy wheel (4.5, and 5.0 in its own lane), loaded as an extension (bl_ext.*)."""

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from addon.core.file.merl import read_merl
from addon.core.fits.curves import fit_material
from addon.core.profiles.compute import compute_profiles

pytestmark = pytest.mark.blender  # the extension in the bpy module

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_manifest_passes_blenders_validator(blender):
    # <bpy>/<version>/ from Blender itself: the same test serves every bpy lane.
    tool = os.path.join(
        blender.utils.resource_path("LOCAL"), "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"
    )
    res = subprocess.run([sys.executable, tool, "validate", ROOT], capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr


def test_load_analyses_stores_and_survives_save_without_the_source(fresh, tmp_path):
    import samples
    from addon.core.file.merl import read_merl
    from addon.core.fits.curves import fit_material
    from addon.core.profiles.compute import compute_profiles

    bpy = fresh
    src = tmp_path / "gold.binary"
    shutil.copy(samples.sample_path("gold"), src)
    mat = bpy.data.materials.new("Gold")
    mat.use_fake_user = True  # orphan data is not saved; in a scene an object would use it
    assert bpy.ops.brdf_moments.load_merl(filepath=str(src), material="Gold") == {"FINISHED"}
    state = mat.brdf_moments
    assert state.analysed and state.source_path == str(src)
    want = fit_material(compute_profiles(read_merl(src)))
    assert state.fit_mu_slope == pytest.approx(want["mu_slope"], rel=1e-5)
    assert state.fit_sigma2 == pytest.approx(want["sigma2"], rel=1e-5)
    assert state.mu_slope == pytest.approx(
        min(max(want["mu_slope"], -2), 0), abs=1e-6
    )  # sliders start at the fit (gold: below -1)
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    os.unlink(src)
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    back = bpy.data.materials["Gold"].brdf_moments.profiles()
    prof = compute_profiles(read_merl(samples.sample_path("gold")))
    np.testing.assert_allclose(back["avg"]["sigma_tt"], prof["avg"]["sigma_tt"], rtol=1e-6)
    np.testing.assert_allclose(back.kd, prof.kd, rtol=1e-6)


def test_bad_file_is_reported_not_raised_as_traceback(fresh, tmp_path):
    bpy = fresh
    bad = tmp_path / "bad.binary"
    bad.write_bytes(b"garbage")
    bpy.data.materials.new("M")
    with pytest.raises(RuntimeError) as info:  # bpy.ops turns an ERROR report into RuntimeError
        bpy.ops.brdf_moments.load_merl(filepath=str(bad), material="M")
    assert "bad.binary" in str(info.value) and "too short" in str(info.value)
    assert not bpy.data.materials["M"].brdf_moments.analysed


def test_a_missing_file_is_reported_and_the_material_keeps_its_analysis(fresh, tmp_path):
    import samples

    bpy = fresh
    src = tmp_path / "gold.binary"
    shutil.copy(samples.sample_path("gold"), src)
    mat = bpy.data.materials.new("Gold")
    assert bpy.ops.brdf_moments.load_merl(filepath=str(src), material="Gold") == {"FINISHED"}
    before = (mat.brdf_moments.source_path, mat.brdf_moments.profiles_data, mat.brdf_moments.fit_sigma2)
    for op in (bpy.ops.brdf_moments.load_merl, bpy.ops.brdf_moments.analyse):
        with pytest.raises(RuntimeError) as info:
            op(filepath=str(tmp_path / "gone.binary"), material="Gold")
        assert "gone.binary: no such file" in str(info.value)
        assert (mat.brdf_moments.source_path, mat.brdf_moments.profiles_data, mat.brdf_moments.fit_sigma2) == before


def test_analyse_of_another_file_takes_its_path_with_its_profiles(fresh, tmp_path):
    import samples

    bpy = fresh
    mat = bpy.data.materials.new("M")
    assert bpy.ops.brdf_moments.load_merl(filepath=samples.sample_path("gold"), material="M") == {"FINISHED"}
    gold_sigma2 = mat.brdf_moments.fit_sigma2
    rough = samples.sample_path("ggx_rough")
    assert bpy.ops.brdf_moments.analyse(filepath=rough, material="M") == {"FINISHED"}
    assert mat.brdf_moments.source_path == rough
    want = fit_material(compute_profiles(read_merl(rough)))
    assert mat.brdf_moments.fit_sigma2 == pytest.approx(want["sigma2"], rel=1e-5)
    assert mat.brdf_moments.fit_sigma2 != pytest.approx(gold_sigma2, rel=0.05)


def test_load_registers_an_undo_step(fresh):
    # ed.undo itself needs a window, which the bpy module has not; what makes Blender push an
    # undo step for an operator is its UNDO flag, checked here on the registered type.
    op = sys.modules["bl_ext.bmtest.brdf_moments.operators.load_merl"].BRDFMOMENTS_OT_load_merl
    assert op.is_registered
    assert "UNDO" in op.bl_options and "REGISTER" in op.bl_options
