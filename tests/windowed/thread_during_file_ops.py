"""Blender 3.4 in a window, without the add-on: does a thread running numpy survive file
operators? The add-on's lifecycle holds its threads back while a file opens because of what
this measured (BENCHMARKS, "Window: Blender never crashes").

    xvfb-run -a -s "-screen 0 1920x1080x24" blender --factory-startup \\
        --python tests/windowed/thread_during_file_ops.py -- --how script --count 20

``--how script``: ``bpy.ops.wm.open_mainfile`` called from a timer, as a script does;
``--how menu``: Ctrl+O and Return sent with xdotool, as an artist opens a file. The thread runs
numpy the whole time. Prints ``survived N`` and quits, or Blender crashes (exit code 139)."""

import os
import subprocess
import sys
import tempfile
import threading

import bpy
import numpy as np

argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
HOW = argv[argv.index("--how") + 1] if "--how" in argv else "script"
COUNT = int(argv[argv.index("--count") + 1]) if "--count" in argv else 20
BLEND = os.path.join(tempfile.mkdtemp(), "opened.blend")
bpy.ops.wm.save_as_mainfile(filepath=BLEND)
stop = threading.Event()
opened = []


def numpy_work():
    """Small array operations back to back, as the add-on's plot drawing does."""
    x = np.linspace(0.0, 10.0, 20000)
    while not stop.is_set():
        for dy in range(-2, 3):
            np.clip(1.5 - np.hypot(np.round(x) - x, dy), 0.0, 1.0)


@bpy.app.handlers.persistent
def count_open(*_args):
    opened.append(1)


def session():
    for _ in range(COUNT):
        if HOW == "script":
            with bpy.context.temp_override(window=bpy.context.window_manager.windows[0]):
                bpy.ops.wm.open_mainfile(filepath=BLEND)
            yield 0.3
        else:
            subprocess.run(["xdotool", "mousemove", "900", "500", "key", "ctrl+o"], check=True)
            yield 1.0
            subprocess.run(["xdotool", "key", "Return"], check=True)  # the browser offers this file
            yield 1.5
    print(f"survived {len(opened)} opens ({HOW})", flush=True)
    stop.set()
    bpy.ops.wm.quit_blender()


steps = session()


def step():
    try:
        return next(steps)
    except StopIteration:
        return None


bpy.app.handlers.load_post.append(count_open)
threading.Thread(target=numpy_work, daemon=True).start()
bpy.app.timers.register(step, first_interval=1.0, persistent=True)
