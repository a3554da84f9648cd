"""The whole BRDF Moments flow on a built-in sample, through the extension's operators:
load and analyse, move the sliders, apply (re-synthesize), export, and render the preview
of original against edited into OUT as PNG.

    python samples/demo.py [--out out] [--sample ggx_glossy] [--size 128]     (bpy module)
    blender -b -P samples/demo.py [-- --out out --sample ... --size ...]  (a real Blender)

Under the bpy module the repository is enabled as an extension; in a real Blender it is
enabled as a legacy add-on, unless it already is (``--installed``: the test lane installs
the packaged zip first). Prints one line per step and writes OUT/demo.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


def _args():
    from addon.script_args import script_args

    p = argparse.ArgumentParser(prog="samples/demo.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=os.path.join(ROOT, "out"))
    p.add_argument("--sample", default="ggx_glossy")
    p.add_argument("--size", type=int, default=192, help="sphere size in pixels (the render is two spheres wide)")
    p.add_argument("--samples", type=int, default=32, help="Cycles samples per pixel")
    p.add_argument(
        "--path",
        choices=("auto", "osl", "baked"),
        default="auto",
        help="preview path; auto = OSL where Cycles has it, else baked",
    )
    p.add_argument("--installed", action="store_true", help="the add-on is already enabled")
    return p.parse_args(script_args())


def _say(step, text):
    print(f"demo: {step}: {text}", flush=True)


def has_operator(bpy, name):
    try:
        getattr(bpy.ops.brdf_moments, name).get_rna_type()
    except (AttributeError, KeyError):
        return False
    return True


def enable_addon(bpy):
    """Make bpy.ops.brdf_moments available, as a user of this Blender would have it."""
    if has_operator(bpy, "apply_edit"):
        return "already enabled"
    import addon_utils

    if bpy.app.version >= (4, 2, 0):
        repo = tempfile.mkdtemp(prefix="brdf_moments_repo_")
        os.symlink(ROOT, os.path.join(repo, "brdf_moments"))
        bpy.context.preferences.extensions.repos.new(
            name="bmdemo", module="bmdemo", custom_directory=repo, source="USER"
        )
        addon_utils.enable("bl_ext.bmdemo.brdf_moments", default_set=True)
        return "extension bl_ext.bmdemo.brdf_moments"
    # Blender 3.4-4.1: a legacy add-on in the user's scripts folder.
    addons = bpy.utils.user_resource("SCRIPTS", path="addons", create=True)
    link = os.path.join(addons, "brdf_moments")
    if not os.path.exists(link):
        os.symlink(ROOT, link)
    bpy.utils.refresh_script_paths()  # a new scripts folder is not on sys.path yet
    addon_utils.modules_refresh()
    addon_utils.enable("brdf_moments", default_set=True)
    return f"legacy add-on in {addons}"


def main():
    args = _args()
    os.makedirs(args.out, exist_ok=True)
    os.environ.setdefault("BRDF_MOMENTS_CACHE", os.path.join(ROOT, ".cache", "engine"))
    os.environ.setdefault("BRDF_MOMENTS_SAMPLES", os.path.join(ROOT, ".cache", "samples"))
    if "bpy" not in sys.modules:  # plain python: the bpy module, with its OSL reachable
        os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="brdf_moments_user_"))
        from addon.wheel import import_bpy

        import_bpy()
    import bpy

    import samples

    t_start = time.perf_counter()
    _say("blender", f"{bpy.app.version_string}, {'background' if bpy.app.background else 'UI'}")
    _say("add-on", args.installed and "installed by the caller" or enable_addon(bpy))
    if not has_operator(bpy, "apply_edit"):
        raise SystemExit("demo: the BRDF Moments add-on is not enabled")

    try:
        merl = samples.sample_path(args.sample)
    except (OSError, ValueError, KeyError) as exc:
        raise SystemExit(f"demo: {exc}") from None
    _say("sample", f"{args.sample} tabulated into {merl}")
    mat = bpy.data.materials.new(args.sample)
    mat.use_fake_user = True
    t0 = time.perf_counter()
    bpy.ops.brdf_moments.load_merl(filepath=merl, material=mat.name)
    state = mat.brdf_moments
    _say(
        "analyse",
        f"mu~ {state.fit_mu_slope:+.3f}, sigma2~ {state.fit_sigma2:.4f}, "
        f"kd {tuple(round(v, 3) for v in state.kd)} ({time.perf_counter() - t0:.1f} s)",
    )

    # The edit: a blurrier, slightly dimmer highlight (warp mode, the default: every view's
    # unclipped lobe widened by the same factor and clipped again by the horizon, SPEC §3).
    state.sigma2 = min(state.fit_sigma2 * 1.5, 0.8)
    state.strength = 0.8
    announced = json.loads(state.announced_json) if state.announced_json else None  # what the panel shows
    if announced:
        _say("sliders", f"announced mu~ {announced['mu_slope']:+.4f}, sigma2~ {announced['sigma2']:.4f}")
    t0 = time.perf_counter()
    bpy.ops.brdf_moments.apply_edit(material=mat.name)
    _say(
        "apply",
        f"target sigma2~ {state.sigma2:.4f}: reached mu~ {state.achieved_mu_slope:+.3f}, "
        f"sigma2~ {state.achieved_sigma2:.4f}, largest albedo {max(state.max_albedo):.3f} "
        f"({time.perf_counter() - t0:.1f} s)",
    )
    fid = state.fidelity()
    if fid is not None:
        from addon.core.edit.fidelity import describe

        _say("apply", describe(fid))
    for warning in filter(None, state.edit_warnings.split("\n")):
        _say("apply", f"warning: {warning}")

    for what in ("TABLE", "PROFILES", "PLOTS"):
        bpy.ops.brdf_moments.export(what=what, directory=args.out, material=mat.name)
    _say("export", f"table, profiles and plots in {args.out}")

    renders = []
    if has_operator(bpy, "build_preview"):
        t0 = time.perf_counter()
        bpy.ops.brdf_moments.build_preview(
            material=mat.name,
            path=args.path.upper(),
            size=args.size,
            samples=args.samples,
            render_to=os.path.join(args.out, f"{args.sample}_preview.png"),
        )
        renders.append(os.path.join(args.out, f"{args.sample}_preview.png"))
        _say(
            "preview",
            f"measured | edited spheres, labelled with the moves, rendered to {renders[-1]} ({time.perf_counter() - t0:.1f} s)",
        )

    summary = {
        "blender": bpy.app.version_string,
        "sample": args.sample,
        "fit": {"mu_slope": state.fit_mu_slope, "sigma2": state.fit_sigma2},
        "target": {"mu_slope": state.mu_slope, "sigma2": state.sigma2, "strength": state.strength, "mode": state.mode},
        "announced": announced,  # what the panel showed beside the sliders before Apply
        "reached": {"mu_slope": state.achieved_mu_slope, "sigma2": state.achieved_sigma2},
        "per_view": state.fidelity(),  # the written table re-measured view by view (SPEC §6)
        "max_albedo": list(state.max_albedo),
        "warnings": state.edit_warnings,
        "files": sorted(os.listdir(args.out)),
        "renders": renders,
        "seconds": round(time.perf_counter() - t_start, 1),
    }
    from addon.core.file.atomic import atomic_path  # guarded and atomic, like every other writer

    with atomic_path(os.path.join(args.out, "demo.json"), ".json") as tmp, open(tmp, "w") as fh:
        json.dump(summary, fh, indent=1, allow_nan=False)
    _say("done", f"{summary['seconds']} s; summary in {os.path.join(args.out, 'demo.json')}")


if __name__ == "__main__":
    main()
