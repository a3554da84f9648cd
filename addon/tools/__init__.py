"""The headless tools: ``python -m addon`` (cli), whole-set analysis, plots, benchmarks, render.

Built on the engine (``addon.core``). Importing a tool never loads bpy or the Blender side; the
commands that drive Blender as a module (render, the preview and artist benchmarks) import
them when they run (tests/test_layout.py).
"""
