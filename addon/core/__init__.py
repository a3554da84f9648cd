"""The engine: numpy and scipy, no bpy. One material's data flows through its packages in the
README's order, file -> profiles -> fits -> edit -> table -> preview:

- ``file``: the MERL table or Neural-BRDF network a material comes from, and every safe read
  and write (the output guard, the input opener, atomic writes, sealed caches).
- ``profiles``: the moments of every view's slice of a table, integrated on its own cells.
- ``fits``: the paper's Sec. 3.4 fits through the profiles, and the moment model they drive.
- ``edit``: the sliders' edit re-synthesizing the table, and what it reached.
- ``material``: the node approximations of a table (the artist's material outside OSL).
- ``preview``: the preview's numbers without Blender (maps, samplers, bake, reference).

Beside them, four modules every step may read, which import none of the steps: ``limits``
(every size, count and range: the one table the engine, the command line and the panel check
against), ``geometry`` (directions, the Rusinkiewicz angles, the paper's view-centred map) and
``microsurface`` (the GGX and Beckmann distributions, Smith's masking, the projected area:
written once for the samples, the edit's microfacet reading and the artist's material) and
``threads`` (the engine's one small thread pool, for numpy work that lets go of the GIL). A
package imports these and the packages before it in the flow that it needs, never one after
it: tests/test_layout.py holds the table.

Each package's ``__all__`` is its public face, what the front ends and a script call. Every
size, count and slider value a public function takes is checked against ``limits.RANGES``
before any work, and refused with one line naming it and its range, as the command line and the
panel refuse it (tests/test_ranges.py finds them all).
"""
