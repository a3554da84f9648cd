"""Analytic, reciprocal BRDFs used to make sample tables (no measured data is shipped).

Each model is a callable ``brdf(wi, wo) -> (3, n)`` on arrays of unit vectors (..., 3),
in the local frame whose z is the normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from addon.core.microsurface import masking, ndf, smith_lambda, tan2


def _rgb(v):
    return np.broadcast_to(np.asarray(v, dtype=float), (3,)).copy()


def _microfacet(distribution, alpha, f0, kd, masking_form, wi, wo):
    """kd / pi + F D G / (4 cos_i cos_o): the microsurface's D and Smith's G of ``masking_form``
    (``core.microsurface``, exact), Schlick's F from ``f0``."""
    wi, wo = np.asarray(wi, float), np.asarray(wo, float)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    ch = np.clip(h[..., 2], 0.0, 1.0)
    d = ndf(distribution, ch, alpha)
    ci = np.clip(wi[..., 2], 1e-12, 1.0)
    co = np.clip(wo[..., 2], 1e-12, 1.0)
    a2 = alpha**2
    g = masking(smith_lambda(distribution, a2 * tan2(ci)), smith_lambda(distribution, a2 * tan2(co)), masking_form)
    cd = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
    f0 = _rgb(f0).reshape((3,) + (1,) * ch.ndim)
    fres = f0 + (1.0 - f0) * (1.0 - cd) ** 5
    spec = fres * (d * g / (4.0 * ci * co))
    return _rgb(kd).reshape((3,) + (1,) * ch.ndim) / np.pi + spec


@dataclass(frozen=True)
class Lambertian:
    albedo: tuple = (0.8, 0.8, 0.8)

    def __call__(self, wi, wo):
        n = np.asarray(wi).shape[:-1]
        return np.broadcast_to((_rgb(self.albedo) / np.pi).reshape((3,) + (1,) * len(n)), (3,) + n).copy()


@dataclass(frozen=True)
class Phong:
    """Diffuse plus a normalised lobe around the mirror: ks (n+2)/(2 pi) cos^n(wi, r(wo))."""

    kd: tuple = (0.1, 0.1, 0.1)
    ks: tuple = (0.5, 0.5, 0.5)
    exponent: float = 200.0

    def __call__(self, wi, wo):
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        r = wo * np.array([-1.0, -1.0, 1.0])
        c = np.clip(np.sum(wi * r, axis=-1), 0.0, 1.0)
        lobe = (self.exponent + 2.0) / (2.0 * np.pi) * c**self.exponent
        return _rgb(self.kd)[:, None] / np.pi + _rgb(self.ks)[:, None] * lobe.reshape(1, -1).reshape((1,) + c.shape)


@dataclass(frozen=True)
class GGX:
    """Microfacet GGX with Smith masking and Schlick Fresnel over a Lambertian base."""

    roughness: float = 0.1  # GGX alpha
    f0: tuple = (0.04, 0.04, 0.04)
    kd: tuple = (0.2, 0.2, 0.2)
    masking: str = "separable"  # or "correlated": height-correlated Smith, 1 / (1 + L_i + L_o)

    def __call__(self, wi, wo):
        return _microfacet("ggx", self.roughness, self.f0, self.kd, self.masking, wi, wo)


@dataclass(frozen=True)
class Beckmann:
    """Microfacet Beckmann with Smith masking (exact Lambda) and a Schlick Fresnel over a
    Lambertian base; the defaults have no Fresnel and no base."""

    roughness: float = 0.1  # Beckmann m
    f0: tuple = (1.0, 1.0, 1.0)
    kd: tuple = (0.0, 0.0, 0.0)
    masking: str = "separable"  # or "correlated" (height-correlated Smith)

    def __call__(self, wi, wo):
        return _microfacet("beckmann", self.roughness, self.f0, self.kd, self.masking, wi, wo)


@dataclass(frozen=True)
class BlinnPhong:
    """Diffuse plus a normalised Blinn-Phong lobe: ks (n+8)/(8 pi) cos^n(theta_h)."""

    kd: tuple = (0.0, 0.0, 0.0)
    ks: tuple = (1.0, 1.0, 1.0)
    exponent: float = 200.0

    def __call__(self, wi, wo):
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        ch = np.clip(h[..., 2], 0.0, 1.0)
        lobe = (self.exponent + 8.0) / (8.0 * np.pi) * ch**self.exponent
        return (
            _rgb(self.kd).reshape((3,) + (1,) * ch.ndim) / np.pi + _rgb(self.ks).reshape((3,) + (1,) * ch.ndim) * lobe
        )
