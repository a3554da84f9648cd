"""What differs between the Blender versions the extension runs on (3.4, 4.x, 5.0).

One home for version checks, so the rest of the extension calls one name and never a
deprecated one (``use_nodes`` is deprecated in 5.0, where every material and world
always has its node tree)."""

import bpy

VERSION = tuple(bpy.app.version[:2])


def node_tree(idblock):
    """The node tree of a material or world, switched on where that is still a setting."""
    if VERSION < (5, 0) and not idblock.use_nodes:
        idblock.use_nodes = True
    return idblock.node_tree


def fix_sampling_pattern(cycles) -> str:
    """Cycles' sampling pattern, set explicitly: its default ('Automatic') is blue noise in
    some versions and Sobol in others, which moves the noise (and edge pixels) between
    versions. Tabulated Sobol exists from 3.5 on (4.x calls it 'Classic'); 3.4 has only
    Sobol and PMJ, where PMJ is its default. Returns the pattern in use."""
    for pattern in ("TABULATED_SOBOL", "PROGRESSIVE_MULTI_JITTER"):
        try:
            cycles.sampling_pattern = pattern
        except (TypeError, ValueError):
            continue
        return pattern
    return cycles.sampling_pattern
