"""Truncated Gaussians on [-pi/2, pi/2]: the one solver for the engine, the preview and OSL.

The moment model (paper Eq. 7-8) sets the *truncated* mean and variance of each lobe to the
targets. Not every pair has a truncated Gaussian: at a given mean, the variance grows with
the Gaussian's width s toward the truncated exponential's (the family's limit as s -> inf, a
closed form, ``variance_cap``). The rule, everywhere: **the mean is kept;
the variance is capped at CAP_FRACTION of that limit** (``reachable_variance``; at the centre the
capped lobe, s ~ 8, is within 2 % of uniform). Then Newton's method in (m, log s) on the
scaled residuals, with the exact Jacobian (derivatives of an exponential family's moments are
covariances) and step halving. ``addon/shaders/brdf_moments_common.h`` (bm_truncated_params)
runs the same.
"""

import math

import numpy as np
from scipy.special import log_ndtr, ndtr

from ..geometry import HALF_PI
from ..limits import check

_SQRT_2PI = math.sqrt(2.0 * math.pi)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
# Nearer the limit the Gaussian's width runs away (s ~ 18 at 0.999 and the centre; at the edges
# m reaches -1e3, where the closed forms underflow): 0.995 converges everywhere in 40 steps.
CAP_FRACTION = 0.995
MIN_S = 1e-4
MAX_S = 20.0
MAX_M = 1e4


def _exp_mean(u):
    """Mean / h of the density e^(u x / h) on [-h, h]: coth(u) - 1/u (series near 0)."""
    u = np.asarray(u, float)
    small = np.abs(u) < 1e-3
    us = np.where(small, 1.0, u)
    return np.where(small, u / 3.0 - u**3 / 45.0, 1.0 / np.tanh(us) - 1.0 / us)


def _exp_var(u):
    """Variance / h^2 of the same density: 1/u^2 - 1/sinh(u)^2 (series near 0)."""
    u = np.asarray(u, float)
    small = np.abs(u) < 1e-2
    us = np.where(small, 1.0, np.clip(u, -300, 300))  # beyond, 1/sinh^2 underflows to 0 anyway
    return np.where(small, 1.0 / 3.0 - u**2 / 15.0 + 2.0 * u**4 / 189.0, 1.0 / us**2 - 1.0 / np.sinh(us) ** 2)


def variance_cap(mean):
    """The largest variance any truncated Gaussian with this mean approaches (the truncated
    exponential's, in closed form once its rate is found by bisection); 0 at the edges."""
    mu = np.clip(np.asarray(mean, float) / HALF_PI, -1.0, 1.0)
    lo, hi = np.full(mu.shape, -1e4), np.full(mu.shape, 1e4)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        below = _exp_mean(mid) < mu
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    u = 0.5 * (lo + hi)
    return np.where(np.abs(mu) >= 1.0, 0.0, np.maximum(_exp_var(u), 0.0) * HALF_PI**2)


_CAP_GRID = {}


def variance_cap_fast(mean):
    """``variance_cap`` interpolated on a fine grid of means (for the reach scans)."""
    if "g" not in _CAP_GRID:
        g = np.linspace(-HALF_PI, HALF_PI, 4001)
        _CAP_GRID["g"] = (g, variance_cap(g))
    g, v = _CAP_GRID["g"]
    return np.interp(np.asarray(mean, float), g, v)


def _oriented(m, s):
    """Standardized bounds, mirrored when the interval lies mostly above the mean (ndtr keeps
    full relative precision only in the lower tail); returns (a, b, flip)."""
    m = np.asarray(m, float)
    s = np.asarray(s, float)
    a, b = (-HALF_PI - m) / s, (HALF_PI - m) / s
    flip = np.where(a + b > 0.0, -1.0, 1.0)
    return np.where(flip < 0, -b, a), np.where(flip < 0, -a, b), flip


def mass(m, s):
    """Z = P(-pi/2 <= X <= pi/2) for X ~ N(m, s^2)."""
    lo, hi, _ = _oriented(m, s)
    return np.maximum(ndtr(hi) - ndtr(lo), 1e-300)


def log_mass(a, b):
    """log(Phi(b) - Phi(a)) for a < b, accurate far in either tail (a lobe centred well beyond
    the horizon has all its truncated mass in a sliver of the far tail)."""
    flip = a > 0  # Phi(b) - Phi(a) = Phi(-a) - Phi(-b): keep the difference on the left tail
    lo, hi = np.where(flip, -b, a), np.where(flip, -a, b)
    l_hi, l_lo = log_ndtr(hi), log_ndtr(lo)
    with np.errstate(divide="ignore"):
        return l_hi + np.log1p(-np.exp(np.minimum(l_lo - l_hi, 0.0)))


