"""The lobe mixture the artist's material renders outside OSL (``core.material.lobes``): its GGX and
Beckmann lobes against textbook forms written out here, its lookup interpolation, and the fit on tables built
from lobes it can represent (their roughness and colours are known)."""

import numpy as np
import pytest

from addon.core.file.merl import tabulate
from addon.core.material import lobes as L


def _directions(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2]) + 1e-3
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _textbook(distribution, alpha, wi, wo):
    """D G1 G1 / (4 cos cos) written out here, independent of the engine's microsurface: GGX's
    D and G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2)); Beckmann's D and Walter et al.'s G1 as they
    published it (a ratio of quadratics in a = 1 / (alpha tan), 1 from a = 1.6)."""
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    ch, ci, co = h[:, 2], wi[:, 2], wo[:, 2]
    t2h = (1.0 - ch**2) / ch**2
    if distribution == "ggx":
        d = 1.0 / (np.pi * alpha**2 * ch**4 * (1.0 + t2h / alpha**2) ** 2)

        def g1(c):
            return 2.0 / (1.0 + np.sqrt(1.0 + alpha**2 * (1.0 - c**2) / c**2))

    else:
        d = np.exp(-t2h / alpha**2) / (np.pi * alpha**2 * ch**4)

        def g1(c):
            a = c / (alpha * np.sqrt(1.0 - c**2))
            return np.where(a < 1.6, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a), 1.0)

    return d * g1(ci) * g1(co) / (4.0 * ci * co)


def test_the_separable_lobes_are_the_textbook_ggx_and_cycles_beckmann():
    """The separable lobe is D G1 G1 / (4 cos cos): GGX's closed forms, and for Beckmann the G1
    of Walter et al.'s fit, which Cycles evaluates (the lobe models what Cycles renders)."""
    wi, wo = _directions(400, 1)
    for alpha in (0.01, 0.1, 0.5):
        np.testing.assert_allclose(L.ggx_lobe(alpha, wi, wo, "separable"), _textbook("ggx", alpha, wi, wo), rtol=1e-9)
    for m in (0.05, 0.2, 0.6):
        want = _textbook("beckmann", m, wi, wo)
        np.testing.assert_allclose(L.microfacet_lobe("beckmann", m, wi, wo, "separable"), want, rtol=1e-9)


def test_the_beckmann_lobe_is_the_samples_exact_beckmann_within_walters_fit():
    """f0 = 1: the samples' Beckmann (exact Smith masking) is Cycles' lobe but for Walter et al.'s
    fit of G1, which they give as within 0.35 % of the exact one: a pair of them within 0.7 %."""
    from samples.analytic import Beckmann

    wi, wo = _directions(400, 11)
    for m in (0.05, 0.2, 0.6):
        ref = Beckmann(roughness=m)(wi, wo)[0]
        got = L.microfacet_lobe("beckmann", m, wi, wo, "separable")
        lit = ref > 0.0  # the narrow lobes underflow to 0 far from the mirror direction
        assert lit.sum() > 100 and np.max(np.abs(got[lit] / ref[lit] - 1.0)) < 7e-3, m


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
    # The colours against the ones the table was made with, on the views where the lobes are
    # picked: their theta_d sits mid-cell in the table (x.5°). At the 36-texel lookup's views
    # the table's nearest cell is a quarter of a degree off, and the best colours for the table
    # there are off the analytic ones by up to 8 % by 64° (the analytic ones cost 3-25 times as
    # much there); the fit as a whole is as close (below).
    fit = L.fit_lobes(table, n_lobes=2, shadowing=shadowing, n_views=L.PICK_VIEWS)
    assert fit.roughness == (r1, r2)
    # the views the sphere mostly shows; at grazing views the table's cells are coarse
    inner = np.array(L.texel_views_deg(L.PICK_VIEWS)) < 70
    for got, want in zip(fit.weights, (kd, c1, c2)):
        np.testing.assert_allclose(got[inner], np.broadcast_to(want, got[inner].shape), rtol=0.03, atol=0.005)
    assert fit.error < 0.05 and fit.albedo_error < 0.02
    # and the error it states is the one measured again from the model
    assert L.measure(fit, table) == pytest.approx((fit.error, fit.albedo_error))
    lookup = L.fit_lobes(table, n_lobes=2, shadowing=shadowing)
    assert lookup.roughness == (r1, r2) and lookup.error < fit.error + 0.002 and lookup.albedo_error < 0.02


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


