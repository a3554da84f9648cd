"""Equirectangular environment maps: lookups, importance sampling, prefiltering, irradiance.

The map is an array (H, W, 3) of linear radiance with its top row first, as image files store
it (loading happens outside the engine). Mapping, as Blender's world Environment Texture
(measured on Cycles 4.5): a world direction d = (x, y, z), z up, goes to
u = 0.5 - atan2(y, x) / 2 pi (so +X is the image centre) and to the row at elevation
asin(z), top row at z = 1. Texels are constant (Cycles' 'Closest' interpolation), which is
what every renderer here shows, so all of them integrate the same function.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np

from ..geometry import HALF_PI
from ..limits import check

LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)  # Rec. 709 weights of a texel's light

NEGATIVE_SHARE = 1e-3  # of a map's light; filtered HDRIs hold slight negatives (Blender's courtyard: -1.6e-4)


def check_radiance(pixels, name="environment"):
    """Refuse a map no renderer can show the same way: NaN or inf anywhere, no light at all, or
    negative values holding more than NEGATIVE_SHARE of its light (below that they are
    ringing from filtering: the baked path clamps them to 0, and the OSL path's difference
    stays under that share). Both preview paths call this on every map file, so a map one
    path would render is never refused by the other."""
    a = np.asarray(pixels)[..., :3]
    finite = np.isfinite(a)
    if not finite.all():
        raise ValueError(f"{name}: the map holds {int((~finite).sum())} NaN or inf values")
    pos = float(np.maximum(a, 0.0).sum(dtype=np.float64))
    if pos <= 0.0:
        raise ValueError(f"{name}: the map holds no light (every value is zero or negative)")
    neg = float(np.minimum(a, 0.0).sum(dtype=np.float64))
    if -neg > NEGATIVE_SHARE * pos:
        raise ValueError(
            f"{name}: the map holds {int((a < 0).sum())} negative values (down to {float(a.min()):.3g}, "
            f"{-neg / pos:.1%} of its light); radiance cannot be negative"
        )


class Environment:
    def __init__(self, pixels, name: str = ""):
        a = np.asarray(pixels)
        if a.ndim != 3 or a.shape[2] < 3 or a.shape[0] < 2 or a.shape[1] < 4:
            raise ValueError(f"{name or 'environment'}: need an (H, W, 3) image, got shape {a.shape}")
        a = np.ascontiguousarray(a[..., :3], dtype=np.float32)
        if not np.isfinite(a).all():
            raise ValueError(f"{name or 'environment'}: the image holds NaN or inf values")
        self.pixels = np.maximum(a, 0.0)
        self.name = name
        self.height, self.width = a.shape[:2]
        h, w = self.height, self.width
        elev_edges = HALF_PI - np.arange(h + 1) * (math.pi / h)
        self.z_edges = np.sin(elev_edges)  # decreasing, z_edges[0] = 1
        self.row_omega = (2.0 * math.pi / w) * (self.z_edges[:-1] - self.z_edges[1:])  # solid angle per texel
        self.flat = self.pixels.reshape(-1, 3)
        self._key = None
        self._sampler = None
        self._mips = None
        self._irr = None
        self._irr_maps = {}
        self._split = None

    # --- construction helpers ---------------------------------------------------------
    @classmethod
    def constant(cls, rgb, width=64, height=32, name="constant"):
        width, height = check("image_side", width, "width"), check("image_side", height, "height")
        return cls(np.broadcast_to(np.asarray(rgb, np.float32), (height, width, 3)), name)

    @classmethod
    def from_function(cls, fn, width=256, height=128, name="function"):
        """Texel values = fn(direction at the texel centre), fn: (n, 3) -> (n, 3)."""
        width, height = check("image_side", width, "width"), check("image_side", height, "height")
        v = (np.arange(height) + 0.5) / height
        u = (np.arange(width) + 0.5) / width
        uu, vv = np.meshgrid(u, v)
        d = uv_to_direction(uu.ravel(), vv.ravel())
        return cls(np.asarray(fn(d), np.float32).reshape(height, width, 3), name)

    def content_key(self) -> str:
        if self._key is None:
            h = hashlib.sha256(b"env-v1")
            h.update(np.asarray(self.pixels.shape, "<i8").tobytes())
            h.update(self.pixels.tobytes())
            self._key = h.hexdigest()
        return self._key

    # --- lookups ----------------------------------------------------------------------
    def texel(self, d):
        """Flat texel index of world directions (n, 3)."""
        u, v = direction_to_uv(d)
        col = np.minimum((u * self.width).astype(np.int64), self.width - 1)
        row = np.clip((v * self.height).astype(np.int64), 0, self.height - 1)
        return row * self.width + col

    def lookup(self, d):
        return self.flat[self.texel(d)]

    # --- importance sampling (luminance x solid angle, with a uniform floor) ------------
    def _build_sampler(self):
        lum = self.pixels @ LUMINANCE
        omega = np.broadcast_to(self.row_omega[:, None], lum.shape)
        energy = (lum * omega).ravel().astype(float)
        total = energy.sum()
        # A floor of uniform sampling keeps the density positive wherever light could be.
        p = omega.ravel() / (4.0 * math.pi)
        if total > 0:
            p = 0.9 * energy / total + 0.1 * p
        cdf = np.cumsum(p)
        cdf /= cdf[-1]
        self._sampler = (p / cdf[-1], cdf, omega.ravel().copy())

    def sample(self, u1, u2, u3):
        """Directions (n, 3) drawn texel-wise by energy, uniformly in solid angle inside the
        texel; returns (d, pdf) with pdf per steradian."""
        if self._sampler is None:
            self._build_sampler()
        p, cdf, omega = self._sampler
        idx = np.minimum(np.searchsorted(cdf, np.asarray(u1, float), side="right"), len(cdf) - 1)
        row, col = np.divmod(idx, self.width)
        u = (col + np.asarray(u2, float)) / self.width
        z = self.z_edges[row] + np.asarray(u3, float) * (self.z_edges[row + 1] - self.z_edges[row])
        d = _direction(u, z)
        return d, p[idx] / omega[idx]

    def pdf(self, d):
        if self._sampler is None:
            self._build_sampler()
        p, _, omega = self._sampler
        idx = self.texel(d)
        return p[idx] / omega[idx]

    # --- lights and the rest ------------------------------------------------------------------
    def split(self, contrast: float = 2.0):
        """(bright, residual): the map clamped at ``contrast`` times its mean luminance (the
        residual: continuous, at most that bright, so prefiltering it is nearly unbiased) and
        the excess above the clamp (``BrightTexels``: small bright lights, sampled on their
        own; prefiltering them would smear them and lobe sampling finds them rarely).
        residual + bright = the map, texel by texel."""
        contrast = check("contrast", contrast, "contrast")
        if self._split is None:
            lum = (self.flat @ LUMINANCE).astype(float)
            omega = np.repeat(self.row_omega, self.width)
            limit = contrast * float(np.sum(lum * omega)) / (4.0 * math.pi)
            over = np.flatnonzero(lum > limit) if limit > 0 else np.zeros(0, np.int64)
            keep = np.ones(lum.size)
            keep[over] = limit / lum[over]
            rest = self.flat * keep[:, None].astype(np.float32)
            excess = self.flat[over] * (1.0 - keep[over, None])
            residual = Environment(rest.reshape(self.pixels.shape), self.name + " (clamped)")
            self._split = (BrightTexels(self, over, excess, (lum[over] - limit) * omega[over]), residual)
        return self._split

    # --- prefiltered lookups (filtered importance sampling) ---------------------------------
    def _build_mips(self):
        levels = [self.pixels.astype(np.float32)]
        weights = [np.broadcast_to(self.row_omega[:, None], (self.height, self.width)).astype(np.float32)]
        while levels[-1].shape[0] % 2 == 0 and levels[-1].shape[1] % 2 == 0 and levels[-1].shape[0] >= 4:
            a, w = levels[-1], weights[-1]
            h, wd = a.shape[:2]
            ww = w.reshape(h // 2, 2, wd // 2, 2)
            s = (a * w[..., None]).reshape(h // 2, 2, wd // 2, 2, 3).sum(axis=(1, 3))
            wsum = ww.sum(axis=(1, 3))
            levels.append((s / wsum[..., None]).astype(np.float32))
            weights.append(wsum)
        self._mips = levels

    def lookup_filtered(self, d, solid_angle):
        """Radiance averaged over about ``solid_angle`` sr around each direction: a MIP level
        whose texels cover that much, blended linearly between levels. Below one texel it is
        the plain (nearest) lookup, so narrow lobes see the map exactly."""
        if self._mips is None:
            self._build_mips()
        u, v = direction_to_uv(d)
        cos_el = np.sqrt(np.maximum(1.0 - np.asarray(d)[:, 2] ** 2, 1e-4))
        texel0 = (2.0 * math.pi**2) / (self.width * self.height) * cos_el
        lam = 0.5 * np.log2(np.maximum(np.asarray(solid_angle, float) / texel0, 1e-30))
        lam = np.clip(lam, 0.0, len(self._mips) - 1)
        out = np.empty((len(u), 3))
        lo = np.floor(lam).astype(np.int64)
        frac = lam - lo
        # level 0 at its texels (nearest), coarser levels bilinear
        for level in np.unique(lo):
            sel = lo == level
            a = self._nearest(0, u[sel], v[sel]) if level == 0 else self._bilinear(level, u[sel], v[sel])
            nxt = min(level + 1, len(self._mips) - 1)
            b = self._bilinear(nxt, u[sel], v[sel])
            f = frac[sel][:, None]
            out[sel] = (1.0 - f) * a + f * b
        return out

    def _nearest(self, level, u, v):
        a = self._mips[level]
        h, w = a.shape[:2]
        col = np.minimum((u * w).astype(np.int64), w - 1)
        row = np.clip((v * h).astype(np.int64), 0, h - 1)
        return a[row, col]

    def _bilinear(self, level, u, v):
        a = self._mips[level]
        h, w = a.shape[:2]
        x = u * w - 0.5
        y = np.clip(v * h - 0.5, 0.0, h - 1.0)
        x0 = np.floor(x)
        y0 = np.minimum(np.floor(y), h - 2) if h > 1 else np.zeros_like(y)
        fx = (x - x0)[:, None]
        fy = (y - y0)[:, None]
        x0 = x0.astype(np.int64) % w
        x1 = (x0 + 1) % w
        y0 = y0.astype(np.int64)
        y1 = np.minimum(y0 + 1, h - 1)
        return (1 - fy) * ((1 - fx) * a[y0, x0] + fx * a[y0, x1]) + fy * ((1 - fx) * a[y1, x0] + fx * a[y1, x1])

    # --- irradiance ------------------------------------------------------------------------
    def _build_irradiance(self, max_bright=8192, bright_share=0.9, coarse_width=128):
        """Point set for E(n) = sum L max(0, n.d) omega: the brightest texels one by one (a sun
        stays sharp; up to ``bright_share`` of the energy) and the rest area-averaged onto a
        coarse grid (what is left is smooth, and so is the cosine)."""
        lum = self.flat @ LUMINANCE
        omega = np.repeat(self.row_omega, self.width)
        energy = lum * omega
        top = np.argsort(-energy)[:max_bright]
        share = np.cumsum(energy[top]) / max(float(energy.sum()), 1e-300)
        bright = top[: int(np.searchsorted(share, bright_share)) + 1] if energy.sum() > 0 else top[:0]
        rest = self.pixels.copy().reshape(-1, 3)
        rest[bright] = 0.0
        rest = rest.reshape(self.height, self.width, 3)
        f = max(1, self.width // coarse_width)
        while self.width % f or self.height % f:
            f -= 1
        h, w = self.height // f, self.width // f
        om = np.broadcast_to(self.row_omega[:, None], (self.height, self.width))
        coarse = (rest * om[..., None]).reshape(h, f, w, f, 3).sum(axis=(1, 3))  # radiance x omega
        zc = (self.z_edges[::f][:-1] + self.z_edges[::f][1:]) * 0.5
        uu, zz = np.meshgrid((np.arange(w) + 0.5) / w, zc)
        d_coarse = _direction(uu.ravel(), zz.ravel())
        row, col = np.divmod(bright, self.width)
        zb = 0.5 * (self.z_edges[row] + self.z_edges[row + 1])
        d_bright = _direction((col + 0.5) / self.width, zb)
        dirs = np.concatenate([d_bright, d_coarse])
        power = np.concatenate([self.flat[bright] * omega[bright, None], coarse.reshape(-1, 3)])
        self._irr = (dirs.astype(np.float32), power.astype(np.float32))

    def irradiance_map(self, diameter: int):
        """E at the normal of each texel centre of a sphere bake, (D, D, 3), rows top first.

        Material independent, so it is computed once per map and resolution (texel centres
        outside the disk use the nearest point on the rim)."""
        d = check("diameter", diameter)
        if d not in self._irr_maps:
            c = (np.arange(d) + 0.5) * (2.0 / d) - 1.0
            x, z = np.meshgrid(c, -c)
            r = np.maximum(np.sqrt(x * x + z * z), 1.0)
            x, z = x / r, z / r
            n = np.stack([x, -np.sqrt(np.maximum(1.0 - x * x - z * z, 0.0)), z], axis=-1).reshape(-1, 3)
            self._irr_maps[d] = self.irradiance(n).reshape(d, d, 3)
        return self._irr_maps[d]

    def irradiance(self, normals, chunk: int = 64):
        """E(n) per normal, (n, 3): the cosine-weighted integral of the map."""
        chunk = check("chunk", chunk, "chunk")
        if self._irr is None:
            self._build_irradiance()
        dirs, power = self._irr
        dirs_t = np.ascontiguousarray(dirs.T)
        normals = np.asarray(normals, np.float32)
        out = np.empty((len(normals), 3))
        for s in range(0, len(normals), chunk):  # small blocks stay in cache
            c = normals[s : s + chunk] @ dirs_t
            np.maximum(c, 0.0, out=c)
            out[s : s + chunk] = c @ power
        return out


class BrightTexels:
    """Radiance on a set of texels of a map, with each texel's share of the set's energy (the
    bake samples them through ``lights.LightClusters``)."""

    def __init__(self, env, texels, radiance, energy):
        self.env = env
        self.texels = np.asarray(texels, np.int64)
        self.size = len(self.texels)
        self.slot = np.full(env.height * env.width, -1, np.int64)  # flat texel -> position in the set
        self.slot[self.texels] = np.arange(self.size)
        e = np.asarray(energy, float)
        self.p = e / e.sum() if self.size and e.sum() > 0 else np.full(self.size, 1.0 / max(self.size, 1))
        self.omega = np.repeat(env.row_omega, env.width)[self.texels]
        self.radiance = np.asarray(radiance, float).reshape(-1, 3)

    def lookup_pdf(self, d):
        """(radiance (n, 3) of the set, zero outside it; pdf per sr)."""
        slot = self.slot[self.env.texel(d)]
        inside = slot >= 0
        s = np.where(inside, slot, 0)
        rad = np.where(inside[:, None], self.radiance[s], 0.0) if self.size else np.zeros((len(slot), 3))
        pdf = np.where(inside, self.p[s] / self.omega[s], 0.0) if self.size else np.zeros(len(slot))
        return rad, pdf


def direction_to_uv(d):
    """(u, v) with v measured from the top row (0 at z = 1)."""
    d = np.asarray(d, float)
    u = 0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2.0 * math.pi)
    u = u - np.floor(u)
    v = 0.5 - np.arcsin(np.clip(d[:, 2], -1.0, 1.0)) / math.pi
    return u, v


def _direction(u, z):
    az = math.pi * (1.0 - 2.0 * np.asarray(u, float))
    z = np.clip(np.asarray(z, float), -1.0, 1.0)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(az), r * np.sin(az), z], axis=-1)


def uv_to_direction(u, v):
    return _direction(u, np.sin(HALF_PI - np.asarray(v, float) * math.pi))
