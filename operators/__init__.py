"""Operators, one per file; ``addon.registration`` registers them."""