def test_the_near_mirror_floor_bounds_what_any_isotropic_lobes_reach():
    """``near_mirror_floor`` is the part of a table near the mirror that varies around half-vector
    rings faster than any closure can: about zero for an isotropic table (a sharp GGX and a
    diffuse term: a few per cent, the table's own cells), large once the table's first theta_h cells get a fifth-order pattern in
    phi_d (what the near-mirror measured materials show), and never above the error the fit
    then reaches: a lower bound, checked against ``measure`` on the fit."""
    from addon.core.file.merl import cell_centres

    r = L.DICTIONARY[1]

    def brdf(wi, wo):
        return 0.05 / np.pi + np.repeat(0.8 * L.ggx_lobe(r * r, wi, wo, "correlated")[None], 3, axis=0)

    smooth = tabulate(brdf)
    # Not zero: the table is piecewise constant, and a ring crossing a theta_d cell edge steps
    # by the change of 1 / cos² theta_o over a cell (a degree), which no closure follows either.
    low = L.near_mirror_floor(smooth)
    assert low < 0.05
    assert L.fit_lobes(smooth, n_lobes=2).error >= low
    theta_h, _, phi_d = cell_centres()
    near = np.degrees(theta_h) < 0.4
    pattern = np.where(near, 1.0 + 0.9 * np.cos(5.0 * phi_d), 1.0)
    rough = type(smooth)(smooth.rho * pattern[None], smooth.valid)
    floor = L.near_mirror_floor(rough)
    assert floor > 0.15
    fit = L.fit_lobes(rough, n_lobes=2)
    assert fit.error >= floor


