"""How close any node setup could come to a table: the best BRDF error (``lobes.measure``'s) of
a mix of closure shapes whose colours follow the view, each view solved on its own (issue 28).

Outside OSL a node tree cannot see the light direction: only closures shape the BRDF across
incoming directions, and the tree sets their colours and parameters, at most per view (a
lookup indexed by the view angle, as ``core.material.lobes`` does). So for every view the best such
setup is a combination of closure shapes, and the best over all setups is bounded below by the
least-squares fit of the table, view by view, over every shape in a dense set: the one here
holds, at 18 roughness values from 0.01 to 1 (those of ``lobes.DICTIONARY`` among them),

- Lambert (Diffuse, every Blender);
- GGX and Beckmann reflection (Glossy, Anisotropic), round and stretched across or along the
  plane of incidence (aspects 0.5 to 6, those of ``lobes.ASPECTS`` among them);
- the same two, round, times Schlick's (1 - wi.h)^5, and of either sign times 4.x's F82 term
  (wi.h)(1 - wi.h)^6, (wi.h) and (wi.h)²: with the plain lobe they span the Fresnel factor of
  every Principled specular and metal layer, and smooth changes of it with theta_d (a thin
  film's, for one);
- Ashikhmin-Shirley (Glossy);
- 3.4's Velvet (Ashikhmin's velvet, 6 widths) and 3.x's Principled sheen (1 - wi.h)^5;
- 3.4's Oren-Nayar term and 4.x's (Fujii's) s/t term, and the retro-reflection terms of 3.x's
  Principled diffuse ((1 - cos theta_i)^5 times 1, (wi.h)², (wi.h)^4, and (wi.h)² alone),
  the diffuse ones of either sign;
- Toon Glossy cones about the mirror direction (14 sizes from 0.5° to 60°), whose mix is any
  radial profile.

Shapes of either sign relax the bound (a setup cannot subtract them) and only lower it. Not
held: 4.x's Sheen (a tabulated fit) and the Multiscatter GGX's added energy; parameters between
the grid's values (a mix of its neighbours comes close). The bound is per view at
``lobes.ERROR_VIEWS_DEG`` on ``lobes.measure``'s quadrature, so it is directly comparable with
a fit's stated error: ``lobes.fit_lobes`` never states less (bench_nodes: none of 236 tables).
Its lobes are among the shapes, all but the aspects its lookup interpolates between texels,
which a mix of the neighbouring aspects follows closely."""

from __future__ import annotations

import math

import numpy as np

from . import lobes
from .lobes import ERROR_VIEWS_DEG, _nnls_gram, _table_at_views, microfacet_lobe
from .principled import pixel_share

# Blender roughness (alpha = r²) and aspects: the fit's own grids, widened, so that the fit's
# lobes are among the shapes
ROUGHNESS = (0.01, 0.014) + lobes.DICTIONARY
ASPECTS = (0.5, 0.7) + lobes.ASPECTS + (6.0,)
VELVET_SIGMA = (0.1, 0.2, 0.35, 0.5, 0.7, 1.0)
TOON_SIZES_DEG = tuple(float(v) for v in np.geomspace(0.5, 60.0, 14))


def ashikhmin_shirley(alpha, wi, wo):
    """Cycles' isotropic Ashikhmin-Shirley glossy: (n + 1) / (8 pi) (n.h)^n / ((wi.h) max(cos_i,
    cos_o)), n = 2 / alpha² - 2."""
    n = max(2.0 / max(alpha, 1e-4) ** 2 - 2.0, 0.0)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    hi = np.maximum(np.abs(np.sum(wi * h, axis=-1)), 1e-6)
    top = np.maximum(np.maximum(wi[..., 2], wo[..., 2]), 1e-6)
    return (n + 1.0) / (8.0 * np.pi) * np.clip(h[..., 2], 0.0, 1.0) ** n / (hi * top)


def velvet_distribution(sigma, cos_h):
    """Ashikhmin's velvet distribution exp(-cot² theta_h / sigma²) / (pi sigma² sin⁴ theta_h)."""
    s2 = np.maximum(1.0 - cos_h * cos_h, 1e-300)
    return np.exp(-(cos_h * cos_h / s2) / sigma**2) / (np.pi * sigma**2 * s2 * s2)


