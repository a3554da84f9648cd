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
measured at views between the texels, where that interpolation shows.

The fit: for every texel view, the weights are non-negative least squares of the table against
the lobes (cosine-weighted, through the half vector on the table's own theta_h cells, as
``core.principled``), with the view's directional albedo as one extra, strongly weighted
equation, so that the energy the artist sees per view is the table's. The roughness of the
lobes is picked greedily from a dictionary (the one that lowers the cost most, then the next),
the cost summed over views with each view's share of a sphere's pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .principled import pixel_share, view_quadrature

N_VIEWS = 18  # texels of the lookup over theta_o in [0, 90°]
N_LOBES = 3
N_PHI_H = 24
# Blender roughness (alpha = r²); Cycles treats alpha² <= 1e-7 as a mirror (r < 0.0178).
DICTIONARY = tuple(float(v) for v in np.exp(np.linspace(np.log(0.02), np.log(1.0), 16)))
ERROR_VIEWS_DEG = tuple(range(0, 81, 5))  # where the error is measured (between texels)
ALBEDO_WEIGHT = 30.0  # the albedo equation's weight against the BRDF residual's norm
SHADOWING = ("correlated", "separable")


def texel_views_deg(n=N_VIEWS):
    return tuple((j + 0.5) * 90.0 / n for j in range(n))


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

    def as_dict(self) -> dict:
        return {
            "roughness": [float(r) for r in self.roughness],
            "weights": np.asarray(self.weights, float).round(6).tolist(),
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
        return cls(r, w, str(d["shadowing"]), float(d["error"]), float(d["albedo_error"]))

    @property
    def n_lobes(self) -> int:
        return len(self.roughness)

    def lookup_pixels(self) -> np.ndarray:
        """The lookup image (1 + K rows, N_VIEWS columns, RGB), bottom row first: row 0 the
        diffuse colour, row k the colour of lobe k; row r is read at v = (r + 1/2) / rows, column
        j at u = (j + 1/2) / N_VIEWS = theta_j / 90°."""
        return np.ascontiguousarray(self.weights, np.float32)

    def weights_at(self, theta_o_deg) -> np.ndarray:
        """The colours at views ``theta_o_deg`` (1 + K, n, 3), interpolated as the texture does."""
        return _interp_weights(self.weights, np.asarray(theta_o_deg, float))


def _interp_weights(weights, theta_deg):
    n = weights.shape[1]
    x = np.clip(theta_deg / 90.0, 0.0, 1.0) * n - 0.5
    j0 = np.clip(np.floor(x).astype(int), 0, n - 1)
    j1 = np.clip(j0 + 1, 0, n - 1)
    t = np.clip(x - np.floor(x), 0.0, 1.0)
    t = np.where(x < 0.0, 0.0, t)
    return weights[:, j0] * (1.0 - t)[None, :, None] + weights[:, j1] * t[None, :, None]


def ggx_lobe(alpha, wi, wo, shadowing="correlated"):
    """Cycles' GGX reflection without Fresnel, D G / (4 cos_i cos_o), for unit vectors (..., 3)."""
    a2 = np.maximum(alpha, 1e-7) ** 2
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    ch2 = np.clip(h[..., 2], 0.0, 1.0) ** 2
    d = a2 / (np.pi * (1.0 + (a2 - 1.0) * ch2) ** 2)
    ci = np.clip(wi[..., 2], 1e-9, 1.0)
    co = np.clip(wo[..., 2], 1e-9, 1.0)

    def lam(c):
        return 0.5 * (np.sqrt(1.0 + a2 * np.maximum(1.0 / (c * c) - 1.0, 0.0)) - 1.0)

    if shadowing == "correlated":
        g = 1.0 / (1.0 + lam(ci) + lam(co))
    elif shadowing == "separable":
        g = 1.0 / ((1.0 + lam(ci)) * (1.0 + lam(co)))
    else:
        raise ValueError(f"unknown shadowing {shadowing!r}")
    return d * g / (4.0 * ci * co)


def lobes_brdf(fit: LobeFit, wi, wo):
    """The model for a LobeFit: (3, n) for unit vectors (n, 3), the colours at each wo's view."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    theta = np.degrees(np.arccos(np.clip(wo[:, 2], -1.0, 1.0)))
    w = fit.weights_at(theta)  # (1 + K, n, 3)
    out = w[0].T / np.pi
    for k, r in enumerate(fit.roughness):
        out = out + w[k + 1].T * ggx_lobe(r * r, wi, wo, fit.shadowing)[None, :]
    return out


def _features(rough, wi, wo, shadowing):
    wo_b = np.broadcast_to(wo, wi.shape)
    rows = [np.full(len(wi), 1.0 / np.pi)]
    rows += [ggx_lobe(r * r, wi, wo_b, shadowing) for r in rough]
    return np.stack(rows)


def _nnls_gram(G, b):
    """min x.G.x - 2 x.b over x >= 0 (G positive definite, a handful of unknowns): active set."""
    from scipy.optimize import nnls

    L = np.linalg.cholesky(G)
    x, _ = nnls(L.T, np.linalg.solve(L, b), maxiter=50 * len(b))
    return x


class _View:
    """One view's normal equations over the whole dictionary (diffuse first), per channel, with
    the albedo equation folded in."""

    def __init__(self, table, deg, wi, wo, w, shadowing, dictionary):
        from .merl import lookup

        rho, valid = lookup(table, wi, np.broadcast_to(wo, wi.shape))
        ok = valid.all(axis=0)
        wi, w, rho = wi[ok], w[ok], rho[:, ok]
        F = _features(dictionary, wi, wo, shadowing)  # (1 + R, n)
        self.share = pixel_share(deg)
        self.G = (F * w) @ F.T
        self.r = (rho * w) @ F.T  # (3, 1 + R)
        self.yy = np.sum(w * rho * rho, axis=1)  # (3,)
        a = F @ w  # each feature's albedo at this view
        alb = rho @ w  # (3,)
        lam = ALBEDO_WEIGHT * float(np.sum(self.yy)) / max(float(np.sum(alb * alb)), 1e-300)
        self.Ga = self.G + lam * np.outer(a, a)
        self.ra = self.r + lam * alb[:, None] * a[None, :]
        self.yya = self.yy + lam * alb * alb
        self.albedo = alb

    def solve(self, idx, channels=(0, 1, 2)):
        """Weights (3, len(idx)) on the columns ``idx`` and the cost (BRDF + albedo terms)."""
        G = self.Ga[np.ix_(idx, idx)]
        G = G + 1e-10 * np.trace(G) / len(idx) * np.eye(len(idx))
        x = np.zeros((3, len(idx)))
        cost = 0.0
        for c in channels:
            x[c] = _nnls_gram(G, self.ra[c, idx])
            cost += float(x[c] @ G @ x[c] - 2.0 * x[c] @ self.ra[c, idx] + self.yya[c])
        return x, cost


def _greedy(vs, n_lobes, n_dict, shares):
    """Indices (into the dictionary) of ``n_lobes`` lobes picked greedily for the views ``vs``:
    each step adds the one that lowers the pixel-share weighted cost (channel sum) most."""
    Ga = np.stack([v.Ga for v in vs])  # (V, M, M)
    ra = np.stack([v.ra.sum(axis=0) for v in vs])  # (V, M)
    yy = np.array([v.yya.sum() for v in vs])
    sh = np.asarray(shares, float)
    chosen = []
    for _ in range(min(n_lobes, n_dict)):
        best = None
        for k in range(n_dict):
            if k in chosen:
                continue
            idx = [0] + [1 + j for j in sorted(chosen + [k])]
            G = Ga[:, idx][:, :, idx]
            G = G + (1e-10 * np.trace(G, axis1=1, axis2=2) / len(idx))[:, None, None] * np.eye(len(idx))
            b = ra[:, idx]
            x = np.linalg.solve(G, b[:, :, None])[:, :, 0]  # unconstrained first: usually feasible
            for m in np.flatnonzero((x < 0.0).any(axis=1)):
                x[m] = _nnls_gram(G[m], b[m])
            cost = float(np.sum(sh * (np.einsum("vi,vij,vj->v", x, G, x) - 2.0 * np.sum(x * b, axis=1) + yy)))
            if best is None or cost < best[0]:
                best = (cost, k)
        chosen.append(best[1])
    return sorted(chosen)


def fit_lobes(table, n_lobes=N_LOBES, shadowing="correlated", n_views=N_VIEWS, dictionary=DICTIONARY) -> LobeFit:
    """Fit the model above to a MerlTable (missing cells left out). One set of roughness values
    serves every view (a roughness picked per view was measured too: no gain, issue 28)."""
    if shadowing not in SHADOWING:
        raise ValueError(f"unknown shadowing {shadowing!r}")
    dictionary = tuple(dictionary)
    views = texel_views_deg(n_views)
    vs = [
        _View(table, deg, wi, wo, w, shadowing, dictionary)
        for deg, (wi, wo, w) in zip(views, view_quadrature(views, N_PHI_H))
    ]
    pick = _greedy(vs, min(n_lobes, len(dictionary)), len(dictionary), [v.share for v in vs])
    idx = [0] + [1 + k for k in pick]
    W = np.zeros((len(idx), n_views, 3))
    for j, v in enumerate(vs):
        W[:, j, :] = v.solve(idx)[0].T
    rough = tuple(dictionary[k] for k in pick)
    err, alb_err = measure(LobeFit(rough, W, shadowing, 0.0, 0.0), table)
    return LobeFit(rough, W, shadowing, err, alb_err)


def measure(fit: LobeFit, table, views_deg=ERROR_VIEWS_DEG):
    """(BRDF error, albedo error) of ``fit`` against ``table`` at ``views_deg``: the relative
    L2 error, cosine and pixel-share weighted over all channels, and the largest relative error
    of the directional albedo over the views and channels (where the table holds 0.1 % of its
    largest albedo)."""
    from .merl import lookup

    num = den = 0.0
    alb_t, alb_f = [], []
    for deg, (wi, wo, w) in zip(views_deg, view_quadrature(views_deg, N_PHI_H)):
        wo_b = np.broadcast_to(wo, wi.shape)
        rho, valid = lookup(table, wi, wo_b)
        ok = valid.all(axis=0)
        wi, wo_b, w, rho = wi[ok], wo_b[ok], w[ok], rho[:, ok]
        vals = lobes_brdf(fit, wi, wo_b)
        s = pixel_share(deg)
        num += s * float(np.sum(w * (vals - rho) ** 2))
        den += s * float(np.sum(w * rho**2))
        alb_t.append(rho @ w)
        alb_f.append(vals @ w)
    alb_t, alb_f = np.array(alb_t), np.array(alb_f)
    held = alb_t > 1e-3 * max(float(alb_t.max()), 1e-12)
    alb_err = float(np.max(np.abs(alb_f - alb_t)[held] / alb_t[held])) if held.any() else 0.0
    return math.sqrt(num / den) if den > 0 else 0.0, alb_err
