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
    out = subprocess.run(
        [sys.executable, os.path.join(ROOT, "scripts", "package.py"), str(tmp_path)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    ext, legacy = out
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        manifest = tomllib.load(fh)
    names = zipfile.ZipFile(ext).namelist()
    for wheel in manifest["wheels"]:
        assert wheel.lstrip("./") in names
    assert any(os.path.basename(w).startswith("scipy-") and "x86_64" in w for w in manifest["wheels"])
    assert "blender_manifest.toml" in names and "__init__.py" in names and "operators/apply_edit.py" in names
    bad = [
        n
        for n in names
        if n.startswith(("tests/", "out/", ".venv/", ".cache/", ".git/", "scripts/", "dist/"))
        or n.endswith((".binary", ".pyc"))
        or "__pycache__" in n
        or ".hypothesis" in n
    ]
    assert bad == []
    # the allow-list: the manifest, the wheels and [build] paths, nothing else (no bench*.py,
    # no samples, no dot-files or tool settings)
    assert sorted(names) == sorted(
        ["blender_manifest.toml", *(w.lstrip("./") for w in manifest["wheels"]), *manifest["build"]["paths"]]
    )
    assert not [n for n in names if "bench" in n or n.startswith(("samples/", ".")) or n == "pyproject.toml"]
    legacy_names = zipfile.ZipFile(legacy).namelist()
    code = sorted(n for n in names if n.endswith(".py"))
    assert sorted(n[len("brdf_moments/") :] for n in legacy_names if n.endswith(".py")) == code
    assert all(n.startswith("brdf_moments/") for n in legacy_names)
    # Blender 3.4-4.1 read bl_info from the legacy zip's __init__.py.
    init = zipfile.ZipFile(legacy).read("brdf_moments/__init__.py").decode()
    assert "bl_info" in init and '"blender": (3, 4, 0)' in init


def _runtime_modules():
    """Files of the modules the extension imports at runtime: everything reachable from the
    root __init__.py through its imports (lazy ones in functions included)."""
    import ast

    def module_file(parts):
        base = os.path.join(ROOT, *parts)
        for cand in (base + ".py", os.path.join(base, "__init__.py")):
            if os.path.isfile(cand):
                return os.path.relpath(cand, ROOT).replace(os.sep, "/")
        return None

    seen, todo = set(), ["__init__.py"]
    while todo:
        rel = todo.pop()
        if rel in seen:
            continue
        seen.add(rel)
        parts = rel[:-3].split("/")
        package = parts[:-1]  # for __init__.py: the package itself
        for node in ast.walk(ast.parse(open(os.path.join(ROOT, rel), encoding="utf-8").read())):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = package[: len(package) - node.level + 1] + (node.module.split(".") if node.module else [])
                for cand in [base] + [base + [a.name] for a in node.names]:
                    for i in range(1, len(cand) + 1):  # the packages on the way are imported too
                        hit = module_file(cand[:i])
                        if hit:
                            todo.append(hit)
    return seen


def test_only_the_extension_ships(tmp_path):
    """The allow-list holds exactly the modules the extension imports and its shaders: no
    headless tool (cli, analyze, bench*, render_command), no samples, no tool settings."""
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as fh:
        manifest = tomllib.load(fh)
    paths = manifest["build"]["paths"]
    assert "paths_exclude_pattern" not in manifest["build"]
    code = {p for p in paths if p.endswith(".py")}
    assert code == _runtime_modules()
    shaders = {
        os.path.relpath(os.path.join(d, f), ROOT).replace(os.sep, "/")
        for d, _, files in os.walk(os.path.join(ROOT, "addon", "shaders"))
        for f in files
    }
    assert set(paths) - code == shaders
    for headless in (
        "addon/tools/cli.py",
        "addon/tools/analyze.py",
        "addon/__main__.py",
        "addon/tools/render_command.py",
        "addon/tools/bench.py",
        "addon/tools/bench_preview.py",
        "addon/script_args.py",
        "samples/demo.py",
    ):
        assert headless not in paths


def _repo_copy(dest, wheels=True):
    """The tracked files of the repository in ``dest``, as a clean checkout has them."""
    import shutil

    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    for rel in filter(None, files.decode().split("\0")):
        if os.path.isfile(os.path.join(ROOT, rel)):
            os.makedirs(os.path.dirname(os.path.join(dest, rel)), exist_ok=True)
            shutil.copy2(os.path.join(ROOT, rel), os.path.join(dest, rel))
    if wheels:
        os.symlink(os.path.realpath(os.path.join(ROOT, "wheels")), os.path.join(dest, "wheels"))


def test_stray_folders_and_bench_files_never_ship(tmp_path):
    src = tmp_path / "src"
    _repo_copy(src)
    for stray in ("stray", "addon/stray", "operators/stray"):  # untracked folders left in the tree
        (src / stray).mkdir()
        (src / stray / "notes.py").write_text("x = 1\n")
    (src / "addon" / "bench_new.py").write_text("# a new benchmark\n")
    (src / "out").mkdir()
    (src / "out" / "edited.binary").write_bytes(b"\0" * 64)
    out = subprocess.run(
        [sys.executable, str(src / "scripts" / "package.py"), str(tmp_path / "dist")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    ext, legacy = out
    names = zipfile.ZipFile(ext).namelist()
    assert len(names) == len(set(names))  # the builder's second copy of the wheel is dropped
    shipped = [
        n
        for n in names + zipfile.ZipFile(legacy).namelist()
        if "stray" in n or "bench" in n or n.startswith(("out/", "brdf_moments/out/"))
    ]
    assert shipped == []
    assert (
        "operators/apply_edit.py" in names
        and "brdf_moments/operators/apply_edit.py" in zipfile.ZipFile(legacy).namelist()
    )


def test_the_legacy_zip_is_built_without_the_scipy_wheel(tmp_path):
    src = tmp_path / "src"
    _repo_copy(src, wheels=False)
    res = subprocess.run(
        [sys.executable, str(src / "scripts" / "package.py"), str(tmp_path / "dist")], capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    (legacy,) = res.stdout.split()
    assert legacy.endswith("-legacy.zip") and "wheel(s) missing" in res.stderr
    names = zipfile.ZipFile(legacy).namelist()
    assert "brdf_moments/__init__.py" in names and not any("wheels/" in n for n in names)
    assert sorted(os.listdir(tmp_path / "dist")) == [os.path.basename(legacy)]
