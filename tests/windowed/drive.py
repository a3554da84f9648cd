"""The windowed lane's driver: runs inside a real Blender window (Xvfb), as an artist would,
with the packaged legacy add-on installed, driven by ``bpy.app.timers`` and real X events
(xdotool). tests/test_windowed_lane.py starts it and checks what it wrote.

Usage: blender --factory-startup --python drive.py -- --out DIR --gold FILE --other FILE

Writes DIR/windowed.json: a snapshot of the material after every step, what happened to
the real key presses, every job's outcome with the main loop's largest stall while it ran
(a 0.05 s timer records its gaps), and screenshots DIR/NN-step.png (ImageMagick ``import``).
"""

import hashlib
import json
import os
import subprocess
import sys
import threading
import time
import traceback

import bpy

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from addon.script_args import script_args  # noqa: E402  (the repository's, not the installed add-on's)

argv = script_args()
OUT = argv[argv.index("--out") + 1]
GOLD = argv[argv.index("--gold") + 1]
OTHER = argv[argv.index("--other") + 1]
MAT = "Material"  # the default cube's
os.makedirs(OUT, exist_ok=True)
# A crash dumps every Python thread's stack here (Blender's own report shows one thread only).
import faulthandler  # noqa: E402

_FAULTS = open(os.path.join(OUT, "faulthandler.txt"), "w")  # noqa: SIM115 - open for the whole session
faulthandler.enable(file=_FAULTS, all_threads=True)

result = {"blender": bpy.app.version_string, "steps": [], "jobs": [], "input": {}, "errors": [], "panel_shots": []}
ticks = []  # main-loop timer ticks (time.monotonic)


def jobs():
    return sys.modules["brdf_moments.addon.blender.jobs"]


def log(*args):
    print("windowed:", *args, flush=True)


# --- the window -------------------------------------------------------------------------------


def window():
    return bpy.context.window_manager.windows[0]


def area(kind):
    return next(a for a in window().screen.areas if a.type == kind)


def override(kind="VIEW_3D"):
    a = area(kind)
    region = next(r for r in a.regions if r.type == "WINDOW")
    return bpy.context.temp_override(window=window(), area=a, region=region)


def centre(kind):
    """An area's centre in X screen coordinates (Blender counts y from the bottom)."""
    a, win = area(kind), window()
    return a.x + a.width // 2, win.height - (a.y + a.height // 2)


driver_busy = []  # (start, end): the driver itself blocked the main loop (a waited-for subprocess)


def blocking(cmd, timeout):
    """A subprocess the driver waits for, on the main thread: its time is the driver's, so the
    main-loop gaps that overlap it are not charged to a job."""
    t0 = time.monotonic()
    try:
        return subprocess.run(cmd, check=True, timeout=timeout)
    finally:
        driver_busy.append((t0, time.monotonic()))


def xdo(*args, wait=True):
    cmd = ["xdotool", *map(str, args)]
    return blocking(cmd, 30) if wait else subprocess.Popen(cmd)


def key_over(kind, key, wait=True):
    """A real key press with the pointer over an area (keys go to the area under the pointer)."""
    x, y = centre(kind)
    xdo("mousemove", x, y)
    return xdo("key", key, wait=wait)


def redraw():
    for a in window().screen.areas:
        a.tag_redraw()


def screenshot(name, wait=True):
    path = os.path.join(OUT, f"{len(result['steps']):02d}-{name}.png")
    cmd = ["import", "-window", "root", path]
    if wait:
        blocking(cmd, 60)
    else:
        subprocess.Popen(cmd)  # during a job: do not stall the main loop being measured
    return path


# --- a second modal handler, behind the job's: it sees only what the job lets through -------

PROBE_EVENTS = []


class WINDOWED_OT_probe(bpy.types.Operator):
    bl_idname = "wm.windowed_probe"
    bl_label = "Windowed lane probe"

    def invoke(self, context, event):
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.value == "PRESS" and event.type in {"RIGHTMOUSE", "N", "ESC"}:
            PROBE_EVENTS.append({"type": event.type, "t": time.monotonic(), "job_running": bool(jobs().running())})
        return {"PASS_THROUGH"}


bpy.utils.register_class(WINDOWED_OT_probe)


# --- the material -----------------------------------------------------------------------------


def digest(text):
    return hashlib.sha1(text.encode()).hexdigest()[:16] if text else ""


def snapshot():
    mat = bpy.data.materials.get(MAT)
    s = mat.brdf_moments
    return {
        "source_path": s.source_path,
        "analysed": s.analysed,
        "fit_mu_slope": s.fit_mu_slope,
        "fit_sigma2": s.fit_sigma2,
        "mu_slope": s.mu_slope,
        "sigma2": s.sigma2,
        "profiles": digest(s.profiles_data),
        "edited_path": s.edited_path,
        "edited_profiles": digest(s.edited_profiles_data),
        "achieved_mu_slope": s.achieved_mu_slope,
        "achieved_sigma2": s.achieved_sigma2,
        "edit_warnings": s.edit_warnings,
        "announced": json.loads(s.announced_json) if s.announced_json else None,
        "preview_material": s.preview_material,
        "scenes": sorted(sc.name for sc in bpy.data.scenes),
        "window_scene": window().scene.name,
        "artist": artist_material(mat),
    }


