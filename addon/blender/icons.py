"""The add-on's own pictures in the panel: the charts and the preview's thumbnail, in one
``bpy.utils.previews`` collection of at most ``MAX_ICONS`` icons, their pixels set here on the
main thread from numpy.

Blender is never asked for an image's own preview (``Image.preview``, ``preview_ensure``): it
renders that in a job thread from the image's buffer, while the add-on rewrites, resizes and
removes those images on the main thread (a live preview stage, Build Preview's finish, a file
being reopened). Blender 3.4 crashed in about one windowed session in four that way. An icon
of this collection holds its own copy of the pixels, which nothing else reads or frees.

Keys name what an icon shows (``chart_key``, ``thumbnail_key``); each icon carries a
signature of what it was made from, so that a caller can tell a current picture from a stale
one. Past ``MAX_ICONS`` the least recently used icon goes, and its ``on_evict`` is called."""

from __future__ import annotations

import math
from collections import OrderedDict

import bpy
import numpy as np

MAX_ICONS = 24  # a material shows up to 8 charts (4 kinds at 2 widths) and 1 thumbnail
THUMBNAIL_WIDTH = 320  # pixels at most: the widest panel (Material Properties) is about 270

_COLLECTION = [None]
_ICONS: OrderedDict = OrderedDict()  # key -> (signature, on_evict); least recently used first


def _collection():
    if _COLLECTION[0] is None:
        from bpy.utils import previews

        _COLLECTION[0] = previews.new()
    return _COLLECTION[0]


def chart_key(material_name, kind, side):
    return f"chart|{material_name}|{kind}|{side}"


def thumbnail_key(material_name):
    return f"thumbnail|{material_name}"


def put(key, rgba, signature=None, on_evict=None) -> int:
    """Icon ``key`` showing ``rgba`` ((H, W, 4) floats in [0, 1], display-referred, straight
    alpha, row 0 on top); returns its icon id. Main thread only."""
    coll = _collection()
    if key in _ICONS:
        _ICONS.move_to_end(key)
    else:
        while len(_ICONS) >= MAX_ICONS:
            old, (_, evicted) = _ICONS.popitem(last=False)
            if old in coll:
                del coll[old]
            if evicted is not None:
                evicted(old)
    _ICONS[key] = (signature, on_evict)
    pv = coll.get(key) or coll.new(key)
    h, w = rgba.shape[:2]
    pv.image_size = (w, h)
    # Blender keeps an icon's pixels as bytes, rows from the bottom.
    pv.image_pixels_float.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())
    return pv.icon_id


def icon_id(key):
    """The icon id of ``key``, or None when there is none (never made, evicted, cleared)."""
    if key not in _ICONS or _COLLECTION[0] is None:
        return None
    _ICONS.move_to_end(key)
    return _COLLECTION[0][key].icon_id


def signature(key):
    """What icon ``key`` was made from (``put``'s ``signature``); None without the icon."""
    entry = _ICONS.get(key)
    return entry[0] if entry is not None else None


def pixels(key):
    """Icon ``key``'s pixels as Blender holds them ((H, W, 4) floats, row 0 on top), or None."""
    if key not in _ICONS or _COLLECTION[0] is None:
        return None
    pv = _COLLECTION[0][key]
    w, h = pv.image_size
    buf = np.empty(w * h * 4, np.float32)
    pv.image_pixels_float.foreach_get(buf)
    return buf.reshape(h, w, 4)[::-1]


def keys() -> list:
    return list(_ICONS)


def sizes() -> list:
    """(width, height) of every icon, as Blender holds them."""
    coll = _COLLECTION[0]
    return [tuple(coll[k].image_size) for k in _ICONS] if coll is not None else []


def drop(match=lambda key: True):
    """Forget the icons whose key ``match`` accepts (their ``on_evict`` is not called)."""
    coll = _COLLECTION[0]
    for key in [k for k in _ICONS if match(k)]:
        del _ICONS[key]
        if coll is not None and key in coll:
            del coll[key]


def close():
    """Unregister: the collection goes back to Blender."""
    _ICONS.clear()
    if _COLLECTION[0] is not None:
        from bpy.utils import previews

        previews.remove(_COLLECTION[0])
        _COLLECTION[0] = None


def redraw():
    """The places the panel can be redrawn (a new picture is in): Material Properties and the
    sidebars. Not the 3D view's own region, whose every redraw costs a frame of software GL."""
    wm = bpy.context.window_manager
    for win in wm.windows if wm is not None else ():
        for area in win.screen.areas:
            if area.type == "PROPERTIES":
                area.tag_redraw()
            elif area.type in ("VIEW_3D", "NODE_EDITOR"):
                for region in area.regions:
                    if region.type == "UI":
                        region.tag_redraw()


# --- the preview's thumbnail --------------------------------------------------------------


def srgb_encode(linear):
    """Linear values in [0, 1] to the sRGB transfer function's (IEC 61966-2-1)."""
    c = np.clip(linear, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055)


def thumbnail_pixels(rgba, width=THUMBNAIL_WIDTH):
    """The thumbnail of a linear, premultiplied (H, W, 4) image (row 0 on top): averaged over
    k x k blocks, k the least that brings it to ``width`` pixels or fewer (the last rows and
    columns that fill no block are left out), then colour un-premultiplied, clipped to [0, 1]
    and sRGB-encoded; alpha stays linear. Icons hold display values, not linear light."""
    h, w = rgba.shape[:2]
    k = max(1, math.ceil(w / width))
    hk, wk = max(h // k, 1), max(w // k, 1)
    block = np.asarray(rgba[: hk * k, : wk * k], np.float64)
    small = block.reshape(hk, block.shape[0] // hk, wk, block.shape[1] // wk, 4).mean(axis=(1, 3))
    alpha = np.clip(small[..., 3:], 0.0, 1.0)
    colour = np.divide(small[..., :3], small[..., 3:], out=np.zeros_like(small[..., :3]), where=small[..., 3:] > 0)
    return np.concatenate([srgb_encode(colour), alpha], axis=2).astype(np.float32)


def put_thumbnail(material_name, rgba):
    """The thumbnail of the preview image ``rgba`` (linear, premultiplied, row 0 on top)."""
    put(thumbnail_key(material_name), thumbnail_pixels(rgba))
    redraw()
