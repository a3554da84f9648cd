"""Lane 2: a real ``blender -b`` (Debian's 3.4.1, no OSL) installs the packaged legacy
add-on the way a user would (Preferences > Install) and runs the demo flow through it."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

pytestmark = pytest.mark.blender  # lane 2: Debian's blender -b

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLENDER = shutil.which("blender")

INSTALL = """
import bpy, sys
zip_path = {zip!r}
bpy.ops.preferences.addon_install(filepath=zip_path, overwrite=True)
bpy.ops.preferences.addon_enable(module="brdf_moments")
import addon_utils
loaded, enabled = addon_utils.check("brdf_moments")
if not enabled:
    sys.exit("the add-on did not enable")
print("lane: installed", zip_path, flush=True)
"""


@pytest.fixture(scope="module")
def lane_run(tmp_path_factory):
    if BLENDER is None:
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail("blender is not installed, so the blender -b lane cannot run (scripts/setup.sh installs it)")
        pytest.skip("no blender binary (scripts/setup.sh installs Debian's)")
    tmp = tmp_path_factory.mktemp("lane")
    built = subprocess.run(
        [sys.executable, os.path.join(ROOT, "scripts", "package.py"), str(tmp / "dist")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    legacy = next(p for p in built if p.endswith("-legacy.zip"))
    out = tmp / "out"
    env = dict(os.environ, BLENDER_USER_SCRIPTS=str(tmp / "scripts"), BLENDER_USER_CONFIG=str(tmp / "config"))
    res = subprocess.run(
        [
            BLENDER,
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python-expr",
            INSTALL.format(zip=legacy),
            "-P",
            os.path.join(ROOT, "samples", "demo.py"),
            "-P",
            os.path.join(ROOT, "tests", "blender", "lane_operators.py"),
            "--",
            "--installed",
            "--out",
            str(out),
            "--size",
            "64",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=1200,
    )
    return res, out, tmp


def test_legacy_addon_runs_the_whole_flow_in_blender_34(lane_run, sample_table):
    from addon.core.profiles.compute import compute_profiles

    res, out, tmp = lane_run
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-4000:]
    assert "lane: installed" in log
    # The copy Blender runs is the installed one, not this checkout.
    assert os.path.isdir(tmp / "scripts" / "addons" / "brdf_moments")
    summary = json.loads((out / "demo.json").read_text())
    assert summary["blender"].startswith("3.4")
    for name in (
        "ggx_glossy_edited.binary",
        "ggx_glossy_profiles.json",
        "ggx_glossy_measured_profiles.png",
        "ggx_glossy_edited_profiles.png",
    ):
        assert name in summary["files"]
    # Same engine, other numpy/scipy: the profiles Blender 3.4 measured agree with ours.
    data = json.loads((out / "ggx_glossy_profiles.json").read_text())
    ours = compute_profiles(sample_table("ggx_glossy"))
    for key in ("alpha", "mu_theta", "sigma_tt", "sigma_pp"):
        np.testing.assert_allclose(data["measured"]["avg"][key], ours["avg"][key], rtol=1e-6, atol=1e-9)
    # The edit (warp mode: a roughness edit to 1.5x the variance, 80 % energy), judged as SPEC §6
    # does: the written table re-measured view by view against what the edit announced (measured
    # on that table), and the whole demo meets it.
    per_view = summary["per_view"]
    assert per_view["meets"]
    assert per_view["energy"] < 0.02 and per_view["mean"] < 0.005
    assert per_view["variance_median"] < 0.02 and per_view["variance_worst"] < 0.02
    # What the panel showed beside the sliders before Apply: the variance asked for (inside the
    # material's region) and the mean slope its curve gives; the table lands on both.
    announced = summary["announced"]
    assert announced["sigma2"] == pytest.approx(summary["target"]["sigma2"], rel=1e-6)
    assert summary["reached"]["sigma2"] == pytest.approx(announced["sigma2"], rel=0.01)
    assert summary["reached"]["mu_slope"] == pytest.approx(announced["mu_slope"], abs=0.01)
    # The preview took the baked path (this Blender has no OSL) and rendered both spheres.
    assert summary["renders"] and os.path.isfile(summary["renders"][0])
    assert "(baked)" in log or "(baked," in log
    assert "Traceback" not in log


def test_analyse_and_reset_run_in_blender_34(lane_run):
    # The two operators the demo does not call, in the same session, on the material it left.
    res, out, _ = lane_run
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    ops = json.loads((out / "operators.json").read_text())
    assert ops["ran"] == {"analyse": ["FINISHED"], "reset_sliders": ["FINISHED"], "restore_material": ["FINISHED"]}
    # The script zeroed the fit first: re-analysing the file restores it.
    for key in ("mu_slope", "sigma2"):
        assert ops["fit_after"][key] == pytest.approx(ops["fit_before"][key], rel=1e-6)
    # The demo had moved the sliders; Reset puts them back on the fit.
    assert ops["edited_sliders"]["strength"] != 1.0
    assert ops["reset_sliders"]["strength"] == 1.0
    assert ops["reset_sliders"]["sigma2"] == pytest.approx(ops["fit_after"]["sigma2"], rel=1e-6)
    assert ops["reset_sliders"]["mu_slope"] == pytest.approx(
        min(max(ops["fit_after"]["mu_slope"], -2.0), 0.0), abs=1e-6
    )


def test_apply_edits_the_material_itself_in_blender_34(lane_run):
    """No OSL in Debian's 3.4: Apply (Auto) put the closer approximation into the demo's material,
    labelled as one; Restore took it out. The fitted lobes, chosen explicitly, build in 3.4 too:
    Diffuse, single-scattering GGX and Beckmann Glossy and Principled (Fresnel lobe) nodes reading
    a packed lookup, fitted with 3.4's separable Smith term. The plot survived a save and reopen."""
    res, out, _ = lane_run
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    ops = json.loads((out / "operators.json").read_text())
    art = ops["artist"]
    # Auto installs the closer of the two in BRDF error: since the lobes may be Fresnel-shaped
    # (issue 37) that is the lobes on the demo's edit (measured 6.5 %), the Principled before
    assert art["used"] in ("lobes", "principled") and art["linked"]
    assert ("lobes (error" if art["used"] == "lobes" else "Principled (error") in art["label"]
    if art["used"] == "principled":
        # the demo widens ggx_glossy's lobe 1.5x (GGX alpha 0.1, Blender roughness sqrt(0.1) =
        # 0.316): the fit is rougher (measured 0.347; sqrt(1.5) x the width would be 0.35)
        assert "ShaderNodeBsdfPrincipled" in art["group"]
        assert art["principled"]["roughness"] > 0.33 and 0.0 < art["principled"]["error"] < 1.0
    else:
        assert 0.0 < art["lobes"]["error"] < 0.10 and art["lobes"]["albedo_error"] < 0.05
    assert "BRDF Moments edit" not in art["after_restore"]
    lobes = art["lobes_run"]
    assert lobes["ran"] == ["FINISHED"] and lobes["used"] == "lobes" and lobes["linked"] and lobes["packed"]
    assert "lobes (error" in lobes["label"]
    fit = lobes["lobes"]
    assert fit["shadowing"] == "separable"
    # stretched lobes (an aspect per view other than 1) take 3.4's Anisotropic node and K more rows
    stretched = any(q != 1.0 for row in fit["aspect"] for q in row)
    kind = "ShaderNodeBsdfAnisotropic" if stretched else "ShaderNodeBsdfGlossy"
    # a Glossy of each lobe's distribution, a Principled (GGX) for a lobe times the Fresnel factor
    kinds = fit.get("kinds", ["ggx"] * len(fit["roughness"]))
    want = sorted(
        ["ShaderNodeBsdfPrincipled", "GGX"] if k == "ggx_fresnel" else [kind, "BECKMANN" if k == "beckmann" else "GGX"]
        for k in kinds
    )
    assert lobes["distributions"] == want
    diffuse = any(v > 0.0 for row in fit["weights"][0] for v in row)
    glossy = sum(k != "ggx_fresnel" for k in kinds)
    rows = int(diffuse) + len(kinds) + (glossy if stretched else 0)
    assert lobes["group"].count("ShaderNodeTexImage") == rows
    assert ("ShaderNodeBsdfDiffuse" in lobes["group"]) == diffuse and "ShaderNodeLayerWeight" in lobes["group"]
    # the lobes meet the albedo; Auto kept the closer in BRDF error
    assert fit["error"] < 1.0 and fit["albedo_error"] < 0.05
    if art["used"] == "principled":
        assert art["principled"]["error"] < fit["error"]
    assert lobes["restore"] == ["FINISHED"] and "BRDF Moments edit" not in lobes["after_restore"]
    assert ops["reopened"]["plot"] and ops["reopened"]["plot_drawn"] > 0.01


