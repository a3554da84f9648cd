"""Quadrature rules over a BRDF slice in the paper's (theta, phi) measure.

The half-vector rule integrates in MERL's own coordinates: u = sqrt(theta_h / (pi/2)) and
phi_h, for a fixed view. Panels in u coincide with the table's theta_h cells, so the narrow
cells around the mirror direction (where a glossy lobe puts all its energy) are integrated
cell by cell instead of being missed by a uniform grid. For a fixed view the rule is
material independent, which is what makes it cacheable.

Change of variables, for w_i = reflect(w_o about h):
    d(theta) d(phi) = dw_i / cos(phi_i),   dw_i = 4 (w_o . h) dw_h,
    dw_h = sin(theta_h) d(theta_h) d(phi_h),   d(theta_h) = pi u du.
The horizon w_i.z = 0 is hit on each phi_h ray at a closed-form theta_h, so the domain
boundary is integrated exactly rather than by masking.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .geometry import HALF_PI, view_centred_angles

RES_TH = 90


@dataclass
class SliceRule:
    """Nodes of one slice: view-centred angles, weights in d(theta)d(phi), and the
    Rusinkiewicz angles of each node (for table lookups)."""

    theta: np.ndarray
    phi: np.ndarray
    weight: np.ndarray
    theta_h: np.ndarray
    theta_d: np.ndarray
    phi_d: np.ndarray


def horizon_theta_h(theta_o, phi_h):
    """Largest theta_h along the ray phi_h for which the mirrored w_i stays above the horizon.

    w_i.z = sin(theta_o) cos(phi_h) sin(2 theta_h) + cos(theta_o) cos(2 theta_h).
    """
    psi = np.arctan2(np.sin(theta_o) * np.cos(phi_h), np.cos(theta_o))
    return 0.5 * (HALF_PI + psi)


def half_vector_rule(theta_o: float, n_phi: int = 360, n_gauss: int = 3, u_edges=None) -> SliceRule:
    """Tensor rule in (u, phi_h) for the view m(theta_o, 0).

    ``u_edges`` are the panel edges in u (default: the 90 MERL theta_h cells). Each panel
    gets ``n_gauss`` Gauss-Legendre nodes, clipped at the horizon; phi_h uses the periodic
    midpoint rule with ``n_phi`` rays.
    """
    if u_edges is None:
        u_edges = np.linspace(0.0, 1.0, RES_TH + 1)
    u_edges = np.asarray(u_edges, dtype=float)
    xg, wg = gauss_legendre(n_gauss)
    phi_h = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    u_max = np.sqrt(horizon_theta_h(theta_o, phi_h) / HALF_PI)  # (n_phi,)

    lo = u_edges[:-1][None, :]
    hi = np.minimum(u_edges[1:][None, :], u_max[:, None])  # (n_phi, n_panels)
    keep = hi > lo
    ray, panel = np.nonzero(keep)
    a, b = lo[0, panel], hi[ray, panel]
    half = 0.5 * (b - a)
    u = (a + half)[:, None] + half[:, None] * xg[None, :]  # (n_seg, n_gauss)
    wu = half[:, None] * wg[None, :]
    ph = np.broadcast_to(phi_h[ray][:, None], u.shape)

    theta_h = HALF_PI * u * u
    sh, ch = np.sin(theta_h), np.cos(theta_h)
    cph, sph = np.cos(ph), np.sin(ph)
    h = np.stack((sh * cph, sh * sph, ch), axis=-1)
    wo = np.array([np.sin(theta_o), 0.0, np.cos(theta_o)])
    # Spelled out, not h @ wo: matmul may take a BLAS (FMA) path or not depending on memory
    # alignment, and the cached operator must be bit-identical to a fresh build.
    cos_d = h[..., 0] * wo[0] + h[..., 2] * wo[2]
    wi = 2.0 * cos_d[..., None] * h - wo
    cos_phi_i = np.sqrt(np.maximum(wi[..., 0] ** 2 + wi[..., 2] ** 2, 1e-300))
    weight = wu * (2.0 * np.pi / n_phi) * (np.pi * u) * sh * 4.0 * cos_d / cos_phi_i

    theta, phi = view_centred_angles(wi)
    # Difference vector: w_i rotated by -phi_h about z, then -theta_h about y.
    x1 = cph * wi[..., 0] + sph * wi[..., 1]
    y1 = -sph * wi[..., 0] + cph * wi[..., 1]
    z1 = wi[..., 2]
    dx = ch * x1 - sh * z1
    dz = sh * x1 + ch * z1
    theta_d = np.arccos(np.clip(dz, -1.0, 1.0))
    phi_d = np.arctan2(y1, dx)
    return SliceRule(theta.ravel(), phi.ravel(), weight.ravel(), theta_h.ravel(), theta_d.ravel(),
                     phi_d.ravel())


@lru_cache(maxsize=None)
def gauss_legendre(n: int):
    """Gauss-Legendre nodes and weights on [-1, 1], computed once per order (numpy's
    leggauss solves an eigenproblem each call; per-view node sets call it hundreds of times)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w


