"""Preview environments: Blender's bundled HDRIs or the user's own, loaded through bpy.

Blender ships eight CC0 studio-light HDRIs (``datafiles/studiolights/world/*.exr``, 1024x512).
Maps are read with ``bpy.data.images`` (the OpenEXR wheel crashes inside Debian's Blender) and
handed to the engine as arrays, top row first.
"""

from __future__ import annotations

import glob
import os

import bpy
import numpy as np

from ...core.preview import Environment

DEFAULT = "studio"
EXTENSIONS = (".exr", ".hdr")


def world_folders():
    """Folders that may hold Blender's studio-light worlds, best first."""
    out = []
    try:
        p = bpy.utils.system_resource("DATAFILES", path="studiolights/world")
        if p:
            out.append(p)
    except (TypeError, ValueError):
        pass
    here = os.path.dirname(bpy.__file__)  # .../<ver>/scripts/modules/bpy
    out += glob.glob(os.path.join(here, "..", "..", "..", "datafiles", "studiolights", "world"))
    out += glob.glob("/usr/share/blender/*/datafiles/studiolights/world")
    out.append("/usr/share/blender/datafiles/studiolights/world")
    return [os.path.normpath(p) for p in out if os.path.isdir(p)]


def bundled_environments() -> dict:
    """{name: path} of the HDRIs that ship with Blender (name = file stem)."""
    found = {}
    for folder in world_folders():
        for path in sorted(glob.glob(os.path.join(folder, "*"))):
            stem, ext = os.path.splitext(os.path.basename(path))
            if ext.lower() in EXTENSIONS and stem not in found:
                found[stem] = path
    return found


def resolve_environment(name_or_path=None) -> str:
    """A bundled HDRI's name, or the path of an .exr/.hdr file; raises ValueError naming the fault."""
    if name_or_path is None or name_or_path == "":
        name_or_path = DEFAULT
    text = os.fspath(name_or_path)
    bundled = bundled_environments()
    if text in bundled:
        return bundled[text]
    if os.path.sep in text or os.path.splitext(text)[1]:
        if not os.path.lexists(text):
            raise ValueError(f"{text}: environment file not found")
        if os.path.splitext(text)[1].lower() not in EXTENSIONS:
            raise ValueError(f"{text}: not an HDR environment (expected .exr or .hdr)")
        path = os.path.abspath(text)
        load_environment(path)  # the same checks for both preview paths, before either uses it
        return path
    names = ", ".join(sorted(bundled)) or "none found"
    raise ValueError(f"{text}: no such bundled environment (bundled: {names}); or give a file path")


_LOADED = {}


def load_environment(path) -> Environment:
    """The map at ``path`` as an engine Environment (cached per file and modification time)."""
    from ...core.file.safeio import check_image_header, register_input
    from ...core.preview.envmap import check_radiance

    path = os.path.abspath(os.fspath(path))
    st = os.stat(path)
    key = (path, st.st_mtime_ns, st.st_size, st.st_ino)
    if key in _LOADED:
        register_input(path)
        return _LOADED[key]
    # The header first: a regular file, a real EXR/HDR, within the pixel limit. Blender
    # would otherwise try to allocate whatever a header claims (and die).
    check_image_header(path)
    img = bpy.data.images.load(path, check_existing=True)
    try:
        w, h = img.size
        if w < 4 or h < 2:
            raise ValueError(f"{path}: cannot read the image (size {w}x{h})")
        buf = np.empty(w * h * img.channels, np.float32)
        img.pixels.foreach_get(buf)
        pix = buf.reshape(h, w, img.channels)[::-1, :, :3]  # Blender rows go bottom-up
        if img.channels < 3:
            pix = np.repeat(buf.reshape(h, w, img.channels)[::-1, :, :1], 3, axis=2)
        check_radiance(pix, path)
        env = Environment(np.ascontiguousarray(pix), os.path.splitext(os.path.basename(path))[0])
    finally:
        if img.users == 0:
            bpy.data.images.remove(img)
    _LOADED.clear()  # one map at a time: they are tens of MB with their caches
    _LOADED[key] = env
    return env


def write_environment(pixels, path):
    """Write an (H, W, 3) top-row-first array as a float EXR (tests, constant worlds); no bpy,
    so a job's work may call it too."""
    from ...core.file.exr import write_exr

    return os.path.abspath(write_exr(pixels, path))
