"""Stress: numerical stability of the moments, from 1e-4 rad lobes to Lambertian, up to 89.9 deg.

Closed forms are truncated normals (scipy.stats.truncnorm) and the uniform slice; table
cases are checked against a textbook two-pass (centred) float64 sum over the same
quadrature nodes, computed here independently of the engine's cell operator.
"""

import math
import os

import numpy as np
import pytest
from scipy.special import ndtr
from scipy.stats import truncnorm

from _stress import assert_profiles_sane, build_operator_in_memory
from addon.core.file.merl import N_CELLS, MerlTable, cell_indices
from addon.core.profiles.compute import compute_profiles, function_profiles, specular_values
from addon.core.profiles.integrate import get_operator, table_sums
from addon.core.profiles.moments import exponents, monomials, profiles_from_sums, shift_amplification
from addon.core.profiles.quadrature import RuleParams, slice_rule

pytestmark = pytest.mark.stress

H = math.pi / 2
LAMBERT = math.pi**2 / 12


def _truncnorm(m, s):
    a, b = (-H - m) / s, (H - m) / s
    mass = math.sqrt(2 * math.pi) * s * (ndtr(b) - ndtr(a))
    mean, var, skew, kurt = (float(x) for x in truncnorm.stats(a, b, loc=m, scale=s, moments="mvsk"))
    return mass, mean, var, skew, kurt


def _uniform():
    # Uniform on [-pi/2, pi/2]: the Lambertian slice in the paper's measure.
    return math.pi, 0.0, LAMBERT, 0.0, -1.2


# (sigma, where the lobe sits): "mirror" is -theta_o, "normal" is theta = 0 (a lobe 1.57 rad
# from the mirror at 89.9 deg), "far" is 0.8 rad on the view side.
LOBES = [(s, where) for s in (1e-4, 3e-4, 1e-3, 1e-2, 0.1, 0.5, 2.0) for where in ("mirror", "normal", "far")]
VIEWS = (0.0, 45.0, 80.0, 89.9)


@pytest.mark.parametrize("sigma, where", LOBES + [(math.inf, "lambertian")])
def test_analytic_lobes_match_closed_forms_at_every_view(stress_log, sigma, where):
    for to_deg in VIEWS:
        to = math.radians(to_deg)
        m = {"mirror": -to, "normal": 0.0, "far": 0.8, "lambertian": 0.0}[where]
        s_phi = min(sigma, 2.0)
        if where == "lambertian":

            def f(theta, phi, _):
                return np.ones((1,) + np.shape(theta))

            mt = mp = _uniform()
        else:

            def f(theta, phi, _, m=m, s=sigma, sp=s_phi):
                return np.exp(-0.5 * ((theta - m) / s) ** 2 - 0.5 * (phi / sp) ** 2)[None]

            mt, mp = _truncnorm(m, sigma), _truncnorm(0.0, s_phi)
        # A lobe narrower than the peak search's grid must be pointed at (the function
        # interface cannot find a needle it never samples; see integrate.find_peak).
        got = {k: v[0, 0] for k, v in function_profiles(f, [to], centre=lambda _t, m=m: (m, 0.0)).items()}
        assert all(np.isfinite(v) for v in got.values()), (to_deg, got)
        case = f"sigma={sigma:g} at {where}, theta_o={to_deg}"
        assert got["alpha"] == pytest.approx(mt[0] * mp[0], rel=1e-8), case
        assert got["mu_theta"] == pytest.approx(mt[1], abs=1e-10 + 1e-9 * sigma), case
        assert got["sigma_tt"] == pytest.approx(mt[2], rel=1e-7), case
        assert got["sigma_pp"] == pytest.approx(mp[2], rel=1e-7), case
        assert got["skew_30"] == pytest.approx(mt[3], abs=1e-5), case
        assert got["kurt_40"] == pytest.approx(mt[4], abs=1e-5), case
        assert got["kurt_04"] == pytest.approx(mp[4], abs=1e-5), case
        assert got["kurt_22"] == pytest.approx(0.0, abs=1e-5), case
        stress_log.record("analytic lobes 1e-4 rad .. Lambertian", "valid", case)


