"""Preview of original and edited materials on spheres in Cycles (and EEVEE): SPEC §4, Blender side.

The numbers come from the bpy-free engine (``addon.core.preview``); this package builds the
scene. Import it only where ``bpy`` is available.

    from addon.blender.preview import build_preview, render_still
    info = build_preview(scene, original, edited=None, *, path="auto", mode="model",
                         env=None, size=256, samples=16, lobe_samples=16, bake_samples=64,
                         engine="CYCLES", profiles=None)

``original`` / ``edited``: a MERL file path, a ``MerlTable`` or a ``MomentParams`` (the
    moment model, e.g. ``MomentParams.from_fit(fit, kd).edited(mu_slope=..., sigma2=...)``).
``path``: ``"osl"`` (Cycles with OSL; shaders in ``addon/shaders`` compiled at run time),
    ``"baked"`` (numpy radiance per texel shown through an Emission shader: any engine, any
    Blender, including Debian's 3.4 without OSL) or ``"auto"`` (OSL when this Blender has it).
``mode`` (OSL only): ``"model"`` uses only the fitted parameters (a slider drag is
    ``update_model(material, params)``: node inputs, nothing re-synthesized); ``"tabulated"``
    reads the table from a float EXR and importance-samples it with the moment lobe.
``env``: a bundled HDRI name (``bundled_environments()``; default "studio") or an .exr/.hdr path.
``size``: render width = height in pixels, or (width, height). ``samples``: Cycles samples per
    pixel; ``lobe_samples``: directions per shading point (OSL); ``bake_samples``: per texel (baked).
``profiles``: optional per-source ``Profiles`` (a loaded material already has them).
Returns ``PreviewInfo(path, mode, layout, materials, environment, baked, notes)``.

Also: ``build_row(scene, sources, labels=...)`` for a row of spheres (e.g. a slider's range);
``set_source(material, source)`` + ``refresh_baked(scene)`` re-bake only what changed on visible
spheres (content cache); ``render_still(scene, "out.png" | "out.exr", quiet=False)``.
Errors: ``ValueError`` (bad input, names the fault), ``MerlError``, ``OSLUnavailable``.
"""

from .build import (
    PreviewInfo,
    bake_cache,
    build_preview,
    build_row,
    model_params,
    quiet_stdout,
    refresh_baked,
    render_still,
    set_source,
    source_of,
    update_model,
)
from .environment import bundled_environments, load_environment, resolve_environment, write_environment
from .osl import OSLUnavailable, compile_shader, osl_available

__all__ = [
    "PreviewInfo",
    "bake_cache",
    "build_preview",
    "build_row",
    "model_params",
    "quiet_stdout",
    "refresh_baked",
    "render_still",
    "set_source",
    "source_of",
    "update_model",
    "bundled_environments",
    "load_environment",
    "resolve_environment",
    "write_environment",
    "OSLUnavailable",
    "compile_shader",
    "osl_available",
]
