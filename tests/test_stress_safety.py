"""Stress: safety. Paths are used as given (never through a shell), export names cannot leave
their folder, nothing is unpickled or eval'd from data, and OSL sources are never built by
pasting strings together.

The code checks parse the product's Python (addon/, operators/, samples/, scripts/, the root
__init__.py) with ``ast``, so a comment or a docstring that mentions a word cannot trip them.
"""

import ast
import os
import re
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from _stress import ROOT, assert_one_line_error, run_cli, sha256
from addon.core.file.names import distinct_name, safe_export_path, safe_name

pytestmark = pytest.mark.stress

PRODUCT = ("addon", "operators", "samples", "scripts")


def _product_files():
    files = [os.path.join(ROOT, "__init__.py")]
    for top in PRODUCT:
        for folder, dirs, names in os.walk(os.path.join(ROOT, top)):
            dirs[:] = [d for d in dirs if not d.startswith((".", "__pycache__"))]
            files += [os.path.join(folder, n) for n in names if n.endswith(".py")]
    return sorted(files)


def _trees():
    for path in _product_files():
        with open(path, encoding="utf-8") as fh:
            yield os.path.relpath(path, ROOT), ast.parse(fh.read(), filename=path)


def _dotted(node):
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return f"{base}.{node.attr}" if base else node.attr
    return ""


UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "marshal", "shelve", "dill", "cloudpickle", "joblib"}
UNSAFE_CALLS = {
    "eval",
    "exec",
    "os.system",
    "os.popen",
    "subprocess.getoutput",
    "subprocess.getstatusoutput",
    "pickle.load",
    "pickle.loads",
    "yaml.load",
    "yaml.unsafe_load",
    "pty.spawn",
    "os.execl",
    "os.spawnl",
}
SUBPROCESS_CALLS = {
    "subprocess.run",
    "subprocess.Popen",
    "subprocess.call",
    "subprocess.check_call",
    "subprocess.check_output",
}


def test_the_product_code_is_scanned():
    files = _product_files()
    assert len(files) > 20 and any(f.endswith(os.path.join("core", "file", "merl.py")) for f in files)


# The one place that may unpickle: a job's result coming back from the job's own forked child
# through an anonymous pipe (multiprocessing's Connection.recv unpickled it all along; the
# arrays now travel out of band, pickle protocol 5). Nothing read from a file, a socket or the
# .blend is ever unpickled.
PICKLE_ALLOWED = {os.path.join("addon", "blender", "jobs.py")}


def test_no_unpickling_eval_exec_or_shell_anywhere_in_the_product(stress_log):
    problems = []
    for rel, tree in _trees():
        pickle_ok = rel in PICKLE_ALLOWED
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom) else [])
                bad = [
                    n for n in names if n and n.split(".")[0] in UNSAFE_MODULES and not (pickle_ok and n == "pickle")
                ]
                if bad:
                    problems.append(f"{rel}:{node.lineno} imports {bad}")
            if not isinstance(node, ast.Call):
                continue
            name = _dotted(node.func)
            if pickle_ok and name in ("pickle.loads", "pickle.dumps"):
                continue
            if name in UNSAFE_CALLS or name.split(".")[-1] in ("eval", "exec") and not name.startswith("self."):
                problems.append(f"{rel}:{node.lineno} calls {name}")
            for kw in node.keywords:
                if kw.arg == "shell" and not (isinstance(kw.value, ast.Constant) and kw.value.value is False):
                    problems.append(f"{rel}:{node.lineno} passes shell={ast.unparse(kw.value)}")
            if (
                name in SUBPROCESS_CALLS
                and node.args
                and isinstance(node.args[0], (ast.Constant, ast.JoinedStr, ast.BinOp))
            ):
                problems.append(f"{rel}:{node.lineno} runs a command line string (use an argument list)")
            if name.endswith(".load") and name.split(".")[0] in ("np", "numpy"):
                for kw in node.keywords:
                    if kw.arg == "allow_pickle" and not (
                        isinstance(kw.value, ast.Constant) and kw.value.value is False
                    ):
                        problems.append(f"{rel}:{node.lineno} np.load with allow_pickle={ast.unparse(kw.value)}")
    assert problems == []
    stress_log.record(
        "safety: code scan",
        "valid",
        f"{len(_product_files())} files, no eval/exec/shell, no pickle but the job pipe from its own forked child",
    )


