"""The profiles: the moments of every view's slice of a table against theta_o (SPEC §3): energy,
mean, covariance, co-skewness and co-kurtosis. Modules in the order they run:

- ``quadrature``: the slice rules in the paper's (theta, phi) measure, half-vector rays and
  pole strips split at the table's own cell edges.
- ``integrate``: the rules collapsed once per list of views into the cached slice operator (and
  the function interface, Monte Carlo, the adaptive reference, the directional albedo).
- ``moments``: the statistics from the operator's raw sums.
- ``compute``: the diffuse/specular split and ``compute_profiles``: a table's ``Profiles``,
  and their JSON.
"""

from .compute import FLOORS, Profiles, compute_profiles, diffuse_floor, function_profiles, monte_carlo_profiles
from .integrate import default_views, directional_albedo
from .quadrature import RuleParams

__all__ = [
    "FLOORS",
    "Profiles",
    "RuleParams",
    "compute_profiles",
    "default_views",
    "diffuse_floor",
    "directional_albedo",
    "function_profiles",
    "monte_carlo_profiles",
]
