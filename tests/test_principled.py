"""The Principled BSDF fitted to a table (the artist's material without OSL): checked against
the analytic GGX materials the sample tables were made from (their parameters are known)."""

import math

import numpy as np
import pytest

from addon.core.material.principled import PrincipledFit, fit_principled, principled_brdf


@pytest.mark.parametrize("name", ["ggx_glossy", "ggx_rough", "red_plastic"])
def test_a_dielectric_ggx_table_gives_back_its_parameters(name, sample_table):
    import samples

    truth = samples.CATALOG[name]
    fit = fit_principled(sample_table(name))
    assert fit.metallic < 0.05
    assert fit.roughness == pytest.approx(math.sqrt(truth.roughness), rel=0.01)
    assert fit.specular == pytest.approx(truth.f0[0], abs=0.003)
    np.testing.assert_allclose(fit.base_color, truth.kd, atol=0.01)
    assert fit.error < 0.1 and fit.albedo_error < 0.01


def test_a_metal_table_gives_back_its_colour(sample_table):
    import samples

    truth = samples.CATALOG["gold"]
    fit = fit_principled(sample_table("gold"))
    assert fit.metallic > 0.95
    assert fit.roughness == pytest.approx(math.sqrt(truth.roughness), rel=0.01)
    np.testing.assert_allclose(fit.base_color, truth.f0, atol=0.01)


def test_the_model_is_the_samples_ggx_at_the_same_parameters():
    """principled_brdf with metallic 0 is the samples' GGX (an independent implementation)."""
    from samples.analytic import GGX

    rng = np.random.default_rng(3)
    v = rng.normal(size=(2, 500, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    wi, wo = v
    ref = GGX(roughness=0.09, f0=(0.04, 0.04, 0.04), kd=(0.3, 0.2, 0.1))(wi, wo)
    ours = principled_brdf(PrincipledFit((0.3, 0.2, 0.1), 0.0, 0.3, 0.04, 0.0, 0.0), wi, wo)
    np.testing.assert_allclose(ours, ref, rtol=1e-9)


def test_ior_and_specular_inputs_give_the_fitted_reflectance():
    fit = PrincipledFit((0.5, 0.5, 0.5), 0.0, 0.3, 0.04, 0.0, 0.0)
    assert ((fit.ior - 1) / (fit.ior + 1)) ** 2 == pytest.approx(0.04)
    assert fit.specular_3x == pytest.approx(0.5)
