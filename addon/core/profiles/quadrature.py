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

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from ..geometry import HALF_PI, view_centred_angles

RES_TH, RES_TD, RES_PD = 90, 90, 180


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


def _ray_breaks(theta_o, phi_h, th_max):
    """theta_h at which each ray phi_h crosses a theta_d or phi_d cell edge: (n_rays, K),
    with th_max where a candidate does not exist or lies outside (0, th_max).

    In the half-vector frame w_o is d_o = (R cos(theta_h + psi2), y', R cos(theta_h - psi)),
    with y' = -sin(theta_o) sin(phi_h) constant along the ray. So theta_d = const is
    cos(theta_h - psi) = cos(theta_d) / R, and phi_d = c (mod pi, the table's fold) is the
    line sin(c) x' = cos(c) y', i.e. cos(theta_h + psi2) = y' cot(c) / R: both closed form.
    """
    a = np.sin(theta_o) * np.cos(phi_h)
    b = np.cos(theta_o)
    r = np.hypot(a, b)[:, None]
    psi = np.arctan2(a, b)[:, None]
    psi2 = np.arctan2(b, a)[:, None]
    yp = (-np.sin(theta_o) * np.sin(phi_h))[:, None]
    out = []
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.cos(np.arange(1, RES_TD) * (HALF_PI / RES_TD))[None, :] / r
        acos = np.arccos(v)  # NaN where the edge is not reached
        out += [psi - acos, psi + acos]
        c = np.arange(1, RES_PD) * (np.pi / RES_PD)
        v = yp * (np.cos(c) / np.sin(c))[None, :] / r
        acos = np.arccos(v)
        out += [acos - psi2, 2.0 * np.pi - acos - psi2]
    t = np.concatenate(out, axis=1)
    tmax = th_max[:, None]
    return np.where((t > 0.0) & (t < tmax), t, tmax)


def _ray_segments(theta_o, phi_h, u_max, u_edges, exact):
    """(ray, a, b): the pieces in u of each ray between consecutive breaks."""
    n = len(phi_h)
    cols = [np.broadcast_to(u_edges[None, :], (n, len(u_edges)))]
    if exact:
        th = _ray_breaks(theta_o, phi_h, HALF_PI * u_max * u_max)
        cols.append(np.sqrt(th / HALF_PI))
    br = np.minimum(np.concatenate(cols, axis=1), u_max[:, None])
    br.sort(axis=1)
    lo, hi = br[:, :-1], br[:, 1:]
    ray, j = np.nonzero(hi > lo)
    return ray, lo[ray, j], hi[ray, j]


def _ray_nodes(theta_o, phi_h, dphi, u_edges, xg, wg, exact):
    """The half-vector rule in (u, phi_h) for the view m(theta_o, 0), on the rays ``phi_h``
    (each of width ``dphi`` in the midpoint rule).

    Panels in u: ``u_edges`` (the 90 MERL theta_h cells) and, with ``exact``, also every point
    where a ray crosses a theta_d or phi_d cell edge, so a nearest-cell table is constant on
    each piece and each ray's integral is exact to Gauss order (only the phi_h direction is a
    quadrature, of a continuous function). Gauss-Legendre nodes (xg, wg) on each piece,
    which ends at the horizon.
    """
    u_max = np.sqrt(horizon_theta_h(theta_o, phi_h) / HALF_PI)  # (n_phi,)
    ray, a, b = _ray_segments(theta_o, phi_h, u_max, u_edges, exact)
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
    weight = wu * dphi * (np.pi * u) * sh * 4.0 * cos_d / cos_phi_i

    theta, phi = view_centred_angles(wi)
    # Difference vector: w_i rotated by -phi_h about z, then -theta_h about y.
    x1 = cph * wi[..., 0] + sph * wi[..., 1]
    y1 = -sph * wi[..., 0] + cph * wi[..., 1]
    z1 = wi[..., 2]
    dx = ch * x1 - sh * z1
    dz = sh * x1 + ch * z1
    theta_d = np.arccos(np.clip(dz, -1.0, 1.0))
    phi_d = np.arctan2(y1, dx)
    return SliceRule(theta.ravel(), phi.ravel(), weight.ravel(), theta_h.ravel(), theta_d.ravel(), phi_d.ravel())


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


# Each count and angle of a rule, and its declared range (core.limits.RANGES).
_RULE_RANGES = {
    "n_phi": "rule_lines",
    "n_panels": "rule_lines",
    "n_panels_phi": "rule_lines",
    "n_gauss": "gauss_nodes",
    "n_gauss_far": "gauss_nodes",
    "n_probe": "rule_probes",
    "fade_from": "fade_angle",
    "fade_to": "fade_angle",
}


