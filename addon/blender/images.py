"""The add-on's images (the profile and region plots, the preview): kept in the .blend, and
drawn off the main thread in a window."""

from __future__ import annotations

import threading

import bpy
import numpy as np

from . import lifecycle


def keep_image(name, rgba, float_buffer=False):
    """The image ``name`` holding ``rgba`` ((H, W, 4), row 0 on top; premultiplied when
    ``float_buffer``), kept in the .blend (fake user, packed: a generated image's pixels are not
    saved, and a reopened file showed the preview's measured sphere black); made anew when its
    size or kind changed."""
    h, w = rgba.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and (
        tuple(img.size) != (w, h)
        or bool(img.is_float) != float_buffer
        or (float_buffer and img.alpha_mode != "PREMUL")  # an older file's: it would pack wrong
    ):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=float_buffer)
        # Packed as EXR (premultiplied: read back exactly) or PNG (the plots' bytes); set before
        # any pixel goes in (changing the alpha mode later reinterprets the buffer).
        if float_buffer:
            img.alpha_mode, img.file_format = "PREMUL", "OPEN_EXR"
        else:
            img.file_format = "PNG"
    img.pixels.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())  # Blender's rows start at the bottom
    img.update()
    img.use_fake_user = True
    img.pack()
    # No Image.preview: Blender would render it in a job thread from this buffer, which the next
    # call rewrites or frees (the panel shows icons of its own, see icons.py).
    return img


def label_image(rgba, layout, labels):
    """Sphere labels drawn into the (H, W, 4) top-row-first image, above each sphere, each within
    its own cell (words dropped from the end until it fits); a label of None is left as it is.
    The cell's margins under the label are cleared first, so a longer label drawn there before
    leaves nothing behind."""
    from .plot_font import draw_text, text_width

    scale = max(1, layout.diameter // 100)
    cell = layout.width / max(layout.count, 1)
    d, top = layout.diameter, layout.top
    for k, (left, text) in enumerate(zip(layout.lefts, labels)):
        if text is None:
            continue
        x0, x1 = int(round(k * cell)), int(round((k + 1) * cell))
        while text_width(text, scale) > x1 - x0 and " " in text:
            text = text.rsplit(" ", 1)[0]
        text = text[: max((x1 - x0) // text_width("x", scale), 0)]
        w = text_width(text, scale)
        y = max(top - 9 * scale, 1)
        y1 = y + 8 * scale
        rgba[: min(top, y1), x0:x1] = 0.0  # the margin above the sphere
        rgba[top:y1, x0:left] = 0.0  # and beside it
        rgba[top:y1, left + d : x1] = 0.0
        x = min(max(left + (d - w) // 2, x0), max(x1 - w, x0))  # over the sphere, inside its cell
        rgba[y - 1 : y1, max(x - 1, 0) : x + w + 1] = (0.0, 0.0, 0.0, 1.0)  # a dark box: legible anywhere
        draw_text(rgba, x, y, text, (1.0, 1.0, 1.0), scale)
    return rgba


# --- images drawn off the main thread ------------------------------------------------------------
# The plots are numpy (0.1-0.3 s each in a window on this machine's software-GL Blender): drawn on
# the main thread after a job, they froze the UI for that long. In a window they are drawn in a
# thread; a timer then puts the pixels into the image (a few ms). A newer request for the same
# image supersedes one still drawing.

_DRAW_GEN: dict = {}  # image name -> generation of the latest request
_DRAWN: list = []  # (image name, generation, pixels, extra, then) from the threads
_DRAW_PENDING: set = set()  # image names requested and not yet in place
_DRAW_LOCK = threading.Lock()


def drawing() -> bool:
    """True while an image requested with ``draw_later`` is not in place yet."""
    return bool(_DRAW_PENDING)


def draw_later(name, draw, then=None, now=False):
    """The image ``name`` from ``draw()`` -> rgba or (rgba, extra); ``then(extra)`` runs on the
    main thread once it is in place. Drawn at once (and the image returned) headless or with
    ``now``; else in a thread, returning None."""

    def split(out):
        return out if isinstance(out, tuple) else (out, None)

    if now or bpy.app.background:
        px, extra = split(draw())
        img = keep_image(name, px)
        if then is not None:
            then(extra)
        return img
    gen = _DRAW_GEN.get(name, 0) + 1
    _DRAW_GEN[name] = gen
    _DRAW_PENDING.add(name)

    def run():
        try:
            px, extra = split(draw())
        except Exception as exc:  # noqa: BLE001 - a failed drawing leaves the last image
            print(f"BRDF Moments: drawing {name}: {type(exc).__name__}: {exc}")
            px = extra = None
        with _DRAW_LOCK:
            _DRAWN.append((name, gen, px, extra, then))

    lifecycle.start_thread(run, "brdf_moments: drawing")
    lifecycle.register_timer(_place_drawn, first_interval=0.02)
    return None


@lifecycle.on_file_load
@lifecycle.on_shutdown
def _drop_all():
    """Unregister, or another file is opened: drawings in flight are superseded and nothing
    waits to be placed."""
    with _DRAW_LOCK:
        for name in list(_DRAW_GEN):
            _DRAW_GEN[name] += 1
        _DRAWN.clear()
    _DRAW_PENDING.clear()


def _place_drawn():
    with _DRAW_LOCK:
        done = list(_DRAWN)
        _DRAWN.clear()
    for name, gen, px, extra, then in done:
        if _DRAW_GEN.get(name) != gen:
            continue  # superseded: the newer drawing will come
        _DRAW_PENDING.discard(name)
        if px is None:
            continue
        keep_image(name, px)
        if then is not None:
            then(extra)
    return 0.02 if _DRAW_PENDING else None
