"""Structural rules of the code base."""

import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_engine_never_imports_bpy():
    core = os.path.join(ROOT, "addon", "core")
    offenders = []
    for folder, _, files in os.walk(core):
        for name in files:
            if not name.endswith(".py"):
                continue
            path = os.path.join(folder, name)
            tree = ast.parse(open(path, encoding="utf-8").read(), path)
            for node in ast.walk(tree):
                mods = []
                if isinstance(node, ast.Import):
                    mods = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module:
                    mods = [node.module]
                if any(m.split(".")[0] in ("bpy", "bmesh", "mathutils", "gpu", "bl_ui") for m in mods):
                    offenders.append(f"{path}:{node.lineno}")
    assert offenders == []
    assert len([f for f in os.listdir(core) if f.endswith(".py")]) >= 6  # the scan saw the engine


def _python_files(*tops):
    for top in tops:
        for folder, _, files in os.walk(os.path.join(ROOT, top)):
            for name in files:
                if name.endswith(".py"):
                    yield os.path.join(folder, name)


def _imported_modules(path):
    """(absolute module name, line) for every import in ``path``, relative ones resolved."""
    rel = os.path.relpath(path, ROOT)[:-3].split(os.sep)
    package = rel[:-1]  # a module's package; for __init__.py the package itself
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            yield module, node.lineno
            for alias in node.names:  # ``from . import cli`` names a module too
                yield f"{module}.{alias.name}", node.lineno


def test_only_the_entry_point_imports_the_cli():
    """cli.py parses arguments and calls the tools; a tool importing it back makes a cycle."""
    offenders = [f"{os.path.relpath(p, ROOT)}:{line}"
                 for p in _python_files("addon", "operators", "samples")
                 if os.path.relpath(p, ROOT) not in (os.path.join("addon", "__main__.py"), os.path.join("addon", "cli.py"))
                 for mod, line in _imported_modules(p) if mod == "addon.cli"]
    assert offenders == []


def test_the_shaders_clamp_the_variance_like_the_engine():
    """OSL cannot import Python: its variance clamp repeats core.fits' constants, checked here."""
    import re

    from addon.core.fits import LAMBERT_VARIANCE, MIN_SIGMA2

    for name in ("brdf_moments_model.osl", "brdf_moments_table.osl"):
        text = open(os.path.join(ROOT, "addon", "shaders", name), encoding="utf-8").read()
        (lo, hi), = re.findall(r"clamp\(Sigma2, ([0-9.e+-]+), ([0-9.e+-]+)\)", text)
        assert float(lo) == MIN_SIGMA2 and abs(float(hi) - LAMBERT_VARIANCE) < 1e-15, name
