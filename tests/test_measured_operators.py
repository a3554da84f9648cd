"""The Load operator with Neural-BRDF weights (bpy 4.5 module, headless execute path)."""

import hashlib
import os
import shutil

import numpy as np
import pytest

import samples
from addon.core.file import nbrdf
from addon.core.fits.curves import fit_material
from addon.core.profiles.compute import compute_profiles

pytestmark = pytest.mark.blender  # the operators in the bpy module

RGL = os.path.join(samples.MEASURED_DIR, "nbrdf-rgl-isotropic.npz")
NIELSEN = os.path.join(samples.MEASURED_DIR, "nbrdf-nielsen.npz")


def _sha(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def material(fresh, monkeypatch):
    monkeypatch.setenv("BRDF_MOMENTS_CACHE", os.environ["BRDF_MOMENTS_CACHE"])
    mat = fresh.data.materials.new("Measured")
    mat.use_fake_user = True
    return fresh, mat


def test_load_a_material_of_a_set_analyses_the_network(material, tmp_path):
    bpy, mat = material
    src = tmp_path / "nielsen.npz"
    shutil.copy(NIELSEN, src)
    before = _sha(src)
    assert bpy.ops.brdf_moments.load_merl(filepath=str(src), network="paintedmetal", material="Measured") == {
        "FINISHED"
    }
    state = mat.brdf_moments
    assert state.analysed and state.source_path == f"{src}:paintedmetal"
    ref = fit_material(compute_profiles(nbrdf.decode(nbrdf.load_network(NIELSEN, "paintedmetal"))))
    assert state.fit_mu_slope == pytest.approx(ref["mu_slope"], rel=1e-5)
    assert state.fit_sigma2 == pytest.approx(ref["sigma2"], rel=1e-5)
    # Apply edits the network's table and never writes the weights file.
    state.strength = 0.5
    assert bpy.ops.brdf_moments.apply_edit(material="Measured") == {"FINISHED"}
    assert os.path.isfile(state.edited_path) and _sha(src) == before
    assert np.isfinite(state.achieved_mu_slope)


def test_a_set_needs_a_choice_and_a_single_network_does_not(material, tmp_path, capsys):
    bpy, mat = material
    with pytest.raises(RuntimeError, match="holds 8 measured materials; pick one"):
        bpy.ops.brdf_moments.load_merl(filepath=NIELSEN, material="Measured")
    assert not mat.brdf_moments.analysed
    folder = tmp_path / "npy"
    folder.mkdir()
    net = nbrdf.load_network(RGL, "satin_white")
    for key, leaf in (("W1", "fc1"), ("W2", "fc2"), ("W3", "fc3"), ("b1", "b1"), ("b2", "b2"), ("b3", "b3")):
        np.save(folder / f"satin_white_{leaf}.npy", getattr(net, key))
    # Picking one .npy of the export stands for its material in that folder.
    assert bpy.ops.brdf_moments.load_merl(filepath=str(folder / "satin_white_fc2.npy"), material="Measured") == {
        "FINISHED"
    }
    assert mat.brdf_moments.source_path == f"{folder}:satin_white"


def test_bad_weights_are_an_error_report(material, tmp_path):
    bpy, mat = material
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(RuntimeError, match="bad.npz: not a valid Neural-BRDF weights file"):
        bpy.ops.brdf_moments.load_merl(filepath=str(bad), material="Measured")
    assert not mat.brdf_moments.analysed


def test_the_panel_floor_reaches_the_analysis_and_a_change_asks_for_a_new_one(material):
    from addon.core.profiles.compute import diffuse_floor

    bpy, mat = material
    state = mat.brdf_moments
    state.floor = "robust"
    assert bpy.ops.brdf_moments.load_merl(filepath=RGL, network="spectralon", material="Measured") == {"FINISHED"}
    table = nbrdf.read_table(f"{RGL}:spectralon")
    np.testing.assert_allclose(tuple(state.kd), diffuse_floor(table, method="robust"), rtol=1e-5)
    state.floor = "min"
    assert not state.analysed
    assert bpy.ops.brdf_moments.analyse(material="Measured") == {"FINISHED"}
    np.testing.assert_allclose(tuple(state.kd), diffuse_floor(table), rtol=1e-5, atol=1e-9)