def test_binomial_shift_is_exact_when_centred_and_measures_its_own_cancellation():
    # Raw moments of N(m, s^2) (untruncated, s tiny: the truncation is below 1e-300) about
    # two centres: at the lobe, and 1.5 rad away.
    m, s = 0.3, 1e-4
    central = {0: 1.0, 1: 0.0, 2: s**2, 3: 0.0, 4: 3 * s**4}

    def raw_about(c):
        d = m - c
        return [sum(math.comb(n, i) * central[i] * d ** (n - i) for i in range(n + 1)) for n in range(5)]

    def sums(c):
        # phi ~ N(0, s^2) independent of theta: raw sums about (c, 0) factor into 1D moments.
        r = raw_about(c)
        return np.array([r[n] * central[k] for n, k in exponents(4)])

    near = profiles_from_sums(sums(m)[None], np.array([m]))
    assert near["sigma_tt"][0] == pytest.approx(s * s, rel=1e-12)
    assert near["kurt_40"][0] == pytest.approx(0.0, abs=1e-9)
    assert shift_amplification(sums(m)[None])[0] == pytest.approx(1.0, rel=1e-9)
    # 1.5 rad away the raw fourth moment is ~(1.5)^4 and the central one 3e-16: the shift
    # cancels 16 digits, which is all a double has. The amplification says so.
    amp = shift_amplification(sums(m - 1.5)[None])[0]
    assert amp > 1e15


def _off_mirror_table(to, centre, half):
    """1 on the cells that the view's own quadrature nodes near (centre, 0) fall in."""
    rule = slice_rule(to, RuleParams())
    cells = cell_indices(rule.theta_h, rule.theta_d, rule.phi_d)
    sel = (np.abs(rule.theta - centre) < half) & (np.abs(rule.phi) < half)
    v = np.zeros(N_CELLS)
    v[np.unique(cells[sel])] = 1.0
    return MerlTable(np.stack([v, v, v]), np.ones((3, N_CELLS), bool)), rule, cells, v


def _two_pass_reference(rule, cells, v):
    """Textbook centred moments over the rule's nodes, in float64: mean first, then sums."""
    w = rule.weight * v[cells]
    a = w.sum()
    mt, mp = (w @ rule.theta) / a, (w @ rule.phi) / a
    s = w @ monomials(rule.theta - mt, rule.phi - mp, 4)
    return {k: v_[0, 0] for k, v_ in profiles_from_sums(s[None, None], np.array([[mt]]), centre_phi=mp).items()}


@pytest.mark.parametrize(
    "to_deg, centre, half",
    [
        (60.0, -0.3, 0.004),
        (60.0, 0.5, 0.01),
        (60.0, 0.5, 0.3),
        (85.0, 0.0, 0.01),
        (89.9, 1.2, 0.02),
        (30.0, -0.52, 0.002),
    ],
)
def test_table_lobe_far_from_the_mirror_keeps_its_higher_moments(stress_log, to_deg, centre, half):
    to = math.radians(to_deg)
    table, rule, cells, v = _off_mirror_table(to, centre, half)
    ref = _two_pass_reference(rule, cells, v)
    prof = compute_profiles(table, np.array([to]), split=False)
    for ch in ("r", "avg"):
        p = {k: val[0] for k, val in prof[ch].items()}
        assert p["alpha"] == pytest.approx(ref["alpha"], rel=1e-6)
        assert p["mu_theta"] == pytest.approx(ref["mu_theta"], abs=1e-7)
        assert p["sigma_tt"] == pytest.approx(ref["sigma_tt"], rel=1e-5)
        assert p["sigma_pp"] == pytest.approx(ref["sigma_pp"], rel=1e-5)
        for k in ("skew_30", "skew_03", "kurt_40", "kurt_04", "kurt_22"):
            assert p[k] == pytest.approx(ref[k], abs=1e-4), k
        assert p["kurt_40"] >= p["skew_30"] ** 2 - 2 - 1e-6  # any distribution satisfies this
    stress_log.record("table lobes far from the mirror", "valid", f"{to_deg} deg, lobe at {centre}, {half}")


