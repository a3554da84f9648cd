"""Moment editing (SPEC §3 "Editing"): re-synthesize a tabulated BRDF from slider targets.

Modules, in the order an edit runs through them:
- ``targets``: the sliders (refused outside their declared ranges, ``core.limits``; clamped inside
  them to what the material can show) and the per-view targets they promise (``view_targets``).
- ``reach``: what a reciprocal table of this material can show (per view, and the region of the
  (mu~, sigma~^2) plane); a request outside the region is clamped to its nearest point.
- ``reciprocal``: the synthesis, a transform of the specular table in (theta_h, theta_d, phi_d)
  (reciprocal by construction) whose controls are solved with exact operator sensitivities.
- ``solve``: ``edit`` itself (sliders -> targets -> controls -> table -> re-measure).
- ``fidelity``: the measuring stick, every view of the written table against its target.
The truncated-Gaussian solver shared with the preview and OSL is ``core.truncated``.
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
