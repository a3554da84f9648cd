"""Run after samples/demo.py in the same blender -b session (lane 2): the operators the demo
does not call, Analyse and Reset Sliders, on the material it left behind. Writes
<out>/operators.json for tests/test_blender_lane.py."""

import json
import os
import sys

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
out = argv[argv.index("--out") + 1]
mat = next(m for m in bpy.data.materials if m.brdf_moments.analysed)
state = mat.brdf_moments
before = {"mu_slope": state.fit_mu_slope, "sigma2": state.fit_sigma2}
edited = {"sigma2": state.sigma2, "strength": state.strength}
state.fit_mu_slope = state.fit_sigma2 = 0.0  # so that only a real re-analysis restores them
ran = {"analyse": sorted(bpy.ops.brdf_moments.analyse(material=mat.name))}
after = {"mu_slope": state.fit_mu_slope, "sigma2": state.fit_sigma2}
ran["reset_sliders"] = sorted(bpy.ops.brdf_moments.reset_sliders(material=mat.name))
sliders = {"mu_slope": state.mu_slope, "sigma2": state.sigma2, "strength": state.strength}
with open(os.path.join(out, "operators.json"), "w") as fh:
    json.dump({"material": mat.name, "ran": ran, "fit_before": before, "fit_after": after,
               "edited_sliders": edited, "reset_sliders": sliders}, fh, indent=1, allow_nan=False)
print("lane: operators", ran, flush=True)
