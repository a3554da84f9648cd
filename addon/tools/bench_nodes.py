"""``python -m addon.tools.bench_nodes [--quick] [names...]``: the artist's material outside OSL
(issue 28), engine only. For every measured material and its edits (σ̃² ×0.5, ×2, strength
0.5), the lobe mixture the nodes render (``core.lobes``) and the single Principled BSDF
(``core.principled``) against the edited table: BRDF error and directional-albedo error (as
each fit states them), and the lobe fit's time. Prints a markdown table and a summary."""

from __future__ import annotations

import itertools
import sys
import time

import numpy as np

EDITS = (("as measured", None), ("σ̃² ×0.5", ("sigma2", 0.5)), ("σ̃² ×2", ("sigma2", 2.0)), ("strength 0.5", None))
QUICK = ("rgl/paper_blue", "rgl/cm_white", "rgl/satin_gold", "rgl/ilm_l3_37_metallic", "nielsen/paintedmetal")


def edited_tables(table):
    """(label, table) for the table and its three edits (an edit that fails is reported)."""
    from ..core.edit import EditTargets, edit
    from ..core.fits import fit_material
    from ..core.profiles import compute_profiles

    prof = compute_profiles(table)
    fit = fit_material(prof)
    yield "as measured", table
    for label, targets in (
        ("σ̃² ×0.5", lambda f: EditTargets(sigma2=f["sigma2"] * 0.5)),
        ("σ̃² ×2", lambda f: EditTargets(sigma2=min(f["sigma2"] * 2.0, np.pi**2 / 12))),
        ("strength 0.5", lambda f: EditTargets(strength=0.5)),
    ):
        try:
            yield label, edit(table, targets(fit), prof, fit, remeasure=False).table
        except ValueError as exc:  # no specular lobe to edit
            yield label, exc


def bench_nodes(names, principled=True, out=print):
    import samples

    from ..core.lobes import fit_lobes
    from ..core.merl import read_merl
    from ..core.principled import fit_principled

    out(
        "| material | edit | lobes: BRDF error | lobes: albedo error | Principled: BRDF | Principled: albedo | fit time |"
    )
    out("|---|---|---|---|---|---|---|")
    errs, albs, times, perrs, palbs = [], [], [], [], []
    for name in names:
        table = read_merl(samples.sample_path(name))
        for label, t in edited_tables(table):
            if isinstance(t, Exception):
                out(f"| {name} | {label} | not editable: {t} | | | | |")
                continue
            t0 = time.perf_counter()
            f = fit_lobes(t)
            took = time.perf_counter() - t0
            p = fit_principled(t) if principled else None
            errs.append(f.error)
            albs.append(f.albedo_error)
            times.append(took)
            pe = pa = ""
            if p is not None:
                perrs.append(p.error)
                palbs.append(p.albedo_error)
                pe, pa = f"{p.error:.1%}", f"{p.albedo_error:.1%}"
            out(f"| {name} | {label} | {f.error:.1%} | {f.albedo_error:.1%} | {pe} | {pa} | {took:.2f} s |")
            sys.stdout.flush()
    e, a = np.array(errs), np.array(albs)
    out("")
    out(
        f"Lobes over {len(e)} tables: BRDF error median {np.median(e):.1%}, 90th percentile "
        f"{np.percentile(e, 90):.1%}, worst {e.max():.1%}; albedo error median {np.median(a):.1%}, worst "
        f"{a.max():.1%}; fit time median {np.median(times):.2f} s, worst {max(times):.2f} s."
    )
    if perrs:
        out(
            f"Principled over the same: BRDF error median {np.median(perrs):.1%}, worst {max(perrs):.1%}; "
            f"albedo error median {np.median(palbs):.1%}, worst {max(palbs):.1%}."
        )


def main(argv):
    import samples

    if "--render" in argv:
        names = [a for a in argv if not a.startswith("--")]
        bench_nodes_render(eevee="--eevee" in argv, names=names or RENDER_NAMES, demo=not names)
        return
    quick = "--quick" in argv
    names = [a for a in argv if not a.startswith("--")]
    if not names:
        names = list(QUICK) if quick else samples.measured_names()
    bench_nodes(names, principled="--no-principled" not in argv)


RENDER_NAMES = QUICK  # five measured materials (as measured), and the demo's edit below
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
    from ..core.fits import fit_material
    from ..core.lobes import fit_lobes, shadowing_for
    from ..core.principled import fit_principled
    from ..core.merl import read_merl
    from ..core.profiles import compute_profiles
    from ..core.render import TableBRDF, bake_sphere, normalized_rmse, relative_rmse, sphere_layout
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
        pf = fit_principled(table)
        for (engine, what), (kind, rep) in itertools.product(engines, (("lobes", lf), ("Principled", pf))):
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


if __name__ == "__main__":
    main(sys.argv[1:])
