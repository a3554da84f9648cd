"""A few GGX lobes and a diffuse lobe with view-dependent colours, fitted to a tabulated BRDF:
the artist's material where OSL is not available (Cycles on a GPU, EEVEE, Debian's 3.4).

The model is what a node tree of Diffuse and Glossy BSDFs (distribution GGX) added together
renders when each closure's colour comes from a small lookup indexed by the view angle:

    rho_c(wi, wo) = W_0c(theta_o) / pi + sum_k W_kc(theta_o) f_k(wi, wo)

with f_k Cycles' GGX reflection of alpha_k = roughness_k² and no Fresnel (the colour is the
weight): D(h) G(wi, wo) / (4 cos_i cos_o). G is what the Cycles of that Blender evaluates:
the height-correlated Smith term 1 / (1 + Lambda_i + Lambda_o) (``bsdf_G`` in
intern/cycles/kernel/closure/bsdf_microfacet.h) in 4.5 and 5.0, the separable product
G1(wi) G1(wo) in Debian's 3.4: both checked by rendering a Glossy sphere under a white sky
(tests/test_artist_material.py for 4.5). The switch came with Cycles' microfacet rewrite, whose
source already has it beside 3.x's Principled v1 Fresnel; ``shadowing_for`` puts it at 3.6
(3.5 and 3.6 themselves not checked). Neither adds multiple-scattering energy (that is the "Multiscatter GGX"
distribution, which the nodes do not use).

The lookup holds W at N_VIEWS view angles theta_j = (j + 1/2) 90° / N_VIEWS (texel centres of
an image indexed by u = theta_o / 90°, linear interpolation, clamped at the ends), so between
two texels the colours are interpolated linearly, as the texture does; the error below is
measured at views between the texels, where that interpolation shows. The lobes are picked
on the views of a lookup half as fine (PICK_VIEWS); the finer lookup costs about 5 % more fit
time and takes up to 1.7 points off where the colours change fast with the view, averaged over
view phases (3.6 at the error views alone; BENCHMARKS.md, "The artist's material").

The fit: for every texel view, the weights are non-negative least squares of the table against
the lobes (cosine-weighted, through the half vector on the table's own theta_h cells, as
``core.material.principled``), with the view's directional albedo as one extra, strongly weighted
equation, so that the energy the artist sees per view is the table's; the diffuse colour is
capped at twice pi times the table's median at that view (``DIFFUSE_QUANTILE``: a metal has no
flat part to lend it). The roughness of the lobes is picked greedily from a dictionary (the
one that lowers the cost most, then the next), the cost summed over views with each view's
share of a sphere's pixels.

A lobe may also be stretched across the plane of incidence or in it, by an aspect q_k(theta_o)
read from the lookup like the colours (alpha sqrt(q) across, alpha / sqrt(q) in the plane; the
nodes give Cycles the tangent N x I and the matching anisotropy). Highlights round about the
mirror direction are stretched across in half vectors, by about 1 / cos theta_o; the broad
lobes of a widened table (σ̃² ×2) lie in the plane (q < 1). After the
roughness values, each lobe's aspect is chosen per view by coordinate descent.

Then a Velvet (Ashikhmin's, 3.x's Velvet BSDF and 4.x's Sheen) and a rough Diffuse (white, at
roughness 1, mixed in by a grey factor) may join them, each where it takes half a point off
the error, and the lobes they made redundant are dropped: the grazing rise and retro-reflection
of broad, widened tables, which no microfacet lobe draws. EEVEE ignores anisotropy and draws
neither as Cycles does: for a scene it renders the lobes are round microfacet lobes
(``closures_for``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..microsurface import DISTRIBUTIONS, masking, smith_lambda, stretched_ndf
from .principled import pixel_share, reflect_about, view_quadrature

N_VIEWS = 36  # texels of the lookup over theta_o in [0, 90°]; ERROR_VIEWS_DEG lie half-way between two
PICK_VIEWS = 18  # the views (texel centres of an 18-texel lookup) where the lobes are picked
N_LOBES = 5  # at most; the fourth and fifth only where they lower the fit's cost by MIN_GAIN
MIN_LOBES = 3
MIN_GAIN = 0.03
N_PHI_H = 24
# Blender roughness (alpha = r²); Cycles treats alpha² <= 1e-7 as a mirror (r < 0.0178).
DICTIONARY = tuple(float(v) for v in np.exp(np.linspace(np.log(0.02), np.log(1.0), 16)))
ERROR_VIEWS_DEG = tuple(range(0, 81, 5))  # where the error is measured (between texels)
ALBEDO_WEIGHT = 30.0  # the albedo equation's weight against the BRDF residual's norm
# The diffuse colour's cap per view: DIFFUSE_OVER times pi times the table's DIFFUSE_QUANTILE
# (cosine weighted) there. A Lambert term is flat over the light's directions; far above the
# table's usual value it adds light wherever the table has next to none, which the BRDF's L2
# error (ruled by the peak) hardly sees but a sphere under a map's lights far from the mirror
# direction shows (issue 37.2: ilm_l3_37_metallic's diffuse colour 0.14 against a median of
# 0.02, its sphere 2-4 times too bright where it mirrors dark walls). A diffuse material's
# colour stays free (its table is flat: the median is about its colour), and the margin leaves
# the greedy pick room to let the diffuse stand in for a broad lobe still to come (at 1x it
# missed the dictionary's own two-lobe tables).
DIFFUSE_QUANTILE = 0.5
DIFFUSE_OVER = 2.0
# A lobe's aspect q per view: its alpha across the plane of incidence over its alpha in it,
# alpha_across = alpha sqrt(q), alpha_in = alpha / sqrt(q) (both Blenders keep alpha_x alpha_y =
# alpha²). A lobe round about the mirror direction, as measured highlights often are, is
# stretched across the plane by about 1 / cos theta_o in half vectors; a widened table's broad
# lobe in it (bench_nodes, σ̃² ×2: ilm_l3_37_matte 33.8 -> 18.4 %, satin_gold 28.3 -> 16.9 %,
# aurora_white 31.6 -> 21.0 % with 0.5 and 0.7; 0.35 added nothing).
ASPECTS = (0.5, 0.7, 1.0, 1.3, 1.7, 2.2, 3.0, 4.0)
ASPECT_RANGE = (0.1, 10.0)  # what a stored fit may hold (the dictionary's and some margin)
SHADOWING = ("correlated", "separable")
# What a lobe is drawn with (``KINDS``): a Glossy BSDF of either distribution, its colour the
# weight; or a Principled BSDF (metallic 1, base colour black, GGX) mixed in by a Mix Shader
# whose factor is the weight: a GGX lobe times the Principled's Fresnel factor of theta_d
# (``fresnel_factor``), grey, its weight at most 1 (the Mix Shader's factor).
# Or a Velvet (3.x) / Sheen with the Ashikhmin distribution (4.x) BSDF: Ashikhmin's velvet, its
# "roughness" the closure's sigma, its colour the weight, round. Not picked with the microfacet
# lobes: once they and their aspects are chosen, one Velvet is added where it lowers the cost by
# MIN_GAIN (picked among the microfacet lobes it took the place of a stretched lobe that does
# better: ilm_l3_37_matte σ̃² ×2 18.4 -> 23.8 %). It is what a widened table's grazing rise needs
# and no microfacet lobe draws (node_bound per view: 17.9 -> 14.2 % there). EEVEE draws Velvet
# as a diffuse closure: for a scene it renders, no Velvet.
# Or a rough diffuse: a white Diffuse BSDF at roughness 1 (Fujii's Oren-Nayar, ``rough_diffuse``)
# mixed in by a Mix Shader whose factor is the weight, grey and at most 1 like a Fresnel lobe's
# (4.x adds to it a multiple-scattering term that depends on the colour: with white it is one
# fixed shape, which a per-channel colour would not be). Added after the lobes as the Velvet is,
# where it lowers the cost the same way: the retro-reflection at grazing views that widened
# tables show (node_bound per view, with the Velvet: 14.2 -> 11.0 % on ilm_l3_37_matte σ̃² ×2).
GGX, BECKMANN, FRESNEL, VELVET, ROUGH_DIFFUSE = "ggx", "beckmann", "ggx_fresnel", "velvet", "rough_diffuse"
KINDS = (GGX, BECKMANN, FRESNEL, VELVET, ROUGH_DIFFUSE)
MICROFACET_KINDS = (GGX, BECKMANN, FRESNEL)
KIND_NAMES = (
    (GGX, "GGX"),
    (BECKMANN, "Beckmann"),
    (FRESNEL, "GGX × Fresnel"),
    (VELVET, "Velvet"),
    (ROUGH_DIFFUSE, "rough Diffuse"),
)
GREY_KINDS = (FRESNEL, ROUGH_DIFFUSE)  # one weight for the three channels, at most FRESNEL_MAX (a Mix Shader's factor)
VELVET_SIGMA = (0.1, 0.2, 0.35, 0.5, 0.7, 1.0)
EXTRA_MIN_GAIN = 0.005  # the relative error a Velvet or a rough diffuse must take off to be drawn (half a point)
PRUNE_POINTS = 0.002  # what the lobes they made redundant may add to the error, in all, when dropped
FRESNEL_MAX = 1.0
# The Principled's "Specular" in 3.x (0.5: IOR 1.5, F0 0.04), which shapes its Fresnel factor there
PRINCIPLED_3X_SPECULAR = 0.5


def texel_views_deg(n=N_VIEWS):
    return tuple((j + 0.5) * 90.0 / n for j in range(n))


def closures_for(engine: str) -> dict:
    """``fit_lobes``' closures for a render ``engine`` (Blender's name): EEVEE ignores anisotropy,
    draws Velvet as a diffuse closure and a Diffuse BSDF without its roughness, so for it round
    microfacet lobes only."""
    if engine.startswith("BLENDER_EEVEE"):
        return {"aspects": (1.0,), "kinds": MICROFACET_KINDS}
    return {"aspects": ASPECTS, "kinds": KINDS}


def shadowing_for(version) -> str:
    """The Smith term of the Cycles in Blender ``version`` (a tuple such as bpy.app.version)."""
    return "correlated" if tuple(version)[:2] >= (3, 6) else "separable"


@dataclass(frozen=True)
class LobeFit:
    roughness: tuple  # Blender roughness of each GGX lobe (alpha = roughness²), ascending
    weights: np.ndarray  # (1 + K, N_VIEWS, 3): diffuse colour, then each lobe's colour, per texel
    shadowing: str  # "correlated" (Blender 4+) or "separable" (3.x)
    error: float  # relative L2 error of the BRDF (cosine and pixel-share weighted, all channels)
    albedo_error: float  # largest relative error of the directional albedo over the views
    aspect: np.ndarray | None = None  # (K, N_VIEWS): each lobe's aspect q per texel (None: all 1)
    kinds: tuple | None = None  # each lobe's closure, one of KINDS (None: all GGX Glossy)
    bound: float | None = None  # node_bound of the table it was fitted to, when computed

    def with_bound(self, bound) -> "LobeFit":
        return LobeFit(
            *(getattr(self, f) for f in ("roughness", "weights", "shadowing", "error", "albedo_error")),
            self.aspect,
            self.kinds,
            None if bound is None else float(bound),
        )

    def describe(self) -> str:
        """The lobes in words: "2 GGX (1 stretched), 1 Beckmann, 1 GGX × Fresnel"."""
        parts = []
        for kind, name in KIND_NAMES:
            ks = [k for k, v in enumerate(self.kinds) if v == kind]
            if ks:
                q = np.asarray(self.aspect, float)[ks]
                n_str = int(np.sum(np.any(q != 1.0, axis=1)))
                parts.append(f"{len(ks)} {name}" + (f" ({n_str} stretched)" if n_str else ""))
        return ", ".join(parts) if parts else "no lobe"

    def __post_init__(self):
        if self.aspect is None:
            object.__setattr__(self, "aspect", np.ones((len(self.roughness), self.weights.shape[1])))
        if self.kinds is None:
            object.__setattr__(self, "kinds", (GGX,) * len(self.roughness))
        if len(self.kinds) != len(self.roughness) or any(k not in KINDS for k in self.kinds):
            raise ValueError(f"lobe kinds must be one of {KINDS} per lobe")

    @property
    def has_diffuse(self) -> bool:
        """Whether the diffuse colour is above black at some view (the nodes draw a Diffuse BSDF)."""
        return bool(np.any(np.asarray(self.weights)[0] > 0.0))

    @property
    def anisotropic(self) -> bool:
        return bool(np.any(np.asarray(self.aspect) != 1.0))

    def as_dict(self) -> dict:
        return {
            "roughness": [float(r) for r in self.roughness],
            "weights": np.asarray(self.weights, float).round(6).tolist(),
            "aspect": np.asarray(self.aspect, float).round(6).tolist(),
            "kinds": list(self.kinds),
            "bound": self.bound,
            "shadowing": self.shadowing,
            "error": self.error,
            "albedo_error": self.albedo_error,
        }

    @classmethod
    def from_dict(cls, d) -> "LobeFit":
        w = np.asarray(d["weights"], float)
        r = tuple(float(v) for v in d["roughness"])
        if w.ndim != 3 or w.shape[0] != len(r) + 1 or w.shape[2] != 3 or not np.all(np.isfinite(w)):
            raise ValueError("lobe weights of the wrong shape")
        q = np.asarray(d.get("aspect", np.ones((len(r), w.shape[1]))), float)
        lo, hi = ASPECT_RANGE
        if q.shape != (len(r), w.shape[1]) or not np.all(np.isfinite(q)) or np.any(q < lo) or np.any(q > hi):
            raise ValueError("lobe aspects of the wrong shape or range")
        kinds = tuple(str(k) for k in d.get("kinds", [GGX] * len(r)))
        if len(kinds) != len(r) or any(k not in KINDS for k in kinds):
            raise ValueError("lobe kinds of the wrong length or unknown")
        fres = [k in GREY_KINDS for k in kinds]
        if any(fres) and (np.any(w[1:][fres] < 0.0) or np.any(w[1:][fres] > FRESNEL_MAX)):
            raise ValueError("a mixed-in lobe's weight lies outside its Mix Shader's [0, 1]")
        bound = d.get("bound")
        bound = None if bound is None else float(bound)
        return cls(r, w, str(d["shadowing"]), float(d["error"]), float(d["albedo_error"]), q, kinds, bound)

    @property
    def n_lobes(self) -> int:
        return len(self.roughness)

    def lookup_pixels(self) -> np.ndarray:
        """The lookup image, bottom row first: row 0 the diffuse colour, row k the colour of
        lobe k, and when a lobe is anisotropic rows K + k its aspect q (grey); row r is read at
        v = (r + 1/2) / rows, column j at u = (j + 1/2) / N_VIEWS = theta_j / 90°."""
        rows = [self.weights]
        if self.anisotropic:
            rows.append(np.repeat(np.asarray(self.aspect, float)[:, :, None], 3, axis=2))
        return np.ascontiguousarray(np.concatenate(rows, axis=0), np.float32)

    def weights_at(self, theta_o_deg) -> np.ndarray:
        """The colours at views ``theta_o_deg`` (1 + K, n, 3), interpolated as the texture does."""
        return _interp_weights(self.weights, np.asarray(theta_o_deg, float))

    def aspect_at(self, theta_o_deg) -> np.ndarray:
        """Each lobe's aspect at views ``theta_o_deg`` (K, n), interpolated as the texture does."""
        q = np.asarray(self.aspect, float)[:, :, None]
        return _interp_weights(q, np.asarray(theta_o_deg, float))[:, :, 0]