def test_numpy_load_refuses_pickles_by_default():
    # The scan accepts np.load without allow_pickle because numpy's default is False: check it.
    import inspect

    assert inspect.signature(np.load).parameters["allow_pickle"].default is False


def test_a_pickled_operator_cache_is_rebuilt_not_loaded(tmp_path, stress_log):
    # A cache folder is data on disk: an object array planted there must never be unpickled.
    from addon.core.profiles.integrate import _load_operator

    folder = tmp_path / "operator-planted"
    folder.mkdir()
    for name in ("theta_o", "offsets", "cells", "weights", "albedo", "centroid", "local"):
        np.save(folder / f"{name}.npy", np.array([{"evil": name}], dtype=object), allow_pickle=True)
    assert _load_operator(str(folder)) is None
    stress_log.record("safety: data never executed", "error", "object arrays in the operator cache")


def test_profiles_json_with_code_in_it_is_data_only(tmp_path, stress_log):
    # fit accepts profiles JSON: strings where numbers belong are refused, never evaluated.
    marker = tmp_path / "PWNED"
    evil = {"theta_o": [0.0, 0.5, 1.0, 1.4], "kd": [0, 0, 0]}
    for ch in ("r", "g", "b", "avg"):
        evil[ch] = {"alpha": [f"__import__('os').system('touch {marker}')"] * 4}
    path = tmp_path / "evil.json"
    path.write_text(__import__("json").dumps(evil))
    res = run_cli("fit", path, "--out", tmp_path / "f.json")
    assert_one_line_error(res, "evil.json", "not a profiles JSON")
    assert not marker.exists()
    stress_log.record("safety: data never executed", "error", "code strings in a profiles JSON")


# --- paths used as given ----------------------------------------------------------------------

NASTY = [
    "a b; $(touch PWNED) `touch PWNED2`",
    "quote ' and \" and |cat",
    "dash -rf --out",
    "ünïcødé ✓",
    "*?[x]",
    "tab\tand\nnewline",
]


