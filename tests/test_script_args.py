"""Scripts that Blender runs read only the arguments after ``--`` (addon/script_args.py):
``blender -b -P samples/demo.py`` without ``--`` used to stop with "unrecognized arguments"."""

import json
import os
import shutil
import subprocess
import sys
import types

import pytest

from addon import script_args as sa

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLENDER = shutil.which("blender")

# Loads samples/demo.py as a module (its main() does not run) and prints what its parser read.
PROBE = """
import importlib.util, json, sys
spec = importlib.util.spec_from_file_location("demo_probe", {demo!r})
demo = importlib.util.module_from_spec(spec)
spec.loader.exec_module(demo)
print("ARGS " + json.dumps(vars(demo._args())), flush=True)
"""


def test_after_the_double_dash_only():
    assert sa.script_args(["blender", "-b", "-P", "x.py", "--", "--out", "o"], blender=True) == ["--out", "o"]
    assert sa.script_args(["x.py", "--", "--out", "o"], blender=False) == ["--out", "o"]
    assert sa.script_args(["blender", "-b", "-P", "x.py", "--"], blender=True) == []


def test_without_double_dash():
    # in Blender every argument is Blender's; under Python they are the script's
    assert sa.script_args(["blender", "-b", "-P", "x.py"], blender=True) == []
    assert sa.script_args(["x.py", "--out", "o"], blender=False) == ["--out", "o"]
    assert sa.script_args(["x.py"], blender=False) == []


def test_inside_blender_is_told_from_bpy(monkeypatch):
    fake = types.SimpleNamespace(app=types.SimpleNamespace(binary_path="/usr/bin/blender"))
    monkeypatch.setitem(sys.modules, "bpy", fake)
    assert sa.inside_blender()
    monkeypatch.setattr(sys, "argv", ["blender", "-b", "-P", "x.py"])
    assert sa.script_args() == []
    fake.app = types.SimpleNamespace(binary_path="", module=True)  # the bpy module
    assert not sa.inside_blender()
    monkeypatch.delitem(sys.modules, "bpy")
    assert not sa.inside_blender()
    assert sa.script_args(["x.py", "--out", "o"]) == ["--out", "o"]


@pytest.mark.blender
@pytest.mark.parametrize("tail", [[], ["--", "--sample", "gold", "--size", "64"]], ids=["no-dashes", "dashes"])
def test_demo_parses_its_arguments_in_a_real_blender(tmp_path, tail):
    if BLENDER is None:
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail("blender is not installed (scripts/setup.sh installs Debian's)")
        pytest.skip("no blender binary (scripts/setup.sh installs Debian's)")
    probe = tmp_path / "probe.py"
    probe.write_text(PROBE.format(demo=os.path.join(ROOT, "samples", "demo.py")))
    env = dict(os.environ, BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"), BLENDER_USER_CONFIG=str(tmp_path / "config"))
    res = subprocess.run(
        [BLENDER, "-b", "--factory-startup", "--python-exit-code", "1", "-P", str(probe), *tail],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-3000:]
    line = next((x for x in res.stdout.splitlines() if x.startswith("ARGS ")), None)
    assert line is not None, log[-3000:]
    args = json.loads(line[5:])
    if tail:
        assert (args["sample"], args["size"]) == ("gold", 64)
    else:
        assert (args["sample"], args["out"]) == ("ggx_glossy", os.path.join(ROOT, "out"))
