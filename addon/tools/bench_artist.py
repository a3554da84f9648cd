"""``python -m addon bench --only artist``: what the artist sees against the converged reference
(issue 19): every preview mode, the live low-resolution preview and its latency, and the
Principled approximation that the artist's material renders outside OSL.

One sphere, D = 115 px (the size of one sphere of the 256-wide preview), under Blender's
"studio" HDRI, on ggx_glossy and ggx_mirror. Ground truth: ``render_reference`` at GT_SPP
(its two halves give its own noise), cached by content. Errors: per-pixel relative RMSE over
the pixels wholly inside the sphere, and RMSE / RMS in brackets.
"""

from __future__ import annotations

import itertools
import math
import os
import sys
import time

import numpy as np

NAMES = ("ggx_glossy", "ggx_mirror")
SIZE = 128
GT_SPP = 8192


def bench_artist(quick=False):
    import samples

    from ..blender.live import upsample
    from ..core.file.merl import read_merl
    from ..core.fits.curves import fit_material
    from ..core.material.principled import fit_principled
    from ..core.preview import MomentParams, TableBRDF, bake_sphere, normalized_rmse, relative_rmse, sphere_layout
    from ..core.preview.live import FINAL_SAMPLES, LIVE_DIAMETER_DIV, LIVE_SAMPLES
    from ..core.profiles.compute import compute_profiles
    from ..wheel import import_bpy
    from .bench_preview import _environment, _read_exr, ground_truth

    bpy = import_bpy()
    from ..blender import material as artist
    from ..blender.preview import build_preview, render_still
    from ..blender.preview import scene as sc

    env, env_path = _environment(bpy)
    layout = sphere_layout(SIZE, SIZE, 1)
    d = layout.diameter
    mask = layout.interior_mask()
    tmp = os.path.join(_tmp_dir(), "bench-artist.exr")
    rows, notes = [], []
    gt_spp = 2048 if quick else GT_SPP
    osl_settings = ((16, 16),) if quick else ((16, 16), (64, 64))

    def err(img, gt):
        return relative_rmse(img, gt, mask), normalized_rmse(img, gt, mask)

    def row(name, what, setting, took, e):
        t = f"{took * 1e3:.0f} ms" if took < 1 else f"{took:.2f} s"
        rows.append(f"| {name} | {what} | {setting} | {t} | {e[0]:.2%} ({e[1]:.2%}) |")

    def tile_image(rgb, cov):
        return layout.compose([np.dstack([rgb * cov[..., None], cov])])

    def cycles(scene, spp):
        scene.cycles.samples = spp
        render_still(scene, tmp, quiet=True)  # warm-up (shader compilation, BVH)
        t = time.perf_counter()
        render_still(scene, tmp, quiet=True)
        return time.perf_counter() - t, _read_exr(bpy, tmp)

    for name in NAMES:
        table = read_merl(samples.sample_path(name))
        prof = compute_profiles(table)
        fit = fit_material(prof)
        brdf = TableBRDF(table, prof)
        gt, noise, took = ground_truth(layout, [brdf], env, f"{name}-i19", gt_spp)
        notes.append(
            f"{name}: ground truth {gt_spp} spp"
            + (f" ({took:.0f} s)" if took else " (cached)")
            + f", its own noise {noise:.2%} per pixel"
        )
        # 1. the default preview: the baked table at Build Preview's setting
        t = time.perf_counter()
        rgb, cov = bake_sphere(brdf, env, d, FINAL_SAMPLES, 0)
        row(
            name,
            "**default preview**: baked table",
            f"{FINAL_SAMPLES}+{FINAL_SAMPLES} samples/texel",
            time.perf_counter() - t,
            err(tile_image(rgb, cov), gt),
        )
        # 2. the live preview's first image: a quarter-resolution bake, upsampled
        d0 = max(d // LIVE_DIAMETER_DIV, 8)
        t = time.perf_counter()
        rgb0, cov0 = bake_sphere(brdf, env, d0, LIVE_SAMPLES, 0)
        took = time.perf_counter() - t
        rgb0 = upsample(rgb0, d)
        row(
            name,
            "live preview, first image",
            f"D/{LIVE_DIAMETER_DIV} = {d0} px, {LIVE_SAMPLES}+{LIVE_SAMPLES}",
            took,
            err(layout.compose([np.dstack([rgb0 * cov[..., None], cov])]), gt),
        )
        # 3. OSL: tabulated, and the sketch (moment model) against the table it sketches
        params = MomentParams.from_fit(fit, tuple(prof.kd))
        for mode, src in (("tabulated", brdf), ("model", params)):
            for spp, lobe in osl_settings:
                bpy.ops.wm.read_homefile(use_empty=True)
                scene = bpy.context.scene
                build_preview(
                    scene, src, None, path="osl", mode=mode, env=env_path, size=SIZE, samples=spp, lobe_samples=lobe
                )
                took, img = cycles(scene, spp)
                row(
                    name,
                    "OSL tabulated" if mode == "tabulated" else "OSL sketch (moment model)",
                    f"{spp} spp x {lobe} lobe",
                    took,
                    err(img, gt),
                )
        # 4. the artist's material outside OSL: the fitted Principled BSDF in Cycles (SVM)
        t = time.perf_counter()
        pfit = fit_principled(table)
        t_fit = time.perf_counter() - t
        bpy.ops.wm.read_homefile(use_empty=True)
        scene = bpy.context.scene
        sc.configure_render(scene, layout, "baked", 16)
        scene.cycles.max_bounces = scene.cycles.diffuse_bounces = scene.cycles.glossy_bounces = 1
        sc.ensure_camera(scene, layout)
        sc.ensure_world(scene, env_path, path="osl")  # the map's importance sampling, as an artist's world
        (obj,) = sc.ensure_spheres(scene, layout)
        mat = bpy.data.materials.new("bench principled")
        mat.use_nodes = True
        artist.apply_principled(mat, pfit)
        obj.data.materials.clear()
        obj.data.materials.append(mat)
        for spp in (256,) if quick else (256, 1024):
            took, img = cycles(scene, spp)
            row(name, "artist's material: Principled approx. (Cycles)", f"{spp} spp", took, err(img, gt))
        notes.append(
            f"{name}: Principled fit in {t_fit:.2f} s: roughness {pfit.roughness:.4f}, metallic "
            f"{pfit.metallic:.3f}, specular {pfit.specular:.4f}, base "
            + ", ".join(f"{v:.3f}" for v in pfit.base_color)
            + f"; stated BRDF error {pfit.error:.1%}, albedo within {pfit.albedo_error:.1%}"
        )
    out = [
        f"### What the artist sees, against the converged reference (one sphere, D = {d} px, `studio` HDRI)",
        "",
        "| material | what | setting | time | rel. RMSE per pixel (RMSE/RMS) |",
        "|---|---|---|---|---|",
    ]
    out += rows
    out += [f"- {n}" for n in notes]
    return out + [""] + bench_live(quick)


LIVE_NAMES = ("ggx_glossy", "ggx_mirror", "rgl/satin_gold", "rgl/colodur_kalahari_2a", "nielsen/greencloth")


def bench_live(quick=False):
    """``bench --only live``: slider move to the live preview's first image (the draft synthesis,
    the engine's table BRDF, the quarter-size bake), then to the refined image (the full
    synthesis, the full-size bake); the image write and the panel redraw are not included.
    Engine only (no bpy): the same work the panel's worker thread does (``core.preview.live.work``),
    step by step to time each."""
    import samples

    from ..core.edit import EditTargets
    from ..core.edit.solve import roughness_region
    from ..core.file.merl import read_merl
    from ..core.fits.curves import fit_material
    from ..core.preview import Environment, TableBRDF, bake_sphere
    from ..core.preview.live import FINAL_SAMPLES, LIVE_DIAMETER_DIV, LIVE_SAMPLES, fast_edit
    from ..core.profiles.compute import compute_profiles

    d = 115  # one sphere of the 256-wide preview
    d0 = max(d // LIVE_DIAMETER_DIV, 8)
    # A bright light on a dim sky: the bake's cost does not depend on the map's content.
    env = Environment.from_function(
        lambda w: 0.2 + 20.0 * np.exp(-((w[:, 0:1] - 0.5) ** 2 + (w[:, 2:3] - 0.7) ** 2) / 0.01).repeat(3, 1), 256, 128
    )
    names = LIVE_NAMES[:2] if quick else LIVE_NAMES
    rows, first, refined, regions = [], [], [], []
    for name in names:
        table = read_merl(samples.sample_path(name))
        prof = compute_profiles(table)
        fit = fit_material(prof)
        t0 = time.perf_counter()
        region = roughness_region(table, prof, fit)  # once per analysis, as Analyse does (warp mode)
        regions.append(time.perf_counter() - t0)
        fast_edit(
            table, EditTargets(sigma2=min(fit["sigma2"] * 1.1, math.pi**2 / 12)), prof, fit, draft=True, region=region
        )  # warm
        for s2 in (1.25, 1.5, 0.8):
            targets = EditTargets(sigma2=min(fit["sigma2"] * s2, math.pi**2 / 12))
            t0 = time.perf_counter()
            draft = fast_edit(table, targets, prof, fit, draft=True, region=region)
            t1 = time.perf_counter()
            bake_sphere(TableBRDF(draft, prof), env, d0, LIVE_SAMPLES, 0)
            t2 = time.perf_counter()
            full = fast_edit(table, targets, prof, fit, region=region)
            t3 = time.perf_counter()
            bake_sphere(TableBRDF(full, prof), env, d, FINAL_SAMPLES, 0)
            t4 = time.perf_counter()
            first.append(t2 - t0)
            refined.append(t4 - t0)
            rows.append(
                f"| {name} | {s2} | {t1 - t0:.2f} s | {t2 - t1:.2f} s | **{t2 - t0:.2f} s** | {t3 - t2:.2f} s | "
                f"{t4 - t3:.2f} s | {t4 - t0:.2f} s |"
            )
    med = float(np.median(first))
    return (
        [
            "### Slider move to the live preview (`bench --only live`)",
            "",
            f"Per move: the draft synthesis, the D/{LIVE_DIAMETER_DIV} = {d0} px bake of it ({LIVE_SAMPLES}+"
            f"{LIVE_SAMPLES} samples) — the first image —, then the full synthesis and the D = {d} px bake "
            f"({FINAL_SAMPLES}+{FINAL_SAMPLES}) that replaces it. The draft is one roughness synthesis at the scale "
            "the material's curve gives for the slider; the region (the curve and the tilt's reach) is computed once "
            f"per analysis, as Analyse does: median {float(np.median(regions)):.1f} s, max {max(regions):.1f} s here.",
            "",
            "| material | σ̃² × | draft synthesis | draft bake | first image | full synthesis | full bake | "
            "refined image |",
            "|---|---|---|---|---|---|---|---|",
        ]
        + rows
        + [
            "",
            f"Median slider-to-first-image latency {med:.2f} s (range {min(first):.2f}–{max(first):.2f} s), "
            f"target 1 s: {'met' if med <= 1.0 else 'missed'}; refined image median {float(np.median(refined)):.2f} s.",
        ]
    )


RENDER_NAMES = (
    "rgl/paper_blue",
    "rgl/cm_white",
    "rgl/satin_gold",
    "rgl/ilm_l3_37_metallic",
    "nielsen/paintedmetal",
)  # five measured materials (as measured), and the demo's edit below
RENDER_SIZE = 128
REF_SAMPLES = 512  # the baked reference: 4x Build Preview's 128+128 per texel


def bench_nodes_render(spp=256, eevee=False, names=RENDER_NAMES, demo=True, out=print):
    """The artist's sphere rendered with the fitted lobes (Cycles, GPU-compatible nodes, on the
    CPU here) against the baked reference of the same table under the same HDRI (`studio`):
    per-pixel relative RMSE over the sphere's interior. Cycles' own noise is estimated from two
    seeds. Needs the bpy module (python -m addon.tools.bench_nodes --render)."""
    import samples

    from ..blender import material as artist
    from ..blender.preview import render_still
    from ..blender.preview import scene as sc
    from ..core.edit import EditTargets, edit
    from ..core.file.merl import read_merl
    from ..core.fits.curves import fit_material
    from ..core.material.lobes import fit_lobes, shadowing_for
    from ..core.material.principled import fit_principled
    from ..core.preview import TableBRDF, bake_sphere, normalized_rmse, relative_rmse, sphere_layout
    from ..core.profiles.compute import compute_profiles
    from ..wheel import import_bpy
    from .bench_preview import _environment, _read_exr

    bpy = import_bpy()
    env, env_path = _environment(bpy)
    layout = sphere_layout(RENDER_SIZE, RENDER_SIZE, 1)
    d, mask = layout.diameter, layout.interior_mask()
    tmp = "/tmp/brdfm-bench-nodes.exr"
    cases = [(name, "as measured", read_merl(samples.sample_path(name))) for name in names]
    if demo:
        glossy = read_merl(samples.sample_path("ggx_glossy"))
        prof = compute_profiles(glossy)
        fit = fit_material(prof)
        sliders = EditTargets(sigma2=min(fit["sigma2"] * 1.5, 0.8), strength=0.8)  # samples/demo.py's
        cases.append(("ggx_glossy", "the demo's edit (σ̃² ×1.5, strength 0.8)", edit(glossy, sliders, prof, fit).table))
    engines = [("CYCLES", "Cycles (CPU)")]
    if eevee:
        next_ = (4, 2, 0) <= bpy.app.version < (5, 0, 0)  # EEVEE Next's engine name in 4.2-4.5
        engines.append(("BLENDER_EEVEE_NEXT" if next_ else "BLENDER_EEVEE", "EEVEE"))
    out(
        "| material | edit | what renders | its stated error | rendered rel. RMSE per pixel (RMSE/RMS; median pixel) | its noise | render time |"
    )
    out("|---|---|---|---|---|---|---|")
    for name, label, table in cases:
        t0 = time.perf_counter()
        tprof = compute_profiles(table)
        rgb, cov = bake_sphere(TableBRDF(table, tprof), env, d, REF_SAMPLES, 0)
        ref = layout.compose([np.dstack([rgb * cov[..., None], cov])])
        t_ref = time.perf_counter() - t0
        lf = fit_lobes(table, shadowing=shadowing_for(bpy.app.version))
        # what Apply installs for a scene EEVEE renders: round lobes (EEVEE ignores anisotropy)
        lf_round = fit_lobes(table, shadowing=shadowing_for(bpy.app.version), aspects=(1.0,)) if eevee else None
        pf = fit_principled(table)
        for (engine, what), (kind, rep) in itertools.product(engines, (("lobes", lf), ("Principled", pf))):
            if kind == "lobes" and engine != "CYCLES":
                rep = lf_round
            bpy.ops.wm.read_homefile(use_empty=True)
            scene = bpy.context.scene
            sc.configure_render(scene, layout, "baked", spp)
            scene.cycles.max_bounces = scene.cycles.diffuse_bounces = scene.cycles.glossy_bounces = 1
            sc.ensure_camera(scene, layout)
            sc.ensure_world(scene, env_path, path="osl")
            (obj,) = sc.ensure_spheres(scene, layout)
            mat = bpy.data.materials.new("bench artist")
            if kind == "lobes":
                artist.apply_lobes(mat, rep)
            else:
                artist.apply_principled(mat, rep)
            obj.data.materials.clear()
            obj.data.materials.append(mat)
            try:
                scene.render.engine = engine
                if engine != "CYCLES":
                    scene.eevee.taa_render_samples = spp
            except TypeError as exc:
                out(f"| {name} | {label} | {what} | | not available: {exc} | | |")
                continue
            imgs, took = [], 0.0
            try:
                for seed in (0, 1):
                    scene.cycles.seed = seed
                    t0 = time.perf_counter()
                    render_still(scene, tmp, quiet=True)
                    took = time.perf_counter() - t0
                    imgs.append(_read_exr(bpy, tmp))
            except RuntimeError as exc:
                out(f"| {name} | {label} | {what} | | failed: {str(exc).splitlines()[0]} | | |")
                continue
            img = 0.5 * (imgs[0] + imgs[1])
            noise = 0.5 * relative_rmse(imgs[0], imgs[1], mask)
            e = relative_rmse(img, ref, mask)
            e2 = normalized_rmse(img, ref, mask)
            a, r = img[mask][:, :3], ref[mask][:, :3]
            med = float(np.median(np.abs(a - r) / np.maximum(r, 1e-3 * float(np.mean(r)))))
            out(
                f"| {name} | {label} | {kind}: {what} {bpy.app.version_string}, {spp}x2 spp | "
                f"{rep.error:.1%} / albedo {rep.albedo_error:.1%} | "
                f"**{e:.2%}** ({e2:.2%}; median pixel {med:.1%}) | {noise:.2%} | {took:.1f} s (reference bake {t_ref:.0f} s) |"
            )
            sys.stdout.flush()


def _tmp_dir():
    from ..core.profiles.integrate import default_cache_dir

    path = os.path.join(default_cache_dir(), "preview")
    os.makedirs(path, exist_ok=True)
    return path
