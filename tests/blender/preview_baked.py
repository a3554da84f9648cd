"""Run inside a real ``blender -b`` (Debian's 3.4, no OSL): the baked preview of the
Lambertian sample under a sky L = A + B z, rendered by Cycles to EXR, against the closed form.

    blender -b --factory-startup --python-exit-code 1 -P preview_baked.py -- ROOT OUT_DIR

Writes OUT_DIR/result.json; exits 1 on any error (``--python-exit-code``).
"""

import json
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from addon.script_args import script_args  # noqa: E402

ROOT, OUT = script_args()[:2]
sys.path.insert(0, ROOT)

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import samples  # noqa: E402
from addon.blender import preview  # noqa: E402
from addon.core.file.merl import read_merl  # noqa: E402
from addon.core.preview import Environment  # noqa: E402
from addon.core.preview.scene import texel_positions  # noqa: E402
from addon.core.profiles.compute import compute_profiles  # noqa: E402

A, B = 1.0, 0.5
os.makedirs(OUT, exist_ok=True)
sky = preview.write_environment(
    Environment.from_function(lambda d: np.repeat(A + B * d[:, 2:3], 3, axis=1), 256, 128).pixels,
    os.path.join(OUT, "sky.exr"),
)
table = read_merl(samples.sample_path("lambertian"))
# Profiles at a few views are enough for the sampling lobe (a loaded material has them all);
# they keep a cold operator cache from costing a minute here.
prof = compute_profiles(table, np.radians([0.0, 30.0, 60.0, 85.0]), max_order=2)
bpy.ops.wm.read_homefile(use_empty=True)
scene = bpy.context.scene
info = preview.build_preview(scene, table, path="auto", env=sky, size=48, samples=4, profiles=[prof])
out = preview.render_still(scene, os.path.join(OUT, "lambert.exr"))
img = bpy.data.images.load(out)
w, h = img.size
buf = np.empty(w * h * 4, np.float32)
img.pixels.foreach_get(buf)
pix = buf.reshape(h, w, 4)[::-1]
lay = info.layout
mask = lay.interior_mask()
jj, ii = np.nonzero(mask)
_, z = texel_positions(lay.diameter, ii - lay.lefts[0], jj - lay.top, 0.5, 0.5)
want = 0.8 * (A + 2.0 * B * z / 3.0)
rel = pix[mask][:, 0] / want - 1.0
result = {
    "blender": bpy.app.version_string,
    "numpy": np.__version__,
    "path": info.path,
    "size": [w, h],
    "pixels": int(mask.sum()),
    "max_rel_err": float(np.abs(rel).max()),
    "mean_rel_err": float(rel.mean()),
    "baked": info.baked,
}
with open(os.path.join(OUT, "result.json"), "w") as fh:
    json.dump(result, fh)
print("preview lane:", result, flush=True)
if not math.isfinite(result["max_rel_err"]):
    sys.exit(1)