@pytest.mark.parametrize("way", ["across", "in the plane"])
def test_a_lobe_round_about_the_mirror_is_met_by_a_stretched_one(way):
    """A highlight round about the mirror direction is stretched across the plane of incidence
    by about 1 / cos theta_o in half vectors (what aurora_white and the felts show); a widened
    table's broad lobe lies in the plane instead (what σ̃² ×2 edits show). A table made of such
    a GGX lobe (aspect 1 / cos theta_o, at most 3; or its inverse, at least 1/2): the fit finds
    its roughness, picks per view the dictionary aspect nearest the true one (or its
    neighbour), and its error is a small part of what round lobes reach on the same table."""
    r = L.DICTIONARY[8]

    def truth(cos_o):
        across = np.minimum(1.0 / np.clip(cos_o, 1e-3, 1.0), 3.0)
        return across if way == "across" else np.maximum(1.0 / across, 0.5)

    def brdf(wi, wo):
        lobe = 0.7 * L.ggx_lobe(r * r, wi, wo, "correlated", truth(wo[..., 2]))
        return np.repeat(lobe[None], 3, axis=0) + 0.05 / np.pi

    table = tabulate(brdf)
    fit = L.fit_lobes(table, n_lobes=1)
    round_only = L.fit_lobes(table, n_lobes=1, aspects=(1.0,))
    assert fit.roughness == (r,) and fit.anisotropic
    assert fit.error < 0.08 and fit.error < 0.25 * round_only.error
    logs = np.log(L.ASPECTS)
    want = truth(np.cos(np.radians(L.texel_views_deg())))
    nearest = np.argmin(np.abs(np.log(want)[:, None] - logs[None, :]), axis=1)
    picked = np.searchsorted(L.ASPECTS, fit.aspect[0])
    assert np.all(np.abs(picked - nearest) <= 1), (fit.aspect[0], want)
    np.testing.assert_allclose(fit.weights[1][1:-1, 0], 0.7, rtol=0.05)
    # what the node setup renders at the first texel: round (no tangent at normal view)
    assert fit.aspect[0][0] == 1.0
    again = L.LobeFit.from_dict(fit.as_dict())
    np.testing.assert_allclose(again.aspect, fit.aspect)
    # the dict keeps 6 digits: a small albedo error moves by about 1e-6
    assert L.measure(again, table) == pytest.approx((fit.error, fit.albedo_error), rel=1e-4, abs=1e-5)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_the_stretched_lobe_is_the_anisotropic_lobe_of_its_axes(distribution):
    """microfacet_lobe with an aspect against the textbook anisotropic GGX or Beckmann written in
    the frame whose x axis is the view's azimuth: alpha / sqrt(q) along it, alpha sqrt(q) across,
    Lambda from a direction's projected roughness; aspect 1 is the round lobe."""
    wi, wo = _directions(400, 7)
    alpha, q = 0.3, 2.5
    ax, ay = alpha / np.sqrt(q), alpha * np.sqrt(q)
    phi = np.arctan2(wo[:, 1], wo[:, 0])
    c, s = np.cos(phi), np.sin(phi)

    def local(v):
        return np.stack((v[:, 0] * c + v[:, 1] * s, -v[:, 0] * s + v[:, 1] * c, v[:, 2]), axis=1)

    li, lo = local(wi), local(wo)
    h = li + lo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    if distribution == "ggx":
        d = 1.0 / (np.pi * ax * ay * ((h[:, 0] / ax) ** 2 + (h[:, 1] / ay) ** 2 + h[:, 2] ** 2) ** 2)

        def lam(v):
            return (-1.0 + np.sqrt(1.0 + ((ax * v[:, 0]) ** 2 + (ay * v[:, 1]) ** 2) / v[:, 2] ** 2)) / 2.0

    else:
        tan2 = (h[:, 0] ** 2 + h[:, 1] ** 2) / h[:, 2] ** 2
        cos2phi = h[:, 0] ** 2 / (h[:, 0] ** 2 + h[:, 1] ** 2)
        d = np.exp(-tan2 * (cos2phi / ax**2 + (1 - cos2phi) / ay**2)) / (np.pi * ax * ay * h[:, 2] ** 4)

        def lam(v):
            # a = 1 / (alpha(phi) tan theta), alpha(phi) sin theta = |(ax x, ay y)|
            a = v[:, 2] / np.hypot(ax * v[:, 0], ay * v[:, 1])
            return np.where(a < 1.6, (1 - 1.259 * a + 0.396 * a * a) / (3.535 * a + 2.181 * a * a), 0.0)

    want = d / (1.0 + lam(li) + lam(lo)) / (4.0 * li[:, 2] * lo[:, 2])
    np.testing.assert_allclose(L.microfacet_lobe(distribution, alpha, wi, wo, "correlated", q), want, rtol=1e-9)
    if distribution == "ggx":
        np.testing.assert_allclose(L.ggx_lobe(alpha, wi, wo, "correlated", q), want, rtol=1e-9)
        np.testing.assert_allclose(L.ggx_lobe(alpha, wi, wo, "correlated", 1.0), L.ggx_lobe(alpha, wi, wo), rtol=1e-12)


def _snell_fresnel(cos_i, eta):
    """The unpolarised dielectric Fresnel reflectance from Snell's law and the s and p amplitudes
    (independent of ``lobes._fresnel_dielectric``'s closed form without the refracted angle)."""
    sin_t = np.sqrt(1.0 - cos_i**2) / eta
    cos_t = np.sqrt(1.0 - sin_t**2)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs**2 + rp**2)


