"""The windowed lane: Debian's Blender 3.4 in a real window under Xvfb (1920x1080), the
packaged legacy add-on installed as a user would, driven by timers and real X key and mouse
events (tests/windowed/drive.py): Load (a missing file, a good one, one cancelled with
Esc) -> Analyse -> slider moves -> Apply (a key and a right-click while it runs) -> Esc on a
second Apply -> undo, redo (ctrl+z, ctrl+shift+z) -> Build Preview -> save -> reopen -> two
hands-off Applies (pressed with a slider move; after the live preview settled).

Screenshots, the driver's JSON and Blender's log are kept in out/test-artifacts/windowed/."""

import json
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from _watch import crash_report, run_watched

pytestmark = pytest.mark.blender  # Blender in a window under Xvfb

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ARTIFACTS = os.path.join(ROOT, "out", "test-artifacts", "windowed")
TOOLS = ("blender", "xvfb-run", "xdotool", "import")

INSTALL = """
import bpy, addon_utils, sys
bpy.ops.preferences.addon_install(filepath={zip!r}, overwrite=True)
bpy.ops.preferences.addon_enable(module="brdf_moments")
if not addon_utils.check("brdf_moments")[1]:
    sys.exit("the add-on did not enable")
print("windowed: installed", {zip!r}, flush=True)
"""


TIMEOUT = 1500  # seconds for the whole session (4-8 min here)


