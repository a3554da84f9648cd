"""Stress: nothing is lost (issue 16) through the extension's operators (bpy wheel).

Blender must keep running: a refused map, a damaged stored analysis or an output over an
input ends in an ERROR report (bpy.ops raises it as RuntimeError), never a crash; the maps
and tables read are never modified; distinct materials export to distinct files.
"""

import base64
import os
import shutil

import numpy as np
import pytest

from _stress import exr_bytes, sha256

pytestmark = pytest.mark.stress
CAT = "nothing lost: Blender operators"


@pytest.fixture
def analysed_gold(fresh, tmp_path):
    import samples

    bpy = fresh
    src = tmp_path / "gold.binary"
    shutil.copy(samples.sample_path("gold"), src)
    mat = bpy.data.materials.new("Gold")
    assert bpy.ops.brdf_moments.load_merl(filepath=str(src), material="Gold") == {"FINISHED"}
    return bpy, mat, src


def _maps(bpy, folder):
    from addon.blender.preview import write_environment

    maps = {}
    big = folder / "huge.exr"
    big.write_bytes(exr_bytes(30000, 15000, body=bytes(2_600_000)))
    maps["30000x15000 EXR"] = (big, "30000x15000")
    text = folder / "text.exr"
    text.write_text("not an image")
    maps["text named .exr"] = (text, "not an OpenEXR file")
    nan = np.full((16, 32, 3), np.nan, np.float32)
    maps["all-NaN map"] = (write_environment(nan, str(folder / "nan.exr")), "NaN")
    maps["all-negative map"] = (
        write_environment(np.full((16, 32, 3), -1.0, np.float32), str(folder / "neg.exr")),
        "no light",
    )
    return maps


def test_build_preview_refuses_bad_maps_on_both_paths_and_blender_lives(analysed_gold, tmp_path, stress_log):
    from addon.blender.preview import osl_available

    bpy, mat, src = analysed_gold
    maps = _maps(bpy, tmp_path)
    digests = {k: sha256(p) for k, (p, _) in maps.items()}
    paths = ["BAKED"] + (["OSL"] if osl_available()[0] else [])
    for case, (path, fragment) in maps.items():
        for route in paths:
            with pytest.raises(RuntimeError) as info:
                bpy.ops.brdf_moments.build_preview(
                    material="Gold", path=route, mode="TABULATED", size=16, samples=1, env=str(path)
                )
            assert fragment in str(info.value) and "Traceback" not in str(info.value), str(info.value)
            stress_log.record(CAT, "error", f"Build Preview ({route.lower()}) with {case}")
    assert {k: sha256(p) for k, (p, _) in maps.items()} == digests
    # Alive, and a good map still works.
    assert bpy.ops.brdf_moments.build_preview(material="Gold", path="BAKED", size=16, samples=1) == {"FINISHED"}


def test_build_preview_never_renders_over_its_map(analysed_gold, tmp_path, stress_log):
    from addon.blender.preview import write_environment

    bpy, mat, src = analysed_gold
    env = write_environment(np.full((16, 32, 3), 0.5, np.float32), str(tmp_path / "sky.exr"))
    digest = sha256(env)
    for target in (env, str(src)):
        with pytest.raises(RuntimeError, match="overwrite the input"):
            bpy.ops.brdf_moments.build_preview(
                material="Gold", path="BAKED", size=16, samples=1, env=env, render_to=target
            )
        stress_log.record(CAT, "error", f"Build Preview render_to = its {'map' if target == env else 'table'}")
    assert sha256(env) == digest
    assert sha256(src) == sha256(tmp_path / "gold.binary")