@dataclass(frozen=True)
class RuleParams:
    """Resolution of the hybrid slice rule (defaults chosen by the benchmark)."""

    n_phi: int = 1440  # half-vector rays
    n_gauss: int = 3  # Gauss nodes per theta_h cell on a ray
    fade_from: float = 60.0  # |phi| (deg) where the half-vector part starts to fade out
    fade_to: float = 75.0  # ... and where it is gone: the poles (|phi| = 90) never see it
    n_panels: int = 192  # tensor panels along theta in the pole strips
    n_panels_phi: int = 64  # ... and along phi, per strip
    n_gauss_far: int = 4
    # Split every line of both rules where it crosses a cell edge (the table is then constant
    # on each piece). False gives the point-sampled rule of operator version 7, for comparison.
    exact: bool = True
    n_probe: int = 2048  # cell probes along each strip line (the bisection starts there)
    # At views from 70 and from 80 deg: these multiples of n_phi and of n_panels_phi (the
    # lines across the slice, whose quadrature is the error left; see slice_rule).
    grazing_rays: tuple = (2, 4)
    grazing_strip: tuple = (2, 2)
    # How the operator reads the table at the rule's nodes: the nearest cell (MERL's own
    # reader), or trilinear between the 8 cells around each node (integrate._build_view).
    interp: str = "nearest"

    def __post_init__(self):
        from ..limits import check

        for name, entry in _RULE_RANGES.items():
            object.__setattr__(self, name, check(entry, getattr(self, name), name))
        if not self.fade_from < self.fade_to:
            raise ValueError(f"fade_to: must be above fade_from ({self.fade_from:g} deg), got {self.fade_to:g}")

    def key(self):
        key = (
            self.n_phi,
            self.n_gauss,
            self.fade_from,
            self.fade_to,
            self.n_panels,
            self.n_panels_phi,
            self.n_gauss_far,
            self.exact,
            self.n_probe,
            self.grazing_rays,
            self.grazing_strip,
        )
        return key if self.interp == "nearest" else key + (self.interp,)  # nearest keys as before


def _composite(lo, hi, panels, n_gauss):
    xg, wg = gauss_legendre(n_gauss)
    e = np.linspace(lo, hi, panels + 1)
    half = 0.5 * np.diff(e)
    mid = 0.5 * (e[1:] + e[:-1])
    return (mid[:, None] + half[:, None] * xg).ravel(), (half[:, None] * wg).ravel()


def _strip_cells(theta_o):
    from ..file.merl import cell_indices_view

    se, ce = np.sin(theta_o), np.cos(theta_o)
    return lambda theta, phi: cell_indices_view(np.asarray(theta, float), np.asarray(phi, float), se, ce)


