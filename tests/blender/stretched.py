"""Run inside Debian's ``blender -b`` (3.4): Cycles renders a stretched lobe of ``core.material.lobes``
through 3.4's Anisotropic node as the fit models it, and a Beckmann lobe and a Fresnel lobe
(3.4's Principled v1 factor), a Velvet and a rough Diffuse too (tests/_stretched.py).

    blender -b --factory-startup --python-exit-code 1 -P stretched.py -- ROOT OUT_DIR
"""

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from addon.script_args import script_args  # noqa: E402

ROOT, OUT = script_args()[:2]
sys.path[:0] = [ROOT, os.path.join(ROOT, "tests")]

import bpy  # noqa: E402
from _stretched import render_errors  # noqa: E402

from addon.blender import material  # noqa: E402

os.makedirs(OUT, exist_ok=True)
err = render_errors(bpy, material, os.path.join(OUT, "stretched.exr"))
kinds = render_errors(bpy, material, os.path.join(OUT, "kinds.exr"), case="kinds")
in_plane = render_errors(bpy, material, os.path.join(OUT, "in-plane.exr"), case="in the plane")
velvet = render_errors(bpy, material, os.path.join(OUT, "velvet.exr"), case="velvet")
rough = render_errors(bpy, material, os.path.join(OUT, "rough.exr"), case="rough")
with open(os.path.join(OUT, "stretched.json"), "w") as fh:
    json.dump(
        {
            "blender": bpy.app.version_string,
            "errors": err,
            "kinds": kinds,
            "in_plane": in_plane,
            "velvet": velvet,
            "rough": rough,
        },
        fh,
    )
