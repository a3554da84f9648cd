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

from ..file.safeio import read_input
from .estimators import bake_sphere


def _code_version():
    """Hash of the modules a bake's numbers come from: a bake made by other code is a miss."""
    h = hashlib.sha256(b"bake")
    here = os.path.dirname(os.path.abspath(__file__))
    for name in ("envmap.py", "estimators.py", "lights.py", "lobe.py", "scene.py"):
        h.update(name.encode() + read_input(os.path.join(here, name), 1 << 20, "engine source", register=False))
    return h.hexdigest()[:16]


BAKE_VERSION = _code_version()


def bake_key(brdf, env, diameter: int, lobe_samples: int, seed: int = 0) -> str:
    """The content key of a bake; its numbers checked as ``bake_sphere`` checks them (a cache
    hit must not let through what a bake would refuse)."""
    from ..limits import check

    d, k = check("diameter", diameter), check("bake_samples", lobe_samples, "lobe_samples")
    h = hashlib.sha256(BAKE_VERSION.encode())
    for part in (brdf.content_key(), env.content_key(), f"{d}:{k}:{check('seed', seed)}"):
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()


class BakeCache:
    """In memory (least recently used first out) and, with ``folder``, on disk as sealed .npz
    files (``cachefs``: verified on read, rebuilt when damaged; bounded by
    ``limits.BAKE_CACHE_MAX_*``, least recently used first: slider drags would otherwise fill
    the disk)."""

    def __init__(self, folder=None, max_items: int = 32, max_files: int | None = None, max_bytes: int | None = None):
        from ..limits import BAKE_CACHE_MAX_BYTES, BAKE_CACHE_MAX_ENTRIES, check

        self.folder = folder
        self.max_items = check("bake_cache_items", max_items, "max_items")
        self.max_files = (
            BAKE_CACHE_MAX_ENTRIES if max_files is None else check("bake_cache_files", max_files, "max_files")
        )
        self.max_bytes = (
            BAKE_CACHE_MAX_BYTES if max_bytes is None else check("bake_cache_bytes", max_bytes, "max_bytes")
        )
        self._mem = OrderedDict()
        self.computed = []  # keys baked by this cache, in order (tests and stats read it)

    def get(self, brdf, env, diameter: int, lobe_samples: int = 64, seed: int = 0):
        """(radiance (D, D, 3), coverage (D, D), key), baking only on a miss."""
        from ..file import cachefs

        key = bake_key(brdf, env, diameter, lobe_samples, seed)
        if key in self._mem:
            self._mem.move_to_end(key)
            rgb, cov = self._mem[key]
            return rgb, cov, key
        path = os.path.join(self.folder, f"bake-{key[:24]}.npz") if self.folder else None
        if path and os.path.exists(path):
            got = _read_bake(path, int(diameter))
            if got is not None:
                self._store(key, *got)
                return got[0], got[1], key
        rgb, cov = bake_sphere(brdf, env, diameter, lobe_samples, seed)
        self.computed.append(key)
        self._store(key, rgb, cov)
        if path:
            from ..file.atomic import atomic_path

            try:
                cachefs.cache_folder(self.folder)
                with atomic_path(path, ".npz") as tmp:
                    with open(tmp, "wb") as fh:
                        np.savez(fh, radiance=rgb, coverage=cov)
                cachefs.write_seal(path)
                cachefs.prune(self.folder, self.max_files, self.max_bytes, keep=(path,), prefix="bake-")
            except (OSError, ValueError):
                pass  # an unwritable cache only costs time
        return rgb, cov, key

    def _store(self, key, rgb, cov):
        self._mem[key] = (rgb, cov)
        self._mem.move_to_end(key)
        while len(self._mem) > self.max_items:
            self._mem.popitem(last=False)


def _read_bake(path, diameter):
    """(radiance, coverage) of a sealed bake file, or None if it is damaged or not a bake."""
    import io

    from ..file import cachefs

    data = cachefs.read_verified(path)
    if data is None:
        return None
    try:
        with np.load(io.BytesIO(data)) as z:
            rgb, cov = np.asarray(z["radiance"]), np.asarray(z["coverage"])
    except Exception:  # noqa: BLE001 - a damaged zip raises many kinds; it is only a miss
        return None
    if (
        rgb.shape != (diameter, diameter, 3)
        or cov.shape != (diameter, diameter)
        or rgb.dtype.kind != "f"
        or not np.isfinite(rgb).all()
    ):
        return None
    return rgb, cov


def prune(folder, prefix, suffix, keep):
    """Keep the ``keep`` most recently used sealed entries ``prefix*suffix`` (cachefs.prune)."""
    from ..file import cachefs

    cachefs.prune(folder, keep, 1 << 62, prefix=prefix)
