"""Moment editing (SPEC §3 "Editing"): re-synthesize a tabulated BRDF from slider targets.

Modules:
- ``targets``: the sliders, clamped, and the per-view targets they imply.
- ``fidelity``: the measuring stick, every view of a written table re-measured against its target.
- ``legacy``: the per-view warps combined per cell (the design issue 18 replaces), kept for comparison.
"""

from .legacy import (MIN_SIGMA2, MODES, EditResult, EditTargets, directional_albedo, edit, resolve_targets,
                     scale_to_albedo, synthesize, target_energy, view_goals)

__all__ = ["MIN_SIGMA2", "MODES", "EditResult", "EditTargets", "directional_albedo", "edit", "resolve_targets",
           "scale_to_albedo", "synthesize", "target_energy", "view_goals"]