def test_the_fresnel_factor_is_each_blenders_principled_metal_with_a_black_base():
    """4.x: Schlick's (1 - wi.h)^5 (F0 = the base colour, 0); 3.x: Principled v1's normalised
    dielectric Fresnel of IOR 1.5 (its Specular 0.5), 0 at normal incidence and 1 at grazing."""
    wi, wo = _directions(500, 7)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    c = np.sum(wi * h, axis=-1)
    np.testing.assert_allclose(L.fresnel_factor(wi, wo, "correlated"), (1.0 - c) ** 5, rtol=1e-12, atol=1e-15)
    f0 = 0.04  # ((1.5 - 1) / (1.5 + 1))²
    want = (_snell_fresnel(c, 1.5) - f0) / (1.0 - f0)
    np.testing.assert_allclose(L.fresnel_factor(wi, wo, "separable"), want, rtol=1e-9, atol=1e-12)
    assert L._fresnel_dielectric(np.array(1.0), 1.5) == pytest.approx(f0)
    assert L._fresnel_dielectric(np.array(0.0), 1.5) == pytest.approx(1.0)
    lobe = L.lobe_shape(L.FRESNEL, 0.4, wi, wo, "correlated")
    np.testing.assert_allclose(lobe, L.ggx_lobe(0.16, wi, wo) * (1.0 - c) ** 5, rtol=1e-12)


@pytest.mark.parametrize("shadowing", L.SHADOWING)
def test_beckmann_and_fresnel_lobes_are_given_back(shadowing):
    """A table of a diffuse colour, a Beckmann lobe and a GGX lobe times the Fresnel factor (grey
    0.8, under the Mix Shader's 1): the fit finds both kinds at their roughness and states a
    small error; the Fresnel lobe's weight is grey and within [0, 1] at every view."""
    rb, rf = L.DICTIONARY[9], L.DICTIONARY[11]
    kd, cb = np.array([0.3, 0.2, 0.1]), np.array([0.5, 0.4, 0.3])

    def brdf(wi, wo):
        fb = L.lobe_shape(L.BECKMANN, rb, wi, wo, shadowing)
        ff = L.lobe_shape(L.FRESNEL, rf, wi, wo, shadowing)
        return kd[:, None] / np.pi + cb[:, None] * fb[None] + 0.8 * ff[None]

    fit = L.fit_lobes(tabulate(brdf), shadowing=shadowing, aspects=(1.0,))
    got = dict(zip(zip(fit.kinds, fit.roughness), range(fit.n_lobes)))
    assert (L.BECKMANN, rb) in got and (L.FRESNEL, rf) in got, (fit.kinds, fit.roughness)
    assert fit.error < 0.05 and fit.albedo_error < 0.03
    w = fit.weights[1 + got[(L.FRESNEL, rf)]]
    assert np.all(w >= 0.0) and np.all(w <= L.FRESNEL_MAX) and np.all(w == w[:, :1])
    # (near normal view theta_d is small and the factor too: there other lobes can stand in)
    assert not np.any(np.all(fit.weights[1:] == 0.0, axis=(1, 2)))  # no lobe drawn for nothing
    again = L.LobeFit.from_dict(fit.as_dict())
    assert again.kinds == fit.kinds and L.measure(again, tabulate(brdf))[0] == pytest.approx(fit.error, rel=1e-4)


def test_a_fresnel_lobe_brighter_than_its_mix_shader_allows_is_capped():
    """The Mix Shader's factor stops at 1: a table of a Fresnel lobe of weight 3 is fitted with
    weights at most 1 (and a stored weight over 1 is refused)."""
    r = L.DICTIONARY[10]
    table = tabulate(lambda wi, wo: np.repeat(3.0 * L.lobe_shape(L.FRESNEL, r, wi, wo)[None], 3, axis=0))
    fit = L.fit_lobes(table, aspects=(1.0,), kinds=(L.FRESNEL,))
    assert fit.kinds and all(k == L.FRESNEL for k in fit.kinds)
    assert np.all(fit.weights[1:] <= L.FRESNEL_MAX + 1e-12) and np.max(fit.weights[1:]) == pytest.approx(1.0)
    d = fit.as_dict()
    d["weights"][1][3] = [1.5, 1.5, 1.5]
    with pytest.raises(ValueError):
        L.LobeFit.from_dict(d)