def graded_edges(centre: float, lo: float, hi: float, r0: float, ratio: float = 1.5):
    """Panel edges on [lo, hi], geometric in distance from ``centre`` (fine at the peak)."""
    centre = float(np.clip(centre, lo, hi))
    edges = [centre]
    for side, bound in ((-1.0, lo), (1.0, hi)):
        r = r0
        span = abs(bound - centre)
        while r < span:
            edges.append(centre + side * r)
            r *= ratio
        edges.append(bound)
    return np.unique(np.asarray(edges))


def graded_tensor_rule(centre_theta, centre_phi, r0, n_gauss=8, ratio=1.5):
    """Tensor Gauss-Legendre rule on [-pi/2, pi/2]^2 graded around a peak.

    Used for slices given as functions, whose peak may sit anywhere and be as narrow as
    1e-4 rad: panels grow geometrically from width r0 at the peak.
    """
    xg, wg = gauss_legendre(n_gauss)

    def axis(c):
        e = graded_edges(c, -HALF_PI, HALF_PI, r0, ratio)
        half = 0.5 * np.diff(e)
        mid = 0.5 * (e[1:] + e[:-1])
        return (mid[:, None] + half[:, None] * xg).ravel(), (half[:, None] * wg).ravel()

    t, wt = axis(centre_theta)
    p, wp = axis(centre_phi)
    return t, wt, p, wp


def _fade(u, ua, ub):
    """1 below ua, 0 above ub, quintic smoothstep between (C2, so both rules stay accurate)."""
    t = np.clip((u - ua) / (ub - ua), 0.0, 1.0)
    return 1.0 - t * t * t * (t * (6.0 * t - 15.0) + 10.0)


@dataclass(frozen=True)
class RuleParams:
    """Resolution of the hybrid slice rule (defaults chosen by the benchmark)."""

    n_phi: int = 1440         # half-vector rays
    n_gauss: int = 3          # Gauss nodes per theta_h cell on a ray
    fade_from: float = 60.0   # |phi| (deg) where the half-vector part starts to fade out
    fade_to: float = 75.0     # ... and where it is gone: the poles (|phi| = 90) never see it
    n_panels: int = 192       # tensor panels along theta in the pole strips
    n_panels_phi: int = 32    # ... and along phi, per strip
    n_gauss_far: int = 4

    def key(self):
        return (self.n_phi, self.n_gauss, self.fade_from, self.fade_to, self.n_panels, self.n_panels_phi,
                self.n_gauss_far)


def _composite(lo, hi, panels, n_gauss):
    xg, wg = gauss_legendre(n_gauss)
    e = np.linspace(lo, hi, panels + 1)
    half = 0.5 * np.diff(e)
    mid = 0.5 * (e[1:] + e[:-1])
    return (mid[:, None] + half[:, None] * xg).ravel(), (half[:, None] * wg).ravel()


def slice_rule(theta_o: float, params: RuleParams = RuleParams()) -> SliceRule:
    """Hybrid rule for the view m(theta_o, 0): exact for constants to ~1e-6 at any view.

    The half-vector rule covers the whole slice, all 90 theta_h cells resolved, except near
    the parametrization's poles w_i = +-y, where its Jacobian 1/cos(phi_i) blows up. There a
    tensor Gauss rule over the strips |phi| > fade_from in (theta, phi) takes over: it needs
    no Jacobian. A smooth (C2) partition of unity in |phi| joins the two.
    """
    from .geometry import half_diff_from_directions, view_centred

    a, b = np.radians(params.fade_from), np.radians(params.fade_to)
    near = half_vector_rule(theta_o, params.n_phi, params.n_gauss)
    w_near = near.weight * _fade(np.abs(near.phi), a, b)
    keep = w_near > 0.0

    t, wt = _composite(-HALF_PI, HALF_PI, params.n_panels, params.n_gauss_far)
    p1, wp1 = _composite(a, HALF_PI, params.n_panels_phi, params.n_gauss_far)
    p, wp = np.concatenate((p1, -p1)), np.concatenate((wp1, wp1))
    T, P = np.meshgrid(t, p, indexing="ij")
    w_far = np.outer(wt, wp) * (1.0 - _fade(np.abs(P), a, b))
    wi = view_centred(T, P)
    th, td, pd = half_diff_from_directions(wi, np.broadcast_to(view_centred(theta_o, 0.0), wi.shape))
    far = w_far > 0.0
    return SliceRule(
        np.concatenate((near.theta[keep], T[far])),
        np.concatenate((near.phi[keep], P[far])),
        np.concatenate((w_near[keep], w_far[far])),
        np.concatenate((near.theta_h[keep], th[far])),
        np.concatenate((near.theta_d[keep], td[far])),
        np.concatenate((near.phi_d[keep], pd[far])),
    )