def _interp_weights(weights, theta_deg):
    n = weights.shape[1]
    x = np.clip(theta_deg / 90.0, 0.0, 1.0) * n - 0.5
    j0 = np.clip(np.floor(x).astype(int), 0, n - 1)
    j1 = np.clip(j0 + 1, 0, n - 1)
    t = np.clip(x - np.floor(x), 0.0, 1.0)
    t = np.where(x < 0.0, 0.0, t)
    return weights[:, j0] * (1.0 - t)[None, :, None] + weights[:, j1] * t[None, :, None]


def ggx_lobe(alpha, wi, wo, shadowing="correlated", aspect=1.0):
    """Cycles' GGX reflection without Fresnel (``microfacet_lobe`` with distribution "ggx")."""
    return microfacet_lobe("ggx", alpha, wi, wo, shadowing, aspect)


def microfacet_lobe(distribution, alpha, wi, wo, shadowing="correlated", aspect=1.0):
    """Cycles' GGX or Beckmann reflection without Fresnel, D G / (4 cos_i cos_o), for unit
    vectors (..., 3). ``aspect`` q (scalar or per point) stretches it across the plane of
    incidence of ``wo``: alpha sqrt(q) across, alpha / sqrt(q) in it (the tangent the node setup
    gives Cycles). The nodes use GGX; Beckmann serves ``node_bound``. Lambda is what Cycles
    evaluates: exact for GGX, Walter et al.'s rational fit for Beckmann."""
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"unknown distribution {distribution!r}")
    if shadowing not in SHADOWING:
        raise ValueError(f"unknown shadowing {shadowing!r}")
    alpha = np.maximum(np.asarray(alpha, float), 1e-7)  # a column of values: one lobe per row
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    ci = np.clip(wi[..., 2], 1e-9, 1.0)
    co = np.clip(wo[..., 2], 1e-9, 1.0)
    q = np.asarray(aspect, float)
    # axes: "in" along wo's azimuth, "across" perpendicular to it (any pair at normal view)
    rad = np.hypot(wo[..., 0], wo[..., 1])
    safe = rad > 1e-12
    cx = np.where(safe, wo[..., 0] / np.where(safe, rad, 1.0), 1.0)
    cy = np.where(safe, wo[..., 1] / np.where(safe, rad, 1.0), 0.0)
    a_in, a_across = alpha / np.sqrt(q), alpha * np.sqrt(q)

    def split(v):
        return v[..., 0] * cx + v[..., 1] * cy, -v[..., 0] * cy + v[..., 1] * cx

    hx, hy = split(h)
    d = stretched_ndf(distribution, hx, hy, h[..., 2], a_in, a_across)

    def lam(v, c):
        x, y = split(v)
        return smith_lambda(distribution, ((a_in * x) ** 2 + (a_across * y) ** 2) / (c * c), rational=True)

    return d * masking(lam(wi, ci), lam(wo, co), shadowing) / (4.0 * ci * co)


