"""Moment profiles from weighted raw sums (SPEC §3).

Every integrator in this package reduces a slice to raw sums
``S[n, m] = sum_k w_k rho_k x_k^n phi_k^m`` with x = theta - c, where c is a per-view centre
close to the lobe (the mirror direction -theta_o, or the located peak). Central moments are
then obtained by an exact binomial shift from c to the mean. When c is near the lobe the
shift is small and the cancellation that plagues E[x^2] - E[x]^2 about the origin does not
occur (a 1e-4 rad lobe at theta = -1.5 keeps all its digits).

When c is far from a narrow lobe (a table whose lobe is not at the mirror), the shift
cancels large terms: ``shift_amplification`` measures by how much, and the table path then
recomputes those sums about the mean (``integrate.centred_view_sums``).
"""

from __future__ import annotations

from math import comb

import numpy as np

PROFILE_KEYS = (
    "alpha",
    "mu_theta",
    "mu_phi",
    "sigma_tt",
    "sigma_tp",
    "sigma_pp",
    "skew_30",
    "skew_21",
    "skew_12",
    "skew_03",
    "kurt_40",
    "kurt_31",
    "kurt_22",
    "kurt_13",
    "kurt_04",
)
CHANNELS = ("r", "g", "b", "avg")

# Keys needed for each maximum order; lower orders are always present.
KEYS_BY_ORDER = {0: PROFILE_KEYS[:1], 1: PROFILE_KEYS[:3], 2: PROFILE_KEYS[:6], 3: PROFILE_KEYS[:10], 4: PROFILE_KEYS}


def exponents(max_order: int):
    """(n, m) pairs with n + m <= max_order, ordered by total order."""
    return [(k - m, m) for k in range(max_order + 1) for m in range(k + 1)]


def n_monomials(max_order: int) -> int:
    return (max_order + 1) * (max_order + 2) // 2


def monomials(x, phi, max_order: int, dtype=float):
    """Array (..., n_monomials) of x^n phi^m in ``exponents`` order."""
    x = np.asarray(x)
    phi = np.asarray(phi)
    px = [np.ones_like(x, dtype=dtype)]
    pp = [np.ones_like(phi, dtype=dtype)]
    for _ in range(max_order):
        px.append(px[-1] * x)
        pp.append(pp[-1] * phi)
    return np.stack([px[n] * pp[m] for n, m in exponents(max_order)], axis=-1)


# (1e-8 rad)^2: 100x narrower than the finest panel of the function rules, 10^4x narrower
# than a MERL cell at the mirror.
VARIANCE_FLOOR = 1e-16


def shift_amplification(sums, max_order: int = 4, tiny: float = 1e-300):
    """Error amplification of the binomial shift to the mean, per sum set (leading axes).

    For the highest even order n on each axis: sum_i C(n, i) |E[x^i]| |dx|^(n-i) divided by
    the central moment it produces. The relative error of the shifted moment is about this
    times the relative error of the raw sums; 1 means no cancellation at all. Sets without
    energy give 1 (nothing to shift), a non-positive central moment gives inf.
    """
    sums = np.asarray(sums, dtype=float)
    if max_order < 2:
        return np.ones(sums.shape[:-1])
    n = 4 if max_order >= 4 else 2
    idx = {e: i for i, e in enumerate(exponents(max_order))}
    alpha = sums[..., 0]
    ok = np.isfinite(alpha) & (alpha > tiny)
    raw = sums / np.where(ok, alpha, 1.0)[..., None]
    worst = np.ones(sums.shape[:-1])
    for axis in ((1, 0), (0, 1)):

        def raw_moment(i):
            return raw[..., idx[(axis[0] * i, axis[1] * i)]]

        d = raw_moment(1)
        terms = [comb(n, i) * raw_moment(i) * (-d) ** (n - i) for i in range(n + 1)]
        central = sum(terms)
        magnitude = sum(np.abs(t) for t in terms)
        with np.errstate(divide="ignore", invalid="ignore"):
            amp = np.where(central > 0, magnitude / np.where(central > 0, central, 1.0), np.inf)
        worst = np.maximum(worst, np.where(ok, amp, 1.0))
    return worst


def profiles_from_sums(sums, centre, max_order: int = 4, tiny: float = 1e-300, centre_phi=0.0):
    """Moment profiles from raw sums.

    ``sums``: (..., n_monomials) raw sums about (centre, centre_phi); the centres broadcast
    against the leading axes. Returns a dict key -> array. Quantities that are undefined (no energy, or a
    zero variance for a standardized moment) are NaN here; exporters turn them into null.
    """
    sums = np.asarray(sums, dtype=float)
    idx = {e: i for i, e in enumerate(exponents(max_order))}
    alpha = sums[..., 0]
    has_energy = alpha > tiny
    safe_alpha = np.where(has_energy, alpha, 1.0)
    out = {"alpha": np.where(np.isfinite(alpha), alpha, np.nan)}
    if max_order < 1:
        return out
    raw = sums / safe_alpha[..., None]  # E[x^n phi^m] about the centre
    dx = raw[..., idx[(1, 0)]]
    mphi = raw[..., idx[(0, 1)]]
    undefined = ~has_energy
    out["mu_theta"] = np.where(undefined, np.nan, np.asarray(centre) + dx)
    out["mu_phi"] = np.where(undefined, np.nan, np.asarray(centre_phi) + mphi)
    if max_order < 2:
        return out

    def central(n, m):
        # E[(x - dx)^n (phi - mphi)^m] by the binomial expansion of both factors.
        total = 0.0
        for i in range(n + 1):
            for j in range(m + 1):
                coef = comb(n, i) * comb(m, j)
                total = total + coef * raw[..., idx[(i, j)]] * (-dx) ** (n - i) * (-mphi) ** (m - j)
        return total

    stt, stp, spp = central(2, 0), central(1, 1), central(0, 2)
    # Round-off can leave a tiny negative variance for a lobe narrower than the rule; clamp.
    stt = np.maximum(stt, 0.0)
    spp = np.maximum(spp, 0.0)
    out["sigma_tt"] = np.where(undefined, np.nan, stt)
    out["sigma_tp"] = np.where(undefined, np.nan, stp)
    out["sigma_pp"] = np.where(undefined, np.nan, spp)
    if max_order < 3:
        return out
    st = np.sqrt(stt)
    sp = np.sqrt(spp)
    # Below the floor a lobe is a point (narrower than any rule resolves): its variance is
    # round-off, and a shape divided by it would be noise. Undefined, like a zero variance.
    t_ok = has_energy & (stt > VARIANCE_FLOOR)
    p_ok = has_energy & (spp > VARIANCE_FLOOR)

    def standardized(n, m):
        ok = (t_ok if n else has_energy) & (p_ok if m else has_energy)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            v = central(n, m) / (np.where(ok, st, 1.0) ** n * np.where(ok, sp, 1.0) ** m)
        return np.where(ok & np.isfinite(v), v, np.nan)

    for n, m in ((3, 0), (2, 1), (1, 2), (0, 3)):
        out[f"skew_{n}{m}"] = standardized(n, m)
    if max_order < 4:
        return out
    excess = {(4, 0): 3.0, (3, 1): 0.0, (2, 2): 1.0, (1, 3): 0.0, (0, 4): 3.0}
    for (n, m), sub in excess.items():
        out[f"kurt_{n}{m}"] = standardized(n, m) - sub
    return out
