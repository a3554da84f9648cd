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

from . import node_bound  # the module: its function of the same name would hide it
from .lobes import LobeFit, fit_lobes, lobes_brdf, measure, near_mirror_floor, shadowing_for
from .principled import PrincipledFit, fit_principled, principled_brdf

__all__ = [
    "LobeFit",
    "PrincipledFit",
    "fit_lobes",
    "fit_principled",
    "lobes_brdf",
    "measure",
    "near_mirror_floor",
    "node_bound",
    "principled_brdf",
    "shadowing_for",
]
