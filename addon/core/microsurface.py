"""A microsurface's closed forms: the GGX and Beckmann distributions of normals, Smith's Lambda,
the masking it gives and the projected area (Walter et al. 2007; Heitz 2014).

Written once here for every step that needs them: the analytic samples (``samples.analytic``),
the node approximations of the artist's material (``core.material``: what Cycles' closures
evaluate) and the edit's microfacet reading of a table (``core.edit.microfacet``, whose D and
areas are tabulated rather than closed forms).

Conventions: ``alpha`` is the distribution's roughness (GGX alpha, Beckmann m). D is normalised
by the area toward the normal, int D cos theta_m dw = 1. Lambda takes ``a2t2``, alpha^2 tan^2
theta of a direction (for a stretched surface, alpha along that direction's azimuth). The area
of the microsurface projected toward v is A(v) = cos theta_v (1 + Lambda(v)), and Smith's
masking of one direction G1 = 1 / (1 + Lambda) = cos theta_v / A(v).
"""

from __future__ import annotations

import math

import numpy as np

DISTRIBUTIONS = ("ggx", "beckmann")
FORMS = ("separable", "correlated")  # Smith's masking: G1(wi) G1(wo), or height-correlated


def tan2(cos_v):
    """tan^2 theta of a direction from cos theta (> 0)."""
    c = np.asarray(cos_v, float)
    return (1.0 - c * c) / (c * c)


def ndf(distribution: str, cos_h, alpha):
    """D at cos theta_h in (0, 1] of the isotropic surface of roughness ``alpha`` (a number or
    an array broadcasting with ``cos_h``)."""
    c = np.asarray(cos_h, float)
    a2 = alpha**2
    if distribution == "ggx":
        return a2 / (np.pi * ((a2 - 1.0) * c * c + 1.0) ** 2)
    if distribution == "beckmann":
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.exp(-(1.0 - c * c) / (c * c * a2)) / (np.pi * a2 * c**4)
        # exp(-tan^2 / m^2) falls faster than 1 / cos^4 grows: 0 (exactly, in doubles) near the
        # horizon, where the quotient would be 0 / 0
        return np.where(c > 1e-12, d, 0.0)
    raise ValueError(f"unknown distribution {distribution!r}")


def stretched_ndf(distribution: str, hx, hy, hz, alpha_x, alpha_y):
    """D of the surface stretched to roughness ``alpha_x`` along x and ``alpha_y`` along y, at
    unit half vectors (hx, hy, hz) in that frame: the isotropic D at the roughness of the half
    vector's azimuth, alpha_h^-2 = cos^2 phi / alpha_x^2 + sin^2 phi / alpha_y^2, times
    alpha_h^2 / (alpha_x alpha_y) (a stretch of slope space; Heitz 2014, Sec. 5)."""
    hx, hy = np.asarray(hx, float), np.asarray(hy, float)
    r2 = hx * hx + hy * hy
    w = (hx / alpha_x) ** 2 + (hy / alpha_y) ** 2
    # At the normal the azimuth is undefined and tan theta_h = 0: any alpha_h gives the same D.
    a2 = np.where(r2 > 0.0, r2 / np.where(r2 > 0.0, w, 1.0), alpha_x * alpha_y)
    return ndf(distribution, np.clip(hz, 0.0, 1.0), np.sqrt(a2)) * (a2 / (alpha_x * alpha_y))


def smith_lambda(distribution: str, a2t2, rational: bool = False):
    """Smith's Lambda of a direction from alpha^2 tan^2 theta, exact. ``rational``: Beckmann's
    by Walter et al.'s rational fit instead, the one Cycles evaluates for its Beckmann closures
    (GGX's closed form is exact either way)."""
    t = np.asarray(a2t2, float)
    if distribution == "ggx":
        return 0.5 * (np.sqrt(1.0 + t) - 1.0)
    if distribution != "beckmann":
        raise ValueError(f"unknown distribution {distribution!r}")
    a = 1.0 / np.sqrt(np.maximum(t, 1e-300))  # 1 / (alpha tan theta)
    if rational:
        return np.where(a < 1.6, (1.0 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a), 0.0)
    from scipy.special import erfc

    # erf(a) - 1 = -erfc(a) keeps its digits where Lambda is tiny (a large)
    return 0.5 * (np.exp(-a * a) / (a * math.sqrt(math.pi)) - erfc(a))


def masking(lambda_i, lambda_o, form: str):
    """Smith's shadowing-masking G of a pair of directions from their Lambdas: separable
    G1(wi) G1(wo), or height-correlated 1 / (1 + Lambda_i + Lambda_o)."""
    if form == "separable":
        return (1.0 / (1.0 + lambda_i)) * (1.0 / (1.0 + lambda_o))
    if form == "correlated":
        return 1.0 / (1.0 + lambda_i + lambda_o)
    raise ValueError(f"unknown masking form {form!r}")


def masking_denominator(cos_i, cos_o, area_i, area_o, form: str):
    """4 cos_i cos_o / G from the projected areas A = cos (1 + Lambda) of the two directions:
    separable 4 A_i A_o, height-correlated 4 (A_i cos_o + A_o cos_i - cos_i cos_o). The same
    forms as ``masking``, for a tabulated surface: both stay finite at the horizon, where
    Lambda and G / cos do not."""
    if form == "separable":
        return 4.0 * area_i * area_o
    if form == "correlated":
        return 4.0 * (area_i * cos_o + area_o * cos_i - cos_i * cos_o)
    raise ValueError(f"unknown masking form {form!r}")
