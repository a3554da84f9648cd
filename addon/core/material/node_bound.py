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
- the same two, round, times the Fresnel factors of theta_d Blender's layers draw: in 4.x the
  metal's (Schlick's with a white F82 tint, and its deepest dip with a black one) and the
  dielectric specular's (IOR 1.1, 1.5, 1.8); in 3.x Principled v1's normalised dielectric
  factor at those IORs (the fit's Fresnel lobe among them);
- Ashikhmin-Shirley (Glossy);
- Velvet (3.x's Velvet BSDF, 4.x's Sheen BSDF with the Ashikhmin distribution: Ashikhmin's
  velvet, the fit's 6 widths) and 3.x's Principled sheen (1 - wi.h)^5;
- Diffuse with roughness (the classic Oren-Nayar at its roughest, Fujii's at roughness 1: with
  Lambert they span every roughness; 4.x adds to Fujii's a multiple-scattering term that grows
  with the colour, so there the single-scattering shape is what a dark rough Diffuse tends to,
  a shade under what it draws: the bound stays a lower bound) and 3.x's Principled diffuse at
  five roughness values;
- Toon Glossy cones about the mirror direction (14 sizes from 0.5° to 60°), whose mix is any
  radial profile.

Every shape is a closure's own, non-negative, and a mix adds them with non-negative weights:
the bound is what a node tree of these closures reaches, not less. (Until 12-07 the Fresnel
and diffuse terms entered as a basis of either sign, mu (1 - mu)^6, mu, mu² times a lobe: a
signed combination draws a lobe dimmer than zero in places, which no closure does, and it
put the bound up to 7.9 points under what these closures reach, bench_nodes' 236 tables;
ilm_l3_37_matte σ̃² ×2: 5.0 against 10.8 %.) Not held: 4.x's
Sheen (a tabulated fit), its thin film, the Multiscatter GGX's added energy; parameters between
the grid's values (a mix of its neighbours comes close). The bound is per view at
``lobes.ERROR_VIEWS_DEG`` on ``lobes.measure``'s quadrature, so it is directly comparable with
a fit's stated error: ``lobes.fit_lobes`` never states less (bench_nodes: none of 236 tables).
Its lobes are among the shapes, all but the aspects its lookup interpolates between texels,
which a mix of the neighbouring aspects follows closely."""

from __future__ import annotations

import math

import numpy as np

from . import lobes
from .lobes import ERROR_VIEWS_DEG, VELVET_SIGMA, _nnls_gram, _table_at_views, microfacet_lobe, velvet
from .principled import pixel_share

# Blender roughness (alpha = r²) and aspects: the fit's own grids, widened, so that the fit's
# lobes are among the shapes
ROUGHNESS = (0.01, 0.014) + lobes.DICTIONARY
ASPECTS = lobes.ASPECTS + (6.0,)  # 0.5 to 6
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


F82_MU = 1.0 / 7.0  # where mu (1 - mu)^6 peaks: 4.x's F82 tint sets the metal's Fresnel there
DIELECTRIC_IOR = (1.1, 1.5, 1.8)  # a Principled specular layer over a black base (3.x: up to 1.8)


def closure_shapes(wi, wo, shadowing="correlated"):
    """The shapes at directions ``wi`` (n, 3) for one view ``wo`` (3,): rows (m, n), each a closure
    Blender draws (its colour or a Mix Shader's factor the weight), so each is non-negative and
    a mix is a non-negative sum of them. ``shadowing``: the Blender, as ``lobes.shadowing_for``
    names it ("correlated": 4.x, "separable": 3.x)."""
    wo_b = np.broadcast_to(wo, wi.shape)
    h = wi + wo_b
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    mu = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)  # cos theta_d
    schlick = (1.0 - mu) ** 5
    dielectric = [lobes._fresnel_dielectric(mu, eta) for eta in DIELECTRIC_IOR]
    if shadowing == "correlated":
        # 4.x: the metal's F82-tint Fresnel F0 + (1 - F0)(1 - mu)^5 - b mu (1 - mu)^6 spans,
        # with the plain lobe, Schlick's (black base, white tint) and the deepest dip (white
        # base, black tint: zero at F82_MU); the specular layer over a black base, dielectric
        fresnel = [schlick, 1.0 - mu * (1.0 - mu) ** 6 / (F82_MU * (1.0 - F82_MU) ** 6)] + dielectric
    else:
        # 3.x: Principled v1 normalises the dielectric Fresnel, (F - F0) / (1 - F0), for its
        # metal and its specular alike (``lobes.fresnel_factor`` at 1.5)
        fresnel = [lobes.principled_v1_factor(mu, eta) for eta in DIELECTRIC_IOR]
    ci, co = np.clip(wi[:, 2], 1e-9, 1.0), float(np.clip(wo[2], 1e-9, 1.0))
    lambert = np.full(len(wi), 1.0 / np.pi)
    rows = [lambert]
    q = np.asarray(ASPECTS, float)[:, None]
    for r in ROUGHNESS:
        for dist in ("ggx", "beckmann"):
            stretched = np.broadcast_to(microfacet_lobe(dist, r * r, wi, wo_b, shadowing, q), (len(q), len(wi)))
            rows.extend(stretched)
            lobe = stretched[ASPECTS.index(1.0)]  # Fresnel layers are round
            rows.extend(lobe * f for f in fresnel)
        rows.append(ashikhmin_shirley(r * r, wi, wo_b))
    rows.extend(velvet(s, wi, wo_b) for s in VELVET_SIGMA)
    rows.append(schlick)  # 3.x Principled sheen
    # Diffuse BSDF with roughness: the classic Oren-Nayar at sigma -> inf (A 0.5, B 0.45) and
    # Fujii's at roughness 1 (A = B), each with Lambert spanning every roughness between
    ti, to = np.arccos(ci), math.acos(co)
    cos_dphi = np.cos(np.arctan2(wi[:, 1], wi[:, 0]) - math.atan2(wo[1], wo[0]))
    oren_nayar = np.maximum(cos_dphi, 0.0) * np.sin(np.maximum(ti, to)) * np.tan(np.minimum(ti, to)) / np.pi
    rows.append(0.5 * lambert + 0.45 * oren_nayar)
    s = wi @ wo - ci * co
    rows.append(lambert + np.where(s > 0.0, s / np.maximum(ci, co), s) / np.pi)
    # 3.x Principled diffuse: (1 + (FD90 - 1) FL)(1 + (FD90 - 1) FV), FD90 = 0.5 + 2 r mu²
    fl, fv = (1.0 - ci) ** 5, (1.0 - co) ** 5
    for rough in (0.0, 0.25, 0.5, 0.75, 1.0):
        fd90 = 0.5 + 2.0 * rough * mu * mu
        rows.append(lambert * (1.0 + (fd90 - 1.0) * fl) * (1.0 + (fd90 - 1.0) * fv))
    mirror = np.array([-wo[0], -wo[1], wo[2]])
    angle = np.degrees(np.arccos(np.clip(wi @ mirror, -1.0, 1.0)))
    rows.extend((angle < size) / ci for size in TOON_SIZES_DEG)
    return np.stack(rows)


def node_bound(table, views_deg=ERROR_VIEWS_DEG, shadowing="correlated"):
    """The least BRDF error (``lobes.measure``'s weighting) any view-dependent mix of
    ``closure_shapes`` reaches on ``table``: per view and channel, non-negative least squares
    the residuals pooled as ``measure`` pools them."""
    num = den = 0.0
    for deg, wi, wo, w, rho in _table_at_views(table, views_deg):
        F = closure_shapes(wi, wo, shadowing)
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
