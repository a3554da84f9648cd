"""``python -m addon bench --only preview``: preview render time against error (SPEC §6).

Scene: the 256 x 256 preview, original and edited spheres side by side, under Blender's
"studio" HDRI. Materials: ggx_mirror, ggx_glossy, ggx_rough and one measured material,
rgl/satin_gold (a Neural-BRDF network of the RGL database, Sztrajman et al. 2021); the edited sphere is the model-mode
edit of the demo (sigma2 x 2, strength 0.8), made by ``addon.core.edit`` and cached.

Ground truth: ``render_reference`` (the converged numpy Monte Carlo) at GT_SPP samples per
pixel, from its own seed, cached on disk by content; its own noise is estimated from its two
halves. Errors are over the pixels wholly inside a sphere: ``relative_rmse`` (per pixel) and
``normalized_rmse`` (RMSE / RMS, dominated by highlights). Times are medians of repeats
(Cycles renders after one warm-up render that compiles the shaders).
"""

from __future__ import annotations

import hashlib
import os
import time

import numpy as np

NAMES = ("ggx_mirror", "ggx_glossy", "ggx_rough", "rgl/satin_gold")
ENV = "studio"
SIZE = 256
GT_SPP = 16384
EDIT = dict(sigma2_scale=2.0, strength=0.8)


def _cache_dir():
    from ..core.profiles.integrate import default_cache_dir

    path = os.path.join(default_cache_dir(), "preview")
    os.makedirs(path, exist_ok=True)
    return path


def _source_hash(*modules):
    """Of the modules' sources; a package counts with every .py file in it (edit is one)."""
    h = hashlib.sha256()
    for m in modules:
        files = [m.__file__]
        if os.path.basename(m.__file__) == "__init__.py":
            folder = os.path.dirname(m.__file__)
            files = [os.path.join(folder, f) for f in sorted(os.listdir(folder)) if f.endswith(".py")]
        for f in files:
            with open(f, "rb") as fh:
                h.update(fh.read())
    return h.hexdigest()[:12]


def edited_table(table, name):
    """The demo's model-mode edit of ``table`` (cached as a MERL file by content and code)."""
    from ..core import edit as edit_mod
    from ..core.edit import EditTargets, edit
    from ..core.file.merl import read_merl, write_merl
    from ..core.fits.curves import fit_material
    from ..core.profiles.compute import compute_profiles

    h = hashlib.sha256(np.ascontiguousarray(table.rho).tobytes())
    h.update(repr(sorted(EDIT.items())).encode() + _source_hash(edit_mod).encode())
    path = os.path.join(_cache_dir(), f"edited-{name.replace('/', '-')}-{h.hexdigest()[:16]}.binary")
    if os.path.exists(path):
        return read_merl(path)
    prof = compute_profiles(table)
    fit = fit_material(prof)
    res = edit(
        table,
        EditTargets(
            sigma2=min(fit["sigma2"] * EDIT["sigma2_scale"], np.pi**2 / 12), strength=EDIT["strength"], mode="model"
        ),
        prof,
        fit,
    )
    write_merl(res.table, path)
    return read_merl(path)


def _environment(bpy):
    if bpy is not None:
        from ..blender.preview import load_environment, resolve_environment

        path = resolve_environment(ENV)
        return load_environment(path), path
    import glob

    import OpenEXR

    from ..core.preview import Environment

    hits = glob.glob(
        os.path.join(os.path.dirname(np.__file__), "..", "bpy", "*", "datafiles", "studiolights", "world", f"{ENV}.exr")
    )
    if not hits:
        raise RuntimeError(f"the {ENV} HDRI was not found (install the bpy module)")
    return Environment(OpenEXR.File(hits[0]).channels()["RGB"].pixels, ENV), hits[0]


def reference_version():
    """Hash of the code a reference render's numbers come from (and of nothing else: a change
    to the bake must not throw away four-minute ground truths)."""
    import inspect

    from ..core.preview import envmap, estimators, lobe, scene

    h = hashlib.sha256(b"reference")
    for fn in (
        estimators.render_reference,
        estimators.reference_sphere,
        estimators._to_world,
        estimators._cosine_sample,
    ):
        h.update(inspect.getsource(fn).encode())
    h.update(_source_hash(envmap, lobe, scene).encode())
    return h.hexdigest()[:16]


