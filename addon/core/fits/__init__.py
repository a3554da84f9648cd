"""The fits: the paper's Sec. 3.4 curves through a material's profiles, and the moment model
they drive. Modules in the order they run:

- ``curves``: the energy spline, the mean slope mu~, the average variance sigma~^2 and, over a
  set, the mu~-sigma~^2 correlation (``fit_material``, ``fit_set``; a set's points read back
  for the region plot).
- ``truncated``: the truncated Gaussians of the moment model (paper Eq. 7-8), the one solver
  that model mode's edit, the preview's lobe and the OSL shaders share.
"""

from . import truncated
from .curves import (
    LAMBERT_VARIANCE,
    MIN_SIGMA2,
    correlation_curve,
    energy_curve,
    fit_correlation,
    fit_material,
    fit_set,
    load_set_points,
)

__all__ = [
    "LAMBERT_VARIANCE",
    "MIN_SIGMA2",
    "correlation_curve",
    "energy_curve",
    "fit_correlation",
    "fit_material",
    "fit_set",
    "load_set_points",
    "truncated",
]
