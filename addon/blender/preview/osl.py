"""The OSL path: shaders compiled at run time, script nodes, the table texture.

The shaders live in ``addon/shaders/*.osl`` and are compiled with Cycles' own compiler
(``_cycles.osl_compile``) into the cache folder, keyed by their source, then loaded by
external script nodes. Moment-model mode needs only node inputs (``set_model_inputs``);
tabulated mode reads the table from a float EXR written once per table content.
"""

from __future__ import annotations

import hashlib
import math
import os

import bpy
import numpy as np

from ...core.fits.curves import LAMBERT_VARIANCE, MIN_SIGMA2
from ...core.limits import MAX_SHADER_SOURCE_BYTES

SHADER_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "shaders")
SHADERS = {"model": "brdf_moments_model", "tabulated": "brdf_moments_table"}


class OSLUnavailable(RuntimeError):
    """This Blender cannot run the OSL path (no OSL in the build, or Cycles cannot query shaders)."""


def osl_available() -> tuple:
    """(available, reason)."""
    if not getattr(bpy.app.build_options, "cycles_osl", False):
        return False, "this Blender build has no OSL (use the baked path)"
    import importlib.util

    if importlib.util.find_spec("oslquery") is None:
        return False, (
            "Cycles cannot import oslquery (with the bpy module, add "
            "<bpy>/<version>/python/lib/python3.X/site-packages to sys.path)"
        )
    return True, ""


def cache_dir() -> str:
    from ...core.profiles.integrate import default_cache_dir

    return os.path.join(default_cache_dir(), "preview")


def compile_shader(name: str, folder=None) -> str:
    """Path of the compiled .oso for shader ``name`` (compiled if its sources changed)."""
    import _cycles

    src = os.path.join(SHADER_DIR, name + ".osl")
    from ...core.file.cachefs import verified, write_seal
    from ...core.file.safeio import read_input

    h = hashlib.sha256()
    for part in sorted(os.listdir(SHADER_DIR)):
        if part.endswith((".osl", ".h")):
            h.update(
                part.encode()
                + read_input(os.path.join(SHADER_DIR, part), MAX_SHADER_SOURCE_BYTES, "shader source", register=False)
            )
    from ...core.file.atomic import atomic_path, own_folder

    folder = own_folder(folder or cache_dir())
    dst = os.path.join(folder, f"{name}-{h.hexdigest()[:12]}.oso")
    # Sealed like every cache entry: a damaged .oso (it made every OSL render fail, on every
    # run) or one without its seal is compiled again, never trusted.
    if not verified(dst):
        with atomic_path(dst, ".oso") as tmp:
            if not _cycles.osl_compile(src, tmp):
                raise RuntimeError(f"{src}: OSL compilation failed (see the console for the compiler's errors)")
        write_seal(dst)
    return dst


def script_node(tree, mode: str):
    """An external script node running the ``mode`` shader ('model' or 'tabulated')."""
    ok, why = osl_available()
    if not ok:
        raise OSLUnavailable(why)
    node = tree.nodes.new("ShaderNodeScript")
    node.mode = "EXTERNAL"
    node.filepath = compile_shader(SHADERS[mode])
    if "BSDF" not in node.outputs:
        # Blender queries the shader through the scene's render engine, which may not be
        # Cycles yet: ask Cycles directly.
        try:
            from cycles import osl as cycles_osl

            cycles_osl.update_script_node(node, lambda kind, msg: None)
        except ImportError:
            pass
    if "BSDF" not in node.outputs:
        # Setting the path makes Cycles query the shader; no sockets means it could not.
        raise OSLUnavailable(f"Cycles could not load {node.filepath} (oslquery missing?)")
    node.label = f"BRDF Moments ({mode})"
    return node


def set_model_inputs(node, params, samples=16, environment="", strength=1.0, pixel_samples=None, filter_scale=None):
    """Write a MomentParams into a model-mode script node: the whole slider update."""
    ins = node.inputs
    if pixel_samples is not None:
        ins["PixelSamples"].default_value = int(pixel_samples)
    if filter_scale is not None:
        ins["Filter"].default_value = float(filter_scale)
    ins["AlphaB"].default_value = (*params.alpha_b, 1.0)
    ins["Alpha1"].default_value = (*params.alpha1, 1.0)
    ins["M1"].default_value = (*params.m1, 1.0)
    ins["Theta0"].default_value = params.theta0
    ins["Theta1"].default_value = params.theta1
    ins["MuSlope"].default_value = params.mu_slope
    ins["Sigma2"].default_value = params.sigma2
    ins["Albedo"].default_value = (*(math.pi * v for v in params.kd), 1.0)
    ins["Samples"].default_value = int(samples)
    ins["Environment"].default_value = environment
    ins["Strength"].default_value = float(strength)


def set_table_inputs(
    node,
    texture_path,
    mu_slope,
    sigma2,
    kd,
    samples=16,
    environment="",
    strength=1.0,
    cosine_share=0.15,
    pixel_samples=None,
    filter_scale=None,
):
    ins = node.inputs
    if pixel_samples is not None:
        ins["PixelSamples"].default_value = int(pixel_samples)
    if filter_scale is not None:
        ins["Filter"].default_value = float(filter_scale)
    ins["Table"].default_value = texture_path
    ins["MuSlope"].default_value = float(mu_slope)
    ins["Sigma2"].default_value = float(min(max(sigma2, MIN_SIGMA2), LAMBERT_VARIANCE))
    ins["CosineShare"].default_value = float(cosine_share)
    ins["Albedo"].default_value = (*(math.pi * float(v) for v in kd), 1.0)
    ins["Samples"].default_value = int(samples)
    ins["Environment"].default_value = environment
    ins["Strength"].default_value = float(strength)


def table_texture_pixels(values, kd):
    """(810, 1800, 3) float32, top row first: max(rho - kd, 0) of each cell in the shader's layout.

    ``values`` is (N_CELLS, 3) (missing cells already at kd, see TableBRDF)."""
    from ...core.file.merl import RES_PD, RES_TD, RES_TH

    spec = np.maximum(np.asarray(values, np.float32) - np.asarray(kd, np.float32)[None, :], 0.0)
    cube = spec.reshape(RES_TH, RES_TD // 10, 10, RES_PD, 3)  # (ith, itd // 10, itd % 10, ipd, c)
    return np.ascontiguousarray(cube.transpose(1, 0, 2, 3, 4).reshape(RES_TH * (RES_TD // 10), 10 * RES_PD, 3))


def write_table_texture(brdf, folder=None) -> str:
    """The table texture of a TableBRDF, written once per content and sealed (``cachefs``): a
    texture whose bytes no longer match its seal is replaced by a freshly written one under a
    new name (OIIO caches textures by path, so a changed file must get a new name too)."""
    from ...core.file import cachefs
    from ...core.file.exr import write_exr
    from ...core.limits import TABLE_TEXTURE_MAX_BYTES, TABLE_TEXTURE_MAX_ENTRIES

    return cachefs.sealed_file(
        folder or cache_dir(),
        f"table-v2-{brdf.content_key()[:24]}",
        ".exr",
        lambda path: write_exr(table_texture_pixels(brdf.values, brdf.kd), path),
        (TABLE_TEXTURE_MAX_ENTRIES, TABLE_TEXTURE_MAX_BYTES),
        prefix="table-",
    )