def fresnel_factor(wi, wo, shadowing="correlated"):
    """The Fresnel factor of theta_d (cos theta_d = wi.h) of a Principled BSDF with metallic 1 and
    a black base colour, in the Cycles whose Smith term is ``shadowing`` (``shadowing_for``):

    - 4.x (``"correlated"``): the metal's F82-tint Fresnel with a white tint, which is Schlick's
      F0 + (1 - F0)(1 - wi.h)^5 with F0 the base colour: (1 - wi.h)^5;
    - 3.x (``"separable"``): Principled v1's ``interpolate_fresnel_color``, cspec0 (1 - FH) + FH
      with cspec0 the base colour and FH = (F(wi.h) - F0) / (1 - F0), F the dielectric Fresnel of
      the IOR its "Specular" gives (0.5: 1.5) and F0 = F(1): FH."""
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    c = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
    if shadowing == "correlated":
        return (1.0 - c) ** 5
    if shadowing != "separable":
        raise ValueError(f"unknown shadowing {shadowing!r}")
    return principled_v1_factor(c, 2.0 / (1.0 - math.sqrt(0.08 * PRINCIPLED_3X_SPECULAR)) - 1.0)


def principled_v1_factor(c, eta):
    """Principled v1's (3.x) Fresnel factor at cos theta_d ``c``: the dielectric Fresnel of IOR
    ``eta`` normalised to run from 0 at normal incidence to 1 at grazing, (F - F0) / (1 - F0)."""
    f0 = _fresnel_dielectric(np.array(1.0), eta)
    return (_fresnel_dielectric(c, eta) - f0) / (1.0 - f0)


