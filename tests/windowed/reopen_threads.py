"""The add-on in Blender 3.4's window: a saved .blend with an analysed material reopened from
a script, N times. After each open it prints which of the add-on's threads were running when
the operator returned (none, since the hold in ``lifecycle.file_loading``: its load_post
handler's plot and warm-up threads ran through the end of the operator before) and how long
the redrawn plot took to be in place. Between opens it waits until the add-on is idle, as a
script must in 3.4 (README). BENCHMARKS, "Window: Blender never crashes".

    python scripts/package.py /tmp/dist            # prints the legacy zip's path
    BLEND=path/to/analysed.blend N=20 BLENDER_USER_SCRIPTS=/tmp/u xvfb-run -a \\
        -s "-screen 0 1920x1080x24" blender --factory-startup --python-expr \\
        "import bpy; bpy.ops.preferences.addon_install(filepath='/tmp/dist/brdf_moments-0.1.0-legacy.zip'); \\
        bpy.ops.preferences.addon_enable(module='brdf_moments')" --python tests/windowed/reopen_threads.py

(the windowed lane leaves such a .blend: its ``out/session.blend``)."""

import os
import sys
import threading
import time

import bpy

BLEND = os.environ["BLEND"]
COUNT = int(os.environ.get("N", "20"))
PKG = "brdf_moments.addon.blender."


def ours():
    return sorted(t.name for t in threading.enumerate() if t.name.startswith("brdf_moments") and t.is_alive())


def session():
    yield 2.0
    lifecycle, images, state = (sys.modules[PKG + m] for m in ("lifecycle", "images", "state"))
    for i in range(COUNT):
        while [n for n in ours() if n != "brdf_moments: announce" or state._ANNOUNCER.busy()]:
            yield 0.05
        with bpy.context.temp_override(window=bpy.context.window_manager.windows[0]):
            bpy.ops.wm.open_mainfile(filepath=BLEND)
        at_return, opened = ours(), time.monotonic()
        while (images.drawing() or lifecycle.held_threads()) and time.monotonic() - opened < 10:
            yield 0.05
        print(f"reopen {i + 1}: running at return {at_return}, plot in place after {time.monotonic() - opened:.2f} s")
    print(f"done: {COUNT} reopens", flush=True)
    bpy.ops.wm.quit_blender()


steps = session()


def step():
    try:
        return next(steps)
    except StopIteration:
        return None


bpy.app.timers.register(step, first_interval=1.0, persistent=True)
