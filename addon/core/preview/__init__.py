"""Preview rendering without Blender (numpy + scipy): the engine half of SPEC §4.

Modules in the order a preview runs:
- ``envmap``: the environment map (Blender's world mapping), its sampling and irradiance.
- ``lights``: the map's bright texels gathered into a few light clusters for the bake.
- ``scene``: the row of spheres under the orthographic camera, texel by texel.
- ``lobe``: the BRDFs the estimators take (the table, the moment model) and their samplers.
- ``estimators``: the bake (the baked path's texture and image) and the converged reference.
- ``cache``: bakes kept by content.
- ``live``: the edit and the bake a slider move runs, in the live preview's thread.

Public API
----------
``Environment(pixels (H, W, 3) top row first, name)``: an equirectangular map with Blender's
    world mapping; ``.constant(rgb)``, ``.from_function(fn)``; lookups, sampling, irradiance.
``sphere_layout(width, height=None, count=2) -> Layout``: pixel-aligned row of unit spheres
    under an orthographic camera looking along +y.
``MomentParams`` (the moment model of a material; ``.from_fit(fit, kd)``, ``.edited(...)``);
    the BRDFs the estimators take: ``TableBRDF(MerlTable, profiles=None)``, ``ModelBRDF(MomentParams)``.
``bake_sphere(brdf, env, diameter, lobe_samples, seed) -> (radiance, coverage)``: the baked
    path's texture. ``render_baked(layout, brdfs, env, ...)``: the image it shows.
``render_reference(layout, brdfs, env, spp, seed)``: the converged Monte Carlo ground truth.
``relative_rmse(image, reference, mask)`` (per pixel) and ``normalized_rmse`` (RMSE / RMS):
    the error measures of the benchmarks; ``lit_pixel_errors`` (per pixel, over the pixels
    holding 5 % of the sphere's peak: the artist's material's render check).
``BakeCache``: bakes by content (material, map, resolution, settings).
"""

from .cache import BakeCache, bake_key
from .envmap import Environment, direction_to_uv, uv_to_direction
from .estimators import (
    bake_sphere,
    lit_pixel_errors,
    normalized_rmse,
    reference_sphere,
    relative_rmse,
    render_baked,
    render_reference,
)
from .lobe import (
    HalfVectorSampler,
    LobeTable,
    ModelBRDF,
    MomentParams,
    TableBRDF,
    truncated_params,
    truncnorm_mass,
    truncnorm_pdf,
    truncnorm_sample,
)
from .scene import VIEW, Layout, interior_texels, local_frames, sphere_layout, sphere_points

__all__ = [
    "BakeCache",
    "bake_key",
    "Environment",
    "direction_to_uv",
    "uv_to_direction",
    "bake_sphere",
    "reference_sphere",
    "relative_rmse",
    "lit_pixel_errors",
    "normalized_rmse",
    "render_baked",
    "render_reference",
    "HalfVectorSampler",
    "LobeTable",
    "ModelBRDF",
    "MomentParams",
    "TableBRDF",
    "truncated_params",
    "truncnorm_mass",
    "truncnorm_pdf",
    "truncnorm_sample",
    "VIEW",
    "Layout",
    "interior_texels",
    "local_frames",
    "sphere_layout",
    "sphere_points",
]