def _fresnel_dielectric(c, eta):
    """The unpolarised Fresnel reflectance of a dielectric of relative IOR ``eta`` at cos ``c``."""
    g = np.sqrt(eta * eta - 1.0 + c * c)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


def velvet_distribution(sigma, cos_h):
    """Ashikhmin's velvet distribution exp(-cot² theta_h / sigma²) / (pi sigma² sin⁴ theta_h)."""
    s2 = np.maximum(1.0 - cos_h * cos_h, 1e-300)
    return np.exp(-(cos_h * cos_h / s2) / sigma**2) / (np.pi * sigma**2 * s2 * s2)


def velvet(sigma, wi, wo):
    """Cycles' Ashikhmin velvet (3.x's Velvet BSDF, 4.x's Sheen BSDF with the Ashikhmin
    distribution): D G / (4 cos_i cos_o) with ``velvet_distribution`` (sigma at least 0.01, as
    Cycles clamps it) and its V-cavity G = min(1, 2 (n.h) min(cos_i, cos_o) / (wo.h))."""
    sigma = max(float(sigma), 0.01)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    ci, co = np.clip(wi[..., 2], 1e-9, 1.0), np.clip(wo[..., 2], 1e-9, 1.0)
    nh = np.clip(h[..., 2], 0.0, 1.0 - 1e-9)
    ho = np.clip(np.sum(wo * h, axis=-1), 1e-9, 1.0)
    g = np.minimum(1.0, 2.0 * nh / ho * np.minimum(ci, co))
    return velvet_distribution(sigma, nh) * g / (4.0 * ci * co)


def _oren_nayar_energy(a, b, c):
    """The directional albedo of Fujii's single-scattering Oren-Nayar (a + b t) at cos ``c``:
    a pi + b G(c), G Fujii's angular integral."""
    c = np.clip(c, 1e-6, 1.0)
    s = np.sqrt(1.0 - c * c)
    th = np.arccos(c)
    g = s * (th - 2.0 / 3.0 - s * c) + 2.0 / 3.0 * (s / c) * (1.0 - s**3)
    return a * np.pi + b * g


def rough_diffuse(wi, wo, shadowing="correlated"):
    """Cycles' Diffuse BSDF at roughness 1 with a white colour: Fujii's Oren-Nayar a + b t,
    a = b = 1 / (pi + pi / 2 - 2 / 3), t = s / max(cos_i, cos_o) where s = wi.wo - cos_i cos_o > 0
    (else s); in 4.x (``"correlated"``) plus the multiple-scattering term
    (1 - E(cos_i)) (1 - E(cos_o)) / (pi (1 - Eavg)), which the white colour makes one shape."""
    a = b = 1.0 / (np.pi + np.pi / 2.0 - 2.0 / 3.0)
    ci, co = np.clip(wi[..., 2], 0.0, 1.0), np.clip(wo[..., 2], 0.0, 1.0)
    s = np.sum(wi * wo, axis=-1) - ci * co
    t = np.where(s > 0.0, s / (np.maximum(ci, co) + 1e-300), s)
    f = a + b * t
    if shadowing == "correlated":
        e_avg = a * np.pi + (2.0 * np.pi - 5.6) / 3.0 * b
        f = f + (1.0 - _oren_nayar_energy(a, b, ci)) * (1.0 - _oren_nayar_energy(a, b, co)) / (np.pi * (1.0 - e_avg))
    elif shadowing != "separable":
        raise ValueError(f"unknown shadowing {shadowing!r}")
    return f


def lobe_shape(kind, roughness, wi, wo, shadowing="correlated", aspect=1.0):
    """One lobe of ``kind`` (``KINDS``) at Blender ``roughness`` (alpha = roughness²; a Velvet's
    sigma), weight 1. Fresnel and Velvet lobes stay round (``aspect`` ignored)."""
    if kind == VELVET:
        return velvet(roughness, wi, wo)
    if kind == ROUGH_DIFFUSE:
        return rough_diffuse(wi, wo, shadowing)
    if kind == BECKMANN:
        return microfacet_lobe("beckmann", roughness * roughness, wi, wo, shadowing, aspect)
    if kind == GGX:
        return microfacet_lobe("ggx", roughness * roughness, wi, wo, shadowing, aspect)
    if kind == FRESNEL:
        return microfacet_lobe("ggx", roughness * roughness, wi, wo, shadowing) * fresnel_factor(wi, wo, shadowing)
    raise ValueError(f"unknown lobe kind {kind!r}")