def artist_material(mat):
    """What Apply put into the artist's own material (issue 28): the installed approximation,
    its label, the group's node types, whether it feeds the output, and the lookup's packing."""
    s = mat.brdf_moments
    node = mat.node_tree.nodes.get("BRDF Moments edit") if mat.node_tree else None
    nodes = list(node.node_tree.nodes) if node is not None and node.node_tree else []
    lookup = bpy.data.images.get(f"BRDFM lookup: {mat.name}")
    return {
        "used": s.artist_shader_used,
        "choice": s.artist_shader,
        "label": node.label if node is not None else "",
        "group": sorted(n.bl_idname for n in nodes),
        "linked": bool(node is not None and node.outputs[0].is_linked),
        "lobes": json.loads(s.lobes_data) if s.lobes_data else None,
        "principled": json.loads(s.principled_data) if s.principled_data else None,
        "lookup_packed": bool(lookup is not None and lookup.packed_file is not None),
        "engine": bpy.context.scene.render.engine,
    }


def preview_digest():
    img = bpy.data.images.get(f"BRDF Moments preview: {MAT}")
    if img is None:
        return None
    import numpy as np

    buf = np.empty(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(buf)
    return hashlib.sha1(buf.tobytes()).hexdigest()


def thumbnail():
    """The preview's thumbnail among the add-on's icons: [its size, the preview image's size]."""
    icons = sys.modules["brdf_moments.addon.blender.icons"]
    px = icons.pixels(icons.thumbnail_key(MAT))
    img = bpy.data.images.get(f"BRDF Moments preview: {MAT}")
    return [list(px.shape[1::-1]) if px is not None else None, list(img.size) if img is not None else None]


def record(name, **extra):
    step = {"name": name, "state": snapshot(), "t": time.monotonic(), **extra}
    result["steps"].append(step)
    log(name, json.dumps(extra)[:300])
    return step


def run_op(op, mode="EXEC_DEFAULT", **kwargs):
    """An operator call as the UI makes it; an ERROR report comes back as its message."""
    with override():
        try:
            return sorted(op(mode, **kwargs)), None
        except RuntimeError as exc:
            return ["CANCELLED"], str(exc).strip()


def wait_jobs():
    """Until every job has ended and the images it asked for (drawn off the main thread) are in."""
    images = sys.modules.get("brdf_moments.addon.blender.images")
    while jobs().running() or (images is not None and images.drawing()):
        yield 0.05


def ours_running():
    """The add-on's threads at work now (a job's listener included; not the slider worker
    waiting for the next move, which runs no Python)."""
    state = sys.modules.get("brdf_moments.addon.blender.state")
    idle = state is not None and not state._ANNOUNCER.busy()
    return sorted(
        t.name
        for t in threading.enumerate()
        if t.name.startswith("brdf_moments") and t.is_alive() and not (idle and t.name == "brdf_moments: announce")
    )


def until_quiet(limit=30.0):
    """Until none of the add-on's threads runs. A script's bpy.ops.wm.save_as_mainfile or
    open_mainfile in Blender 3.4's window crashes when any thread runs numpy meanwhile
    (lifecycle's docstring): that is Blender's, and a script must wait, as this one does."""
    t0 = time.monotonic()
    while ours_running() and time.monotonic() - t0 < limit:
        yield 0.05


def last_job():
    return jobs().HISTORY[-1] if jobs().HISTORY else None


class held_apply:
    """Apply's child sleeps ``seconds`` after its work: the job stays running long enough for a
    key press to arrive while it runs. On this machine Blender's software-GL frames hold the main
    loop for up to ~4 s, so an event may be handled only then, and an Apply takes 2-4 s; without
    the hold the key could race the job's end. The job machinery (the modal handler, the events
    it passes on or keeps, Esc) is the real one; the held Apply's time is not quoted."""

    def __init__(self, seconds):
        self.seconds = seconds

    def __enter__(self):
        cls = sys.modules["brdf_moments.operators.apply_edit"].BRDFMOMENTS_OT_apply_edit
        self.cls, self.start, hold = cls, cls.start, self.seconds

        def start(op, context):
            work = self.start(op, context)

            def held(report_progress):
                out = work(report_progress)
                time.sleep(hold)  # in the child process
                return out

            return held

        cls.start = start
        return self

    def __exit__(self, *exc):
        self.cls.start = self.start


# --- the panel at Blender's default width ------------------------------------------------------
# Issue 29: the panel is checked where an artist sees it, in the 3D view's sidebar (tab "BRDF
# Moments") and in Material Properties, at the widths a fresh Blender gives them. The panel
# records every text cell it draws with the width that cell gets (addon/blender/panel.py,
# AUDIT); here each text is measured with blf in the UI's font and must fit its cell. The
# panel's width model is checked against the screenshots in tests/test_windowed_lane.py.

# What a cell needs beside its text, in widget units (Blender's text margins are 0.4 unit a
# side; an icon takes 1 unit; a drop-down's arrow 1; a checkbox's box 1).
CELL_PADDING = {"label": 0.5, "button": 0.9, "menu": 1.9, "slider": 1.3, "check": 1.5}


def panel_module():
    return sys.modules["brdf_moments.addon.blender.panel"]


def widget_unit():
    system = bpy.context.preferences.system
    if bpy.app.version >= (4, 0, 0):
        return int(round(18.0 * system.ui_scale)) + 2 * system.pixel_size
    return int((20 * system.dpi * system.pixel_size + 36) / 72)


def text_px(text):
    import blf

    size = bpy.context.preferences.ui_styles[0].widget_label.points * bpy.context.preferences.system.ui_scale
    try:
        blf.size(0, size)
    except TypeError:
        blf.size(0, size, 72)
    return blf.dimensions(0, text)[0]


def cut_cells(entries):
    """The recorded cells whose text does not fit: what Blender would draw with an ellipsis."""
    unit = widget_unit()
    out = []
    for e in entries:
        need = text_px(e["text"]) + CELL_PADDING[e["kind"]] * unit + (unit if e["icon"] else 0)
        if need > e["avail"] + 0.5:
            out.append({**e, "need": round(need, 1)})
    return out


def ui_region(kind):
    return next(r for r in area(kind).regions if r.type == ("UI" if kind == "VIEW_3D" else "WINDOW"))


def crop(region, name):
    """Screenshots of one region, the panel itself: the top, then page after page as the
    mouse wheel scrolls it (up to 4), until a page shows nothing new; scrolled back after."""
    y = window().height - region.y - region.height
    paths, last = [], None
    xdo("mousemove", region.x + region.width // 2, y + region.height // 2)
    for page in range(4):
        path = os.path.join(OUT, f"panel-{len(result['panel_shots']):02d}-{name}-{page}.png")
        blocking(["import", "-window", "root", "-crop", f"{region.width}x{region.height}+{region.x}+{y}", path], 60)
        with open(path, "rb") as fh:
            digest_now = hashlib.sha1(fh.read()).hexdigest()
        if digest_now == last:
            os.remove(path)
            break
        paths.append(path)
        last = digest_now
        xdo("click", "--repeat", 12, "5")  # the wheel, down
        yield 0.5
        redraw()
        yield 1.5  # a frame of software GL takes a second or more here while jobs run
    xdo("click", "--repeat", 60, "4")  # back to the top
    redraw()
    yield 0.4
    return paths


class _Stub:
    """A layout that draws nothing: draw_material's whole panel, every section open, records its
    cells at a real region's width (the sections folded in the window are checked this way)."""

    def __getattr__(self, name):
        if name in ("row", "column", "box", "split"):
            return lambda *a, **k: _Stub()
        if name == "operator":
            return lambda *a, **k: type("Props", (), {})()
        return lambda *a, **k: None


def show_our_tab():
    """The 3D view's sidebar open on the BRDF Moments tab: its tab clicked (Blender 3.4 has no
    Python access to a sidebar's active tab), found by what the panel draws."""
    area("VIEW_3D").spaces.active.show_region_ui = True
    panel = panel_module()
    for k in range(40):
        panel.AUDIT = []
        redraw()
        yield 0.3
        if any(e["panel"].startswith("VIEW3D_PT_brdf_moments") for e in panel.AUDIT):
            panel.AUDIT = None
            return
        ui = ui_region("VIEW_3D")
        xdo("mousemove", ui.x + ui.width - 10, window().height - (ui.y + ui.height) + 15 + 15 * k)
        xdo("click", 1)
        yield 0.3
    panel.AUDIT = None
    raise RuntimeError("the BRDF Moments tab was not found in the 3D view's sidebar")


def panel_shot(name, charts=False):
    """The panel at this step: screenshots of the sidebar and of Material Properties, every
    text cell drawn there and in the whole panel measured (``charts``: each chart in turn)."""
    yield from show_our_tab()
    panel = panel_module()
    wm = bpy.context.window_manager
    kinds = [k for k, *_ in panel.CHARTS] if charts else [wm.brdf_moments_chart]
    for kind in kinds:
        wm.brdf_moments_chart = kind
        panel.AUDIT = []
        redraw()
        yield 0.5
        for _ in range(100):  # until the charts drawn for these widths are in
            if not panel.charts_pending():
                break
            yield 0.1
        panel.AUDIT = []
        redraw()
        yield 0.5
        drawn = list(panel.AUDIT)
        panel.AUDIT = []
        mat = bpy.data.materials[MAT]
        whole = {}
        for kind_area in ("VIEW_3D", "PROPERTIES"):
            region = ui_region(kind_area)
            panel._PANEL[0] = f"whole panel at the {kind_area} width"
            panel.draw_material(_Stub(), mat, type("Ctx", (), {"region": region})())
            whole[kind_area] = region.width
        full = list(panel.AUDIT)
        panel.AUDIT = None
        side, props = ui_region("VIEW_3D"), ui_region("PROPERTIES")
        result["panel_shots"].append(
            {
                "step": name,
                "chart": kind,
                "sidebar": (yield from crop(side, f"{name}-{kind.lower()}-sidebar")),
                "properties": (yield from crop(props, f"{name}-{kind.lower()}-properties")),
                "sidebar_width": side.width,
                "properties_width": props.width,
                "content_width": {k: panel.content_width(type("Ctx", (), {"region": ui_region(k)})()) for k in whole},
                "drawn": drawn,
                "whole": full,
                "cut": cut_cells(drawn + full),
                "chart_sizes": sorted({tuple(size) for size in panel.chart_sizes()}),
            }
        )
        log(
            "panel",
            name,
            kind,
            len(drawn),
            "cells drawn,",
            len(full),
            "in the whole panel,",
            len(result["panel_shots"][-1]["cut"]),
            "cut",
        )
    # The check itself: a long label in the sidebar's cell is found cut.
    ui = panel.content_width(type("Ctx", (), {"region": ui_region("VIEW_3D")})())
    probe = {
        "panel": "control",
        "text": "Analyse again, keeping the sliders where they are",
        "kind": "label",
        "icon": True,
        "avail": ui,
    }
    result["cut_control"] = bool(cut_cells([probe]))


# --- the artist's session ---------------------------------------------------------------------


def session():
    # BRDF_MOMENTS_LANE_VIEWPORT_AA (a manual experiment, not CI): Blender's viewport
    # anti-aliasing preference for this run. At its default (8 samples) every image change
    # (the live preview, the plots) makes the 3D view re-accumulate 8 frames, ~6 s of two cores
    # in software GL (BENCHMARKS "Workflow in a real window").
    aa = os.environ.get("BRDF_MOMENTS_LANE_VIEWPORT_AA")
    if aa:
        bpy.context.preferences.system.viewport_aa = aa
    result["viewport_aa"] = bpy.context.preferences.system.viewport_aa
    result["ui"] = {"unit": widget_unit(), "ui_scale": bpy.context.preferences.system.ui_scale}
    yield 1.0
    key_over("VIEW_3D", "Escape")  # closes the first-run splash
    area("PROPERTIES").spaces.active.context = "MATERIAL"
    bpy.context.view_layer.objects.active = bpy.data.objects["Cube"]
    yield 0.5
    redraw()
    yield 0.3
    yield from panel_shot("start")
    screenshot("start")
    record("start")
    # A control: the main loop with no job, over 3 s, on this (possibly loaded) machine, once the
    # redraw after the screenshot has settled.
    yield 1.0
    t0 = time.monotonic()
    yield 3.0
    result["idle"] = {"start": t0, "end": time.monotonic(), "loadavg": os.getloadavg()}

    # A missing file: one line in the report, nothing changed, no traceback.
    status, message = run_op(bpy.ops.brdf_moments.load_merl, filepath=os.path.join(OUT, "missing.binary"), material=MAT)
    record("load_missing", status=status, message=message)

    # Load: the file browser's execute starts the threaded analysis.
    status, message = run_op(bpy.ops.brdf_moments.load_merl, filepath=GOLD, material=MAT)
    yield from wait_jobs()
    redraw()
    yield 0.5
    record("load", status=status, message=message, job=last_job(), shot=screenshot("loaded"))
    yield from panel_shot("loaded", charts=True)

    # Load another file and press Esc at once: the material keeps the first file and its analysis.
    # The analysis takes about half a second, so the Esc may come late: try a few times.
    attempts = []
    for _ in range(4):
        status, message = run_op(bpy.ops.brdf_moments.load_merl, filepath=OTHER, material=MAT)
        key_over("VIEW_3D", "Escape")
        yield from wait_jobs()
        attempts.append({"status": status, "job": last_job(), "state": snapshot()})
        if last_job()["outcome"] == "cancelled":
            break
        run_op(bpy.ops.brdf_moments.load_merl, filepath=GOLD, material=MAT)  # back to the first file
        yield from wait_jobs()
    record("load_cancelled", attempts=attempts)

    # Analyse again (the panel's button).
    status, message = run_op(bpy.ops.brdf_moments.analyse, "INVOKE_DEFAULT", material=MAT)
    yield from wait_jobs()
    record("analyse", status=status, job=last_job())

    # Slider moves.
    s = bpy.data.materials[MAT].brdf_moments
    s.mu_slope = max(-1.0, min(0.0, s.fit_mu_slope)) + 0.1
    s.sigma2 = s.fit_sigma2 * 1.6
    redraw()
    yield 0.3
    record("sliders", shot=screenshot("sliders"))
    yield from panel_shot("sliders")

    # Apply, and while it runs: a key that toggles the 3D view's sidebar, and a right-click
    # (a context menu opens; the job must go on). A probe handler started before the job sits
    # behind it: it sees the events only if the job passes them on.
    with override():
        bpy.ops.wm.windowed_probe("INVOKE_DEFAULT")
    with held_apply(8.0):
        status, message = run_op(bpy.ops.brdf_moments.apply_edit, "INVOKE_DEFAULT", material=MAT)
    yield 0.5
    sidebar = area("VIEW_3D").spaces.active.show_region_ui
    key_over("VIEW_3D", "n")
    for _ in range(100):  # the main loop may be slow to get to the event on a loaded machine
        yield 0.1
        if area("VIEW_3D").spaces.active.show_region_ui != sidebar:
            break
    result["input"]["sidebar_before"] = sidebar
    result["input"]["sidebar_after"] = area("VIEW_3D").spaces.active.show_region_ui
    result["input"]["job_running_after_key"] = bool(jobs().running())
    x, y = centre("VIEW_3D")
    xdo("mousemove", x - 300, y - 200)
    xdo("click", 3)
    for _ in range(100):
        yield 0.1
        if any(e["type"] == "RIGHTMOUSE" for e in PROBE_EVENTS):
            break
    yield 0.3
    result["input"]["shot_menu"] = screenshot("apply-right-click", wait=False)
    yield 0.5
    xdo("mousemove", 40, 500)  # far from the menu: Blender closes it
    yield 0.5
    result["input"]["job_running_after_right_click"] = bool(jobs().running())
    redraw()
    yield 0.3
    result["input"]["shot_during_job"] = screenshot("apply-running", wait=False)
    yield from wait_jobs()
    redraw()
    yield 0.5
    record("apply", status=status, job=last_job(), shot=screenshot("applied"))
    yield from panel_shot("applied")

    # A second Apply, cancelled with a real Esc: the material stays as the first Apply left it.
    s.sigma2 = s.fit_sigma2 * 2.5
    with held_apply(8.0):
        status, message = run_op(bpy.ops.brdf_moments.apply_edit, "INVOKE_DEFAULT", material=MAT)
    yield 1.0
    running_before_esc = bool(jobs().running())
    key_over("VIEW_3D", "Escape")
    yield from wait_jobs()
    record("apply_cancelled", status=status, job=last_job(), running_before_esc=running_before_esc)
    result["input"]["probe_events"] = list(PROBE_EVENTS)

    # Undo and redo with the real keys.
    key_over("VIEW_3D", "ctrl+z")
    yield 0.8
    record("undo")
    key_over("VIEW_3D", "ctrl+shift+z")
    yield 0.8
    record("redo")

    # Build Preview (a job if the operator is one; else it runs in the call and is timed here).
    props = bpy.ops.brdf_moments.build_preview.get_rna_type().properties
    kwargs = {k: v for k, v in (("size", 64), ("samples", 4)) if k in props}
    t0 = time.monotonic()
    status, message = run_op(bpy.ops.brdf_moments.build_preview, "INVOKE_DEFAULT", material=MAT, **kwargs)
    call = time.monotonic() - t0
    yield from wait_jobs()
    redraw()
    yield 0.8
    record(
        "build_preview",
        status=status,
        message=message,
        call_seconds=call,
        job=last_job(),
        shot=screenshot("preview"),
        thumbnail=thumbnail(),
    )
    yield from panel_shot("preview")

    # Save, then reopen (the driver's timers are persistent).
    blend = os.path.join(OUT, "session.blend")
    yield from until_quiet()
    with override():
        bpy.ops.wm.save_as_mainfile(filepath=blend)
    record("save", blend=blend, preview=preview_digest())
    yield from until_quiet()
    quiet_before = ours_running()
    with override():
        bpy.ops.wm.open_mainfile(filepath=blend)
    # What the load_post handler started (plots, warm-up) must not be running yet: it waits
    # for the operator to return (lifecycle.file_loading's hold).
    running_at_return = ours_running()
    yield 1.0
    reopened_scene = window().scene.name
    window().scene = bpy.data.scenes["Scene"]  # back to the artist's scene, the cube active
    bpy.context.view_layer.objects.active = bpy.data.objects["Cube"]
    yield 0.3
    area("PROPERTIES").spaces.active.context = "MATERIAL"
    redraw()
    yield 0.5
    record(
        "reopen",
        reopened_scene=reopened_scene,
        preview=preview_digest(),
        shot=screenshot("reopened"),
        quiet_before=quiet_before,
        running_at_return=running_at_return,
    )
    yield from panel_shot("reopened")

    # An Apply as an artist makes it in the reopened file: a new slider value, Apply, then wait
    # with hands off (no screenshots, keys or redraws from the driver): the Apply time to quote.
    yield 2.0
    solve = sys.modules.get("brdf_moments.addon.core.edit.solve")
    result["warm_after_reopen"] = bool(solve and solve._RINGS)  # built by the file-load handler
    s = bpy.data.materials[MAT].brdf_moments
    s.mu_slope = max(-1.0, min(0.0, s.fit_mu_slope))  # the slope back at the fit: a variance edit
    # First a value typed and Apply pressed at once: the Apply's child solves while the live
    # preview of the same value starts in Blender (the worst case for the Apply's time).
    s.sigma2 = s.fit_sigma2 * 1.25
    status, message = run_op(bpy.ops.brdf_moments.apply_edit, "INVOKE_DEFAULT", material=MAT)
    yield from wait_jobs()
    record("apply_at_once", status=status, message=message, job=last_job())
    for _ in range(300):  # the live preview it started
        if not [t for t in threading.enumerate() if t.name == "brdf_moments: live preview" and t.is_alive()]:
            break
        yield 0.1
    before_live = preview_digest()
    s.sigma2 = s.fit_sigma2 * 1.3
    # The artist looks at the live preview until it settles, then presses Apply.
    live_seen = False
    for _ in range(300):
        yield 0.1
        live = [t for t in threading.enumerate() if t.name == "brdf_moments: live preview" and t.is_alive()]
        live_seen = live_seen or bool(live)
        if live_seen and not live:
            break
    result["live_before_quiet_apply"] = live_seen
    # What the artist sees then: the spheres above the sliders, the edited one redrawn.
    redraw()
    yield 0.5
    record("live", changed=preview_digest() != before_live, shot=screenshot("live"))
    before = preview_digest()
    status, message = run_op(bpy.ops.brdf_moments.apply_edit, "INVOKE_DEFAULT", material=MAT)
    yield from wait_jobs()
    # The written table baked into the preview's edited sphere: its bake starts from a timer once
    # the Apply ends, so under load it may not have begun when the job is seen finished. (The
    # pixels may not change: Apply writes the synthesis the settled live preview showed.)
    live = sys.modules["brdf_moments.addon.blender.live"]
    for _ in range(300):
        yield 0.1
        if live.SHOWN.get(MAT) == "applied":
            break
    result["preview_applied"] = live.SHOWN.get(MAT) == "applied"
    result["preview_changed_by_apply"] = preview_digest() != before
    solve = sys.modules.get("brdf_moments.addon.core.edit.solve")
    record("apply_quiet", status=status, message=message, job=last_job())

    # An Apply cancelled with Esc pauses the live preview for nothing: it must take up the
    # sliders again (its image changes to the edit the Apply would have made).
    s.sigma2 = s.fit_sigma2 * 1.15
    status, message = run_op(bpy.ops.brdf_moments.apply_edit, "INVOKE_DEFAULT", material=MAT)
    yield 0.5
    key_over("VIEW_3D", "Escape")
    yield from wait_jobs()
    before = preview_digest()
    resumed = False
    for _ in range(300):
        yield 0.1
        if preview_digest() != before:
            resumed = True
            break
    record("apply_cancelled_live", status=status, job=last_job(), preview=before is not None, live_resumed=resumed)

    # The artist's material without OSL (issue 28): the panel's menu set to the fitted lobes,
    # Apply, the material rendered in the window's 3D view with EEVEE, then Restore.
    s.artist_shader = "LOBES"
    redraw()
    yield 0.3
    yield from panel_shot("lobes-chosen")
    status, message = run_op(bpy.ops.brdf_moments.apply_edit, "INVOKE_DEFAULT", material=MAT)
    yield from wait_jobs()
    space = area("VIEW_3D").spaces.active
    shading = space.shading.type
    space.shading.type = "RENDERED"
    # the object in view, whole (the session's earlier steps may leave the view inside the cube)
    view = space.region_3d
    kept_view = (view.view_location.copy(), view.view_distance)
    view.view_location = (0.0, 0.0, 0.0)
    view.view_distance = 9.0
    redraw()
    yield 3.0
    record("apply_lobes", status=status, message=message, job=last_job(), shot=screenshot("lobes-rendered"))
    yield from panel_shot("lobes-applied")
    # Issue 37.4: the panel's Find the Bound (a background job, node_bound) then puts the bound
    # beside the error; the rendered material and the sidebar stating both in one screenshot.
    status, message = run_op(bpy.ops.brdf_moments.node_bound, "INVOKE_DEFAULT", material=MAT)
    yield from wait_jobs()
    redraw()
    yield 3.0
    record("bound_lobes", status=status, message=message, job=last_job(), shot=screenshot("lobes-bound"))
    yield from panel_shot("lobes-bound")
    space.shading.type = shading
    view.view_location, view.view_distance = kept_view
    status, message = run_op(bpy.ops.brdf_moments.restore_material, material=MAT)
    yield 0.3
    record("restore_lobes", status=status, message=message)
    s.artist_shader = "AUTO"


# --- the timers -------------------------------------------------------------------------------

STEPS = session()


def step():
    try:
        delay = next(STEPS)
    except StopIteration:
        finish()
        return None
    except Exception:  # noqa: BLE001 - written into the result, and the run fails
        result["errors"].append(traceback.format_exc())
        finish()
        return None
    return float(delay)


def tick():
    ticks.append(time.monotonic())
    return 0.05


def largest_gap(start, end, series=None):
    """The longest gap between ticks of ``series`` over [start, end] and the ticks inside; a
    main-loop gap overlapping the driver's own blocking (``driver_busy``) is not counted."""
    main = series is None
    series = ticks if series is None else series
    inside = [t for t in series if start <= t <= end + 0.05]
    before = [t for t in series if t < start][-1:]
    gaps = [
        b - a for a, b in zip(before + inside, inside) if not (main and any(s < b and e > a for s, e in driver_busy))
    ]
    return (max(gaps) if gaps else None), len(inside)


def is_ours(filename):
    """A frame of the installed add-on (not of this driver, wherever the repository is)."""
    mod = sys.modules.get("brdf_moments")
    return mod is not None and filename.startswith(os.path.dirname(mod.__file__) + os.sep)


def inner_ours(frame):
    """The add-on's innermost frames on a stack, as 'file:line function' (up to 3)."""
    out = []
    while frame is not None and len(out) < 3:
        if is_ours(frame.f_code.co_filename):
            out.append(f"{os.path.basename(frame.f_code.co_filename)}:{frame.f_lineno} {frame.f_code.co_name}")
        frame = frame.f_back
    return out


def probe():
    """A Python thread that wakes every 10 ms: its gaps are how long another thread (the job's
    worker) kept the GIL, apart from the main loop's own drawing. It also samples what the main
    thread is doing when the main loop has not ticked for STALL s: a Python stack (some Python
    code, ours or the driver's, holds the loop) or none (Blender's own C code: drawing, events)."""
    main = threading.main_thread().ident
    sampled = None
    run_start = None
    while True:
        time.sleep(0.01)
        now = time.monotonic()
        if probe_ticks and now - probe_ticks[-1] > GIL_GAP:
            # Some thread held the GIL that long; it has just let go: what each thread runs now.
            names = {t.ident: t.name for t in threading.enumerate()}
            gil_gaps.append(
                {
                    "since": probe_ticks[-1],
                    "length": now - probe_ticks[-1],
                    "threads": {
                        names.get(ident, str(ident)): [
                            f"{os.path.basename(f.filename)}:{f.lineno} {f.name}"
                            for f in traceback.extract_stack(fr)[-4:]
                        ]
                        for ident, fr in sys._current_frames().items()
                        if ident != threading.get_ident()
                    },
                }
            )
        probe_ticks.append(now)
        if not cpu_marks or now - cpu_marks[-1][0] > 0.5:
            cpu_marks.append((now, time.process_time(), thread_cpu()))  # Blender's CPU time, all its threads
        # Runs of the add-on's own Python on the main thread (panel drawing, a job's modal and
        # finish): how long our code, not Blender's drawing, holds the main loop at a time.
        f = sys._current_frames().get(main)
        ours_now = False
        while f is not None and not ours_now:
            ours_now = is_ours(f.f_code.co_filename)
            f = f.f_back
        if ours_now:
            where = inner_ours(sys._current_frames().get(main))
            if run_start is None:
                run_start, run_where, run_cpu = now, where, main_thread_cpu()
        elif run_start is not None:
            ours_runs.append((run_start, now, run_where))
            ours_cpu.append((run_start, now, main_thread_cpu() - run_cpu))
            run_start = None
        last = ticks[-1] if ticks else None
        if last is None or now - last < STALL or sampled == last:
            continue
        sampled = last
        frame = sys._current_frames().get(main)
        stack = traceback.extract_stack(frame)[-4:] if frame is not None else []
        stalls.append(
            {"since": last, "at": now, "stack": [f"{os.path.basename(f.filename)}:{f.lineno} {f.name}" for f in stack]}
        )
        if ours_now:
            stalls[-1]["ours_where"] = where  # the add-on's frames at that instant


def thread_cpu():
    """Blender's CPU seconds so far by thread name, digits dropped ("llvmpipe-3" -> "llvmpipe":
    the software GL rasterizer's threads; "blender": the main thread, its task pool and jobs,
    Python's threads). Read from /proc, which any thread may do without touching Blender."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as fh:
                raw = fh.read()
        except OSError:
            continue  # the thread ended
        name, rest = raw[raw.index("(") + 1 : raw.rindex(")")], raw[raw.rindex(")") + 2 :].split()
        key = name.rstrip("0123456789").rstrip("-:_ ") or name
        out[key] = out.get(key, 0.0) + (int(rest[11]) + int(rest[12])) / tick  # utime + stime
    return out


def main_thread_cpu():
    """The main thread's own CPU seconds so far (/proc; 10 ms resolution). A run of the add-on's
    Python on the main thread lasts longer on the wall than in CPU when Blender's rasterizer
    threads hold both cores: the CPU is what the add-on spent, the rest it waited."""
    try:
        with open(f"/proc/self/task/{threading.main_thread().native_id}/stat") as fh:
            rest = fh.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(rest[11]) + int(rest[12])) / os.sysconf("SC_CLK_TCK")


probe_ticks = []
cpu_marks = []  # (monotonic, process CPU seconds, {thread name: CPU seconds}) every 0.5 s
gil_gaps = []  # the probe's gaps over GIL_GAP s, with every thread's stack right after
GIL_GAP = 0.15
ours_runs = []  # (start, end, where) of sampled runs of the add-on's Python on the main thread
ours_cpu = []  # (start, end, main-thread CPU seconds) of the same runs
stalls = []  # main-loop stalls over STALL s, with what the main thread ran
STALL = 0.25


def cpu_share(start, end):
    """Blender's own CPU use over [start, end], in cores (2.0: both cores busy)."""
    inside = [m for m in cpu_marks if start <= m[0] <= end]
    if len(inside) < 2:
        return None
    return (inside[-1][1] - inside[0][1]) / (inside[-1][0] - inside[0][0])


def cpu_by_thread(start, end):
    """The same share split by thread name (``thread_cpu``), in cores; threads that ended
    inside the span are missing from its last mark, so the parts may sum to less."""
    inside = [m for m in cpu_marks if start <= m[0] <= end]
    if len(inside) < 2:
        return None
    (t0, _, a), (t1, _, b) = inside[0], inside[-1]
    return {k: round((b[k] - a.get(k, 0.0)) / (t1 - t0), 3) for k in sorted(b) if b[k] - a.get(k, 0.0) > 0.0}


def finish():
    if "idle" in result:
        result["idle"]["largest_gap"] = largest_gap(result["idle"]["start"], result["idle"]["end"])[0]
        result["idle"]["ticks"] = largest_gap(result["idle"]["start"], result["idle"]["end"])[1]
        result["idle"]["largest_gil_gap"] = largest_gap(result["idle"]["start"], result["idle"]["end"], probe_ticks)[0]
    result["loadavg_end"] = os.getloadavg()
    # The probe thread goes on sampling while this runs: the stalls so far, taken once (one it
    # appended during this loop, a stall of finish() itself, had none of the fields below).
    taken = list(stalls)
    for st in taken:
        after = [t for t in ticks if t > st["since"]]
        st["length"] = (after[0] if after else time.monotonic()) - st["since"]
        end = st["since"] + st["length"]
        # How long the add-on's own Python held the main thread inside the stall: one sample
        # showing its frames says only that it ran at that instant (a 10 ms import, say).
        st["ours_seconds"] = sum(max(0.0, min(b, end) - max(a, st["since"])) for a, b, _ in ours_runs)
        # The CPU of the runs that overlap the stall (whole runs: CPU is not known within one).
        st["ours_cpu_seconds"] = sum(c for a, b, c in ours_cpu if a < end and b > st["since"])
        st["driver"] = any(a < st["since"] + st["length"] and b > st["since"] for a, b in driver_busy)
        st["job"] = next(
            (
                j["label"]
                for j in jobs().HISTORY
                if j["start"] <= st["since"] + st["length"] and j["end"] >= st["since"]
            ),
            None,
        )
    result["stalls"] = taken
    result["gil_gaps"] = gil_gaps
    result["idle"]["blender_cpu"] = (
        cpu_share(result["idle"]["start"], result["idle"]["end"]) if "idle" in result else None
    )
    if cpu_marks:
        result["blender_cpu_by_thread"] = cpu_by_thread(cpu_marks[0][0], cpu_marks[-1][0])  # the whole session
    if "idle" in result:
        result["idle"]["blender_cpu_by_thread"] = cpu_by_thread(result["idle"]["start"], result["idle"]["end"])
    result["ours_longest"] = max(((b - a, w) for a, b, w in ours_runs), default=(0.0, []))
    for job in jobs().HISTORY:
        gap, n = largest_gap(job["start"], job["end"])
        result["jobs"].append(
            {
                **job,
                "seconds": job["end"] - job["start"],
                "ticks": n,
                "largest_gap": gap,
                "largest_gil_gap": largest_gap(job["start"], job["end"], probe_ticks)[0],
                "blender_cpu": cpu_share(job["start"], job["end"]),
                "blender_cpu_by_thread": cpu_by_thread(job["start"], job["end"]),
                "largest_ours": max(
                    [
                        min(b, job["end"]) - max(a, job["start"])
                        for a, b, _ in ours_runs
                        if a < job["end"] and b > job["start"]
                    ],
                    default=0.0,
                ),
                "largest_ours_where": max(
                    [(b - a, w) for a, b, w in ours_runs if a < job["end"] and b > job["start"]], default=(0.0, [])
                )[1],
            }
        )
    with open(os.path.join(OUT, "windowed.json"), "w") as fh:
        json.dump(result, fh, indent=1)
    log("done", len(result["steps"]), "steps,", len(result["errors"]), "errors")
    bpy.ops.wm.quit_blender()


threading.Thread(target=probe, daemon=True).start()
bpy.app.timers.register(tick, first_interval=0.05, persistent=True)
bpy.app.timers.register(step, first_interval=0.5, persistent=True)
