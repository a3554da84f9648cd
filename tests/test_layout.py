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
    assert len(list(_python_files(os.path.join("addon", "core")))) >= 40  # the scan saw the engine


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
    """OSL cannot import Python: its variance clamp repeats core.fits.curves' constants, checked here."""
    import re

    from addon.core.fits.curves import LAMBERT_VARIANCE, MIN_SIGMA2

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


# --- one way down ---------------------------------------------------------------------------
# Every module of the product, as a dotted name ("__init__" is the extension's entry point).
SCANNED = ("addon", "operators", "samples", "scripts")


def _modules():
    mods = {"__init__": os.path.join(ROOT, "__init__.py")}
    for p in _python_files(*SCANNED):
        name = os.path.relpath(p, ROOT)[:-3].replace(os.sep, ".")
        mods[name.removesuffix(".__init__")] = p
    return mods


def _import_graph():
    """module -> {(imported module, line)}, every import counted (those inside functions too:
    a lazy import still runs, and a circle through one only waits for the first call).

    ``from pkg import name`` counts as an import of ``pkg.name`` when that is a module; an
    import of the module's own package (or one above it) is not an edge: a package's
    ``__init__`` always runs before its modules, whoever imports them."""
    mods = _modules()
    graph = {}
    for name, path in mods.items():
        ancestors = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 1)}
        edges = set()
        for target, line in _imported_modules(path):
            target = target.lstrip(".")  # the entry point's ``from .addon...`` is the package root's
            while target and target not in mods:
                target = target.rpartition(".")[0]  # ``from m import function`` is an import of m
            if target and target != name and target not in ancestors:
                edges.add((target, line))
        graph[name] = edges
    return graph


def _circles(graph):
    """The strongly connected groups of more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted({t for t, _ in graph[root]})))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, targets = work[-1]
            for t in targets:
                if t not in index:
                    index[t] = low[t] = len(index)
                    stack.append(t)
                    on_stack.add(t)
                    work.append((t, iter(sorted({u for u, _ in graph[t]}))))
                    break
                if t in on_stack:
                    low[node] = min(low[node], index[t])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    group = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        group.append(m)
                        if m == node:
                            break
                    if len(group) > 1:
                        found.append(sorted(group))
    return found


def test_no_import_circles():
    """No module imports, directly or through others, one that imports it back."""
    graph = _import_graph()
    assert _circles(graph) == []
    assert len(graph) >= 80  # the scan saw the product


def test_the_circle_finder_finds_circles():
    """The finder itself, on made-up graphs: a three-module ring (the shape merl -> names ->
    nbrdf -> merl had) and a two-module one are found; a chain and a diamond are not."""
    ring = {"a": {("b", 1)}, "b": {("c", 1)}, "c": {("a", 1)}, "d": {("a", 1)}}
    assert _circles(ring) == [["a", "b", "c"]]
    pair = {"x": {("y", 1)}, "y": {("x", 2)}, "z": set()}
    assert _circles(pair) == [["x", "y"]]
    diamond = {"a": {("b", 1), ("c", 1)}, "b": {("d", 1)}, "c": {("d", 1)}, "d": set()}
    assert _circles(diamond) == []


# --- the engine's rooms ----------------------------------------------------------------------
# addon/core/ holds one package per step of the README's flow (file -> profiles -> fits -> edit
# -> table -> preview; the table step's node approximations are ``material``), in that order,
# and beside them the modules every step may read, which import no step. Each package names the
# packages it may import: only ones before it in the flow.
ENGINE_GROUND = ("limits", "geometry", "microsurface", "threads")
ENGINE = {
    "file": (),  # the MERL table, networks, the guard and opener, atomic writes, sealed caches
    "profiles": ("file",),  # integrates a table's slices
    "fits": ("file",),  # reads a set's fits.json through the opener
    "edit": ("file", "profiles", "fits"),  # re-measures and re-fits what it writes
    "material": ("file",),  # reads the table it approximates
    "preview": ("file", "profiles", "fits", "edit"),  # the live preview runs the edit
}


def _engine_package(module):
    """The engine package ``module`` belongs to, "" for a ground module, None outside the engine."""
    parts = module.split(".")
    if parts[:2] != ["addon", "core"]:
        return None
    if len(parts) == 2 or parts[2] in ENGINE_GROUND:
        return ""
    return parts[2]


def _engine_violations(graph):
    """Imports between the engine's rooms that ENGINE does not allow."""
    bad = []
    for name, edges in sorted(graph.items()):
        own = _engine_package(name)
        if own is None:
            continue
        for target, line in sorted(edges):
            other = _engine_package(target)
            if other is None or other == own or other == "":
                continue
            if own == "" or other not in ENGINE.get(own, ()):
                bad.append(f"{name}:{line} imports {target} ({own or 'ground'} -> {other})")
    return bad


def test_the_engine_is_one_package_per_step():
    """addon/core/ holds the steps' packages and the ground modules, nothing else; the ground
    modules are the only ones at its top."""
    core = os.path.join(ROOT, "addon", "core")
    entries = {e for e in os.listdir(core) if e != "__pycache__"}
    want = {"__init__.py"} | {f"{m}.py" for m in ENGINE_GROUND} | set(ENGINE)
    assert entries == want
    for package in ENGINE:
        assert os.path.isfile(os.path.join(core, package, "__init__.py")), package


