"""Neural-BRDF weights as a material source on the command line (profiles, fit, analyze, edit)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import samples
from addon.core.file import nbrdf
from addon.core.file.merl import read_merl

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RGL = os.path.join(samples.MEASURED_DIR, "nbrdf-rgl-isotropic.npz")
NIELSEN = os.path.join(samples.MEASURED_DIR, "nbrdf-nielsen.npz")


def run(*args):
    return subprocess.run(
        [sys.executable, "-m", "addon", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=dict(os.environ),
        timeout=600,
    )


def test_profiles_of_a_network_equal_those_of_its_decoded_table(tmp_path):
    from addon.core.profiles.compute import compute_profiles

    out = tmp_path / "p.json"
    res = run("profiles", f"{RGL}:paper_blue", "--out", str(out))
    assert res.returncode == 0, res.stderr
    got = json.loads(out.read_text())
    ref = compute_profiles(read_merl(samples.sample_path("rgl/paper_blue"))).to_json()
    assert got["kd"] == pytest.approx(ref["kd"], rel=1e-12, abs=1e-15)
    np.testing.assert_allclose(got["avg"]["alpha"], ref["avg"]["alpha"], rtol=1e-9)


@pytest.mark.parametrize(
    "cmd",
    [
        ["profiles", RGL, "--out", "{tmp}/p.json"],
        ["fit", RGL, "--out", "{tmp}/f.json"],
        ["edit", RGL, "--out", "{tmp}/e.binary"],
    ],
)
def test_a_set_without_a_material_is_a_one_line_error_listing_names(tmp_path, cmd):
    res = run(*[c.format(tmp=tmp_path) for c in cmd])
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and RGL in lines[0] and "acrylic_felt_green" in lines[0] and "FILE:NAME" in lines[0]
    assert "Traceback" not in res.stderr and not os.listdir(tmp_path)


@pytest.mark.parametrize(
    "content,fault",
    [(b"", "not a valid Neural-BRDF weights file"), (b"PK\x03\x04junk", "not a valid Neural-BRDF weights file")],
)
def test_bad_weights_files_exit_2_naming_file_and_fault(tmp_path, content, fault):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(content)
    for cmd in (
        ["profiles", str(bad), "--out", str(tmp_path / "p.json")],
        ["edit", f"{bad}:x", "--out", str(tmp_path / "e.binary")],
        ["analyze", str(bad), "--out", str(tmp_path / "out")],
    ):
        res = run(*cmd)
        assert res.returncode == 2, res
        assert str(bad) in res.stderr and fault in res.stderr and "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_unknown_material_and_material_on_a_merl_file(tmp_path):
    res = run("profiles", f"{RGL}:satin_gld", "--out", str(tmp_path / "p.json"))
    assert res.returncode == 2 and "no material 'satin_gld'" in res.stderr and "satin_gold" in res.stderr
    merl = samples.sample_path("lambertian")
    res = run("profiles", f"{merl}:x", "--out", str(tmp_path / "p.json"))
    # Not a weights file, so the whole argument is a (missing) MERL path.
    assert res.returncode == 2 and f"{merl}:x: cannot read file" in res.stderr


@pytest.mark.slow
def test_edit_a_network_writes_a_merl_file_and_never_the_weights(tmp_path):
    before = open(RGL, "rb").read()
    out = tmp_path / "gold.binary"
    res = run("edit", f"{RGL}:satin_gold", "--alpha-scale", "0.5", "--out", str(out))
    assert res.returncode == 0, res.stderr
    edited, orig = read_merl(out), nbrdf.read_table(f"{RGL}:satin_gold")
    np.testing.assert_array_equal(edited.valid, orig.valid)
    # Half the energy: the edited table's total is half the original's.
    assert edited.rho.sum() / orig.rho.sum() == pytest.approx(0.5, rel=0.02)
    res = run("edit", f"{RGL}:satin_gold", "--out", RGL)
    assert res.returncode == 2 and "refusing to overwrite" in res.stderr
    assert open(RGL, "rb").read() == before


@pytest.mark.slow
def test_fit_and_analyze_a_folder_of_npy_and_two_sets_with_a_shared_name(tmp_path):
    folder = tmp_path / "npy"
    folder.mkdir()
    for name in ("cardboard", "paper_white"):
        net = nbrdf.load_network(RGL, name)
        for key, leaf in (("W1", "fc1"), ("W2", "fc2"), ("W3", "fc3"), ("b1", "b1"), ("b2", "b2"), ("b3", "b3")):
            np.save(folder / f"{name}_{leaf}.npy", getattr(net, key))
    out = tmp_path / "out"
    res = run(
        "analyze",
        str(folder),
        f"{NIELSEN}:cardboard",
        f"{NIELSEN}:greencloth",
        "--out",
        str(out),
        "--no-plots",
        "--jobs",
        "1",
    )
    assert res.returncode == 0, res.stderr
    fits = json.loads((out / "fits.json").read_text())["materials"]
    # Both cardboards are kept, told apart by their set's name.
    assert sorted(fits) == sorted(["nbrdf-nielsen/cardboard", "npy/cardboard", "greencloth", "paper_white"])
    for f in fits.values():
        assert np.isfinite(f["alpha_b"])
    res = run("fit", f"{folder}:paper_white", f"{NIELSEN}:greencloth", "--out", str(tmp_path / "f.json"))
    assert res.returncode == 0, res.stderr
    assert sorted(json.loads((tmp_path / "f.json").read_text())["materials"]) == ["greencloth", "paper_white"]