def test_a_metal_gets_no_diffuse_light_where_it_reflects_nothing():
    """A metal (a sharp GGX lobe and a haze that falls to nothing 40° from the mirror, no diffuse
    part): a Lambert term, flat over the light's directions, adds light wherever the table has
    none, which the BRDF's L2 error hardly sees (the peak rules it) but a sphere under a map's
    lights far from the mirror direction shows (issue 37.2: ilm_l3_37_metallic 578-828 % off
    per pixel). Beyond 50° of half-vector tilt, where the table reflects under 0.1 % of each
    view's albedo, the fit adds under half the light the fit with an uncapped diffuse colour
    adds, at no cost in BRDF error."""
    from addon.core.file.merl import lookup
    from addon.core.material.principled import view_quadrature

    r = L.DICTIONARY[2]

    def brdf(wi, wo):
        h = wi + wo
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        haze = 0.3 * np.exp(-((np.arccos(np.clip(h[..., 2], -1.0, 1.0)) / np.radians(20.0)) ** 2))
        return np.stack([c * (L.ggx_lobe(r * r, wi, wo) + haze) for c in (0.9, 0.7, 0.5)])

    table = tabulate(brdf)
    fit = L.fit_lobes(table)
    uncapped = L.fit_lobes(table, diffuse_quantile=None)
    views = (20, 40, 60)
    for deg, (wi, wo, w) in zip(views, view_quadrature(views, L.N_PHI_H)):
        wo = np.broadcast_to(wo, wi.shape)
        h = wi + wo
        far = h[:, 2] / np.linalg.norm(h, axis=1) < np.cos(np.radians(50.0))
        albedo = lookup(table, wi, wo)[0] @ w
        assert np.all(lookup(table, wi[far], wo[far])[0] @ w[far] < 1e-3 * albedo)  # the table: next to none
        added = L.lobes_brdf(fit, wi[far], wo[far]) @ w[far]
        assert np.all(added < 0.5 * (L.lobes_brdf(uncapped, wi[far], wo[far]) @ w[far])), deg
    assert fit.error <= uncapped.error + 0.002 and fit.albedo_error < 0.02


def test_the_velvet_is_ashikhmins_written_out():
    """Cycles' Ashikhmin velvet, written out here from Ashikhmin et al.'s distribution
    exp(-cot² / sigma²) / (pi sigma² sin⁴) and the V-cavity min(1, 2 cos_h min(cos_i, cos_o) / (wo.h))."""
    wi, wo = _directions(2000, 11)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    ch, ci, co = h[:, 2], wi[:, 2], wo[:, 2]
    sigma = 0.35
    sin2 = 1.0 - ch**2
    d = np.exp(-(ch**2 / sin2) / sigma**2) / (np.pi * sigma**2 * sin2**2)
    g = np.minimum(1.0, 2.0 * ch * np.minimum(ci, co) / np.sum(wo * h, axis=-1))
    np.testing.assert_allclose(L.lobe_shape(L.VELVET, sigma, wi, wo), d * g / (4.0 * ci * co), rtol=1e-9)