def test_inf_in_the_stored_analysis_is_refused_by_export_and_build_preview(analysed_gold, tmp_path, stress_log):
    bpy, mat, src = analysed_gold
    state = mat.brdf_moments
    good = state.profiles_data
    raw = np.frombuffer(base64.b64decode(state.profiles_data), "<f8").copy()  # float64 since 2026-12-02
    raw[200] = np.inf
    state.profiles_data = base64.b64encode(raw.tobytes()).decode()
    out = tmp_path / "exports"
    out.mkdir()
    with pytest.raises(RuntimeError, match="damaged"):
        bpy.ops.brdf_moments.export(what="PROFILES", directory=str(out), material="Gold")
    stress_log.record(CAT, "error", "Export with inf in the stored profiles")
    with pytest.raises(RuntimeError, match="damaged"):
        bpy.ops.brdf_moments.build_preview(material="Gold", path="BAKED", mode="TABULATED", size=16, samples=1)
    stress_log.record(CAT, "error", "Build Preview with inf in the stored profiles")
    state.fit_sigma2 = float("inf")
    with pytest.raises(RuntimeError, match="inf or NaN"):
        bpy.ops.brdf_moments.build_preview(material="Gold", path="BAKED", size=16, samples=1)
    stress_log.record(CAT, "error", "Build Preview with an inf fit")
    state.profiles_data, state.fit_sigma2 = good, 0.1
    state.fit_data = '{"mu_slope": -0.9, "sigma2": Infinity'  # the full-precision fit, damaged
    with pytest.raises(RuntimeError, match="stored fit is damaged"):
        bpy.ops.brdf_moments.build_preview(material="Gold", path="BAKED", size=16, samples=1)
    stress_log.record(CAT, "error", "Build Preview with a damaged stored fit")
    assert list(out.iterdir()) == []


def test_export_of_colliding_material_names_writes_distinct_files(analysed_gold, tmp_path, stress_log):
    bpy, mat, src = analysed_gold
    other = mat.copy()
    mat.name, other.name = "a/b", "a_b"
    out = tmp_path / "exports"
    out.mkdir()
    for name in ("a/b", "a_b"):
        assert bpy.ops.brdf_moments.export(what="PROFILES", directory=str(out), material=name) == {"FINISHED"}
    files = sorted(os.listdir(out))
    assert len(files) == 2 and "a_b_profiles.json" in files, files
    stress_log.record("nothing lost: 8 name collisions", "valid", "Export of materials a/b and a_b: two files")


def test_a_damaged_table_texture_is_written_again_under_a_new_name(fresh, tmp_path, stress_log):
    import samples
    from addon.blender.preview.osl import write_table_texture
    from addon.core.file.merl import read_merl
    from addon.core.preview import TableBRDF

    brdf = TableBRDF(read_merl(samples.sample_path("gold")))
    first = write_table_texture(brdf, str(tmp_path))
    assert write_table_texture(brdf, str(tmp_path)) == first  # verified: reused
    with open(first, "r+b") as fh:
        fh.truncate(os.path.getsize(first) // 2)
    second = write_table_texture(brdf, str(tmp_path))
    assert second != first and os.path.getsize(second) > os.path.getsize(first)
    stress_log.record("nothing lost: 5 damaged caches and bad maps", "valid", "truncated OSL table texture: rewritten")


def test_a_damaged_edit_is_refused_by_export(analysed_gold, tmp_path, stress_log):
    bpy, mat, src = analysed_gold
    state = mat.brdf_moments
    state.strength = 0.5
    assert bpy.ops.brdf_moments.apply_edit(material="Gold") == {"FINISHED"}
    assert os.path.isfile(state.edited_path + ".seal")
    with open(state.edited_path, "r+b") as fh:  # same size, one value changed
        fh.seek(1000)
        fh.write(np.array([123.0]).tobytes())
    out = tmp_path / "exports"
    out.mkdir()
    with pytest.raises(RuntimeError, match="damaged"):
        bpy.ops.brdf_moments.export(what="TABLE", directory=str(out), material="Gold")
    assert list(out.iterdir()) == []
    stress_log.record(CAT, "error", "Export of an edited table changed after Apply")


def test_a_damaged_edit_is_refused_by_build_preview(analysed_gold, stress_log):
    """Build Preview checks the edited table's seal in its work (off the main thread in a
    window), and still refuses a damaged one in one line, before anything is shown."""
    bpy, mat, src = analysed_gold
    state = mat.brdf_moments
    state.strength = 0.6
    assert bpy.ops.brdf_moments.apply_edit(material="Gold") == {"FINISHED"}
    with open(state.edited_path, "r+b") as fh:  # same size, one value changed
        fh.seek(2000)
        fh.write(np.array([321.0]).tobytes())
    scenes = sorted(s.name for s in bpy.data.scenes)
    with pytest.raises(RuntimeError, match="damaged"):
        bpy.ops.brdf_moments.build_preview(material="Gold", size=32, samples=1)
    assert sorted(s.name for s in bpy.data.scenes) == scenes  # no preview scene made
    stress_log.record(CAT, "error", "Build Preview of an edited table changed after Apply")
