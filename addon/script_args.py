"""The arguments meant for a script that Blender or Python runs (stdlib only, no bpy import).

``blender -b -P script.py -- --out x`` hands the script Blender's whole command line:
the script's own arguments are the ones after ``--``. Without ``--`` (``blender -b -P
script.py``) every argument is Blender's, so the script has none; reading ``sys.argv[1:]``
there gives ``-b -P script.py`` and argparse stops with "unrecognized arguments".
Run as ``python script.py --out x`` (the bpy module, or no Blender at all), they are
``sys.argv[1:]`` as usual.
"""

from __future__ import annotations

import sys


def inside_blender() -> bool:
    """True in a Blender executable, False under plain Python or the bpy module.

    Blender imports bpy before any script runs; only the executable has a binary path
    (the bpy module reports an empty one)."""
    bpy = sys.modules.get("bpy")
    app = getattr(bpy, "app", None)
    return bool(getattr(app, "binary_path", "")) and not getattr(app, "module", False)


def script_args(argv=None, blender=None) -> list:
    """The script's own arguments from ``argv`` (default ``sys.argv``).

    ``blender``: whether ``argv`` is a Blender command line (default: ask ``inside_blender``)."""
    argv = list(sys.argv if argv is None else argv)
    if "--" in argv:
        return argv[argv.index("--") + 1 :]
    if blender is None:
        blender = inside_blender()
    return [] if blender else argv[1:]