# --- every Blender command the README shows, exactly as written --------------------------------


def readme_blender_commands():
    """The `blender …` commands of README.md (inline code and sh blocks), as written."""
    import re

    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as fh:
        text = fh.read()
    found = [" ".join(c.split()) for c in re.findall(r"`(blender [^`]+)`", text)]
    found += [line.split("#")[0].strip() for line in text.splitlines() if line.startswith("blender ")]
    return sorted({c for c in found if " -P " in c or " --python " in c})


def fresh_clone(dest):
    """The repository's files as a fresh clone has them: what git tracks (and new files not
    yet committed), none of this checkout's caches, outputs or venvs."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    for rel in filter(None, (os.fsdecode(r) for r in listed)):
        src = os.path.join(ROOT, rel)
        if os.path.isfile(src) and not os.path.islink(src):
            os.makedirs(os.path.dirname(os.path.join(dest, rel)) or dest, exist_ok=True)
            shutil.copy2(src, os.path.join(dest, rel))
    return dest


def test_the_readme_shows_the_blender_commands_the_lane_runs():
    commands = readme_blender_commands()
    assert "blender -b -P samples/demo.py -- --out out" in commands
    assert "blender -b --factory-startup --python-exit-code 1 -P samples/demo.py -- --out out" in commands


@pytest.mark.parametrize("command", readme_blender_commands())
def test_every_readme_blender_command_exits_0(command, tmp_path):
    """Issue 29: the demo ran to "demo: done", then Blender 3.4 crashed at exit (code 139) in
    addon_utils.disable_all. Each README command, run as written from a fresh copy of the
    repository (the demo enables that copy as the user's add-on), must exit 0."""
    import shlex

    if BLENDER is None:
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail("blender is not installed, so the blender -b lane cannot run")
        pytest.skip("no blender binary (scripts/setup.sh installs Debian's)")
    clone = fresh_clone(tmp_path / "clone")
    argv = shlex.split(command)
    assert argv[0] == "blender"
    env = dict(
        os.environ,  # the shared sample and operator caches (BRDF_MOMENTS_*) only save time
        BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"),
        BLENDER_USER_CONFIG=str(tmp_path / "config"),
    )
    res = subprocess.run([BLENDER, *argv[1:]], cwd=clone, capture_output=True, text=True, env=env, timeout=1200)
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-4000:]
    assert "demo: done" in log and "Traceback" not in log and "crash" not in log.lower()
    summary = json.loads((clone / "out" / "demo.json").read_text())
    assert summary["blender"].startswith("3.4") and summary["renders"]