def lobes_brdf(fit: LobeFit, wi, wo):
    """The model for a LobeFit: (3, n) for unit vectors (n, 3), the colours at each wo's view."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    theta = np.degrees(np.arccos(np.clip(wo[:, 2], -1.0, 1.0)))
    w = fit.weights_at(theta)  # (1 + K, n, 3)
    q = fit.aspect_at(theta)  # all 1 for round lobes: the round path
    out = w[0].T / np.pi
    for k, (kind, r) in enumerate(zip(fit.kinds, fit.roughness)):
        out = out + w[k + 1].T * lobe_shape(kind, r, wi, wo, fit.shadowing, q[k])[None, :]
    return out


def _table_at_views(table, views_deg):
    """Per view: (deg, wi, wo, weights, rho (3, n)) on ``view_quadrature``'s directions where
    the table was measured (missing cells left out)."""
    from ..file.merl import lookup

    for deg, (wi, wo, w) in zip(views_deg, view_quadrature(views_deg, N_PHI_H)):
        rho, valid = lookup(table, wi, np.broadcast_to(wo, wi.shape))
        ok = valid.all(axis=0)
        yield deg, wi[ok], wo, w[ok], rho[:, ok]


def _features(lobes, wi, wo, shadowing, aspects=(1.0,)):
    """Diffuse, then every (kind, roughness) lobe at every aspect, aspects varying fastest (a
    Fresnel or Velvet lobe, always round, repeated). ``aspects`` (K,) arrays in a list: each
    lobe at its own aspects."""
    wo_b = np.broadcast_to(wo, wi.shape)
    own = isinstance(aspects, list)
    q = None if own else np.asarray(aspects, float)[:, None]  # all the aspects of one lobe in one call
    rows = [np.full((1, len(wi)), 1.0 / np.pi)]
    fresnel = fresnel_factor(wi, wo_b, shadowing) if any(kind == FRESNEL for kind, _ in lobes) else None
    round_ggx = {}  # a Fresnel lobe is the round GGX lobe of its roughness times the factor
    batch = {}  # at one aspect, every roughness of a distribution in one call (the same geometry)
    if not own and len(q) == 1:
        for kind, name in ((GGX, "ggx"), (BECKMANN, "beckmann")):
            rs = sorted({r for kd, r in lobes if kd == kind or (kind == GGX and kd == FRESNEL)})
            if rs:
                shapes = microfacet_lobe(name, np.square(rs)[:, None], wi, wo_b, shadowing, q[0, 0])
                batch.update({(kind, r): shape[None] for r, shape in zip(rs, shapes)})
        if q[0, 0] == 1.0:
            round_ggx.update({r: shape[0] for (kind, r), shape in batch.items() if kind == GGX})
    for k, (kind, r) in enumerate(lobes):
        if own:
            q = np.atleast_1d(np.asarray(aspects[k], float))[:, None]
        if kind == FRESNEL:
            if r not in round_ggx:
                round_ggx[r] = lobe_shape(GGX, r, wi, wo_b, shadowing)
            shape = round_ggx[r] * fresnel
        elif kind in (VELVET, ROUGH_DIFFUSE):
            shape = lobe_shape(kind, r, wi, wo_b, shadowing)
        elif (kind, r) in batch:
            shape = batch[(kind, r)]
        else:
            shape = lobe_shape(kind, r, wi, wo_b, shadowing, q)
            if kind == GGX and np.any(q == 1.0):
                round_ggx[r] = shape[int(np.argmax(q[:, 0] == 1.0))] if shape.ndim == 2 else shape
        rows.append(np.broadcast_to(shape, (len(q), len(wi))))
    return np.concatenate(rows)


def _nnls_gram(G, b):
    """min x.G.x - 2 x.b over x >= 0 (G positive definite, a handful of unknowns): active set."""
    from scipy.optimize import nnls

    L = np.linalg.cholesky(G)
    x, _ = nnls(L.T, np.linalg.solve(L, b), maxiter=50 * len(b))
    return x


def _nnls_capped(G, b, cap):
    """min x.G.x - 2 x.b over 0 <= x <= cap (per unknown, inf: no cap): the unknown furthest
    over its cap held at it and the rest solved again, until none is over (exact for one capped
    unknown: the cost minimised over the others is convex in it)."""
    n = len(b)
    cap = np.broadcast_to(np.asarray(cap, float), (n,))
    capped = np.isfinite(cap)
    held = np.zeros(n, bool)
    x = np.zeros(n)
    for _ in range(int(capped.sum()) + 1):
        free = ~held
        if not free.any():  # scipy's nnls crashes on an empty problem
            break
        x[free] = _nnls_gram(G[np.ix_(free, free)], b[free] - G[np.ix_(free, held)] @ x[held])
        over = capped & ~held & (x > cap)
        if not over.any():
            break
        k = int(np.flatnonzero(over)[np.argmax((x - cap)[over])])
        held[k], x[k] = True, cap[k]
    return x


def _quantile(rho, w, q):
    """Per channel, the value of ``rho`` (3, n) at cumulative weight ``q`` of ``w`` (n,)."""
    out = np.zeros(len(rho))
    for c, v in enumerate(rho):
        order = np.argsort(v, kind="stable")
        cum = np.cumsum(w[order])
        if len(v):
            out[c] = v[order][min(int(np.searchsorted(cum, q * cum[-1])), len(v) - 1)]
    return out


class _View:
    """One view's normal equations over a set of lobes (diffuse first), per channel, with the
    albedo equation folded in. ``with_lobes`` makes them again for other lobes, the table's
    values at the quadrature kept."""

    def __init__(self, deg, wi, wo, w, rho, shadowing, dictionary, aspects=(1.0,), diffuse_quantile=DIFFUSE_QUANTILE):
        self.deg, self.wo, self.shadowing = deg, wo, shadowing
        self.wi, self.w, self.rho = wi, w, rho
        self.share = pixel_share(deg)
        q = diffuse_quantile
        self.diffuse_cap = np.full(3, np.inf) if q is None else DIFFUSE_OVER * np.pi * _quantile(rho, w, q)
        self._normal_equations(dictionary, aspects)

    def with_lobes(self, lobes, aspects):
        other = object.__new__(_View)
        keep = ("deg", "wo", "shadowing", "wi", "w", "rho", "share", "diffuse_cap")
        other.__dict__.update({k: self.__dict__[k] for k in keep})
        other._normal_equations(lobes, aspects)
        return other

    def _normal_equations(self, lobes, aspects):
        wi, w, rho = self.wi, self.w, self.rho
        F = _features(lobes, wi, self.wo, self.shadowing, aspects)  # (1 + R Q, n)
        self.G = (F * w) @ F.T
        self.r = (rho * w) @ F.T  # (3, 1 + R Q)
        self.yy = np.sum(w * rho * rho, axis=1)  # (3,)
        a = F @ w  # each feature's albedo at this view
        alb = rho @ w  # (3,)
        lam = ALBEDO_WEIGHT * float(np.sum(self.yy)) / max(float(np.sum(alb * alb)), 1e-300)
        self.Ga = self.G + lam * np.outer(a, a)
        self.ra = self.r + lam * alb[:, None] * a[None, :]
        self.yya = self.yy + lam * alb * alb
        # the norms of the channels' sum, without and with the albedo equation (``_cost_fn``)
        total = rho.sum(axis=0)
        self.yy_sum = float(np.sum(w * total * total))
        self.yya_sum = self.yy_sum + lam * float(alb.sum()) ** 2
        self.albedo = alb

    def solve(self, idx, grey=None):
        """Weights (3, len(idx)) on the columns ``idx`` and the cost (BRDF + albedo terms): each
        channel its own weights, but the columns flagged in ``grey`` (Fresnel lobes) one weight
        for all three, in [0, FRESNEL_MAX]."""
        idx = [int(i) for i in idx]
        grey = np.zeros(len(idx), bool) if grey is None else np.asarray(grey, bool)
        own = [i for i, g in zip(idx, grey) if not g]
        shared = [i for i, g in zip(idx, grey) if g]
        no, ns = len(own), len(shared)
        n = 3 * no + ns
        H, b = np.zeros((n, n)), np.zeros(n)
        G = self.Ga
        for c in range(3):
            sl = slice(c * no, (c + 1) * no)
            H[sl, sl] = G[np.ix_(own, own)]
            H[sl, 3 * no :] = G[np.ix_(own, shared)]
            H[3 * no :, sl] = G[np.ix_(shared, own)]
            b[sl] = self.ra[c, own]
        H[3 * no :, 3 * no :] = 3.0 * G[np.ix_(shared, shared)]
        b[3 * no :] = self.ra[:, shared].sum(axis=0)
        H = H + 1e-10 * np.trace(H) / n * np.eye(n)
        cap = np.full(n, np.inf)
        cap[3 * no :] = FRESNEL_MAX
        if 0 in own:
            cap[own.index(0) : 3 * no : no] = self.diffuse_cap
        z = _nnls_capped(H, b, cap)
        x = np.zeros((3, len(idx)))
        x[:, np.flatnonzero(~grey)] = z[: 3 * no].reshape(3, no)
        x[:, np.flatnonzero(grey)] = z[3 * no :][None, :]
        return x, float(z @ H @ z - 2.0 * z @ b + np.sum(self.yya))


def _cost_fn(vs, capped_cols=None, residual=False):
    """The pixel-share weighted cost per view of a set of columns per view, for the channels'
    sum (a quick stand-in for the three channels while lobes are chosen: it ranks the
    candidates, but its constant is the channels' own norms, not their sum's, so it is no
    squared residual and may fall below 0, where ``_greedy``'s MIN_GAIN stop never acts and
    all N_LOBES are taken (ilm_l3_37_matte σ̃² ×2); the fits measured in BENCHMARKS are made so; with
    ``residual`` the sum's own norm, the squared residual of fitting the sum); the columns flagged in
    ``capped_cols`` (Fresnel lobes, one weight for the three channels) capped at 3 FRESNEL_MAX,
    the diffuse (column 0) at the sum of its caps per channel."""
    Ga = np.stack([v.Ga for v in vs])  # (V, M, M)
    ra = np.stack([v.ra.sum(axis=0) for v in vs])  # (V, M)
    yy = np.array([v.yya_sum if residual else v.yya.sum() for v in vs])
    rows = np.arange(len(vs))[:, None]
    capped_cols = np.zeros(Ga.shape[1], bool) if capped_cols is None else np.asarray(capped_cols, bool)
    col_cap = np.where(capped_cols, 3.0 * FRESNEL_MAX, np.inf)[None, :].repeat(len(vs), axis=0)  # (V, M)
    col_cap[:, 0] = [float(np.sum(v.diffuse_cap)) for v in vs]

    def costs(cols, constrained=True):
        """Per view; ``constrained=False``: without the bounds, a lower bound on the cost."""
        G = Ga[rows[:, :, None], cols[:, :, None], cols[:, None, :]]
        G = G + (1e-10 * np.trace(G, axis1=1, axis2=2) / cols.shape[1])[:, None, None] * np.eye(cols.shape[1])
        b = ra[rows, cols]
        cap = col_cap[rows, cols]  # (V, m)
        x = np.linalg.solve(G, b[:, :, None])[:, :, 0]  # unconstrained first: usually feasible
        if constrained:
            for m in np.flatnonzero((x < 0.0).any(axis=1) | (x > cap).any(axis=1)):
                x[m] = _nnls_capped(G[m], b[m], cap[m])
        return np.einsum("vi,vij,vj->v", x, G, x) - 2.0 * np.sum(x * b, axis=1) + yy

    return costs


def _greedy(vs, n_lobes, n_dict, shares, capped_cols=None, min_lobes=None, min_gain=0.0):
    """Indices (into the dictionary) of up to ``n_lobes`` lobes picked greedily for the views
    ``vs``: each step adds the one that lowers the pixel-share weighted cost (channel sum) most;
    past ``min_lobes``, only while that lowers the cost by ``min_gain`` of it at least."""
    costs, sh, V = _cost_fn(vs, capped_cols), np.asarray(shares, float), len(vs)
    min_lobes = n_lobes if min_lobes is None else min_lobes
    chosen, last = [], float(np.sum(sh * costs(np.zeros((V, 1), int))))
    for _ in range(min(n_lobes, n_dict)):
        # the bounds only raise a cost: candidates in the order of their unbounded cost, until
        # that is above the best bounded one found (the same pick, far fewer NNLS solves)
        trials = []
        for k in range(n_dict):
            if k in chosen:
                continue
            cols = np.broadcast_to(np.array([0] + [1 + j for j in sorted(chosen + [k])]), (V, len(chosen) + 2))
            trials.append((float(np.sum(sh * costs(cols, constrained=False))), k, cols))
        best = None
        for low, k, cols in sorted(trials, key=lambda t: (t[0], t[1])):
            if best is not None and low >= best[0]:
                break
            cost = float(np.sum(sh * costs(cols)))
            if best is None or cost < best[0] or (cost == best[0] and k < best[1]):
                best = (cost, k)
        if len(chosen) >= min_lobes and best[0] > (1.0 - min_gain) * last:
            break
        chosen.append(best[1])
        last = best[0]
    return sorted(chosen)


def _choose_aspects(vs, n_lobes, n_aspects, shares, round_index=0, round_views=(0,), passes=2, round_lobes=()):
    """Each lobe's aspect per view (indices (K, V)) for views ``vs`` whose columns are the
    lobes' aspects (lobe k, aspect a at 1 + k n_aspects + a): coordinate descent from round
    lobes, each lobe in turn taking per view the aspect that costs least with the others fixed.
    Views in ``round_views`` and lobes in ``round_lobes`` (Fresnel lobes) keep aspect 1 (index
    ``round_index``)."""
    capped = _grey_columns(vs, [k in round_lobes for k in range(n_lobes)], n_aspects)
    costs, V = _cost_fn(vs, capped), len(vs)
    pick = np.full((n_lobes, V), round_index)
    allowed = np.ones((n_aspects, V), bool)
    allowed[:, list(round_views)] = False
    allowed[round_index, list(round_views)] = True
    for _ in range(passes):
        for k in range(n_lobes):
            if k in round_lobes:
                continue
            table = np.full((n_aspects, V), np.inf)
            for a in range(n_aspects):
                trial = pick.copy()
                trial[k] = a
                cols = np.concatenate([np.zeros((1, V), int), 1 + np.arange(n_lobes)[:, None] * n_aspects + trial])
                table[a] = np.where(allowed[a], costs(cols.T), np.inf)
            pick[k] = np.argmin(table, axis=0)
    return pick


def _lobe_costs(vs, grey_cols):
    """(cost of columns (K, V), the BRDF's norm): ``_cost_fn``'s squared residual of the
    channels' sum, pixel-share weighted and summed over the views, and the sum's own norm in
    the same weighting without the albedo equation, so that sqrt(cost / norm) stands for a
    relative BRDF error."""
    costs, sh = _cost_fn(vs, grey_cols, residual=True), np.array([v.share for v in vs])
    norm = float(np.sum(sh * np.array([v.yy_sum for v in vs])))

    def cost(cols):
        return float(np.sum(sh * costs(np.vstack([np.zeros((1, cols.shape[1]), int), cols]).T)))

    return cost, norm


def _extras_pick(vs, cols, nq, q1, extras, grey_cols):
    """Which of the ``extras`` (Velvets and a rough diffuse, after the K chosen lobes in the
    views' columns, each at ``nq`` repeated aspects) to add to the lobes ``cols`` (K, V): the
    one that lowers ``_lobe_costs`` most, then again among the other kind, each only if by
    MIN_GAIN of it and EXTRA_MIN_GAIN of the relative BRDF error it stands for (a closure more
    only where it shows: on a table the lobes already meet, a few per cent of a small residual
    is not worth a node). Returns (their indices into ``extras``, ``cols`` with their rows)."""
    K, V = cols.shape
    cost, norm = _lobe_costs(vs, grey_cols)

    def with_extra(k):
        return np.vstack([cols, np.full((1, V), 1 + (K + k) * nq + q1)])

    picked = []
    for _ in range(2):
        last = cost(cols)
        trials = [
            (cost(with_extra(k)), k) for k, (kind, _) in enumerate(extras) if all(extras[p][0] != kind for p in picked)
        ]
        if not trials:
            break
        c, k = min(trials)
        points = math.sqrt(max(last, 0.0) / norm) - math.sqrt(max(c, 0.0) / norm)
        if c > (1.0 - MIN_GAIN) * last or points < EXTRA_MIN_GAIN:
            break
        picked.append(k)
        cols = with_extra(k)
    return picked, cols


def _grey_columns(vs, grey, nq):
    """The views' columns of the lobes flagged ``grey`` (one weight for the three channels)."""
    out = np.zeros(vs[0].Ga.shape[0], bool)
    for k, f in enumerate(grey):
        out[1 + k * nq : 1 + (k + 1) * nq] = f
    return out


def _prune(vs, cols, n_kept, grey_cols):
    """The lobes (indices into ``cols``' rows) left once those the extras (the last ``n_kept``
    rows, kept) made redundant are dropped: the one whose loss raises ``_lobe_costs``' relative
    error least, again and again, while in all it rises by under PRUNE_POINTS."""
    cost, norm = _lobe_costs(vs, grey_cols)
    keep = list(range(len(cols)))
    start = math.sqrt(max(cost(cols), 0.0) / norm)
    while len(keep) > n_kept + 1:
        c, k = min((cost(cols[[i for i in keep if i != k]]), k) for k in keep[: len(keep) - n_kept])
        if math.sqrt(max(c, 0.0) / norm) - start >= PRUNE_POINTS:
            break
        keep.remove(k)
    return keep


def fit_lobes(
    table,
    n_lobes: int = N_LOBES,
    shadowing="correlated",
    n_views: int = N_VIEWS,
    dictionary=DICTIONARY,
    aspects=ASPECTS,
    kinds=KINDS,
    diffuse_quantile=DIFFUSE_QUANTILE,
) -> LobeFit:
    """Fit the model above to a MerlTable (missing cells left out). One set of lobes (kind and
    roughness, picked among ``kinds`` × ``dictionary``) serves every view (a roughness picked
    per view was measured too: no gain, issue 28); each Glossy lobe's aspect may change from
    view to view (``aspects=(1.0,)``: isotropic lobes). Lobes whose weight is 0 at every view
    are dropped (the node tree draws no closure for them). The diffuse colour is capped per view
    at DIFFUSE_OVER pi times the table's ``diffuse_quantile`` there (None: no cap)."""
    from ..limits import check

    n_lobes, n_views = check("lobes", n_lobes, "n_lobes"), check("lookup_texels", n_views, "n_views")
    if diffuse_quantile is not None:
        diffuse_quantile = check("share", diffuse_quantile, "diffuse_quantile")
    picking = list(_table_at_views(table, texel_views_deg(min(PICK_VIEWS, n_views))))
    samples = picking if n_views <= PICK_VIEWS else list(_table_at_views(table, texel_views_deg(n_views)))
    return _fit_samples(
        samples, n_lobes, shadowing, n_views, dictionary, aspects, kinds, table, None, diffuse_quantile, picking
    )


def _fit_samples(
    samples,
    n_lobes,
    shadowing,
    n_views,
    dictionary,
    aspects,
    kinds,
    table=None,
    error_samples=None,
    diffuse_quantile=DIFFUSE_QUANTILE,
    picking=None,
):
    """The fit on the lookup's views ``samples`` (one per texel). The lobes, the Glossy lobes'
    aspects and the Velvet and rough Diffuse are chosen on the views ``picking`` (default: the
    same); each texel takes the aspects of the picking view nearest it, and its colours are
    solved at its own view."""
    if shadowing not in SHADOWING:
        raise ValueError(f"unknown shadowing {shadowing!r}")
    if any(k not in KINDS for k in kinds) or not any(k in MICROFACET_KINDS for k in kinds):
        raise ValueError(f"lobe kinds must be among {KINDS}, one of {MICROFACET_KINDS} at least")
    dictionary, aspects = tuple(dictionary), tuple(float(q) for q in aspects)
    if 1.0 not in aspects or any(not ASPECT_RANGE[0] <= q <= ASPECT_RANGE[1] for q in aspects):
        raise ValueError(f"aspects must hold 1 and lie in {ASPECT_RANGE}")
    lobes_all = [(kind, r) for kind in kinds if kind in MICROFACET_KINDS for r in dictionary]
    picking = samples if picking is None else picking
    vs = [_View(*at, shadowing, lobes_all, diffuse_quantile=diffuse_quantile) for at in picking]
    fres_cols = np.array([False] + [kind in GREY_KINDS for kind, _ in lobes_all])
    # The lobes among round ones, then each Glossy lobe's aspect per view (the first texel stays
    # round: at normal view the plane of incidence, the lobe's tangent, is undefined).
    pick = _greedy(
        vs,
        min(n_lobes, len(lobes_all)),
        len(lobes_all),
        [v.share for v in vs],
        fres_cols,
        min(MIN_LOBES, n_lobes),
        MIN_GAIN,
    )
    chosen = [lobes_all[k] for k in pick]
    fresnel = [kind == FRESNEL for kind, _ in chosen]
    round_q = aspects.index(1.0)
    stretch = len(aspects) > 1 and not all(fresnel)
    extras = [(VELVET, s) for s in VELVET_SIGMA] if VELVET in kinds else []
    extras += [(ROUGH_DIFFUSE, 1.0)] if ROUGH_DIFFUSE in kinds else []
    # the chosen lobes at every aspect (or round), the extras' candidates after them
    used = aspects if stretch else (1.0,)
    nq, q1 = len(used), used.index(1.0)
    vs = [v.with_lobes(chosen + extras, used) for v in vs]
    qi = np.full((len(chosen), len(vs)), round_q)  # each lobe's aspect per view, into ``aspects``
    if stretch:
        round_lobes = tuple(k for k, f in enumerate(fresnel) if f)
        qi = _choose_aspects(vs, len(chosen), nq, [v.share for v in vs], q1, round_lobes=round_lobes)
    cols = 1 + np.arange(len(chosen))[:, None] * nq + (qi if stretch else np.full_like(qi, q1))  # (K, views)
    if extras:
        grey_cols = _grey_columns(vs, [kind in GREY_KINDS for kind, _ in chosen + extras], nq)
        picked, cols = _extras_pick(vs, cols, nq, q1, extras, grey_cols)
        if picked:
            chosen += [extras[k] for k in picked]
            qi = np.vstack([qi, np.full((len(picked), len(vs)), round_q)])
            rest = _prune(vs, cols, len(picked), grey_cols)
            chosen, qi, cols = [chosen[i] for i in rest], qi[rest], cols[rest]
    fresnel = [kind in GREY_KINDS for kind, _ in chosen]
    if samples is not picking:
        # the lookup's texels: each takes the aspects of the picking view nearest it, and its
        # colours are solved at its own view, on those lobes at those aspects alone
        near = np.abs(np.subtract.outer(texel_views_deg(n_views), [v.deg for v in vs])).argmin(axis=1)
        qi = qi[:, near]
        vs = [
            _View(*at, shadowing, chosen, list(np.asarray(aspects)[qi[:, j]]), diffuse_quantile)
            for j, at in enumerate(samples)
        ]
        cols = np.repeat(1 + np.arange(len(chosen))[:, None], len(vs), axis=1)
    W = np.zeros((1 + len(chosen), n_views, 3))
    for j, v in enumerate(vs):
        W[:, j, :] = v.solve([0] + [int(c) for c in cols[:, j]], [False] + fresnel)[0].T
    q = np.asarray(aspects)[qi]
    keep = [k for k in range(len(chosen)) if np.any(W[1 + k] > 0.0)]  # a closure only for a lobe in use
    W = W[[0] + [1 + k for k in keep]]
    q = q[keep] if keep else np.ones((0, n_views))
    rough = tuple(chosen[k][1] for k in keep)
    kinds_kept = tuple(chosen[k][0] for k in keep)
    fit = LobeFit(rough, W, shadowing, 0.0, 0.0, q, kinds_kept)
    err, alb_err = measure(fit, table) if error_samples is None else _measure_samples(fit, error_samples)
    return LobeFit(rough, W, shadowing, err, alb_err, q, kinds_kept)


def measure(fit: LobeFit, table, views_deg=ERROR_VIEWS_DEG):
    """(BRDF error, albedo error) of ``fit`` against ``table`` at ``views_deg``: the relative
    L2 error, cosine and pixel-share weighted over all channels, and the largest relative error
    of the directional albedo over the views and channels (where the table holds 0.1 % of its
    largest albedo)."""
    return _measure_samples(fit, _table_at_views(table, views_deg))


def _measure_samples(fit, samples):
    num = den = 0.0
    alb_t, alb_f = [], []
    for deg, wi, wo, w, rho in samples:
        vals = lobes_brdf(fit, wi, np.broadcast_to(wo, wi.shape))
        s = pixel_share(deg)
        num += s * float(np.sum(w * (vals - rho) ** 2))
        den += s * float(np.sum(w * rho**2))
        alb_t.append(rho @ w)
        alb_f.append(vals @ w)
    alb_t, alb_f = np.array(alb_t), np.array(alb_f)
    held = alb_t > 1e-3 * max(float(alb_t.max()), 1e-12)
    alb_err = float(np.max(np.abs(alb_f - alb_t)[held] / alb_t[held])) if held.any() else 0.0
    return math.sqrt(num / den) if den > 0 else 0.0, alb_err


NEAR_MIRROR_DEG = 0.3  # half-vector rings this close to the mirror bound every node setup
RING_HARMONICS = 2  # the azimuthal orders a closure may follow on such a ring (1, cos, sin, cos 2, sin 2)
RING_AZIMUTHS = 96


def near_mirror_floor(table, views_deg=ERROR_VIEWS_DEG, theta_h_max_deg: float = NEAR_MIRROR_DEG):
    """A lower bound on ``measure``'s BRDF error for any node setup of isotropic closures (issue 28).

    An isotropic closure (Diffuse, Glossy, Principled, Sheen; EEVEE renders every closure so)
    whose colour follows only the view changes, on a ring of half vectors within a third of a
    degree of the normal, only smoothly with the ring's azimuth (through cos theta_i and the
    shadowing, by a few per cent): within the span of the first ``RING_HARMONICS`` Fourier
    orders, which also holds the cos 2 phi of a mildly anisotropic lobe. What the table does on
    those rings outside that span, no such setup follows. Returns that part's share of the
    table's norm in ``measure``'s weighting (the same denominator; the rings integrated more
    finely over azimuth, each by its weighted least-squares residual)."""
    from ..file.merl import lookup, theta_h_edges
    from ..limits import check

    theta_h_max_deg = check("near_mirror_deg", theta_h_max_deg, "theta_h_max_deg")
    den = sum(pixel_share(deg) * float(np.sum(w * rho**2)) for deg, _, _, w, rho in _table_at_views(table, views_deg))
    if den <= 0.0:
        return 0.0
    edges = theta_h_edges()
    rings = int(np.searchsorted(edges, math.radians(theta_h_max_deg)))
    ph = (np.arange(RING_AZIMUTHS) + 0.5) / RING_AZIMUTHS * 2.0 * np.pi
    basis = [np.ones_like(ph)]
    for m in range(1, RING_HARMONICS + 1):
        basis += [np.cos(m * ph), np.sin(m * ph)]
    B = np.stack(basis, axis=1)
    num = 0.0
    for deg in views_deg:
        t = math.radians(deg)
        wo = np.array([math.sin(t), 0.0, math.cos(t)])
        for k in range(rings):
            th, dth = 0.5 * (edges[k] + edges[k + 1]), edges[k + 1] - edges[k]
            h = np.stack((np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.full_like(ph, np.cos(th))), axis=-1)
            wi, w, above = reflect_about(h, math.sin(th) * dth * (2.0 * np.pi / len(ph)), wo)
            rho, valid = lookup(table, wi, np.broadcast_to(wo, wi.shape))
            if not (valid.all() and above.all()):
                continue
            # The part no closure follows: the residual of the weighted least-squares fit of
            # the ring by the span of B (the best any closure can do there).
            Bw = B * w[:, None]
            coef = np.linalg.solve(B.T @ Bw, Bw.T @ rho.T)  # (orders, 3)
            r = rho - (B @ coef).T
            num += pixel_share(deg) * float(np.sum(w * r * r))
    return math.sqrt(num / den)
