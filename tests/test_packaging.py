"""The installable archives: Blender's builder makes the extension zip with the scipy
wheel and without tests or generated files; the legacy zip carries the same code."""

import os
import subprocess
import sys
import tomllib
import zipfile

import pytest

pytestmark = pytest.mark.blender  # Blender's extension builder (in the bpy wheel)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_extension_zip_bundles_scipy_and_leaves_out_tests_and_outputs(tmp_path):
    out = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "package.py"), str(tmp_path)],
                         capture_output=True, text=True, check=True).stdout.split()
    ext, legacy = out
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        manifest = tomllib.load(fh)
    names = zipfile.ZipFile(ext).namelist()
    for wheel in manifest["wheels"]:
        assert wheel.lstrip("./") in names
    assert any(os.path.basename(w).startswith("scipy-") and "x86_64" in w for w in manifest["wheels"])
    assert "blender_manifest.toml" in names and "__init__.py" in names and "operators/apply_edit.py" in names
    bad = [n for n in names if n.startswith(("tests/", "out/", ".venv/", ".cache/", ".git/", "scripts/", "dist/"))
           or n.endswith((".binary", ".pyc")) or "__pycache__" in n or ".hypothesis" in n]
    assert bad == []
    legacy_names = zipfile.ZipFile(legacy).namelist()
    code = sorted(n for n in names if n.endswith(".py"))
    assert sorted(n[len("brdf_moments/"):] for n in legacy_names if n.endswith(".py")) == code
    assert all(n.startswith("brdf_moments/") for n in legacy_names)
    # Blender 3.4-4.1 read bl_info from the legacy zip's __init__.py.
    init = zipfile.ZipFile(legacy).read("brdf_moments/__init__.py").decode()
    assert "bl_info" in init and '"blender": (3, 4, 0)' in init