def test_without_recentring_the_float32_shift_would_lose_the_kurtosis():
    # Why profiles recentres: the same table through the mirror-centred float32 sums alone.
    to = math.radians(60.0)
    table, rule, cells, v = _off_mirror_table(to, 0.5, 0.01)
    ref = _two_pass_reference(rule, cells, v)
    op = get_operator(np.array([to]))
    sums = table_sums(op, specular_values(table, np.zeros(3), split=False, dtype=np.float32))
    naive = profiles_from_sums(sums, -np.array([[to]]))
    assert shift_amplification(sums)[0, 3] > 1e6
    assert abs(naive["kurt_40"][0, 3] - ref["kurt_40"]) > 0.1  # digits gone: the bug this guards against
    assert compute_profiles(table, np.array([to]), split=False)["avg"]["kurt_40"][0] == pytest.approx(
        ref["kurt_40"], abs=1e-4
    )


def test_lambertian_table_up_to_89_9_degrees(stress_log):
    views = np.radians([0.0, 45.0, 80.0, 89.0, 89.5, 89.9])
    table = MerlTable(np.full((3, N_CELLS), 0.5 / math.pi), np.ones((3, N_CELLS), bool))
    prof = compute_profiles(table, views, split=False)
    assert_profiles_sane(prof)
    p = prof["avg"]
    np.testing.assert_allclose(p["alpha"], 0.5 * math.pi, rtol=5e-6)
    np.testing.assert_allclose(p["mu_theta"], 0.0, atol=5e-6)
    np.testing.assert_allclose(p["sigma_tt"], LAMBERT, rtol=5e-6)
    np.testing.assert_allclose(p["sigma_pp"], LAMBERT, rtol=5e-6)
    np.testing.assert_allclose(p["kurt_40"], -1.2, atol=5e-5)
    np.testing.assert_allclose(p["kurt_04"], -1.2, atol=5e-5)
    for to in views:
        stress_log.record("theta_o up to 89.9 deg", "valid", f"lambertian table at {math.degrees(to):.1f}")


@pytest.mark.parametrize("name", ["ggx_mirror", "gold", "ggx_rough", "phong"])
def test_sample_tables_at_grazing_views_are_finite_and_consistent(sample_table, stress_log, name):
    views = np.radians([0.0, 45.0, 80.0, 89.0, 89.5, 89.9])
    prof = compute_profiles(sample_table(name), views)
    assert_profiles_sane(prof)
    a = prof["avg"]["alpha"]
    assert np.all(np.isfinite(a) & (a > 0))
    for k in ("mu_theta", "sigma_tt", "sigma_pp", "skew_30", "kurt_40"):
        assert np.all(np.isfinite(prof["avg"][k])), k
    for to in views:
        stress_log.record("theta_o up to 89.9 deg", "valid", f"{name} at {math.degrees(to):.1f}")


FACTORS = [1e-30, 1e-100, 1e-200, 1e-300, 1e-310, 1e-320]


@pytest.mark.parametrize("factor", FACTORS)
def test_near_black_channel_keeps_its_moments(sample_table, stress_log, factor):
    # Scaling one channel scales its specular part (kd is its minimum, scaled too), so every
    # moment of that channel must equal the unscaled one, however dark it gets, as long as
    # the values stay representable. Below 2.2e-308 doubles are subnormal: at 1e-310 the
    # table keeps ~13 digits, at 1e-320 most cells keep one or two (the quantum is 5e-324),
    # so only rough agreement is possible there; finiteness and sanity hold everywhere.
    base = sample_table("ggx_glossy")
    views = np.radians([0.0, 30.0, 60.0, 85.0])
    want = compute_profiles(base, views)
    dark = base.copy()
    dark.rho[0] *= factor
    got = compute_profiles(dark, views)
    assert_profiles_sane(got)
    tol = {1e-310: 1e-4, 1e-320: 5e-2}.get(factor, 2e-5)
    np.testing.assert_allclose(got["r"]["alpha"] / factor, want["r"]["alpha"], rtol=tol)
    for k in ("mu_theta", "sigma_tt", "sigma_pp", "skew_30", "kurt_40", "kurt_04"):
        np.testing.assert_allclose(got["r"][k], want["r"][k], rtol=tol, atol=tol, err_msg=k)
        np.testing.assert_allclose(got["g"][k], want["g"][k], rtol=2e-5, atol=2e-5, err_msg=k)
    stress_log.record("near-zero energy channel", "valid", f"red x {factor:g}")