@pytest.mark.parametrize("shadowing", L.SHADOWING)
def test_a_velvet_sheen_is_given_back_and_drawn_only_where_it_shows(shadowing):
    """A cloth (a diffuse colour and a Velvet of sigma 0.35, colour 0.6): the fit draws one
    Velvet of that sigma, comes within 2 %, where microfacet lobes alone stay 20 % off, and
    drops the lobes the Velvet made redundant; a table of a diffuse colour and a GGX lobe gets
    no Velvet."""
    kd = np.array([0.3, 0.2, 0.1])

    def cloth(wi, wo):
        return kd[:, None] / np.pi + 0.6 * L.lobe_shape(L.VELVET, 0.35, wi, wo)[None]

    table = tabulate(cloth)
    fit = L.fit_lobes(table, shadowing=shadowing)
    micro = L.fit_lobes(table, shadowing=shadowing, kinds=L.MICROFACET_KINDS)
    velvets = [rv for k, rv in zip(fit.kinds, fit.roughness) if k == L.VELVET]
    assert velvets == [0.35], (fit.kinds, fit.roughness)
    assert fit.error < 0.02 and micro.error > 0.2, (fit.error, micro.error)
    assert fit.n_lobes <= 2, fit.describe()
    r = L.DICTIONARY[8]
    plastic = tabulate(lambda wi, wo: kd[:, None] / np.pi + 0.5 * L.lobe_shape(L.GGX, r, wi, wo, shadowing)[None])
    assert L.VELVET not in L.fit_lobes(plastic, shadowing=shadowing).kinds
    again = L.LobeFit.from_dict(fit.as_dict())
    assert again.kinds == fit.kinds and L.measure(again, table)[0] == pytest.approx(fit.error, rel=1e-4)


@pytest.mark.parametrize("deg", [0.0, 30.0, 60.0, 80.0, 88.0])
def test_the_rough_diffuse_is_fujiis_and_4x_keeps_a_white_ones_energy(deg):
    """The white rough Diffuse at roughness 1 reflects, by quadrature over the light's
    directions: in 3.x (Fujii's single scattering) a pi + b G(cos theta_o), G written out here
    from Fujii's note, a = b = 1 / (pi + pi / 2 - 2 / 3); in 4.x, with its multiple scattering,
    all the light it receives (OpenPBR's energy-preserving Oren-Nayar)."""
    n = 300
    th = (np.arange(n) + 0.5) / n * np.pi / 2
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    t, p = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    dw = (np.sin(t) * (np.pi / 2 / n) * (2 * np.pi / (2 * n))).ravel()
    o = np.radians(deg)
    wo = np.broadcast_to(np.array([np.sin(o), 0.0, np.cos(o)]), wi.shape)
    a = 1.0 / (np.pi + np.pi / 2 - 2.0 / 3.0)
    s, c = np.sin(o), np.cos(o)
    g = s * (o - 2.0 / 3.0 - s * c) + (2.0 / 3.0) * (s / c) * (1.0 - s**3) if deg else 0.0
    single = np.sum(L.rough_diffuse(wi, wo, "separable") * wi[:, 2] * dw)
    assert single == pytest.approx(a * np.pi + a * g, rel=2e-3)
    assert np.sum(L.rough_diffuse(wi, wo, "correlated") * wi[:, 2] * dw) == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("shadowing", L.SHADOWING)
def test_a_rough_diffuse_is_given_back(shadowing):
    """A table of a coloured Lambert and a white rough Diffuse mixed in at 0.6: the fit draws
    one rough Diffuse, its grey weight within [0, 1], and comes within 2 %, where microfacet
    lobes alone stay further off."""
    kd = np.array([0.3, 0.2, 0.1])

    def brdf(wi, wo):
        return kd[:, None] / np.pi + 0.6 * L.lobe_shape(L.ROUGH_DIFFUSE, 1.0, wi, wo, shadowing)[None]

    table = tabulate(brdf)
    fit = L.fit_lobes(table, shadowing=shadowing)
    micro = L.fit_lobes(table, shadowing=shadowing, kinds=L.MICROFACET_KINDS)
    assert fit.kinds.count(L.ROUGH_DIFFUSE) == 1, fit.describe()
    w = fit.weights[1 + fit.kinds.index(L.ROUGH_DIFFUSE)]
    assert np.all(w >= 0.0) and np.all(w <= L.FRESNEL_MAX) and np.all(w == w[:, :1])
    assert fit.error < 0.02 and micro.error > fit.error + 0.02, (fit.error, micro.error)