@pytest.mark.parametrize("name", NASTY)
def test_cli_uses_odd_file_names_literally(tmp_path, stress_log, name):
    import samples

    folder = tmp_path / f"in {name}"
    folder.mkdir()
    src = folder / f"{name}.binary"
    shutil.copy(samples.sample_path("gold"), src)
    digest = sha256(src)
    out = tmp_path / f"out {name}.json"
    res = run_cli("profiles", src, "--out", out, "--elevations", "2", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert out.is_file() and sha256(src) == digest
    res = run_cli("fit", src, "--out", tmp_path / f"fit {name}.json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert name in __import__("json").loads((tmp_path / f"fit {name}.json").read_text())["materials"]
    # Nothing ran: no file appeared but the ones asked for.
    made = sorted(p.name for p in tmp_path.iterdir())
    assert made == sorted([f"in {name}", f"out {name}.json", f"fit {name}.json"])
    assert os.listdir(folder) == [f"{name}.binary"]
    stress_log.record("safety: paths used literally", "valid", name)


def test_load_merl_uses_an_odd_path_literally(fresh, tmp_path, stress_log):
    import samples

    bpy = fresh
    src = tmp_path / "x; $(touch PWNED).binary"
    shutil.copy(samples.sample_path("gold"), src)
    bpy.data.materials.new("M")
    assert bpy.ops.brdf_moments.load_merl(filepath=str(src), material="M") == {"FINISHED"}
    assert bpy.data.materials["M"].brdf_moments.source_path == str(src)
    assert sorted(os.listdir(tmp_path)) == [src.name]
    stress_log.record("safety: paths used literally", "valid", "Load MERL")


# --- export names -----------------------------------------------------------------------------

ESCAPES = [
    "../evil",
    "../../etc/passwd",
    "/abs/path",
    "a/../../b",
    "..",
    ".",
    "",
    "..\\..\\win",
    "C:\\x\\y",
    "nul",
    "CON.txt",
    ".hidden",
    "name\x00with nul",
    "line\nbreak",
    "x" * 400,
    "é" * 300,
    "  . ",
    "a/b/c",
    "~/home",
    "$HOME",
    "%APPDATA%",
]


@pytest.mark.parametrize("name", ESCAPES)
def test_export_names_cannot_leave_the_folder(tmp_path, stress_log, name):
    folder = tmp_path / "exports"
    folder.mkdir()
    path = safe_export_path(folder, name)
    assert os.path.dirname(path) == os.path.realpath(folder)
    base = os.path.basename(path)
    assert base.endswith(".binary") and not base.startswith(".") and "\x00" not in base and "\n" not in base
    assert len(base.encode("utf-8")) <= 255
    with open(path, "wb") as fh:  # and it is a name the file system takes
        fh.write(b"ok")
    assert os.listdir(folder) == [base] and sorted(os.listdir(tmp_path)) == ["exports"]
    stress_log.record("safety: export names", "clamped", repr(name)[:40])


def test_a_link_planted_in_the_folder_cannot_redirect_an_export(tmp_path, stress_log):
    folder = tmp_path / "exports"
    folder.mkdir()
    outside = tmp_path / "outside.binary"
    os.symlink(outside, folder / "gold.binary")
    with pytest.raises(ValueError, match="leave the folder"):
        safe_export_path(folder, "gold")
    assert not outside.exists()
    with pytest.raises(ValueError):
        safe_export_path("", "gold")
    stress_log.record("safety: export names", "error", "symlink out of the folder")


@settings(
    max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(name=st.text(min_size=0, max_size=300))
@example(name="x" * 400)
@example(name="..")
def test_any_text_becomes_a_file_name_inside_the_folder(tmp_path, stress_log, name):
    folder = tmp_path / "exports"
    folder.mkdir(exist_ok=True)
    path = safe_export_path(folder, name, suffix=".json")
    assert os.path.dirname(path) == os.path.realpath(folder)
    base = os.path.basename(path)
    assert base not in (".", "..") and "/" not in base and "\x00" not in base and not base.startswith(".")
    assert len(base.encode("utf-8")) <= 255
    assert safe_name(safe_name(name)) == safe_name(name)  # cleaning is idempotent
    other = distinct_name(name)  # the analyze command's per-material names: same guarantees
    assert "/" not in other and "\x00" not in other and other not in (".", "..") and not other.startswith(".")
    assert len(other.encode("utf-8")) <= 250
    stress_log.record("safety: export names (random text)", "valid" if safe_name(name) == name else "clamped")


# --- OSL --------------------------------------------------------------------------------------

# An OSL shader header (a parameter list with OSL types) or a closure declaration; English
# prose in docstrings ("the OSL shader renders ...") does not match.
OSL_SOURCE = re.compile(
    r"\b(shader|surface)\s+\w+\s*\(\s*(output\s+)?(float|color|point|vector|normal|string|int|"
    r"closure)\b|\bclosure\s+color\s+\w+|\boutput\s+closure\b"
)


def test_no_python_code_carries_or_builds_osl_source(stress_log):
    """OSL shaders live in .osl files shipped with the extension; Python only points nodes at
    them. A string that holds OSL source, or an f-string naming an .osl file, would mean a
    shader (or its name) assembled from data."""
    problems = []
    for rel, tree in _trees():
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and OSL_SOURCE.search(node.value):
                problems.append(f"{rel}:{node.lineno} holds OSL source in a string")
            if isinstance(node, ast.JoinedStr):
                text = "".join(v.value for v in node.values if isinstance(v, ast.Constant))
                if OSL_SOURCE.search(text) or ".osl" in text:
                    problems.append(f"{rel}:{node.lineno} formats OSL source or an .osl name")
            if (
                isinstance(node, ast.Call)
                and _dotted(node.func).endswith("osl_compile")
                and node.args
                and isinstance(node.args[0], (ast.JoinedStr, ast.BinOp))
            ):
                problems.append(f"{rel}:{node.lineno} compiles OSL built from pieces")
    assert problems == []
    stress_log.record("safety: OSL", "valid", "no OSL source in Python")


def _osl_files():
    out = []
    for folder, dirs, names in os.walk(os.path.join(ROOT, "addon")):
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        out += [os.path.join(folder, n) for n in names if n.endswith(".osl")]
    return sorted(out)


def test_shipped_osl_files_are_static(stress_log):
    files = _osl_files()
    if not files:
        pytest.skip("no .osl file is shipped yet (the Python side is checked above)")
    for path in files:
        text = open(path, encoding="utf-8").read()
        # No template placeholders a formatter would fill: {name}, ${name}, %(name)s.
        assert not re.search(r"\{[A-Za-z_]\w*\}|\$\{|%\(\w+\)s", text), path
        assert OSL_SOURCE.search(text), f"{path} does not look like an OSL shader"
        stress_log.record("safety: OSL", "valid", os.path.basename(path))
