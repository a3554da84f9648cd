"""How close any node setup could come to a table (``core.material.node_bound``): its own closure shapes
against textbook forms (the microfacet lobes it shares with ``core.material.lobes`` are checked in
test_lobes), and the bound itself on tables whose content is known."""

import numpy as np
import pytest

from addon.core.file.merl import tabulate
from addon.core.material import lobes as L
from addon.core.material import node_bound as B


@pytest.mark.parametrize("sigma", [0.2, 0.5, 1.0])
def test_the_velvet_distribution_is_normalised(sigma):
    """A microfacet distribution's projected area is the surface's: int D cos theta_h dw = 1."""
    th = np.linspace(1e-6, np.pi / 2, 200001)
    d = L.velvet_distribution(sigma, np.cos(th))
    assert np.trapz(d * np.cos(th) * np.sin(th) * 2 * np.pi, th) == pytest.approx(1.0, abs=1e-6)


def test_a_table_made_of_the_shapes_is_reached_and_a_lobe_fit_states_more():
    """A diffuse term, a Beckmann lobe with a Schlick rise and a velvet sheen, colours following
    the view. Their sum is one of the setups the bound ranges over, so the bound is at most that
    sum's own error against the table (what tabulating it into cells costs); the GGX lobes the
    nodes render stay well above it."""
    from addon.core.material.principled import pixel_share

    kd = np.array([0.3, 0.2, 0.1])

    def brdf(wi, wo):
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        sch = (1.0 - np.clip(np.sum(wi * h, axis=-1), 0, 1)) ** 5
        spec = L.microfacet_lobe("beckmann", L.DICTIONARY[9] ** 2, wi, wo) * (0.04 + 0.96 * sch)
        sheen = L.velvet(0.35, wi, wo) * (0.5 + 0.5 * wo[..., 2])
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
    from addon.core.file.merl import read_merl

    table = read_merl(samples.sample_path(name))
    bound = B.node_bound(table)
    fit = L.fit_lobes(table)
    assert 0.0 <= bound <= fit.error + 1e-9


@pytest.mark.parametrize("shadowing", ["correlated", "separable"])
def test_every_shape_is_a_closure_that_adds_light(shadowing):
    """A node tree mixes closures with non-negative weights, and no closure draws less than
    nothing: every shape the bound ranges over is non-negative at every light direction and
    view (a basis of either sign, as the bound had before, reaches tables no setup draws)."""
    rng = np.random.default_rng(7)
    v = rng.normal(size=(4000, 3))
    wi = v / np.linalg.norm(v, axis=1, keepdims=True)
    wi[:, 2] = np.abs(wi[:, 2])
    for deg in (0.0, 30.0, 60.0, 85.0):
        t = np.radians(deg)
        F = B.closure_shapes(wi, np.array([np.sin(t), 0.0, np.cos(t)]), shadowing)
        assert F.shape[1] == len(wi) and np.all(np.isfinite(F)) and F.min() >= 0.0, deg
