"""Run after samples/demo.py in the same blender -b session (lane 2): the operators the demo
does not call, Analyse and Reset Sliders, on the material it left behind. Writes
<out>/operators.json for tests/test_blender_lane.py."""

import json
import os
import sys

import bpy

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
from addon.script_args import script_args  # noqa: E402

argv = script_args()
out = argv[argv.index("--out") + 1]
mat = next(m for m in bpy.data.materials if m.brdf_moments.analysed)
state = mat.brdf_moments


def record():
    """What the edit put into the material: the group's nodes, the fits, the lookup's packing."""
    node = mat.node_tree.nodes.get("BRDF Moments edit")
    nodes = list(node.node_tree.nodes) if node else []
    lookup = bpy.data.images.get(f"BRDFM lookup: {mat.name}")
    return {
        "used": state.artist_shader_used,
        "label": node.label if node else "",
        "group": sorted(n.bl_idname for n in nodes),
        "distributions": sorted([n.bl_idname, n.distribution] for n in nodes if hasattr(n, "distribution")),
        "linked": bool(node and node.outputs[0].is_linked),
        "principled": json.loads(state.principled_data) if state.principled_data else None,
        "lobes": json.loads(state.lobes_data) if state.lobes_data else None,
        "packed": bool(lookup is not None and lookup.packed_file is not None),
    }


# Apply put the edit into the material itself (no OSL here: Auto's approximation)
artist = record()
ran_restore = sorted(bpy.ops.brdf_moments.restore_material(material=mat.name))
artist["after_restore"] = sorted(n.name for n in mat.node_tree.nodes)
# the other approximation, chosen explicitly: the fitted lobes (plain nodes and a packed lookup)
state.artist_shader = "LOBES"
ran_lobes = sorted(bpy.ops.brdf_moments.apply_edit(material=mat.name))
artist["lobes_run"] = {"ran": ran_lobes, **record()}
artist["lobes_run"]["restore"] = sorted(bpy.ops.brdf_moments.restore_material(material=mat.name))
artist["lobes_run"]["after_restore"] = sorted(n.name for n in mat.node_tree.nodes)
state.artist_shader = "AUTO"
before = {"mu_slope": state.fit_mu_slope, "sigma2": state.fit_sigma2}
edited = {"sigma2": state.sigma2, "strength": state.strength}
state.fit_mu_slope = state.fit_sigma2 = 0.0  # so that only a real re-analysis restores them
ran = {"analyse": sorted(bpy.ops.brdf_moments.analyse(material=mat.name)), "restore_material": ran_restore}
after = {"mu_slope": state.fit_mu_slope, "sigma2": state.fit_sigma2}
ran["reset_sliders"] = sorted(bpy.ops.brdf_moments.reset_sliders(material=mat.name))
sliders = {"mu_slope": state.mu_slope, "sigma2": state.sigma2, "strength": state.strength}
# save and reopen: the plot is redrawn from the stored profiles
name = mat.name
bpy.ops.wm.save_as_mainfile(filepath=os.path.join(out, "lane.blend"))
bpy.ops.wm.open_mainfile(filepath=os.path.join(out, "lane.blend"))
img = bpy.data.images.get(f"BRDF Moments plot: {name}")
px = list(img.pixels[:]) if img is not None else []
reopened = {
    "plot": img is not None,
    "plot_size": list(img.size) if img else [],
    "plot_drawn": sum(1 for v in px[0::4] if abs(v - 0.16) > 0.1) / max(len(px) // 4, 1),
}
with open(os.path.join(out, "operators.json"), "w") as fh:
    json.dump(
        {
            "material": name,
            "ran": ran,
            "fit_before": before,
            "fit_after": after,
            "edited_sliders": edited,
            "reset_sliders": sliders,
            "artist": artist,
            "reopened": reopened,
        },
        fh,
        indent=1,
        allow_nan=False,
    )
print("lane: operators", ran, flush=True)