def _docstring(path):
    return ast.get_docstring(ast.parse(open(path, encoding="utf-8").read(), path)) or ""


def test_each_engine_package_says_what_it_holds_and_in_what_order():
    """The engine's docstring names its packages in the order of the flow (ENGINE's); each
    package's docstring names every module it holds (the order its modules run)."""
    core = os.path.join(ROOT, "addon", "core")
    top = _docstring(os.path.join(core, "__init__.py"))
    found = [top.find(f"``{p}``") for p in ENGINE]
    assert -1 not in found and found == sorted(found), found
    assert all(f"``{m}``" in top for m in ENGINE_GROUND)
    for package in ENGINE:
        folder = os.path.join(core, package)
        text = _docstring(os.path.join(folder, "__init__.py"))
        modules = [f[:-3] for f in os.listdir(folder) if f.endswith(".py") and f != "__init__.py"]
        assert modules and [m for m in modules if f"``{m}``" not in text] == [], package


def test_the_engine_packages_import_only_what_their_row_allows():
    """Every import inside the engine (lazy ones too) stays in its package, reads the ground, or
    goes to a package its ENGINE row names; the ground imports no package; and every row names
    only packages before it in the flow, so the engine's rooms have no circle and no upward arrow."""
    order = list(ENGINE)
    for package, allowed in ENGINE.items():
        assert all(order.index(a) < order.index(package) for a in allowed), package
    graph = _import_graph()
    assert _engine_violations(graph) == []
    assert len([m for m in graph if _engine_package(m)]) >= 35  # the scan saw the packages


def test_the_engine_rule_sees_a_step_reaching_forward():
    """The rule itself, on made-up imports: a file module reading the profiles (the shape the old
    cachefs -> integrate import had) and a ground module importing a step are refused; a step
    reading the ground or an allowed earlier step is not."""
    graph = {
        "addon.core.file.cachefs": {("addon.core.profiles.integrate", 26), ("addon.core.limits", 19)},
        "addon.core.limits": {("addon.core.file.safeio", 3)},
        "addon.core.edit.solve": {("addon.core.profiles.compute", 19), ("addon.core.geometry", 4)},
        "addon.core.material.lobes": {("addon.core.edit.microfacet", 7)},
    }
    assert _engine_violations(graph) == [
        "addon.core.file.cachefs:26 imports addon.core.profiles.integrate (file -> profiles)",
        "addon.core.limits:3 imports addon.core.file.safeio (ground -> file)",
        "addon.core.material.lobes:7 imports addon.core.edit.microfacet (material -> edit)",
    ]


# The floors of the house, lowest first. A module may import its own room (the longest name
# listed that it falls under) or a room on a lower floor; never one beside it or above it.
FLOORS = (
    # The engine's ground (``ENGINE_GROUND``, under "addon.core"); the package root and its
    # stdlib helpers.
    ("addon.core", "addon", "addon.script_args", "addon.wheel"),
    # The engine's steps, one floor each, in the order of the flow.
    *((f"addon.core.{package}",) for package in ENGINE),
    # The figure writer both sides export with, and the sample catalogue the tools and tests read.
    ("addon.tools.plots", "samples"),
    # The glue: per-material state, panels, jobs, the preview scene.
    ("addon.blender",),
    # One operator per file, standing on the glue.
    ("operators",),
    # The headless commands; the bridges among them drive the glue as a module (above).
    ("addon.tools",),
    # Entry points: the extension's (it gathers the operators and the glue), `python -m addon`,
    # `python -m samples`, the demo and the scripts.
    ("__init__", "addon.__main__", "samples.__main__", "samples.demo", "scripts"),
)


def _room(module):
    """(floor, room) of ``module``: the longest listed name it falls under."""
    best = None
    for floor, rooms in enumerate(FLOORS):
        for room in rooms:
            if _within(module, (room,)) and (best is None or len(room) > len(best[1])):
                best = (floor, room)
    return best


def _upward(graph):
    bad = []
    for name, edges in sorted(graph.items()):
        floor, room = _room(name)
        for target, line in sorted(edges):
            t_floor, t_room = _room(target)
            if t_room != room and t_floor >= floor:
                where = "above" if t_floor > floor else "beside"
                bad.append(f"{name}:{line} imports {target}, {where} it ({room} -> {t_room})")
    return bad


def test_imports_go_one_way_down():
    """Every import goes down a floor or stays in its room: the glue does not reach up for the
    operators (the entry point gathers both), the engine for the glue or the tools, and so on."""
    graph = _import_graph()
    assert [m for m in graph if _room(m) is None] == []  # every module has a floor
    assert _upward(graph) == []


def test_the_floor_check_sees_the_old_registration():
    """The shape this rule was written for: the glue importing an operator (the old
    registration.py) is upward; an operator importing the glue is not."""
    graph = {
        "addon.blender.registration": {("operators.analyse", 9)},
        "operators.analyse": {("addon.blender.jobs", 3)},
        "addon.blender.jobs": set(),
    }
    assert _upward(graph) == [
        "addon.blender.registration:9 imports operators.analyse, above it (addon.blender -> operators)"
    ]
