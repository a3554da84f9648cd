"""The lobe mixture the artist's material renders outside OSL (``core.lobes``): its GGX lobe
against the samples' independent GGX, its lookup interpolation, and the fit on tables built
from lobes it can represent (their roughness and colours are known)."""

import numpy as np
import pytest

from addon.core import lobes as L
from addon.core.merl import tabulate


def _directions(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_the_separable_lobe_is_the_samples_ggx_without_fresnel():
    """f0 = 1 makes Schlick's Fresnel 1 everywhere: the samples' GGX is then D G1 G1 / (4 cos cos)."""
    from samples.analytic import GGX

    wi, wo = _directions(400, 1)
    for alpha in (0.01, 0.1, 0.5):
        ref = GGX(roughness=alpha, f0=(1.0, 1.0, 1.0), kd=(0.0, 0.0, 0.0))(wi, wo)[0]
        np.testing.assert_allclose(L.ggx_lobe(alpha, wi, wo, "separable"), ref, rtol=1e-9)


def test_the_correlated_term_is_larger_and_agrees_at_normal_view():
    """1 / (1 + a + b) >= 1 / ((1 + a)(1 + b)) for a, b >= 0, equal when one Lambda is 0."""
    wi, wo = _directions(400, 2)
    sep = L.ggx_lobe(0.3, wi, wo, "separable")
    cor = L.ggx_lobe(0.3, wi, wo, "correlated")
    assert np.all(cor >= sep * (1 - 1e-12))
    wo0 = np.broadcast_to([0.0, 0.0, 1.0], wi.shape)
    np.testing.assert_allclose(L.ggx_lobe(0.3, wi, wo0, "correlated"), L.ggx_lobe(0.3, wi, wo0, "separable"))
    assert L.shadowing_for((3, 4, 1)) == "separable" and L.shadowing_for((4, 5, 0)) == "correlated"


def test_the_lookup_interpolates_as_a_linear_clamped_texture():
    n = L.N_VIEWS
    w = np.random.default_rng(3).uniform(size=(2, n, 3))
    fit = L.LobeFit((0.3,), w, "correlated", 0.0, 0.0)
    centres = np.array(L.texel_views_deg())
    np.testing.assert_allclose(fit.weights_at(centres), w)
    mid = 0.5 * (centres[:-1] + centres[1:])
    np.testing.assert_allclose(fit.weights_at(mid), 0.5 * (w[:, :-1] + w[:, 1:]))
    np.testing.assert_allclose(fit.weights_at([0.0, 90.0]), w[:, [0, -1]])
    again = L.LobeFit.from_dict(fit.as_dict())
    assert again.roughness == fit.roughness
    np.testing.assert_allclose(again.weights, w, atol=1e-6)
    with pytest.raises(ValueError):
        L.LobeFit.from_dict({**fit.as_dict(), "roughness": [0.1, 0.2]})


@pytest.mark.parametrize("shadowing", L.SHADOWING)
def test_a_table_of_two_dictionary_lobes_gives_them_back(shadowing):
    """A table made of a diffuse colour and two Glossy lobes of the dictionary (constant colours):
    the fit finds those roughness values and colours, and states a small error."""
    r1, r2 = L.DICTIONARY[5], L.DICTIONARY[10]
    kd = np.array([0.3, 0.2, 0.1])
    c1, c2 = np.array([0.6, 0.5, 0.4]), np.array([0.2, 0.3, 0.4])

    def brdf(wi, wo):
        f1 = L.ggx_lobe(r1 * r1, wi, wo, shadowing)
        f2 = L.ggx_lobe(r2 * r2, wi, wo, shadowing)
        return kd[:, None] / np.pi + c1[:, None] * f1[None] + c2[:, None] * f2[None]

    table = tabulate(brdf)
    fit = L.fit_lobes(table, n_lobes=2, shadowing=shadowing)
    assert fit.roughness == (r1, r2)
    # the views the sphere mostly shows; at grazing views the table's cells are coarse
    inner = np.array(L.texel_views_deg()) < 70
    for got, want in zip(fit.weights, (kd, c1, c2)):
        np.testing.assert_allclose(got[inner], np.broadcast_to(want, got[inner].shape), rtol=0.03, atol=0.005)
    assert fit.error < 0.05 and fit.albedo_error < 0.02
    # and the error it states is the one measured again from the model
    assert L.measure(fit, table) == pytest.approx((fit.error, fit.albedo_error))


def test_colours_that_follow_the_view_are_fitted_per_view():
    """A lobe whose colour grows toward grazing (as a measured Fresnel rise does) is met view by
    view through the lookup: the fitted colour follows the one the table was made with."""
    r = L.DICTIONARY[8]

    def colour(cos_o):
        return 0.2 + 0.8 * (1.0 - cos_o) ** 3

    def brdf(wi, wo):
        return np.repeat((colour(wo[..., 2]) * L.ggx_lobe(r * r, wi, wo, "correlated"))[None], 3, axis=0)

    fit = L.fit_lobes(tabulate(brdf), n_lobes=1)
    assert fit.roughness == (r,)
    views = np.radians(L.texel_views_deg())
    inner = np.degrees(views) < 70
    np.testing.assert_allclose(fit.weights[1][inner, 0], colour(np.cos(views[inner])), rtol=0.03)
    assert fit.albedo_error < 0.03
