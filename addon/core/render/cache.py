"""Bakes cached by content: a material is baked again only when something it shows changed.

The key hashes the BRDF's content (table values and kd, or the moment parameters), the map's
pixels, the resolution and the estimator settings. Moving a sphere or renaming a material
does not change it; touching a slider, the map or the render size does.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict

import numpy as np

from .estimators import bake_sphere

def _code_version():
    """Hash of the modules a bake's numbers come from: a bake made by other code is a miss."""
    h = hashlib.sha256(b"bake")
    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("envmap.py", "estimators.py", "lights.py", "lobe.py", "scene.py"):
        with open(os.path.join(here, name), "rb") as fh:
            h.update(name.encode() + fh.read())
    return h.hexdigest()[:16]


BAKE_VERSION = _code_version()


def bake_key(brdf, env, diameter, lobe_samples, seed=0) -> str:
    h = hashlib.sha256(BAKE_VERSION.encode())
    for part in (brdf.content_key(), env.content_key(), f"{int(diameter)}:{int(lobe_samples)}:{int(seed)}"):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


class BakeCache:
    """In memory (least recently used first out) and, with ``folder``, on disk as .npz (the
    ``max_files`` most recently written are kept: slider drags would otherwise fill the disk)."""

    def __init__(self, folder=None, max_items=32, max_files=256):
        self.folder = folder
        self.max_items = int(max_items)
        self.max_files = int(max_files)
        self._mem = OrderedDict()
        self.computed = []          # keys baked by this cache, in order (tests and stats read it)

    def get(self, brdf, env, diameter, lobe_samples=64, seed=0):
        """(radiance (D, D, 3), coverage (D, D), key), baking only on a miss."""
        key = bake_key(brdf, env, diameter, lobe_samples, seed)
        if key in self._mem:
            self._mem.move_to_end(key)
            rgb, cov = self._mem[key]
            return rgb, cov, key
        path = os.path.join(self.folder, f"bake-{key[:24]}.npz") if self.folder else None
        if path and os.path.exists(path):
            try:
                with np.load(path) as z:
                    rgb, cov = z["radiance"], z["coverage"]
                self._store(key, rgb, cov)
                return rgb, cov, key
            except (OSError, ValueError, KeyError):
                pass  # a damaged cache file is just a miss
        rgb, cov = bake_sphere(brdf, env, diameter, lobe_samples, seed)
        self.computed.append(key)
        self._store(key, rgb, cov)
        if path:
            from ..atomic import atomic_path

            with atomic_path(path, ".npz") as tmp:
                with open(tmp, "wb") as fh:
                    np.savez(fh, radiance=rgb, coverage=cov)
            prune(self.folder, "bake-", ".npz", self.max_files)
        return rgb, cov, key

    def _store(self, key, rgb, cov):
        self._mem[key] = (rgb, cov)
        self._mem.move_to_end(key)
        while len(self._mem) > self.max_items:
            self._mem.popitem(last=False)


def prune(folder, prefix, suffix, keep):
    """Delete all but the ``keep`` newest files ``prefix*suffix`` in ``folder``."""
    try:
        names = [n for n in os.listdir(folder) if n.startswith(prefix) and n.endswith(suffix)]
    except OSError:
        return
    if len(names) <= keep:
        return
    def age(path):
        try:
            return os.path.getmtime(path)
        except OSError:  # removed meanwhile by another Blender sharing the cache
            return -1.0

    paths = sorted((os.path.join(folder, n) for n in names), key=age, reverse=True)
    for p in paths[keep:]:
        try:
            os.unlink(p)
        except OSError:
            pass