def z_moments(m, s):
    """E[z], central c2, c3, c4 and raw E[z^3] of z = (x - m)/s, x ~ N(m, s^2) on [-pi/2, pi/2].

    The density ratios phi(a)/Z, phi(b)/Z are formed in logs: tail-safe."""
    m = np.asarray(m, float)
    s = np.asarray(s, float)
    a, b = (-HALF_PI - m) / s, (HALF_PI - m) / s
    log_z = log_mass(a, b)
    pa = np.exp(-0.5 * a * a - _LOG_SQRT_2PI - log_z)
    pb = np.exp(-0.5 * b * b - _LOG_SQRT_2PI - log_z)
    m1 = pa - pb
    m2 = 1.0 + (a * pa - b * pb)
    m3 = 2.0 * m1 + (a * a * pa - b * b * pb)
    m4 = 3.0 * m2 + (a**3 * pa - b**3 * pb)
    c2 = np.maximum(m2 - m1 * m1, 1e-300)
    c3 = m3 - 3.0 * m1 * m2 + 2.0 * m1**3
    c4 = m4 - 4.0 * m1 * m3 + 6.0 * m1 * m1 * m2 - 3.0 * m1**4
    return m1, c2, c3, c4, m3


def moments(m, s):
    """Mean and variance of N(m, s^2) truncated to [-pi/2, pi/2]."""
    m = np.asarray(m, float)
    s = np.asarray(s, float)
    mu, c2, _, _, _ = z_moments(m, s)
    mean = np.clip(m + s * mu, -HALF_PI, HALF_PI)
    var = s * s * c2
    # The closed form cancels when all the mass sits in a sliver at one edge; there the law is
    # exponential to first order, and its variance is its squared mean distance from that edge.
    d = np.minimum(np.abs(HALF_PI - mean), np.abs(mean + HALF_PI))
    return mean, np.where(np.isfinite(var) & (var > 1e-300), var, np.maximum(d * d, 1e-300))


def reachable_variance(mean, var):
    """The rule: the target variance, capped at CAP_FRACTION of the limit at this mean."""
    mean = np.clip(np.asarray(mean, float), -HALF_PI * (1 - 1e-9), HALF_PI * (1 - 1e-9))
    var = np.maximum(np.broadcast_to(np.asarray(var, float), mean.shape), 1e-14)
    return np.minimum(var, CAP_FRACTION * variance_cap(mean))


def solve(mean, var, iters: int = 40):
    """(m, s, var_used) of the Gaussian whose truncation has this mean and (capped) variance."""
    iters = check("iterations", iters, "iters")
    mean = np.clip(np.asarray(mean, float), -HALF_PI * (1 - 1e-9), HALF_PI * (1 - 1e-9))
    var = np.maximum(reachable_variance(mean, var), 1e-14)
    sd = np.sqrt(var)
    m = mean.copy()
    ls = np.log(np.clip(sd, MIN_S, MAX_S))
    lo, hi = math.log(MIN_S), math.log(MAX_S)

    def residual(m, ls):
        s = np.exp(ls)
        mu, c2, c3, c4, m3 = z_moments(m, s)
        return (m + s * mu - mean) / sd, np.log(s * s * c2 / var), (s, mu, c2, c3, c4, m3)

    r1, r2, st = residual(m, ls)
    for _ in range(iters):
        s, mu, c2, c3, c4, m3 = st
        j11, j12 = c2 / sd, s * (m3 - mu * (c2 + mu * mu)) / sd
        j21, j22 = c3 / (s * c2), (c4 - c2 * c2 + 2.0 * mu * c3) / c2
        det = j11 * j22 - j12 * j21
        ok = np.abs(det) > 1e-300
        det = np.where(ok, det, 1.0)
        dm = np.where(ok, -(j22 * r1 - j12 * r2) / det, -r1 / np.maximum(j11, 1e-300))
        dl = np.where(ok, -(-j21 * r1 + j11 * r2) / det, 0.0)
        # Bounded steps: m by at most 4 of the current widths (m runs far out for lobes near the cap).
        dm = np.clip(dm, -0.5 - 4.0 * s, 0.5 + 4.0 * s)
        dl = np.clip(dl, -1.0, 1.0)
        norm = r1 * r1 + r2 * r2
        step = np.ones_like(m)
        done = np.zeros(m.shape, bool)
        new_m, new_l, new_1, new_2, new_st = m, ls, r1, r2, st
        for half in range(6):
            nm = np.clip(m + step * dm, -MAX_M, MAX_M)
            nl = np.clip(ls + step * dl, lo, hi)
            q1, q2, qs = residual(nm, nl)
            take = ~done & ((q1 * q1 + q2 * q2 < norm) | (half == 5))
            new_m, new_l = np.where(take, nm, new_m), np.where(take, nl, new_l)
            new_1, new_2 = np.where(take, q1, new_1), np.where(take, q2, new_2)
            new_st = tuple(np.where(take, x, y) for x, y in zip(qs, new_st))
            done |= take
            if done.all():
                break
            step = np.where(done, step, 0.5 * step)
        m, ls, r1, r2, st = new_m, new_l, new_1, new_2, new_st
        if float(np.max(r1 * r1 + r2 * r2, initial=0.0)) < 1e-24:
            break
    return m, np.exp(ls), var
