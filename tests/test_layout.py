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
