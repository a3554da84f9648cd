"""A Principled BSDF fitted to a tabulated BRDF: the edited material where OSL is not available.

Blender's Principled BSDF (GGX distribution, no coat, sheen or transmission) is modelled here as

    rho_c = (1 - m) b_c / pi + F_c(wi.h) D(h) G1(wi) G1(wo) / (4 cos_i cos_o)

with D the GGX distribution of alpha = roughness², G1 separable Smith, F Schlick from
F0_c = (1 - m) s + m b_c (metallic m, base colour b, dielectric reflectance s at normal
incidence). It is an approximation of what Cycles and EEVEE render (their dielectric Fresnel is
not Schlick's, and Blender 4's layering darkens the diffuse under the specular by its albedo);
the rendered error is measured in BENCHMARKS.md, not assumed.

The fit is weighted least squares of the table against the model over the views
theta_o = 0, 5, ..., 80°, each integrated over incoming directions through the half vector on
the table's own square-root spaced theta_h cells (so a mirror-like peak is resolved):
minimises sum over views of w(theta_o) times the integral of (rho_fit - rho)² cos(theta_i)
d omega_i, with w = sin cos theta_o, the share of a sphere's pixels that see that view.
Schlick's Fresnel always reaches 1 at grazing angles, so an edit that scales the specular
energy down is approximated with a smaller reflectance and leaves the grazing rim too bright:
that is the "albedo within" figure the panel states.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..microsurface import masking, ndf, smith_lambda, tan2

DIELECTRIC_MAX = 0.08  # Blender 3.x's "Specular" = 1 is F0 0.08; Blender 4 reaches it through the IOR
VIEWS_DEG = tuple(range(0, 81, 5))
N_PHI_H = 24


@dataclass(frozen=True)
class PrincipledFit:
    base_color: tuple  # linear RGB
    metallic: float
    roughness: float  # Blender's roughness (GGX alpha = roughness²)
    specular: float  # dielectric F0 at normal incidence, 0 to DIELECTRIC_MAX
    error: float  # relative L2 error of the fitted BRDF (cosine-weighted, all channels)
    albedo_error: float  # largest relative error of the directional albedo over the views

    @property
    def ior(self) -> float:
        """The IOR whose normal-incidence reflectance is ``specular`` (Blender 4's inputs)."""
        r = math.sqrt(min(max(self.specular, 1e-8), 0.99))
        return (1.0 + r) / (1.0 - r)

    @property
    def specular_3x(self) -> float:
        """Blender 3.x's "Specular" input (0.5 = F0 0.04)."""
        return self.specular / DIELECTRIC_MAX

    def as_dict(self) -> dict:
        return {
            "base_color": list(self.base_color),
            "metallic": self.metallic,
            "roughness": self.roughness,
            "specular": self.specular,
            "error": self.error,
            "albedo_error": self.albedo_error,
        }


def _lobe_terms(alpha, wi, wo):
    """GGX lobe D G1 G1 / (4 cos cos) and the Schlick weight (1 - wi.h)^5 at ``alpha``."""
    alpha = max(alpha, 1e-7)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    ci = np.clip(wi[..., 2], 1e-9, 1.0)
    co = np.clip(wo[..., 2], 1e-9, 1.0)
    a2 = alpha * alpha
    g = masking(smith_lambda("ggx", a2 * tan2(ci)), smith_lambda("ggx", a2 * tan2(co)), "separable")
    sch = (1.0 - np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)) ** 5
    return ndf("ggx", np.clip(h[..., 2], 0.0, 1.0), alpha) * g / (4.0 * ci * co), sch


def principled_brdf(fit, wi, wo):
    """The model above for a PrincipledFit: (3, ...) for unit vectors (..., 3)."""
    lobe, sch = _lobe_terms(fit.roughness**2, np.asarray(wi, float), np.asarray(wo, float))
    base = np.asarray(fit.base_color, float).reshape((3,) + (1,) * lobe.ndim)
    f0 = (1.0 - fit.metallic) * fit.specular + fit.metallic * base
    return (1.0 - fit.metallic) * base / np.pi + (f0 + (1.0 - f0) * sch) * lobe


def view_quadrature(views_deg, n_phi=N_PHI_H):
    """Per view: (wi (n, 3), wo (3,), weights cos(theta_i) d omega_i), through the half vector,
    one point per theta_h cell of the table (its square-root spacing resolves narrow peaks)."""
    from ..file.merl import theta_h_edges

    edges = theta_h_edges()
    th, dth = 0.5 * (edges[:-1] + edges[1:]), np.diff(edges)
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2.0 * np.pi
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    h = np.stack((np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)), axis=-1).reshape(-1, 3)
    dwh = (np.sin(TH) * dth[:, None] * (2.0 * np.pi / n_phi)).ravel()
    out = []
    for deg in views_deg:
        t = math.radians(deg)
        wo = np.array([math.sin(t), 0.0, math.cos(t)])
        wi, w, ok = reflect_about(h, dwh, wo)
        out.append((wi[ok], wo, w[ok]))
    return out


def reflect_about(h, dwh, wo):
    """``wo`` reflected about each half vector ``h`` (n, 3) of solid angle ``dwh``: (wi, its
    weight cos(theta_i) d omega_i, where wo.h and wi both lie above the surface), with
    d omega_i = 4 (wo.h) d omega_h."""
    oh = h @ wo
    wi = 2.0 * oh[:, None] * h - wo
    return wi, 4.0 * oh * dwh * wi[:, 2], (oh > 0.0) & (wi[:, 2] > 0.0)


def pixel_share(deg):
    """A view's share of a sphere's pixels under an orthographic camera (sin cos theta_o):
    grazing views cover little of the image."""
    t = math.radians(deg)
    return max(math.sin(t), math.sin(math.radians(2.5))) * math.cos(t)