def velvet(sigma, wi, wo):
    """Cycles 3.4's Velvet: D G / (4 cos_i cos_o) with ``velvet_distribution`` and its
    V-cavity G = min(1, 2 (n.h) min(cos_i, cos_o) / (wo.h))."""
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    ci, co = np.clip(wi[..., 2], 1e-9, 1.0), np.clip(wo[..., 2], 1e-9, 1.0)
    nh = np.clip(h[..., 2], 0.0, 1.0 - 1e-9)
    ho = np.clip(np.sum(wo * h, axis=-1), 1e-9, 1.0)
    g = np.minimum(1.0, 2.0 * nh / ho * np.minimum(ci, co))
    return velvet_distribution(sigma, nh) * g / (4.0 * ci * co)


def closure_shapes(wi, wo, shadowing="correlated"):
    """The shapes at directions ``wi`` (n, 3) for one view ``wo`` (3,): (rows (m, n), signed (m,)
    True where the row may enter with either sign)."""
    wo_b = np.broadcast_to(wo, wi.shape)
    h = wi + wo_b
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    hd = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
    schlick, f82 = (1.0 - hd) ** 5, hd * (1.0 - hd) ** 6
    ci, co = np.clip(wi[:, 2], 1e-9, 1.0), float(np.clip(wo[2], 1e-9, 1.0))
    rows, signed = [np.full(len(wi), 1.0 / np.pi)], [False]

    def add(row, either=False):
        rows.append(row)
        signed.append(either)

    q = np.asarray(ASPECTS, float)[:, None]
    for r in ROUGHNESS:
        for dist in ("ggx", "beckmann"):
            stretched = np.broadcast_to(microfacet_lobe(dist, r * r, wi, wo_b, shadowing, q), (len(q), len(wi)))
            for row in stretched:
                add(row)
            lobe = stretched[ASPECTS.index(1.0)]  # the round lobe
            add(lobe * schlick)
            for fresnel in (f82, hd, hd * hd):
                add(lobe * fresnel, either=True)
        add(ashikhmin_shirley(r * r, wi, wo_b))
    for s in VELVET_SIGMA:
        add(velvet(s, wi, wo_b))
    add(schlick)  # 3.x Principled sheen
    # diffuse terms: Oren-Nayar (3.4), Fujii's s / t (4.x), Principled v1's retro-reflection
    ti, to = np.arccos(ci), math.acos(co)
    cos_dphi = np.cos(np.arctan2(wi[:, 1], wi[:, 0]) - math.atan2(wo[1], wo[0]))
    add(np.maximum(cos_dphi, 0.0) * np.sin(np.maximum(ti, to)) * np.tan(np.minimum(ti, to)) / np.pi)
    s = wi @ wo - ci * co
    add(np.where(s > 0.0, s / np.maximum(ci, co), s) / np.pi, either=True)
    fl = (1.0 - ci) ** 5
    for row in (fl, fl * hd**2, fl * hd**4, hd**2):
        add(row, either=True)
    mirror = np.array([-wo[0], -wo[1], wo[2]])
    angle = np.degrees(np.arccos(np.clip(wi @ mirror, -1.0, 1.0)))
    for size in TOON_SIZES_DEG:
        add((angle < size) / ci)
    return np.stack(rows), np.array(signed)


def node_bound(table, views_deg=ERROR_VIEWS_DEG, shadowing="correlated"):
    """The least BRDF error (``lobes.measure``'s weighting) any view-dependent mix of
    ``closure_shapes`` reaches on ``table``: per view and channel, non-negative least squares
    (signed shapes doubled), the residuals pooled as ``measure`` pools them."""
    num = den = 0.0
    for deg, wi, wo, w, rho in _table_at_views(table, views_deg):
        F, signed = closure_shapes(wi, wo, shadowing)
        F = np.concatenate([F, -F[signed]])
        # each shape scaled to unit norm: sharp lobes are 1e6 times a diffuse term, and the
        # normal equations would lose the small shapes to rounding
        F = F / np.maximum(np.sqrt((F * F) @ w), 1e-300)[:, None]
        G = (F * w) @ F.T + 1e-12 * np.eye(len(F))
        b = (rho * w) @ F.T
        res = 0.0
        for c in range(rho.shape[0]):
            x = _nnls_gram(G, b[c])
            res += float(np.sum(w * (x @ F - rho[c]) ** 2))
        share = pixel_share(deg)
        num += share * res
        den += share * float(np.sum(w * rho**2))
    return math.sqrt(num / den) if den > 0 else 0.0
