"""One truncated-Gaussian solver (core.fits.truncated) for the engine, the preview and OSL, against
closed forms and an independent implementation (scipy.stats.truncnorm)."""

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import truncnorm

from addon.core.fits import truncated as T
from addon.core.preview.lobe import truncated_params

H = math.pi / 2


def _exp_density_moments(lam):
    """Mean and variance of e^(lam x) on [-pi/2, pi/2], by quadrature (independent of the closed form)."""
    z = quad(lambda x: math.exp(lam * x), -H, H)[0]
    m = quad(lambda x: x * math.exp(lam * x), -H, H)[0] / z
    v = quad(lambda x: (x - m) ** 2 * math.exp(lam * x), -H, H)[0] / z
    return m, v


@pytest.mark.parametrize("lam", [0.0, 0.3, -1.0, 2.5, -6.0, 12.0])
def test_variance_cap_is_the_truncated_exponential(lam):
    m, v = _exp_density_moments(lam)
    assert T.variance_cap(np.array([m]))[0] == pytest.approx(v, rel=1e-7)


def test_cap_bounds_every_truncated_gaussian():
    rng = np.random.default_rng(4)
    m0 = rng.uniform(-3, 3, 4000)
    s0 = np.exp(rng.uniform(math.log(1e-3), math.log(50.0), 4000))
    a, b = (-H - m0) / s0, (H - m0) / s0
    mean, var = truncnorm.stats(a, b, loc=m0, scale=s0, moments="mv")
    ok = np.isfinite(mean) & np.isfinite(var) & (np.abs(mean) < H - 1e-3)
    assert np.all(var[ok] <= T.variance_cap(mean[ok]) * (1 + 1e-9))


def test_reachable_targets_are_solved_exactly():
    rng = np.random.default_rng(0)
    mean = rng.uniform(-1.5, 1.5, 2000)
    var = rng.uniform(0.001, 1.0, 2000) * T.CAP_FRACTION * T.variance_cap(mean)
    m, s, used = T.solve(mean, var)
    np.testing.assert_array_equal(used, var)  # inside the cap: nothing is changed
    mt, vt = truncnorm.stats((-H - m) / s, (H - m) / s, loc=m, scale=s, moments="mv")
    np.testing.assert_allclose(mt, mean, atol=1e-9)
    np.testing.assert_allclose(vt, var, rtol=1e-7)


def test_out_of_reach_keeps_the_mean_and_caps_the_variance():
    # The example: mean -1.0, variance 0.3 (above the limit 0.2963 at that mean).
    m, s, used = T.solve(np.array([-1.0]), np.array([0.3]))
    cap = _exp_density_moments(-2.682562196544281 / H)[1]  # the rate whose mean is -1.0
    assert used[0] == pytest.approx(T.CAP_FRACTION * cap, rel=1e-6)
    mt, vt = truncnorm.stats((-H - m) / s, (H - m) / s, loc=m, scale=s, moments="mv")
    assert mt[0] == pytest.approx(-1.0, abs=1e-9)
    assert vt[0] == pytest.approx(used[0], rel=1e-7)
    # The preview's lobe follows the same rule.
    mp, sp = truncated_params(np.array([-1.0]), np.array([0.3]))
    np.testing.assert_allclose([mp[0], sp[0]], [m[0], s[0]], rtol=1e-12)
