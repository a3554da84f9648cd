"""The Blender side: registration, per-material state, panels, jobs, the preview scene.

Imports bpy. Uses the engine (``addon.core``) and, for exporting figures, ``addon.tools.plots``;
the engine never imports this side (tests/test_layout.py).
"""
