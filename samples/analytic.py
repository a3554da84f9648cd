"""Analytic, reciprocal BRDFs used to make sample tables (no measured data is shipped).

Each model is a callable ``brdf(wi, wo) -> (3, n)`` on arrays of unit vectors (..., 3),
in the local frame whose z is the normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _rgb(v):
    return np.broadcast_to(np.asarray(v, dtype=float), (3,)).copy()


def _masking(lam_i, lam_o, form):
    """Smith's shadowing-masking from the two Lambdas: separable or height-correlated."""
    if form == "separable":
        return 1.0 / ((1.0 + lam_i) * (1.0 + lam_o))
    if form == "correlated":
        return 1.0 / (1.0 + lam_i + lam_o)
    raise ValueError(f"unknown masking {form!r}")


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
    """Microfacet GGX with separable Smith masking and Schlick Fresnel over a Lambertian base."""

    roughness: float = 0.1  # GGX alpha
    f0: tuple = (0.04, 0.04, 0.04)
    kd: tuple = (0.2, 0.2, 0.2)
    masking: str = "separable"  # or "correlated": height-correlated Smith, 1 / (1 + L_i + L_o)

    def __call__(self, wi, wo):
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        a2 = self.roughness**2
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        ch = np.clip(h[..., 2], 0.0, 1.0)
        d = a2 / (np.pi * ((a2 - 1.0) * ch * ch + 1.0) ** 2)
        ci = np.clip(wi[..., 2], 1e-12, 1.0)
        co = np.clip(wo[..., 2], 1e-12, 1.0)

        def g1(c):
            t2 = (1.0 - c * c) / (c * c)
            return 2.0 / (1.0 + np.sqrt(1.0 + a2 * t2))

        def lam(c):  # Smith's Lambda for GGX
            t2 = (1.0 - c * c) / (c * c)
            return 0.5 * (np.sqrt(1.0 + a2 * t2) - 1.0)

        cd = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
        schlick = (1.0 - cd) ** 5
        f0 = _rgb(self.f0).reshape((3,) + (1,) * ch.ndim)
        fres = f0 + (1.0 - f0) * schlick
        # The separable form as g1 g1 (the sample tables' bytes); the same value as _masking's.
        g = g1(ci) * g1(co) if self.masking == "separable" else _masking(lam(ci), lam(co), self.masking)
        spec = fres * (d * g / (4.0 * ci * co))
        return _rgb(self.kd).reshape((3,) + (1,) * ch.ndim) / np.pi + spec


@dataclass(frozen=True)
class Beckmann:
    """Microfacet Beckmann with Smith masking (Walter et al. 2007's rational form of G1) and a
    Schlick Fresnel over a Lambertian base; the defaults have no Fresnel and no base."""

    roughness: float = 0.1  # Beckmann m
    f0: tuple = (1.0, 1.0, 1.0)
    kd: tuple = (0.0, 0.0, 0.0)
    masking: str = "separable"  # or "correlated" (height-correlated Smith, exact Lambda)

    def __call__(self, wi, wo):
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        m2 = self.roughness**2
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        ch = np.clip(h[..., 2], 1e-6, 1.0)
        d = np.exp(-(1.0 - ch * ch) / (ch * ch * m2)) / (np.pi * m2 * ch**4)
        ci = np.clip(wi[..., 2], 1e-12, 1.0)
        co = np.clip(wo[..., 2], 1e-12, 1.0)

        def g1(c):
            a = c / (self.roughness * np.sqrt(np.maximum(1.0 - c * c, 1e-300)))
            return np.where(a < 1.6, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a), 1.0)

        def lam(c):  # Smith's exact Lambda for Beckmann
            from scipy.special import erf

            a = c / (self.roughness * np.sqrt(np.maximum(1.0 - c * c, 1e-300)))
            return 0.5 * (erf(a) - 1.0) + np.exp(-a * a) / (2.0 * a * np.sqrt(np.pi))

        cd = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
        f0 = _rgb(self.f0).reshape((3,) + (1,) * ch.ndim)
        fres = f0 + (1.0 - f0) * (1.0 - cd) ** 5
        # The separable form keeps Walter et al.'s rational G1 (the sample tables' bytes).
        g = g1(ci) * g1(co) if self.masking == "separable" else _masking(lam(ci), lam(co), self.masking)
        spec = fres * (d * g / (4.0 * ci * co))
        return _rgb(self.kd).reshape((3,) + (1,) * ch.ndim) / np.pi + spec


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
