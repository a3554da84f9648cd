"""The artist's material outside OSL: node setups that approximate a (possibly edited) table in
any engine and any Blender. Modules in the order they run:

- ``principled``: one Principled BSDF fitted to the table; also the view quadrature and the
  pixel shares the other two weigh their errors with.
- ``lobes``: a Diffuse and up to five GGX, Beckmann or Fresnel-shaped lobes whose weights
  follow the view, fitted to the table (the Lobes approximation).
- ``node_bound``: the least error any view-dependent mix of Blender's closures reaches on the
  table: how close any node setup could come (the panel's Find the Bound).

Their GGX and Beckmann lobes are ``core.microsurface``'s, with the Lambda Cycles evaluates.
"""