def test_each_lobe_at_its_own_aspect_is_the_column_of_the_full_set():
    """``_features`` with one aspect per lobe (the lookup's texels) gives the very columns the
    picking views hold for every lobe at every aspect."""
    wi, wo = _directions(400, 5)[0], np.array([np.sin(0.9), 0.0, np.cos(0.9)])
    lobes = [(L.GGX, 0.2), (L.BECKMANN, 0.35), (L.FRESNEL, 0.2), (L.VELVET, 0.5)]
    full = L._features(lobes, wi, wo, "correlated", L.ASPECTS)
    nq = len(L.ASPECTS)
    for picks in ([0, 7, 2, 2], [5, 2, 2, 0]):
        own = L._features(lobes, wi, wo, "correlated", [L.ASPECTS[p] for p in picks])
        np.testing.assert_array_equal(own[0], full[0])
        for k, p in enumerate(picks):
            want = full[1 + k * nq + (p if lobes[k][0] in (L.GGX, L.BECKMANN) else 0)]
            np.testing.assert_allclose(own[1 + k], want, rtol=1e-12, atol=0.0)


def test_a_finer_lookup_follows_a_colour_that_swings_with_the_view():
    """The lookup's texels lie twice as close as the views the lobes are picked on: the same
    lobes, and the colours solved at each texel's own view. A colour that swings with the view
    (period 20°) is met better half-way between the texels, at ERROR_VIEWS_DEG, which no fit
    sees, and at the texels themselves."""
    r = L.DICTIONARY[8]

    def swing(theta_deg):
        return 1.0 + 0.8 * np.cos(2.0 * np.pi * theta_deg / 20.0)

    def brdf(wi, wo):
        theta = np.degrees(np.arccos(np.clip(wo[..., 2], -1.0, 1.0)))
        return np.repeat((swing(theta) * L.ggx_lobe(r * r, wi, wo, "correlated"))[None], 3, axis=0)

    table = tabulate(brdf)
    assert L.N_VIEWS == 2 * L.PICK_VIEWS
    coarse = L.fit_lobes(table, n_lobes=1, n_views=L.PICK_VIEWS, kinds=(L.GGX,))
    fine = L.fit_lobes(table, n_lobes=1, kinds=(L.GGX,))
    assert coarse.roughness == fine.roughness == (r,)
    assert fine.weights.shape[1] == L.N_VIEWS
    assert fine.error < 0.85 * coarse.error  # 22.4 % -> 16.9 % here; the rest is the table's own cells
    # at the fine texels' views the colour is nearer the swing than the coarse lookup draws it
    # there (the table's cells smooth the swing itself: its peaks come out ~15 % low either way)
    views = np.array(L.texel_views_deg())
    inner = views < 70
    near = np.abs(fine.weights[1][inner, 0] - swing(views[inner]))
    drawn = np.abs(coarse.weights_at(views[inner])[1, :, 0] - swing(views[inner]))
    assert np.mean(near) < 0.8 * np.mean(drawn)
    assert L.measure(fine, table) == pytest.approx((fine.error, fine.albedo_error))


def test_a_table_of_one_fresnel_lobe_gives_it_back_through_the_finer_lookup():
    """Only Fresnel lobes (always round: no aspect is chosen, though aspects are offered): the
    lookup's texels take them round too. The lobe of the table comes back, with its grey
    weight, wherever the lobe holds light (from 30°: Schlick's factor with a black base is
    under 1e-4 nearer the normal, where any weight fits the table)."""
    r, c = L.DICTIONARY[8], 0.7

    def brdf(wi, wo):
        return np.repeat((c * L.lobe_shape(L.FRESNEL, r, wi, wo))[None], 3, axis=0)

    fit = L.fit_lobes(tabulate(brdf), n_lobes=1, kinds=(L.FRESNEL,))
    assert fit.kinds == (L.FRESNEL,) and fit.roughness == (r,)
    assert fit.weights.shape == (2, L.N_VIEWS, 3) and not fit.anisotropic
    views = np.array(L.texel_views_deg())
    lit = (views >= 30) & (views <= 80)
    np.testing.assert_allclose(fit.weights[1][lit], c, rtol=0.02)