def ground_truth(layout, brdfs, env, tag, spp=GT_SPP):
    """(image, estimated relative RMSE of its own noise, seconds spent or 0 if cached)."""
    from ..core.preview import relative_rmse, render_reference

    h = hashlib.sha256(f"gt:{spp}:{layout}:{reference_version()}".encode())
    for b in brdfs:
        h.update(b.content_key().encode())
    h.update(env.content_key().encode())
    path = os.path.join(_cache_dir(), f"gt-{tag.replace('/', '-')}-{h.hexdigest()[:16]}.npz")
    if os.path.exists(path):
        with np.load(path) as z:
            return z["image"], float(z["noise"]), 0.0
    t = time.perf_counter()
    halves = [render_reference(layout, brdfs, env, spp=spp // 2, seed=1000 + 17 * k) for k in range(2)]
    took = time.perf_counter() - t
    image = 0.5 * (halves[0] + halves[1])
    # each half has twice the variance of the mean: rmse(h0 - h1) / 2 estimates the mean's
    noise = 0.5 * relative_rmse(halves[0], halves[1], layout.interior_mask())
    np.savez(path, image=image, noise=noise)
    return image, noise, took


def _median_time(fn, repeat, setup=None):
    """Median seconds of ``fn()`` over ``repeat`` calls; ``setup()`` runs untimed before each."""
    times, out = [], None
    for _ in range(repeat):
        arg = setup() if setup else None
        t = time.perf_counter()
        out = fn(arg) if setup else fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def _read_exr(bpy, path):
    img = bpy.data.images.load(path)
    w, h = img.size
    buf = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(buf)
    bpy.data.images.remove(img)
    return buf.reshape(h, w, 4)[::-1]


def bench_preview(quick=False):
    import samples

    from ..core.file.merl import read_merl
    from ..core.preview import (
        BakeCache,
        ModelBRDF,
        TableBRDF,
        normalized_rmse,
        relative_rmse,
        render_baked,
        render_reference,
        sphere_layout,
    )

    try:
        from ..wheel import import_bpy

        bpy = import_bpy()
        from ..blender.preview import build_preview, render_still
    except ImportError:
        bpy = None
    env, env_path = _environment(bpy)
    layout = sphere_layout(SIZE, SIZE, 2)
    mask = layout.interior_mask()
    names = (NAMES[0], NAMES[-1]) if quick else NAMES  # quick: one analytic, one measured
    rep = 1 if quick else 3
    bake_ks = (16, 32, 64) if quick else (8, 16, 32, 64, 128)
    ref_spps = (256,) if quick else (256, 1024)
    osl_settings = ((16, 16),) if quick else ((16, 16), (16, 64), (64, 16), (64, 64))
    gt_spp = 4096 if quick else GT_SPP
    rows, verdicts, notes = [], [], []
    tmp = os.path.join(_cache_dir(), "bench-render.exr")

    def err(img, gt):
        return relative_rmse(img, gt, mask), normalized_rmse(img, gt, mask)

    for name in names:
        table = read_merl(samples.sample_path(name))
        edited = edited_table(table, name)
        brdfs = [TableBRDF(table), TableBRDF(edited)]
        gt, gt_noise, gt_time = ground_truth(layout, brdfs, env, name, gt_spp)
        notes.append(
            f"{name}: ground truth {gt_spp} spp"
            + (f" ({gt_time:.0f} s)" if gt_time else " (cached)")
            + f", its own noise {gt_noise:.2%} per pixel"
        )
        refs = []
        for spp in ref_spps:
            t = time.perf_counter()
            img = render_reference(layout, brdfs, env, spp=spp, seed=1)
            took = time.perf_counter() - t
            e = err(img, gt)
            rows.append((name, "numpy reference", f"{spp} spp", took, e))
            refs.append((spp, took, e))
        baked = []
        for k in bake_ks:
            if bpy is None:

                def bake():
                    env._irr_maps.clear()  # the irradiance map is part of a first bake
                    return render_baked(layout, brdfs, env, lobe_samples=k, seed=0)

                took, img = _median_time(bake, rep)
                e = err(img, gt)
                rows.append((name, "baked (numpy only, no bpy)", f"{k}+{k} samples/texel", took, e))
                baked.append((k, took, e))
                continue
            from ..blender.preview import build as build_mod

            def fresh_scene():
                # A new empty scene each time: the preview skips images whose bake is current,
                # so a second build in the same scene would time nothing.
                bpy.ops.wm.read_homefile(use_empty=True)
                env._irr_maps.clear()  # the irradiance map is part of a first bake
                build_mod.CACHE = BakeCache()  # memory only: really bake, never read a cached one
                return bpy.context.scene

            def bake(scene):
                info = build_preview(
                    scene, brdfs[0], brdfs[1], path="baked", env=env_path, size=SIZE, samples=16, bake_samples=k
                )
                if len(info.baked) != 2:
                    raise RuntimeError(f"the timed build baked {info.baked}, not both spheres")
                return scene

            t_bake, scene = _median_time(bake, rep, setup=fresh_scene)
            t_render, _ = _median_time(lambda: render_still(scene, tmp, quiet=True), rep)
            build_mod.CACHE = None
            e = err(_read_exr(bpy, tmp), gt)
            rows.append(
                (
                    name,
                    "baked: numpy bake + Cycles 16 spp",
                    f"{k}+{k} samples/texel ({t_bake:.2f} s + {t_render:.2f} s)",
                    t_bake + t_render,
                    e,
                )
            )
            baked.append((k, t_bake + t_render, e))
        # the target: within 2x the reference's error in a tenth of its time (each reference run)
        for spp, t_ref, e_ref in refs:
            fit = [b for b in baked if b[1] <= t_ref / 10]
            if fit:
                k, t_b, e_b = min(fit, key=lambda b: b[2][0])
                verdicts.append(
                    f"| {name} | {spp} spp: {t_ref:.1f} s, {e_ref[0]:.2%} ({e_ref[1]:.2%}) | "
                    f"{k}+{k}: {t_b:.2f} s, {e_b[0]:.2%} ({e_b[1]:.2%}) | {e_b[0] / e_ref[0]:.2f}x "
                    f"({e_b[1] / e_ref[1]:.2f}x) | {'met' if e_b[0] <= 2 * e_ref[0] else 'missed'} |"
                )
            else:
                verdicts.append(
                    f"| {name} | {spp} spp: {t_ref:.1f} s | no bake within {t_ref / 10:.2f} s | — | missed |"
                )
        if bpy is None:
            continue
        from ..blender.preview import model_params

        model_gt = None
        for mode in ("tabulated", "model"):
            if mode == "model":
                mbrdfs = [ModelBRDF(model_params(b)) for b in brdfs]
                model_gt, m_noise, _ = ground_truth(layout, mbrdfs, env, name + "-model", 4096)
                e_model = err(model_gt, gt)
                notes.append(
                    f"{name}: the moment model itself differs from the table by {e_model[0]:.1%} per pixel "
                    f"({e_model[1]:.1%} RMSE/RMS); model ground truth 4096 spp, noise {m_noise:.2%}"
                )
            for spp, lobe in osl_settings:
                bpy.ops.wm.read_homefile(use_empty=True)
                scene = bpy.context.scene
                srcs = brdfs if mode == "tabulated" else [model_params(b) for b in brdfs]
                build_preview(
                    scene,
                    srcs[0],
                    srcs[1],
                    path="osl",
                    mode=mode,
                    env=env_path,
                    size=SIZE,
                    samples=spp,
                    lobe_samples=lobe,
                )
                t0 = time.perf_counter()
                render_still(scene, tmp, quiet=True)  # warm-up: OSL compiles the shader on first use
                first = time.perf_counter() - t0
                took, _ = _median_time(lambda: render_still(scene, tmp, quiet=True), rep)
                img = _read_exr(bpy, tmp)
                e = err(img, model_gt if mode == "model" else gt)
                rows.append(
                    (
                        name,
                        f"OSL {mode}" + (" (vs model)" if mode == "model" else ""),
                        f"{spp} spp x {lobe} lobe",
                        took,
                        e,
                    )
                )
                if mode == "model" and (spp, lobe) == (16, 16):
                    verdicts.append(
                        f"| {name} | OSL moment model, two spheres, 256², 16 spp x 16 lobe | "
                        f"{took:.1f} s (first render {first:.1f} s) | target 10 s | "
                        f"{'met' if took <= 10 else 'missed'} |"
                    )
    out = [
        "### Preview: render time against error (256 x 256, two spheres)",
        "",
        f"Environment: Blender's `{ENV}` HDRI (1024 x 512; small lights up to 1000x its mean). Original and",
        "edited (model-mode edit: variance x 2, strength 0.8) side by side, D = "
        f"{layout.diameter} px each. Errors against the ground truth over the {int(mask.sum())} pixels",
        "wholly inside a sphere: per-pixel relative RMSE, and in brackets RMSE / RMS. OSL model mode is",
        "measured against the numpy reference of the model itself (what it is meant to show).",
        "",
        "| material | path | setting | time | rel. RMSE (RMSE/RMS) |",
        "|---|---|---|---|---|",
    ]
    for name, path, setting, took, e in rows:
        t = f"{took * 1e3:.0f} ms" if took < 1 else f"{took:.2f} s"
        out.append(f"| {name} | {path} | {setting} | {t} | {e[0]:.2%} ({e[1]:.2%}) |")
    out += [
        "",
        "Targets:",
        "",
        "| material | reference | fastest-enough bake (≤ 1/10 of its time) | error ratio | |",
        "|---|---|---|---|---|",
    ]
    out += [v for v in verdicts if "spp:" in v]
    out += ["", "| material | what | time | target | |", "|---|---|---|---|---|"]
    out += [v for v in verdicts if "OSL moment model" in v]
    out += [""] + [f"- {n}" for n in notes]
    return out


def render_default_error(names=("ggx_glossy", "ggx_mirror"), extra=(("--path", "osl"),), gt_spp=GT_SPP):
    """``python -m addon render`` as a user runs it (its defaults: 256², studio, original and
    edited), against the converged reference; then with each of ``extra``'s options for
    comparison. Returns markdown lines (BENCHMARKS.md, issue 29)."""
    import subprocess
    import sys
    import tempfile

    import samples

    from ..core.file.merl import read_merl, write_merl
    from ..core.preview import TableBRDF, normalized_rmse, relative_rmse, sphere_layout
    from ..wheel import import_bpy

    bpy = import_bpy()
    env, _ = _environment(bpy)
    layout = sphere_layout(SIZE, SIZE, 2)
    mask = layout.interior_mask()
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    lines = [
        "| material | `render` options | time | rel. RMSE per pixel (RMSE/RMS) |",
        "|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="brdfm-render-default-") as tmp:
        for name in names:
            path = samples.sample_path(name)
            table = read_merl(path)
            edited = edited_table(table, name)
            edited_path = os.path.join(tmp, f"{name.replace('/', '-')}-edited.binary")
            write_merl(edited, edited_path)
            gt, noise, _ = ground_truth(layout, [TableBRDF(table), TableBRDF(edited)], env, name, gt_spp)
            for options in ((), *extra):
                out = os.path.join(tmp, "render.exr")
                t = time.perf_counter()
                subprocess.run(
                    [sys.executable, "-m", "addon", "render", path, "--edited", edited_path, *options, "--out", out],
                    cwd=root,
                    check=True,
                    capture_output=True,
                )
                took = time.perf_counter() - t
                img = _read_exr(bpy, out)
                e = relative_rmse(img, gt, mask), normalized_rmse(img, gt, mask)
                what = " ".join(options) or "(defaults)"
                lines.append(f"| {name} | {what} | {took:.1f} s | {e[0]:.2%} ({e[1]:.2%}) |")
            lines.append(f"| {name} | ground truth {gt_spp} spp, its own noise | | {noise:.2%} |")
    return lines


if __name__ == "__main__":  # python -m addon.tools.bench_preview [GT_SPP]: render's default (issue 29)
    import sys

    print("\n".join(render_default_error(gt_spp=int(sys.argv[1]) if len(sys.argv) > 1 else GT_SPP)))
