"""Moment editing (SPEC §3 "Editing"): re-synthesize a tabulated BRDF from the sliders.

A variance or mean-slope move in warp mode is a roughness edit; modules in the order it runs:
- ``floor``: the diffuse floor fitted jointly with the lobe (bounded by the paper's).
- ``microfacet``: the table read as F(theta_d) D(theta_h) / masking, D from back-scattering.
- ``roughness``: the slope-space operator (every cell from its source cell, masking recomputed).
- ``scale``: the roughness scale solved for the requested sigma~^2; the material's curve.
- ``solve``: ``edit`` itself: the roughness edit, the tilt for a mean slope off the curve (the
  reciprocal per-view transform of ``reciprocal``), the announcement measured on the table, the
  region; energy-only edits; model mode (the paper's sketch) through ``targets`` and ``reach``.
- ``fidelity``: the measuring stick, every view of a table against what was announced; the report.
- ``blas``: BLAS on one thread around the solve's many tiny products.
The truncated-Gaussian solver shared with the preview and OSL is ``core.fits.truncated``.
"""

from .reach import ReachableRegion, reachable_region
from .reciprocal import Superseded
from .solve import EditResult, directional_albedo, edit, scale_to_albedo, synthesize
from .targets import MIN_SIGMA2, MODES, EditTargets, ViewTargets, resolve_targets, target_energy, view_targets

__all__ = [
    "MIN_SIGMA2",
    "MODES",
    "EditResult",
    "EditTargets",
    "ReachableRegion",
    "Superseded",
    "ViewTargets",
    "directional_albedo",
    "edit",
    "reachable_region",
    "resolve_targets",
    "scale_to_albedo",
    "synthesize",
    "target_energy",
    "view_targets",
]