def test_register_unregister_register_with_work_in_flight_in_blender_34(tmp_path):
    """The lifecycle cycle of tests/blender/cycle.py (checked as in tests/test_lifecycle.py)
    in Debian's Blender 3.4, the add-on installed from the packaged legacy zip."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from test_lifecycle import check_cycle

    if BLENDER is None:
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail("blender is not installed, so the blender -b lane cannot run")
        pytest.skip("no blender binary (scripts/setup.sh installs Debian's)")
    built = subprocess.run(
        [sys.executable, os.path.join(ROOT, "scripts", "package.py"), str(tmp_path / "dist")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    legacy = next(p for p in built if p.endswith("-legacy.zip"))
    env = dict(os.environ, BLENDER_USER_SCRIPTS=str(tmp_path / "scripts"), BLENDER_USER_CONFIG=str(tmp_path / "config"))
    res = subprocess.run(
        [
            BLENDER,
            "-b",
            "--factory-startup",
            "--python-exit-code",
            "1",
            "--python-expr",
            INSTALL.format(zip=legacy),
            "-P",
            os.path.join(ROOT, "tests", "blender", "cycle.py"),
            "--",
            "--module",
            "brdf_moments",
            "--out",
            str(tmp_path / "out"),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=1200,
    )
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-4000:]
    assert "cycle: done" in log
    result = json.loads((tmp_path / "out" / "cycle.json").read_text())
    assert result["blender"].startswith("3.4")
    check_cycle(result)