def _line_breaks(cells, lines, lo, hi, n_probe, iters=18):
    """Where the cell changes along each line phi = lines[j], theta in [lo, hi]: (line, theta).

    Probes n_probe + 1 points per line, then bisects every probe interval whose ends differ
    down to (hi - lo) / n_probe / 2**iters. A cell that comes and goes between two probes is
    missed (the nodes then point-sample it); at the default spacing of 1.5e-3 rad that is
    only the tips of cells, which are 0.02 rad or more across in the strips.
    """
    t = np.linspace(lo, hi, n_probe + 1)
    ids = np.empty((len(lines), n_probe + 1), dtype=np.int64)
    step = max(1, (1 << 17) // (n_probe + 1))  # the cell lookup's temporaries scale with its input
    for i in range(0, len(lines), step):
        sub = lines[i : i + step]
        ids[i : i + step] = cells(np.tile(t, len(sub)), np.repeat(sub, n_probe + 1)).reshape(len(sub), -1)
    line, j = np.nonzero(ids[:, 1:] != ids[:, :-1])
    left, right, id_left, phi = t[j], t[j + 1], ids[line, j], lines[line]
    for _ in range(iters):
        mid = 0.5 * (left + right)
        same = cells(mid, phi) == id_left
        left = np.where(same, mid, left)
        right = np.where(same, right, mid)
    return line, 0.5 * (left + right)


def _strip_rule(theta_o, params, a, b):
    """Nodes (theta, phi, weight) of the pole strips |phi| > fade_from, faded in by 1 - fade.

    Lines of constant phi at the Gauss nodes of a composite rule in phi; along each line,
    Gauss panels (at most pi / n_panels long) that are split at every cell edge when
    ``params.exact``: the monomials are polynomials in theta there, so each line's integral
    of a nearest-cell table is exact, and only the phi direction is a quadrature.
    """
    p1, wp1 = _composite(a, HALF_PI, params.n_panels_phi, params.n_gauss_far)
    p, wp = np.concatenate((p1, -p1)), np.concatenate((wp1, wp1))
    wp = wp * (1.0 - _fade(np.abs(p), a, b))
    on = wp > 0.0
    p, wp = p[on], wp[on]
    if not params.exact:
        t, wt = _composite(-HALF_PI, HALF_PI, params.n_panels, params.n_gauss_far)
        T, P = np.meshgrid(t, p, indexing="ij")
        return T.ravel(), P.ravel(), np.outer(wt, wp).ravel()
    edges = np.linspace(-HALF_PI, HALF_PI, params.n_panels + 1)
    line, t = _line_breaks(_strip_cells(theta_o), p, -HALF_PI, HALF_PI, params.n_probe)
    line = np.concatenate((line, np.repeat(np.arange(len(p)), len(edges))))
    t = np.concatenate((t, np.tile(edges, len(p))))
    order = np.lexsort((t, line))
    line, t = line[order], t[order]
    seg = np.flatnonzero((line[1:] == line[:-1]) & (t[1:] > t[:-1]))
    lo, hi, ln = t[seg], t[seg + 1], line[seg]
    xg, wg = gauss_legendre(params.n_gauss)
    half = 0.5 * (hi - lo)
    T = (lo + half)[:, None] + half[:, None] * xg[None, :]
    W = (half * wp[ln])[:, None] * wg[None, :]
    return T.ravel(), np.repeat(p[ln], len(xg)), W.ravel()


def slice_rule(theta_o: float, params: RuleParams = RuleParams()) -> SliceRule:
    """Hybrid rule for the view m(theta_o, 0): exact for constants to ~1e-6 at any view.

    The half-vector rule covers the whole slice, all 90 theta_h cells resolved, except near
    the parametrization's poles w_i = +-y, where its Jacobian 1/cos(phi_i) blows up. There a
    tensor Gauss rule over the strips |phi| > fade_from in (theta, phi) takes over: it needs
    no Jacobian. A smooth (C2) partition of unity in |phi| joins the two. With
    ``params.exact`` both rules split their lines at the table's cell edges, so a
    nearest-cell table is integrated exactly along every line (rays in u, strip lines in
    theta); what is left is the quadrature across lines, of a continuous function.
    """
    parts = list(slice_rule_parts(theta_o, params))
    return SliceRule(*(np.concatenate([getattr(p, f) for p in parts]) for f in SliceRule.__dataclass_fields__))


def slice_rule_parts(theta_o: float, params: RuleParams = RuleParams(), chunk: int = 360):
    """``slice_rule`` in pieces (``chunk`` rays at a time, then the strips), in the same node
    order: a grazing view has ~2 M nodes, and building them whole would dominate the peak."""
    from ..geometry import half_diff_from_directions, view_centred

    a, b = np.radians(params.fade_from), np.radians(params.fade_to)
    if params.exact and theta_o >= np.radians(70.0) - 1e-9:
        # Near the mirror the phi_d cell edges run along the rays (phi_d = -phi_h at
        # theta_h = 0) and leave them only slowly at grazing views, as theta_d's edge through
        # the mirror does: the table jumps across slivers of phi_h narrower than the ray
        # spacing, which the midpoint rule resolves at first order. More rays, there only.
        g = int(theta_o >= np.radians(80.0) - 1e-9)
        params = replace(
            params,
            n_phi=params.n_phi * params.grazing_rays[g],
            n_panels_phi=params.n_panels_phi * params.grazing_strip[g],
        )
    u_edges = np.linspace(0.0, 1.0, RES_TH + 1)
    xg, wg = gauss_legendre(params.n_gauss)
    phi_h = (np.arange(params.n_phi) + 0.5) * (2.0 * np.pi / params.n_phi)
    for i in range(0, params.n_phi, chunk):
        near = _ray_nodes(theta_o, phi_h[i : i + chunk], 2.0 * np.pi / params.n_phi, u_edges, xg, wg, params.exact)
        w_near = near.weight * _fade(np.abs(near.phi), a, b)
        keep = w_near > 0.0
        yield SliceRule(
            near.theta[keep], near.phi[keep], w_near[keep], near.theta_h[keep], near.theta_d[keep], near.phi_d[keep]
        )
        del near

    T, P, w_far = _strip_rule(theta_o, params, a, b)
    wi = view_centred(T, P)
    th, td, pd = half_diff_from_directions(wi, np.broadcast_to(view_centred(theta_o, 0.0), wi.shape))
    yield SliceRule(T, P, w_far, th, td, pd)
