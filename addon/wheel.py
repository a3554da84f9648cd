"""Import the ``bpy`` module (PyPI wheel) for headless use, with OSL working.

The wheel ships OSL, but its Cycles imports ``oslquery`` from
``<bpy dir>/<version>/python/lib/python3.X/site-packages``, which is not on ``sys.path``;
without it, script nodes silently get no sockets. The command line and the test harness call
``import_bpy()``; the extension itself never touches ``sys.path`` (SPEC §4).
"""

from __future__ import annotations

import glob
import importlib.util
import os
import sys


def bpy_site_packages():
    """The wheel's bundled site-packages folder (holding ``oslquery``), or None."""
    spec = importlib.util.find_spec("bpy")
    roots = list(spec.submodule_search_locations or []) if spec else []
    if spec and spec.origin:
        roots.append(os.path.dirname(spec.origin))
    for root in roots:
        # spec paths may point at bpy/ or, once imported, at bpy/<ver>/scripts/modules/bpy
        for base in (root, os.path.join(root, "..", "..", "..", "..")):
            hits = sorted(glob.glob(os.path.join(base, "[0-9]*", "python", "lib", "python3*", "site-packages")))
            for h in hits:
                if os.path.isdir(os.path.join(h, "oslquery")):
                    return os.path.normpath(h)
    return None


def import_bpy():
    """``import bpy`` with the OSL query module reachable; returns the module.

    Raises ImportError with a clear message when the bpy module is not installed."""
    extra = bpy_site_packages()
    try:
        import bpy
    except ImportError as exc:
        raise ImportError(f"rendering needs Blender's bpy module (pip install bpy): {exc}") from None
    if extra is None:
        extra = bpy_site_packages()
    if extra and extra not in sys.path:
        sys.path.append(extra)
    return bpy
