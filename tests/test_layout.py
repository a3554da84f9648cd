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
    offenders = [
        f"{os.path.relpath(p, ROOT)}:{line}"
        for p in _python_files("addon", "operators", "samples")
        if os.path.relpath(p, ROOT)
        not in (os.path.join("addon", "__main__.py"), os.path.join("addon", "tools", "cli.py"))
        for mod, line in _imported_modules(p)
        if mod == "addon.tools.cli"
    ]
    assert offenders == []


def test_the_shaders_clamp_the_variance_like_the_engine():
    """OSL cannot import Python: its variance clamp repeats core.fits' constants, checked here."""
    import re

    from addon.core.fits import LAMBERT_VARIANCE, MIN_SIGMA2

    for name in ("brdf_moments_model.osl", "brdf_moments_table.osl"):
        text = open(os.path.join(ROOT, "addon", "shaders", name), encoding="utf-8").read()
        ((lo, hi),) = re.findall(r"clamp\(Sigma2, ([0-9.e+-]+), ([0-9.e+-]+)\)", text)
        assert float(lo) == MIN_SIGMA2 and abs(float(hi) - LAMBERT_VARIANCE) < 1e-15, name


BPY = ("bpy", "bmesh", "mathutils", "gpu", "bl_ui", "addon_utils")
BLENDER_SIDE = ("addon.blender", "operators")
# Tools that drive Blender as a module (the bpy wheel): they import the Blender side when they
# run, inside the command, never when imported.
BRIDGES = {"render_command.py", "bench_preview.py", "bench_artist.py"}


def _within(module, roots):
    return any(module == r or module.startswith(r + ".") for r in roots)


def _module_level_imports(path):
    """The modules ``path`` imports when it is itself imported (not those inside functions)."""
    lazy = set()
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            lazy.update(id(n) for n in ast.walk(node) if isinstance(n, (ast.Import, ast.ImportFrom)))
    lines = {n.lineno for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)) and id(n) not in lazy}
    return [(m, line) for m, line in _imported_modules(path) if line in lines]


def test_each_side_imports_only_what_it_may():
    """core imports neither side; the tools never import bpy or the Blender side when imported
    (``python -m addon fit`` starts without Blender); the Blender side takes from the tools
    only the figure writer (Export > Plots)."""
    bad = []
    for p in _python_files(os.path.join("addon", "core")):
        bad += [
            f"core {os.path.relpath(p, ROOT)}:{line} {m}"
            for m, line in _imported_modules(p)
            if _within(m, BLENDER_SIDE + ("addon.tools",) + BPY)
        ]
    tools = list(_python_files(os.path.join("addon", "tools")))
    for p in tools:
        bad += [
            f"tool {os.path.relpath(p, ROOT)}:{line} {m}"
            for m, line in _module_level_imports(p)
            if _within(m, BLENDER_SIDE + BPY)
        ]
        if os.path.basename(p) not in BRIDGES:
            bad += [
                f"tool {os.path.relpath(p, ROOT)}:{line} {m}"
                for m, line in _imported_modules(p)
                if _within(m, BLENDER_SIDE + BPY)
            ]
    side = list(_python_files(os.path.join("addon", "blender"))) + list(_python_files("operators"))
    for p in side:
        bad += [
            f"blender {os.path.relpath(p, ROOT)}:{line} {m}"
            for m, line in _imported_modules(p)
            if _within(m, ("addon.tools",)) and not _within(m, ("addon.tools.plots",))
        ]
    assert bad == []
    assert len(tools) >= 8 and len(side) >= 15  # the scan saw both sides