def test_zero_channel_is_undefined_not_nan_in_json(sample_table, stress_log):
    base = sample_table("ggx_glossy")
    dark = base.copy()
    dark.rho[2] = 0.0
    prof = compute_profiles(dark, np.radians([0.0, 45.0]))
    assert_profiles_sane(prof)
    data = prof.to_json()
    assert data["b"]["alpha"] == [0.0, 0.0]
    assert data["b"]["mu_theta"] == [None, None]
    assert all(v is not None for v in data["r"]["kurt_40"])
    stress_log.record("near-zero energy channel", "clamped", "blue exactly 0: moments null")


def test_operator_streamed_into_the_cache_equals_the_in_memory_build(tmp_path):
    # The cache is written view by view (low peak memory); it must hold exactly what an
    # in-memory build computes, including the centroid data the recentring reads.
    from addon.core.profiles.integrate import _MEMO

    views = np.radians([0.0, 33.0, 88.0])
    get_operator(views, cache_dir=str(tmp_path))
    _MEMO.clear()
    cached = get_operator(views, cache_dir=str(tmp_path))
    fresh = build_operator_in_memory(views)
    for k in ("offsets", "cells"):
        np.testing.assert_array_equal(np.asarray(getattr(cached, k)), np.asarray(getattr(fresh, k)), err_msg=k)
    # Since operator version 8 the strip lines' cell edges are found by bisection on the cell
    # index, whose trig numpy's SIMD loops may round differently with memory alignment: a
    # probe that lands within an ulp of an edge can move a break point by one bisection step
    # (6e-9 rad). Seen: 1093 of 1.1 M moments about the centroids differ, by <= 3.5e-18.
    for k in ("weights", "albedo", "centroid", "local"):
        a, b = np.asarray(getattr(cached, k), float), np.asarray(getattr(fresh, k), float)
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-12 * np.abs(b).max(), err_msg=k)
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".tmp-")]
    _MEMO.clear()


def test_the_operator_cache_keeps_the_most_recently_used_within_its_bound(tmp_path):
    # Each operator folder is hundreds of MB: the cache keeps at most OPERATOR_CACHE_MAX_ENTRIES
    # of the current version, least recently used out first, and only folders it marked.
    # (Foreign and unmarked folders are never touched: tests/test_stress_lost.py.)
    from addon.core.file.atomic import MARKER
    from addon.core.limits import OPERATOR_CACHE_MAX_ENTRIES
    from addon.core.profiles.integrate import _MEMO, _OPERATOR_PREFIX, _SEAL

    names = [f"{_OPERATOR_PREFIX}{i:020d}" for i in range(OPERATOR_CACHE_MAX_ENTRIES + 2)]
    for age, name in enumerate(names):
        (tmp_path / name).mkdir()
        (tmp_path / name / MARKER).write_text("x")
        (tmp_path / name / _SEAL).write_text("{}")
        os.utime(tmp_path / name / _SEAL, (1e9 + age, 1e9 + age))
    _MEMO.clear()
    get_operator(np.radians([10.0]), cache_dir=str(tmp_path))
    left = sorted(n for n in os.listdir(tmp_path) if n.startswith(_OPERATOR_PREFIX))
    assert len(left) == OPERATOR_CACHE_MAX_ENTRIES
    # the new one (most recent) and the newest of the others stay
    assert set(names[-(OPERATOR_CACHE_MAX_ENTRIES - 1) :]) <= set(left)
    _MEMO.clear()
