"""The microsurface's closed forms (``core.microsurface``) against their definitions, integrated
numerically here: D is normalised by the area toward the normal, Lambda is what the projected
area of that D makes it, Walter et al.'s Beckmann fit stays within its stated error, the
stretched D is the textbook anisotropic one, and the two ways of writing the masking agree."""

import math

import numpy as np
import pytest
from scipy.integrate import dblquad, quad

from addon.core import microsurface as S


@pytest.mark.parametrize("distribution", S.DISTRIBUTIONS)
@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_the_distribution_is_normalised_by_the_area_toward_the_normal(distribution, alpha):
    """2 pi int D(theta) cos theta sin theta dtheta = 1."""
    f = lambda t: float(S.ndf(distribution, math.cos(t), alpha)) * math.cos(t) * math.sin(t)  # noqa: E731
    total, _ = quad(f, 0.0, 0.5 * math.pi, points=[math.atan(alpha)], limit=200)
    assert 2.0 * math.pi * total == pytest.approx(1.0, rel=1e-7)


def _area(distribution, alpha, theta_v):
    """A(v) = int max(0, v.m) D(m) dw_m over the hemisphere of normals, numerically."""
    sv, cv = math.sin(theta_v), math.cos(theta_v)

    def f(phi, t):
        return (
            max(0.0, sv * math.sin(t) * math.cos(phi) + cv * math.cos(t))
            * float(S.ndf(distribution, math.cos(t), alpha))
            * math.sin(t)
        )

    value, _ = dblquad(f, 0.0, 0.5 * math.pi, 0.0, 2.0 * math.pi, epsabs=1e-10, epsrel=1e-8)
    return value


@pytest.mark.parametrize("distribution", S.DISTRIBUTIONS)
@pytest.mark.parametrize("theta_deg", [30.0, 70.0, 85.0])
def test_lambda_is_what_the_projected_area_of_d_makes_it(distribution, theta_deg):
    """Smith: A(v) = cos theta_v (1 + Lambda(v)), with Lambda from alpha^2 tan^2 theta_v."""
    alpha, t = 0.4, math.radians(theta_deg)
    lam = float(S.smith_lambda(distribution, alpha**2 * math.tan(t) ** 2))
    assert math.cos(t) * (1.0 + lam) == pytest.approx(_area(distribution, alpha, t), rel=1e-6)


def test_walters_beckmann_fit_is_within_its_stated_error():
    """Walter et al. 2007 give their rational G1 as within 0.35 % of the exact one."""
    a2t2 = np.geomspace(1e-4, 1e4, 2001)
    exact = 1.0 / (1.0 + S.smith_lambda("beckmann", a2t2))
    fit = 1.0 / (1.0 + S.smith_lambda("beckmann", a2t2, rational=True))
    assert np.max(np.abs(fit / exact - 1.0)) < 3.5e-3
    assert np.all(S.smith_lambda("beckmann", a2t2[a2t2 < 1.0 / 1.6**2], rational=True) == 0.0)  # a >= 1.6


@pytest.mark.parametrize("distribution", S.DISTRIBUTIONS)
def test_the_stretched_distribution_is_the_textbook_anisotropic_one(distribution):
    """D(h) for alpha_x along x and alpha_y along y, written out: GGX 1 / (pi ax ay (x^2/ax^2 +
    y^2/ay^2 + z^2)^2), Beckmann exp(-(x^2/ax^2 + y^2/ay^2) / z^2) / (pi ax ay z^4); with equal
    roughness it is the round D, and at the normal it is finite."""
    rng = np.random.default_rng(5)
    h = rng.normal(size=(500, 3))
    h[:, 2] = np.abs(h[:, 2]) + 0.05
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    x, y, z = h.T
    ax, ay = 0.15, 0.45
    if distribution == "ggx":
        want = 1.0 / (np.pi * ax * ay * ((x / ax) ** 2 + (y / ay) ** 2 + z**2) ** 2)
    else:
        want = np.exp(-((x / ax) ** 2 + (y / ay) ** 2) / z**2) / (np.pi * ax * ay * z**4)
    np.testing.assert_allclose(S.stretched_ndf(distribution, x, y, z, ax, ay), want, rtol=1e-9)
    np.testing.assert_allclose(
        S.stretched_ndf(distribution, x, y, z, 0.3, 0.3), S.ndf(distribution, z, 0.3), rtol=1e-12
    )
    at_normal = S.stretched_ndf(distribution, 0.0, 0.0, 1.0, ax, ay)
    assert float(at_normal) == pytest.approx(1.0 / (np.pi * ax * ay), rel=1e-12)


@pytest.mark.parametrize("form", S.FORMS)
def test_the_masking_and_its_denominator_are_the_same_forms(form):
    """4 cos_i cos_o / G(Lambda_i, Lambda_o) is the denominator of the areas A = cos (1 + Lambda);
    and the separable G is G1 G1 with GGX's G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2))."""
    rng = np.random.default_rng(9)
    ci, co = rng.uniform(0.05, 1.0, (2, 300))
    a2 = 0.2
    li, lo = (S.smith_lambda("ggx", a2 * S.tan2(c)) for c in (ci, co))
    got = S.masking_denominator(ci, co, ci * (1.0 + li), co * (1.0 + lo), form)
    np.testing.assert_allclose(got, 4.0 * ci * co / S.masking(li, lo, form), rtol=1e-12)
    if form == "separable":
        g1 = [2.0 / (1.0 + np.sqrt(1.0 + a2 * (1.0 - c * c) / (c * c))) for c in (ci, co)]
        np.testing.assert_allclose(S.masking(li, lo, form), g1[0] * g1[1], rtol=1e-14)


def test_unknown_names_are_refused():
    for call in (
        lambda: S.ndf("phong", 0.5, 0.1),
        lambda: S.smith_lambda("phong", 0.5),
        lambda: S.masking(0.1, 0.1, "other"),
        lambda: S.masking_denominator(0.5, 0.5, 0.6, 0.6, "other"),
    ):
        with pytest.raises(ValueError):
            call()
