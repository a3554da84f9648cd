"""Operators, one per file; ``addon.blender.registration`` registers them."""