def _quadrature(views_deg=VIEWS_DEG, n_phi=N_PHI_H):
    """Every view's directions (wi, wo) and weights, each view weighted by its pixel share."""
    views = view_quadrature(views_deg, n_phi)
    wis = [wi for wi, _, _ in views]
    wos = [np.broadcast_to(wo, wi.shape) for wi, wo, _ in views]
    ws = [w * pixel_share(deg) for deg, (_, _, w) in zip(views_deg, views)]
    return np.concatenate(wis), np.concatenate(wos), np.concatenate(ws), [len(w) for w in ws]


def _box_qp(A, b, ub, iters=8):
    """min u.A.u - 2 u.b over 0 <= u <= ub (A positive definite, 4 unknowns): an active set,
    variables pinned at a bound while their gradient pushes outward, the rest solved exactly."""
    n = len(b)
    fixed = np.zeros(n, bool)
    u = np.zeros(n)
    for _ in range(iters):
        free = ~fixed
        u_f = u.copy()
        if free.any():
            rhs = b[free] - A[np.ix_(free, fixed)] @ u[fixed]
            u_f[free] = np.linalg.solve(A[np.ix_(free, free)], rhs)
        out = free & ((u_f < 0.0) | (u_f > ub))
        u = np.clip(u_f, 0.0, ub)
        g = A @ u - b  # half the gradient
        release = fixed & (((u <= 0.0) & (g < 0.0)) | ((u >= ub) & (g > 0.0)))
        if not out.any() and not release.any():
            return u
        fixed = (fixed & ~release) | out
    return u


def _map_to_principled(G, r, yy, metal_steps=41):
    """Best (cost, metallic, specular, base) for one roughness.

    Per channel the model is linear in x_c = (diffuse d_c, F0_c): cost_c = x G x - 2 x.r_c + yy_c.
    Principled ties them: d_c = (1 - m) b_c, F0_c = (1 - m) s + m b_c; for each metallic m this
    is linear least squares in (b, s), solved in closed form and clipped to the inputs' ranges."""
    best = None
    for m in np.linspace(0.0, 1.0, metal_steps):
        A = np.zeros((4, 4))
        rhs = np.zeros(4)
        Ms = []
        for c in range(3):
            M = np.zeros((2, 4))
            M[0, c] = 1.0 - m  # d_c (the 1/pi sits in the feature)
            M[1, c], M[1, 3] = m, 1.0 - m
            Ms.append(M)
            A += M.T @ G @ M
            rhs += M.T @ r[c]
        A += 1e-12 * np.trace(A) * np.eye(4) + 1e-300
        # box-constrained least squares: |L^T u - L^-1 rhs|^2 is the cost up to a constant
        ub = np.array([1.0, 1.0, 1.0, 0.0 if m >= 1.0 else DIELECTRIC_MAX])
        u = _box_qp(A, rhs, ub)
        cost = sum(float((M @ u) @ G @ (M @ u) - 2.0 * (M @ u) @ r[c] + yy[c]) for c, M in enumerate(Ms))
        # a grey dielectric and a little metal can be the same BRDF: prefer the dielectric
        if best is None or cost < best[0] - 1e-9 * abs(best[0]) - 1e-15:
            best = (cost, float(m), float(u[3]), tuple(float(v) for v in u[:3]))
    return best


def fit_principled(table) -> PrincipledFit:
    """Fit the Principled model to a MerlTable (missing cells left out): a search over the
    roughness, and for each roughness the other inputs in closed form."""
    from scipy.optimize import minimize_scalar

    from ..file.merl import lookup

    wi, wo, w, sizes = _quadrature()
    rho, valid = lookup(table, wi, wo)
    ok = valid.all(axis=0)
    wi, wo, w, rho = wi[ok], wo[ok], w[ok], rho[:, ok]
    view = np.repeat(np.arange(len(sizes)), sizes)[ok]
    norm2 = float(np.sum(w[None, :] * rho**2)) or 1.0

    def solve(rough, metal_steps=11):
        lobe, sch = _lobe_terms(rough * rough, wi, wo)
        feats = np.stack([np.full_like(lobe, 1.0 / np.pi), lobe * (1.0 - sch)])
        y = rho - lobe * sch
        G = (feats * w) @ feats.T
        r = (y * w) @ feats.T  # (3, 2)
        yy = np.sum(w * y * y, axis=1)
        return _map_to_principled(G, r, yy, metal_steps)

    grid = np.exp(np.linspace(np.log(0.02), 0.0, 25))
    costs = [solve(g)[0] for g in grid]
    k = int(np.argmin(costs))
    lo_r, hi_r = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    res = minimize_scalar(lambda g: solve(g)[0], bounds=(lo_r, hi_r), method="bounded", options={"xatol": 1e-4})
    rough = float(res.x) if res.fun <= costs[k] else float(grid[k])
    cost, metal, spec, base = solve(rough, 51)
    fit = PrincipledFit(base, metal, rough, spec, 0.0, 0.0)
    vals = principled_brdf(fit, wi, wo)
    err = float(np.sqrt(np.sum(w[None, :] * (vals - rho) ** 2) / norm2))
    alb_t = np.stack([np.bincount(view, weights=w * rho[c], minlength=len(sizes)) for c in range(3)])
    alb_f = np.stack([np.bincount(view, weights=w * vals[c], minlength=len(sizes)) for c in range(3)])
    held = alb_t > 1e-3 * max(float(alb_t.max()), 1e-12)
    alb_err = float(np.max(np.abs(alb_f - alb_t)[held] / alb_t[held])) if held.any() else 0.0
    return PrincipledFit(base, metal, rough, spec, err, alb_err)
