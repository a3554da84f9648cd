"""How close any node setup could come to a table (``core.node_bound``): its closure shapes
against textbook forms, and the bound itself on tables whose content is known."""

import numpy as np
import pytest

from addon.core import lobes as L
from addon.core import node_bound as B
from addon.core.merl import tabulate


def _directions(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_the_beckmann_lobe_is_the_samples_beckmann_without_fresnel():
    """f0 = 1: the samples' Beckmann (Walter's G1 written as a ratio) is D G1 G1 / (4 cos cos)."""
    from samples.analytic import Beckmann

    wi, wo = _directions(400, 11)
    for m in (0.05, 0.2, 0.6):
        ref = Beckmann(roughness=m)(wi, wo)[0]
        np.testing.assert_allclose(L.microfacet_lobe("beckmann", m, wi, wo, "separable"), ref, rtol=1e-9)


def test_the_stretched_beckmann_is_the_anisotropic_beckmann_of_its_axes():
    """Written in the frame whose x axis is the view's azimuth: alpha / sqrt(q) along it, alpha
    sqrt(q) across, Lambda from the direction's projected roughness."""
    wi, wo = _directions(400, 12)
    alpha, q = 0.3, 2.5
    ax, ay = alpha / np.sqrt(q), alpha * np.sqrt(q)
    phi = np.arctan2(wo[:, 1], wo[:, 0])
    c, s = np.cos(phi), np.sin(phi)

    def local(v):
        return np.stack((v[:, 0] * c + v[:, 1] * s, -v[:, 0] * s + v[:, 1] * c, v[:, 2]), axis=1)

    li, lo = local(wi), local(wo)
    h = li + lo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    tan2 = (h[:, 0] ** 2 + h[:, 1] ** 2) / h[:, 2] ** 2
    cos2phi = h[:, 0] ** 2 / (h[:, 0] ** 2 + h[:, 1] ** 2)
    d = np.exp(-tan2 * (cos2phi / ax**2 + (1 - cos2phi) / ay**2)) / (np.pi * ax * ay * h[:, 2] ** 4)

    def lam(v):
        a_dir = np.sqrt((ax * v[:, 0]) ** 2 + (ay * v[:, 1]) ** 2) / np.hypot(v[:, 0], v[:, 1])
        a = v[:, 2] / (a_dir * np.hypot(v[:, 0], v[:, 1]))
        return np.where(a < 1.6, (1 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a), 0.0)

    want = d / (1.0 + lam(li) + lam(lo)) / (4.0 * li[:, 2] * lo[:, 2])
    np.testing.assert_allclose(L.microfacet_lobe("beckmann", alpha, wi, wo, "correlated", q), want, rtol=1e-9)


@pytest.mark.parametrize("sigma", [0.2, 0.5, 1.0])
def test_the_velvet_distribution_is_normalised(sigma):
    """A microfacet distribution's projected area is the surface's: int D cos theta_h dw = 1."""
    th = np.linspace(1e-6, np.pi / 2, 200001)
    d = B.velvet_distribution(sigma, np.cos(th))
    assert np.trapz(d * np.cos(th) * np.sin(th) * 2 * np.pi, th) == pytest.approx(1.0, abs=1e-6)


def test_a_table_made_of_the_shapes_is_reached_and_a_lobe_fit_states_more():
    """A diffuse term, a Beckmann lobe with a Schlick rise and a velvet sheen, colours following
    the view. Their sum is one of the setups the bound ranges over, so the bound is at most that
    sum's own error against the table (what tabulating it into cells costs); the GGX lobes the
    nodes render stay well above it."""
    from addon.core.principled import pixel_share

    kd = np.array([0.3, 0.2, 0.1])

    def brdf(wi, wo):
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        sch = (1.0 - np.clip(np.sum(wi * h, axis=-1), 0, 1)) ** 5
        spec = L.microfacet_lobe("beckmann", L.DICTIONARY[9] ** 2, wi, wo) * (0.04 + 0.96 * sch)
        sheen = B.velvet(0.35, wi, wo) * (0.5 + 0.5 * wo[..., 2])
        return kd[:, None] / np.pi + np.stack([0.8 * spec + 0.1 * sheen] * 3)

    table = tabulate(brdf)
    num = den = 0.0
    for deg, wi, wo, w, rho in L._table_at_views(table, L.ERROR_VIEWS_DEG):
        own = brdf(wi, np.broadcast_to(wo, wi.shape))
        num += pixel_share(deg) * np.sum(w * (own - rho) ** 2)
        den += pixel_share(deg) * np.sum(w * rho**2)
    own_error = np.sqrt(num / den)
    bound = B.node_bound(table)
    assert own_error < 0.1
    assert bound <= own_error * (1 + 1e-6)
    assert L.fit_lobes(table).error > 1.5 * own_error


@pytest.mark.parametrize("name", ["ggx_glossy", "phong", "gold", "ggx_mirror"])
def test_no_lobe_fit_states_less_than_the_bound(name):
    """The fit's lobes are among the bound's shapes (its grids hold the fit's; an aspect the
    lookup interpolates between texels is followed by the neighbouring ones), so the error a fit
    states is not below the bound on the same table."""
    import samples
    from addon.core.merl import read_merl

    table = read_merl(samples.sample_path(name))
    bound = B.node_bound(table)
    fit = L.fit_lobes(table)
    assert 0.0 <= bound <= fit.error + 1e-9
