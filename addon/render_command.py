"""``python -m addon render``: original (and edited) spheres rendered by Cycles (SPEC §4, §5).

Needs the ``bpy`` module. OUT ending in .png is display-referred (Standard view, sRGB);
ending in .exr it is linear scene radiance, 32-bit float, so renders compare numerically.
"""

from __future__ import annotations

import os
import time


def run(args, input_error):
    from .core.nbrdf import parse_source, read_table

    out = os.fspath(args.out)
    if os.path.splitext(out)[1].lower() not in (".png", ".exr"):
        raise input_error(f"{out}: the output must end in .png (display) or .exr (linear radiance)")
    for src in filter(None, (args.file, args.edited)):
        src = parse_source(src)[0]
        if os.path.exists(out) and os.path.exists(src) and os.path.samefile(out, src):
            raise input_error(f"{out}: refusing to overwrite the input file; choose another output name")
    original = read_table(args.file)
    edited = read_table(args.edited) if args.edited else None
    t0 = time.perf_counter()
    try:
        from .wheel import import_bpy

        bpy = import_bpy()
    except ImportError as exc:
        raise input_error(str(exc)) from None
    from . import preview

    try:
        env = preview.resolve_environment(args.env)
    except ValueError as exc:
        raise input_error(str(exc)) from None
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    try:
        with preview.quiet_stdout():
            info = preview.build_preview(scene, original, edited, path=args.path, mode=args.mode, env=env,
                                         size=args.size, samples=args.samples, lobe_samples=args.lobe_samples,
                                         bake_samples=args.bake_samples)
        preview.render_still(scene, out, quiet=True)
    except preview.OSLUnavailable as exc:
        raise input_error(f"--path osl: {exc}") from None
    how = f"OSL, {info.mode} mode" if info.path == "osl" else "baked"
    print(f"wrote {out} ({how}, {info.layout.width}x{info.layout.height}, environment "
          f"{os.path.basename(info.environment)}, {time.perf_counter() - t0:.1f} s)")
    return 0