@pytest.fixture(scope="module")
def lane(tmp_path_factory):
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        why = f"{', '.join(missing)} not installed, so the windowed lane cannot run (scripts/setup.sh installs them)"
        if os.environ.get("BRDF_MOMENTS_REQUIRE_LANES"):
            pytest.fail(why)
        pytest.skip(why)
    import samples

    tmp = tmp_path_factory.mktemp("windowed")
    built = subprocess.run(
        [sys.executable, os.path.join(ROOT, "scripts", "package.py"), str(tmp / "dist")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    legacy = next(p for p in built if p.endswith("-legacy.zip"))
    gold, other = tmp / "gold.binary", tmp / "rough.binary"
    shutil.copy(samples.sample_path("gold"), gold)
    shutil.copy(samples.sample_path("ggx_rough"), other)
    out = tmp / "out"
    # Blender's temporary directory (its crash report goes there) is this run's own.
    crash_dir = tmp / "blender-tmp"
    crash_dir.mkdir()
    env = dict(
        os.environ,
        BLENDER_USER_SCRIPTS=str(tmp / "scripts"),
        BLENDER_USER_CONFIG=str(tmp / "config"),
        TMPDIR=str(crash_dir),
    )
    cmd = [
        "xvfb-run",
        "-a",
        "-s",
        "-screen 0 1920x1080x24",
        "blender",
        "--factory-startup",
        "--python-exit-code",
        "1",
        "--python-expr",
        INSTALL.format(zip=legacy),
        "--python",
        os.path.join(ROOT, "tests", "windowed", "drive.py"),
        "--",
        "--out",
        str(out),
        "--gold",
        str(gold),
        "--other",
        str(other),
    ]
    code, why = run_watched(cmd, env, tmp / "blender.log", [out / "faulthandler.txt"], crash_dir, TIMEOUT)
    log = (tmp / "blender.log").read_text(errors="replace")
    # Kept for a person to look at (git-ignored): what the artist saw at each step.
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    os.makedirs(ARTIFACTS)
    for name in os.listdir(out) if out.is_dir() else []:
        if name.endswith((".png", ".json")):
            shutil.copy(out / name, ARTIFACTS)
    with open(os.path.join(ARTIFACTS, "blender.log"), "w") as fh:
        fh.write(log)
    report = crash_report(out / "faulthandler.txt", crash_dir)
    if report:
        with open(os.path.join(ARTIFACTS, "crash.txt"), "w") as fh:
            fh.write(report)
    if why is not None or not (out / "windowed.json").is_file():
        why = why or f"exited with code {code} before writing windowed.json"
        pytest.fail(f"Blender {why}\n{log[-4000:]}\n{report or '(no crash report)'}", pytrace=False)
    data = json.loads((out / "windowed.json").read_text())
    data["steps"] = {s["name"]: s for s in data["steps"]}
    return data, log, str(gold), str(other)


def edit_fields(state):
    return {
        k: state[k] for k in ("edited_path", "edited_profiles", "achieved_mu_slope", "achieved_sigma2", "edit_warnings")
    }


def analysis_fields(state):
    return {k: state[k] for k in ("source_path", "analysed", "profiles", "fit_mu_slope", "fit_sigma2")}


def test_the_session_ran_to_the_end_without_a_traceback(lane):
    data, log, _, _ = lane
    assert data["errors"] == [], data["errors"]
    assert data["blender"].startswith("3.4")
    assert "windowed: installed" in log and "Traceback" not in log
    assert list(data["steps"]) == [
        "start",
        "load_missing",
        "load",
        "load_cancelled",
        "analyse",
        "sliders",
        "apply",
        "apply_cancelled",
        "undo",
        "redo",
        "build_preview",
        "save",
        "reopen",
        "apply_at_once",
        "live",
        "apply_quiet",
        "apply_cancelled_live",
        "apply_lobes",
        "bound_lobes",
        "restore_lobes",
    ]


def test_load_a_missing_file_then_a_good_one_then_cancel_one(lane):
    from addon.core.file.merl import read_merl
    from addon.core.fits.curves import fit_material
    from addon.core.profiles.compute import compute_profiles

    data, _, gold, other = lane
    st = data["steps"]
    # A missing file: one line, nothing changed.
    assert st["load_missing"]["status"] == ["CANCELLED"]
    assert "missing.binary: no such file" in st["load_missing"]["message"]
    assert st["load_missing"]["state"] == st["start"]["state"] and not st["start"]["state"]["analysed"]
    # Load: the threaded analysis lands, with the fits this engine computes.
    load = st["load"]
    assert load["status"] == ["FINISHED"] and load["job"]["outcome"] == "finished"
    assert load["state"]["source_path"] == gold and load["state"]["analysed"]
    want = fit_material(compute_profiles(read_merl(gold)))
    assert load["state"]["fit_mu_slope"] == pytest.approx(want["mu_slope"], rel=1e-4)
    assert load["state"]["fit_sigma2"] == pytest.approx(want["sigma2"], rel=1e-4)
    # Esc during a Load of another file: the material keeps the first file and its analysis.
    attempts = st["load_cancelled"]["attempts"]
    cancelled = [a for a in attempts if a["job"]["outcome"] == "cancelled"]
    assert cancelled, [a["job"] for a in attempts]
    for a in cancelled:
        assert a["state"]["source_path"] == gold
        assert analysis_fields(a["state"]) == analysis_fields(load["state"])
    # Analyse again: the same file gives the same stored profiles.
    assert st["analyse"]["job"]["outcome"] == "finished"
    assert analysis_fields(st["analyse"]["state"]) == analysis_fields(load["state"])


def test_input_reaches_the_ui_while_apply_runs(lane):
    data, _, _, _ = lane
    inp = data["input"]
    assert inp["sidebar_after"] != inp["sidebar_before"]  # the N key toggled the 3D view's sidebar
    assert inp["job_running_after_key"]  # ... while the job was running
    # A right-click did not cancel it (it finished), and it was running when the right-click
    # arrived (the probe below). Whether it still runs a second later depends on how fast the
    # Apply is (4-7 s here now), so that is not asserted.
    assert data["steps"]["apply"]["job"]["outcome"] == "finished"
    # The probe handler behind the job got the key and the right-click while the job ran,
    # and not the Esc that cancelled the second Apply (the job keeps that one).
    seen = {(e["type"], e["job_running"]) for e in inp["probe_events"]}
    assert ("N", True) in seen and ("RIGHTMOUSE", True) in seen, inp["probe_events"]
    cancel = data["steps"]["apply_cancelled"]["job"]
    assert not [e for e in inp["probe_events"] if e["type"] == "ESC" and cancel["start"] <= e["t"] <= cancel["end"]]


def test_apply_reaches_the_sliders_and_a_cancelled_apply_changes_nothing(lane):
    from addon.core.file.merl import read_merl
    from addon.core.fits.curves import fit_material
    from addon.core.profiles.compute import compute_profiles

    data, _, gold, _ = lane
    st = data["steps"]
    sliders, apply = st["sliders"]["state"], st["apply"]["state"]
    assert sliders["sigma2"] == pytest.approx(1.6 * sliders["fit_sigma2"], rel=1e-5)
    assert os.path.isfile(apply["edited_path"]) and apply["edited_profiles"]
    # What the panel announced beside the sliders (SPEC §3: the variance asked for, the mean slope
    # the material's curve gives there) is what the table re-fits to, or the panel says it was not
    # reached and what the table re-fits (BENCHMARKS "Editing").
    said = apply["announced"]
    assert said is not None, apply
    assert apply["achieved_sigma2"] == pytest.approx(said["sigma2"], rel=0.01)
    if apply["achieved_mu_slope"] != pytest.approx(said["mu_slope"], abs=0.01):
        assert f"mean slope {apply['achieved_mu_slope']:+.3f} for {said['mu_slope']:+.3f}" in apply["edit_warnings"]
    # The table Blender wrote, measured again here: its fit is what the panel reports.
    edited = read_merl(apply["edited_path"])
    assert not np.array_equal(edited.rho, read_merl(gold).rho)
    refit = fit_material(compute_profiles(edited))
    assert refit["sigma2"] == pytest.approx(apply["achieved_sigma2"], rel=0.02)
    # The second Apply, Esc after a second: cancelled, the first Apply's result untouched.
    second = st["apply_cancelled"]
    assert second["running_before_esc"] and second["job"]["outcome"] == "cancelled"
    assert edit_fields(second["state"]) == edit_fields(apply)
    assert analysis_fields(second["state"]) == analysis_fields(apply)
    # An Apply cancelled once the preview exists: the live preview it paused shows the sliders
    # again (it stayed frozen on the last image before).
    third = st["apply_cancelled_live"]
    assert third["job"]["outcome"] == "cancelled" and third["preview"], third
    assert third["live_resumed"], third


def test_undo_and_redo_with_the_keys(lane):
    data, _, _, _ = lane
    st = data["steps"]
    undo, redo, apply = st["undo"]["state"], st["redo"]["state"], st["apply"]["state"]
    # ctrl+z takes back the Apply (the cancelled one made no undo step): back to the analysis.
    assert undo["edited_path"] == "" and undo["edited_profiles"] == ""
    assert analysis_fields(undo) == analysis_fields(st["analyse"]["state"])
    assert edit_fields(redo) == edit_fields(apply) and redo["sigma2"] == apply["sigma2"]


def test_build_preview_then_save_and_reopen(lane):
    data, _, _, _ = lane
    st = data["steps"]
    prev = st["build_preview"]
    assert prev["message"] is None and "FINISHED" in prev["status"] or "RUNNING_MODAL" in prev["status"]
    if prev["job"] and prev["job"]["label"] not in ("Analysing", "Re-synthesizing"):
        assert prev["job"]["outcome"] == "finished"
    assert prev["state"]["preview_material"] and "BRDF Moments Preview" in prev["state"]["scenes"]
    # The panel's thumbnail of it is an icon of the add-on's own, at the image's size (under 320 px).
    shown, image = prev["thumbnail"]
    assert shown is not None and shown == image, prev["thumbnail"]
    back, saved = st["reopen"]["state"], st["save"]["state"]
    assert os.path.isfile(st["save"]["blend"])
    for key in (
        "source_path",
        "profiles",
        "fit_mu_slope",
        "fit_sigma2",
        "mu_slope",
        "sigma2",
        "edited_path",
        "edited_profiles",
        "achieved_sigma2",
        "preview_material",
        "artist",
    ):
        assert back[key] == saved[key], key
    assert back["scenes"] == saved["scenes"]
    # The preview image comes back with the file, pixel for pixel (a generated image's pixels are
    # not saved: the measured sphere had come back black).
    assert st["save"]["preview"] is not None and st["reopen"]["preview"] == st["save"]["preview"]
    # Nothing of the add-on ran while the file operator was under way: the load_post handler's
    # plot and warm-up waited for it to return (Blender 3.4 crashed on a thread running then).
    assert st["reopen"]["quiet_before"] == [] and st["reopen"]["running_at_return"] == []


def test_the_artists_material_without_osl(lane):
    """No OSL in Debian's 3.4: the first Apply put Auto's approximation into the artist's own
    material, labelled with its stated error; the panel's menu set to the fitted lobes, Apply
    built them (Diffuse and Glossy GGX nodes, colours from a packed lookup the Layer Weight
    indexes), EEVEE drew them in the 3D view, and Restore took them out. The stated errors are
    measured again here on the table Blender wrote (issue 28)."""
    from addon.core.file.merl import read_merl
    from addon.core.material.lobes import LobeFit, closures_for, fit_lobes, measure

    data, _, _, _ = lane
    st = data["steps"]
    first = st["apply"]["state"]["artist"]
    assert first["used"] in ("lobes", "principled") and first["linked"], first
    assert ("lobes (error" if first["used"] == "lobes" else "Principled (error") in first["label"], first
    lobes_step = st["apply_lobes"]
    assert lobes_step["status"] == ["RUNNING_MODAL"] and lobes_step["job"]["outcome"] == "finished", lobes_step
    art, state = lobes_step["state"]["artist"], lobes_step["state"]
    assert art["choice"] == "LOBES" and art["used"] == "lobes" and art["linked"] and art["lookup_packed"], art
    assert "lobes (error" in art["label"]
    fit = LobeFit.from_dict(art["lobes"])
    # one closure per lobe: a Glossy (GGX or Beckmann) or, for a Fresnel-shaped lobe, a Principled
    glossy = [k for k in art["group"] if k in ("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic")]
    kinds = fit.kinds or ("ggx",) * fit.n_lobes
    assert len(glossy) == sum(k in ("ggx", "beckmann") for k in kinds)
    assert art["group"].count("ShaderNodeBsdfPrincipled") == sum(k == "ggx_fresnel" for k in kinds)
    assert art["group"].count("ShaderNodeTexImage") == fit.lookup_pixels().shape[0]
    # a Diffuse node only where the fit has a diffuse part
    assert ("ShaderNodeBsdfDiffuse" in art["group"]) == bool(np.any(fit.weights[0] > 0.0))
    assert "ShaderNodeLayerWeight" in art["group"]
    assert fit.shadowing == "separable"  # what 3.4's Cycles renders
    table = read_merl(state["edited_path"])
    err, alb = measure(fit, table)
    assert err == pytest.approx(fit.error, rel=1e-3) and alb == pytest.approx(fit.albedo_error, rel=1e-3, abs=1e-4)
    assert f"{100 * fit.error:.1f} %" in art["label"]
    # The window's scene renders with EEVEE (3.4's default), which draws every lobe round: the
    # lobes were fitted round; the fit is the engine's for that table (not a stale one).
    # and no Velvet (EEVEE draws it as a diffuse closure)
    assert art["engine"] == "BLENDER_EEVEE" and not fit.anisotropic and "velvet" not in kinds
    assert "ShaderNodeBsdfVelvet" not in art["group"]
    again = fit_lobes(table, shadowing="separable", **closures_for("BLENDER_EEVEE"))
    assert again.roughness == pytest.approx(fit.roughness) and again.error == pytest.approx(fit.error, rel=1e-3)
    assert os.path.isfile(lobes_step["shot"])
    back = st["restore_lobes"]
    assert back["status"] == ["FINISHED"] and not back["state"]["artist"]["linked"]
    assert back["state"]["artist"]["label"] == "" and back["state"]["artist"]["used"] == ""


def test_an_apply_in_the_reopened_file(lane):
    """Reopened, the file is ready to edit: the edits' shared setup was built by the file-load
    handler (not left to the Apply's child); a slider move, the live preview settling, then an
    Apply with hands off, which reaches the slider. Its time is the figure BENCHMARKS quotes for
    Apply in a window (target 3 s; not asserted, the machine is shared)."""
    data, _, _, _ = lane
    st = data["steps"]
    assert data["warm_after_reopen"]
    quiet = st["apply_quiet"]
    assert quiet["job"]["label"] == "Re-synthesizing" and quiet["job"]["outcome"] == "finished", quiet["job"]
    state = quiet["state"]
    assert state["sigma2"] == pytest.approx(1.3 * state["fit_sigma2"], rel=1e-5)
    # The re-fitted variance is the one asked for (a roughness edit solves for it), or the panel
    # says it fell short.
    said = state["announced"]
    assert said is not None, state
    if state["achieved_sigma2"] != pytest.approx(said["sigma2"], rel=0.02):
        assert f"variance {state['achieved_sigma2']:.4g} for {said['sigma2']:.4g}" in state["edit_warnings"], state
    assert state["edited_path"] != st["reopen"]["state"]["edited_path"] and os.path.isfile(state["edited_path"])
    # The live preview ran for these sliders before Apply, so Apply wrote its kept synthesis:
    # the synthesis stage (progress 3/10 to 6/10) is a lookup, not a solve (3-5 s here).
    assert data["live_before_quiet_apply"]
    # The slider's move redrew the edited sphere the artist sees above the sliders (its
    # screenshot, 13-live.png or the like, shows them in the Edit section).
    assert st["live"]["changed"] and os.path.isfile(st["live"]["shot"]), st["live"]
    assert data["preview_applied"]  # the written table, baked into the preview's edited sphere
    at = {(d, t): m for m, d, t in quiet["job"]["marks"]}
    synthesis = at[(6, 10)] - at[(3, 10)]
    assert synthesis < 1.0, quiet["job"]["marks"]
    at_once = st["apply_at_once"]["job"]
    assert at_once["outcome"] == "finished", at_once
    print(f"\nApply pressed with the slider's move, hands off: {at_once['end'] - at_once['start']:.1f} s")
    print(
        f"Apply in the reopened file after the live preview, hands off: "
        f"{quiet['job']['end'] - quiet['job']['start']:.1f} s (synthesis stage {synthesis:.2f} s)"
    )


def test_the_main_loop_keeps_running_during_jobs(lane):
    """Two clocks while each job runs (the figures go to BENCHMARKS.md): a 0.05 s Blender
    timer (the main loop) and a Python thread waking every 10 ms (the GIL). The jobs' work
    runs in a child process, so the GIL stays free: before that, the thread saw gaps of
    0.7-1.3 s here. The main loop's own gaps are Blender drawing in software GL; on a loaded
    machine they reach seconds with no job at all, so they are bounded by the idle control
    and Blender's own stalls outside jobs in the same session rather than by a fixed figure. The 0.2 s target is checked on
    what the add-on controls: the GIL, and the add-on's own runs of Python on the main thread
    (sampled every 10 ms by the same thread; a stall's stack says whose it was)."""
    data, _, _, _ = lane
    jobs, idle = data["jobs"], data["idle"]
    assert {j["label"] for j in jobs} >= {"Analysing", "Re-synthesizing"}
    print(
        f"\n{'idle control':>16} {'':>9}: {idle['end'] - idle['start']:6.1f} s, main loop {idle['largest_gap'] or idle['end'] - idle['start']:.3f} s, "
        f"GIL {idle['largest_gil_gap']:.3f} s, load {idle['loadavg'][0]:.1f}"
    )
    for j in jobs:
        print(
            f"{j['label']:>16} {j['outcome']:>9}: {j['seconds']:6.1f} s, main loop {j['largest_gap'] or 0:.3f} s, "
            f"GIL {j['largest_gil_gap']:.3f} s, the add-on's Python on the main thread {j['largest_ours']:.3f} s"
        )
    for j in jobs:
        if j.get("marks"):
            marks = ", ".join(f"{d}/{t} at {m - j['start']:.1f} s" for m, d, t in j["marks"])
            print(f"  {j['label']} {j['outcome']}: progress {marks}; Blender's own CPU {j.get('blender_cpu')} cores")
    print(f"  idle: Blender's own CPU {idle.get('blender_cpu')} cores")
    for st in data.get("stalls", []):
        where = " <- ".join(reversed(st["stack"])) or "Blender's C code (no Python on the main thread)"
        who = "the driver's own wait" if st["driver"] else where
        ours = f"; the add-on's Python {st['ours_seconds']:.3f} s of it" if st.get("ours_seconds") else ""
        print(f"  stall {st['length']:.2f} s during {st['job'] or 'no job'}: {who}{ours}")
    print(f"  the add-on's longest main-thread run: {data['ours_longest'][0]:.3f} s at {data['ours_longest'][1]}")
    for j in jobs:
        print(
            f"  {j['label']} {j['outcome']}: longest add-on run {j['largest_ours']:.3f} s at {j['largest_ours_where']}"
        )
    for g in data.get("gil_gaps", []):
        print(
            f"  GIL held {g['length']:.2f} s; then: "
            + "; ".join(f"{k}: {' <- '.join(reversed(v))}" for k, v in g["threads"].items())
        )
    idle_gap = idle["largest_gap"] or idle["end"] - idle["start"]  # no tick at all: the whole control
    # Blender's own longest stall with no job and no driver step, anywhere in the session (the
    # 3 s control can miss them: 1.2 s in it, 4.7 s later in one run here).
    alone = max((st["length"] for st in data.get("stalls", []) if not st["job"] and not st["driver"]), default=0.0)
    for j in jobs:
        assert j["largest_gil_gap"] < 0.3, j
        # The add-on's own Python on the main thread (drawing the panel, a job's modal and
        # finish; plots are drawn in a thread): the 0.2 s target, on the part the add-on controls.
        assert j["largest_ours"] < 0.2, j
        # No freeze beyond what the same machine shows idle (work on the main thread would
        # give one gap as long as the job: 40-60 s for an Apply here) ...
        assert (j["largest_gap"] or 0.0) < max(3.0, 2.5 * idle_gap, alone), (j, idle, alone)
        # ... and through a long job the main loop keeps turning: 20 ticks a second when
        # quiet, 5-6 at a load of 13 on 2 cores; frozen, it would tick once.
        if j["seconds"] > 30:
            assert j["ticks"] >= j["seconds"], j
    # Every main-loop stall during a job that the driver did not cause was Blender's own C code
    # (software-GL drawing: the same stalls come with no job): the add-on's Python held the
    # main thread for under 0.2 s of it. (A stall sampled once with our frames on the stack is
    # not ours by that alone: a cold-disk import of 30 ms inside a 2 s draw was, in CI.)
    for st in data.get("stalls", []):
        if st["job"] and not st["driver"]:
            # The 0.2 s is the add-on's main-thread CPU; on the wall its Python may take longer
            # while Blender's rasterizer threads hold both cores (1.0-1.9 cores of llvmpipe here
            # through every job): bounded loosely, so a real hog on the main thread still fails.
            assert st["ours_cpu_seconds"] < 0.2, st
            assert st["ours_seconds"] < 0.6, st


def test_the_sidebar_states_the_lobes_error_and_their_bound(lane):
    """Issue 37.4: with the fitted lobes applied and rendered in the 3D view, the panel offers
    Find the Bound; its job (node_bound, in the background) ends, and the sidebar, at Blender's
    default width, states the error and the bound, each figure whole on one line, no text cut.
    The bound is the engine's for the table Blender wrote, with 3.4's Smith term."""
    from addon.core.file.merl import read_merl
    from addon.core.material.lobes import LobeFit
    from addon.core.material.node_bound import node_bound

    data, _, _, _ = lane
    step = data["steps"]["bound_lobes"]
    assert step["status"] == ["RUNNING_MODAL"] and step["job"]["outcome"] == "finished", step
    fit = LobeFit.from_dict(step["state"]["artist"]["lobes"])
    assert step["state"]["artist"]["used"] == "lobes" and fit.bound is not None
    assert fit.bound == pytest.approx(node_bound(read_merl(step["state"]["edited_path"]), shadowing="separable"))
    assert fit.bound <= fit.error
    assert os.path.isfile(step["shot"])

    def sidebar(name):
        shot = next(s for s in data["panel_shots"] if s["step"] == name)
        return shot, [e["text"].replace("\u00a0", " ") for e in shot["drawn"] if e["panel"].startswith("VIEW3D_PT")]

    _, before = sidebar("lobes-applied")
    assert "Find the Bound" in before and not any(re.search(r"bound \d", line) for line in before), before
    shot, lines = sidebar("lobes-bound")
    assert "Find the Bound" not in lines
    for figure in (f"error {100 * fit.error:.1f} %", f"bound {100 * fit.bound:.1f} %"):
        assert any(figure in line for line in lines), (figure, lines)
    assert shot["cut"] == [] and shot["sidebar_width"] <= round(220 * data["ui"]["ui_scale"]) + 1


def test_screenshots_show_the_window(lane):
    import matplotlib.image

    data, _, _, _ = lane
    shots = [s["shot"] for s in data["steps"].values() if s.get("shot")]
    shots += [data["input"]["shot_during_job"]]
    assert len(shots) >= 6
    for shot in shots:
        name = os.path.basename(shot)
        img = matplotlib.image.imread(os.path.join(ARTIFACTS, name))
        assert img.shape[:2] == (1080, 1920), name
        assert img[..., :3].std() > 0.02, name  # not a blank screen


def _button_width(path):
    """The widest run of the factory theme's button grey in a screenshot of a panel: the width
    Blender gives a full-width button there, i.e. the panel's layout width."""
    import matplotlib.image

    img = matplotlib.image.imread(os.path.join(ARTIFACTS, os.path.basename(path)))[..., :3]
    grey = np.all(np.abs(img - 0.33) < 0.015, axis=2)
    best = 0
    for row in grey:
        edges = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        if len(starts):
            best = max(best, int((ends - starts).max()))
    return best


def _chart_span(path):
    """The longest run of the charts' background colour (plot_image's BACKGROUND, 41/255) that
    at least 3 rows of a screenshot have (a chart's rows above its title): its width as drawn."""
    import matplotlib.image

    img = np.round(matplotlib.image.imread(os.path.join(ARTIFACTS, os.path.basename(path)))[..., :3] * 255)
    hit = np.all(img == 41, axis=2)
    lengths = []
    for row in hit:
        edges = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        lengths += [int(n) for n in ends - starts if n >= 64]
    return max((n for n in set(lengths) if lengths.count(n) >= 3), default=0)


def test_the_panel_fits_blenders_default_width(lane):
    """Issue 29: in the 3D view's sidebar (tab BRDF Moments) and in Material Properties, at the
    widths a fresh Blender gives them, no text the panel draws is cut. Every text cell the panel
    drew in the window, and every cell of the whole panel (folded sections too) laid out at the
    same widths, is measured with blf in the UI font against the width its cell gets; the
    panel's width model is checked against the buttons in the screenshots."""
    data, _, _, _ = lane
    shots = data["panel_shots"]
    assert [s["step"] for s in shots] == [
        "start",
        *["loaded"] * 4,
        "sliders",
        "applied",
        "preview",
        "reopened",
        "lobes-chosen",
        "lobes-applied",
        "lobes-bound",
    ], [s["step"] for s in shots]
    assert {s["chart"] for s in shots if s["step"] == "loaded"} == {"ENERGY", "MEAN", "VARIANCE", "REGION"}
    assert data["cut_control"]  # the check finds a label that does not fit
    unit = data["ui"]["unit"]
    for shot in shots:
        assert shot["cut"] == [], (shot["step"], shot["chart"], shot["cut"])
        panels = {e["panel"].split("_PT_")[0] for e in shot["drawn"]}
        assert {"VIEW3D", "MATERIAL"} <= panels, (shot["step"], panels)
        # Blender's default sidebar: 220 px at scale 1 (UI_SIDEBAR_PANEL_WIDTH); the lane does not widen it.
        assert shot["sidebar_width"] <= round(220 * data["ui"]["ui_scale"]) + 1, shot["sidebar_width"]
        assert shot["sidebar"] and shot["properties"], shot  # at least the top of each
        if shot["step"] == "start":
            continue  # no file yet: no full-width button to measure
        drawn = _button_width(shot["sidebar"][0])  # the sliders and Load Set… span the sidebar's layout
        model = shot["content_width"]["VIEW_3D"]
        # The cells are measured against the model's width: it must not be wider than what
        # Blender draws (then a label the audit passes could still be cut on screen) ...
        assert model <= drawn + 2, (shot["step"], model, drawn)
        assert model >= drawn - unit, (shot["step"], model, drawn)  # ... nor needlessly narrow
    sections = {e["panel"] for s in shots for e in s["whole"]}
    assert {"whole panel at the VIEW_3D width", "whole panel at the PROPERTIES width"} <= sections
    texts = {e["text"] for s in shots for e in s["whole"]}
    for must in ("Fit", "RMSE", "Reset", "Apply", "Build Preview", "Edited Table", "Restore Shader", "Load Set…"):
        assert must in texts, must
    # The charts are drawn at the size the panel shows them (not Blender's 128 px thumbnail):
    # the layout's width less Blender's 4 px around a preview on each side.
    import matplotlib.image

    # On screen, the chart's background spans exactly that many pixels (drawn 1:1, not scaled:
    # Blender would shrink it if the panel's width model were wider than its layout).
    for shot in shots[1:]:
        for kind, pages in (("VIEW_3D", shot["sidebar"]), ("PROPERTIES", shot["properties"])):
            side = int(shot["content_width"][kind]) - 8
            assert [side, side] in shot["chart_sizes"], (shot["step"], kind, shot["chart_sizes"])
            assert _chart_span(pages[0]) == side, (shot["step"], kind, _chart_span(pages[0]), side)
    for shot in shots:
        for page in shot["sidebar"]:
            img = matplotlib.image.imread(os.path.join(ARTIFACTS, os.path.basename(page)))
            assert img.shape[1] == shot["sidebar_width"]
