"""The moment lobe (paper Eq. 7-8) as a sampler, and the BRDFs a preview can show.

Directions are in the view-centred parametrization of SPEC §3: w_i = m(theta, phi) =
(sin t cos p, sin p, cos t cos p) with the view w_o = m(theta_o, 0). The moment measure is
d theta d phi; solid angle is d w = cos(phi) d theta d phi, and the cosine to the normal is
cos(theta) cos(phi). So the rendering integral of a slice against radiance L is

    L_o = int f(t, p) L(m(t, p)) cos(t) cos(p)^2 dt dp,

and with (t, p) drawn from a density q(t, p) (in dt dp) the estimator is f L cos t cos^2 p / q.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import ndtr, ndtri

from ..fits import truncated as _truncated
from ..fits.curves import LAMBERT_VARIANCE, MIN_SIGMA2, energy_curve
from ..geometry import HALF_PI

_SQRT_2PI = math.sqrt(2.0 * math.pi)
# Widest Gaussian used: within 0.3 % of uniform on the interval, and float32 (the OSL
# shader) still resolves its truncated variance. The Lambertian limit is reached here.
MAX_S = _truncated.MAX_S


# --- truncated Gaussians on [-pi/2, pi/2] ---------------------------------------------------


# The truncated Gaussian's mass and its tail-safe bounds are the one solver's (core.fits.truncated).
_oriented = _truncated._oriented
truncnorm_mass = _truncated.mass


def truncnorm_pdf(x, m, s):
    """Density of N(m, s^2) truncated to [-pi/2, pi/2] (Eq. 8: normalized on the interval), formed
    in logs so that a lobe centred beyond the horizon (its mass a sliver of the far tail) stays
    finite and right."""
    x = np.asarray(x, float)
    m = np.asarray(m, float)
    s = np.asarray(s, float)
    log_z = _truncated.log_mass((-HALF_PI - m) / s, (HALF_PI - m) / s) + np.log(s * _SQRT_2PI)
    inside = np.abs(x) <= HALF_PI
    return np.where(inside, np.exp(-0.5 * ((x - m) / s) ** 2 - log_z), 0.0)


def truncnorm_sample(m, s, u):
    """Inverse-CDF sample of the truncated Gaussian for uniforms ``u`` in [0, 1)."""
    lo, hi, flip = _oriented(m, s)
    plo, phi_ = ndtr(lo), ndtr(hi)
    z = ndtri(np.clip(plo + np.asarray(u, float) * (phi_ - plo), 1e-300, 1.0 - 1e-16))
    x = np.asarray(m, float) + flip * np.asarray(s, float) * np.clip(z, lo, hi)
    return np.clip(x, -HALF_PI, HALF_PI)


def truncated_params(mean, var, iters: int = 40):
    """(m, s) of the Gaussian whose truncation to [-pi/2, pi/2] has this mean and variance,
    by the one rule of ``core.fits.truncated`` (the mean kept, the variance capped where no truncated
    Gaussian reaches it). The OSL shaders run the same iteration. ``iters`` is checked there."""
    m, s, _ = _truncated.solve(mean, var, iters)
    return m, s


# --- lobes per view -----------------------------------------------------------------------------


@dataclass
class LobeTable:
    """Per-view lobe parameters on a grid of theta_o: untruncated (m_t, s_t) for theta and
    s_p for phi (centred at 0), and the share of the estimator given to the lobe."""

    theta_o: np.ndarray
    m_t: np.ndarray
    s_t: np.ndarray
    s_p: np.ndarray

    @classmethod
    def from_moments(cls, theta_o, mu_theta, var_theta, var_phi):
        theta_o = np.asarray(theta_o, float)
        mu = np.nan_to_num(np.asarray(mu_theta, float), nan=0.0)
        vt = np.nan_to_num(np.asarray(var_theta, float), nan=LAMBERT_VARIANCE)
        vp = np.nan_to_num(np.asarray(var_phi, float), nan=LAMBERT_VARIANCE)
        vt = np.clip(vt, 1e-8, LAMBERT_VARIANCE)
        vp = np.clip(vp, 1e-8, LAMBERT_VARIANCE)
        m_t, s_t = truncated_params(mu, vt)
        _, s_p = truncated_params(np.zeros_like(vp), vp)
        return cls(theta_o, m_t, s_t, s_p)

    def at(self, theta_o):
        """Parameters interpolated at the given views (clamped to the grid)."""
        t = np.clip(np.asarray(theta_o, float), self.theta_o[0], self.theta_o[-1])
        if len(self.theta_o) == 1:
            return (np.full(t.shape, self.m_t[0]), np.full(t.shape, self.s_t[0]), np.full(t.shape, self.s_p[0]))
        return (
            np.interp(t, self.theta_o, self.m_t),
            np.interp(t, self.theta_o, self.s_t),
            np.interp(t, self.theta_o, self.s_p),
        )


# --- BRDFs ----------------------------------------------------------------------------------------


def _rgb(v):
    return tuple(float(x) for x in np.broadcast_to(np.asarray(v, float), (3,)))


@dataclass(frozen=True)
class MomentParams:
    """The moment model of one material (SPEC §3, Eq. 7-8, with the Sec. 3.4 energy spline).

    rho(theta_o; t, p) = kd + alpha_c(theta_o) g(t; mean mu_slope theta_o, var sigma2)
    g(p; mean 0, var sigma2), g truncated Gaussians normalized on [-pi/2, pi/2] whose
    truncated moments are the targets. kd is the BRDF floor (1/sr); alpha per channel."""

    alpha_b: tuple
    alpha1: tuple
    m1: tuple
    theta0: float
    theta1: float
    mu_slope: float
    sigma2: float
    kd: tuple = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for name in ("alpha_b", "alpha1", "m1", "kd"):
            object.__setattr__(self, name, _rgb(getattr(self, name)))
        vals = [*self.alpha_b, *self.alpha1, *self.m1, *self.kd, self.theta0, self.theta1, self.mu_slope, self.sigma2]
        if not all(math.isfinite(v) for v in vals):
            raise ValueError("moment parameters must be finite")
        if not 0.0 < self.sigma2 <= LAMBERT_VARIANCE * (1 + 1e-9):
            raise ValueError(f"sigma2 must be in (0, pi^2/12], got {self.sigma2}")

    @classmethod
    def from_fit(cls, fit: dict, kd=(0.0, 0.0, 0.0)) -> "MomentParams":
        """From ``fits.fit_material`` output (per-channel energy; shared knots, slope, variance).

        A material with no specular lobe (all energy in kd) gets zero energy and a
        Lambertian-wide lobe."""
        ch = fit.get("channels") or {}
        if fit.get("mu_slope") is None or fit.get("sigma2") is None or not ch:
            z = (0.0, 0.0, 0.0)
            return cls(z, z, z, fit.get("theta0", 0.785), fit.get("theta1", 1.31), 0.0, LAMBERT_VARIANCE, kd)
        pick = [ch.get(c, {}) for c in "rgb"]
        return cls(
            tuple(p.get("alpha_b", 0.0) for p in pick),
            tuple(p.get("alpha1", 0.0) for p in pick),
            tuple(p.get("m1", 0.0) for p in pick),
            float(fit["theta0"]),
            float(fit["theta1"]),
            float(fit["mu_slope"]),
            float(np.clip(fit["sigma2"], MIN_SIGMA2, LAMBERT_VARIANCE)),
            kd,
        )

    def edited(
        self,
        strength: float = 1.0,
        colour=(1.0, 1.0, 1.0),
        grazing_boost: float = 1.0,
        mu_slope: float | None = None,
        sigma2: float | None = None,
    ) -> "MomentParams":
        """The sliders applied to the model, exactly as the editing engine defines the energy:
        alpha' = strength colour (alpha_b + boost (alpha - alpha_b)). The Hermite curve is
        linear in its end values and slopes, so this is again a curve of the same form.
        The sliders are checked against their declared ranges (``core.limits``), as ``edit``'s."""
        from types import SimpleNamespace

        from ..limits import TARGET_FIELDS, check_targets

        sliders = dict(strength=strength, colour=colour, grazing_boost=grazing_boost, mu_slope=mu_slope, sigma2=sigma2)
        check_targets(SimpleNamespace(**sliders), TARGET_FIELDS)
        k = np.asarray(colour, float) * float(strength)
        b = float(grazing_boost)
        ab, a1, m1 = (np.asarray(v) for v in (self.alpha_b, self.alpha1, self.m1))
        return replace(
            self,
            alpha_b=tuple(k * ab),
            alpha1=tuple(k * ((1 - b) * ab + b * a1)),
            m1=tuple(k * b * m1),
            mu_slope=self.mu_slope if mu_slope is None else float(mu_slope),
            sigma2=self.sigma2 if sigma2 is None else float(sigma2),
        )

    def energy(self, theta_o):
        """alpha per channel at the views, (n, 3); never negative."""
        a = energy_curve(theta_o, self.alpha_b, self.theta0, self.theta1, self.alpha1, self.m1)
        return np.maximum(a, 0.0)

    def content_key(self) -> str:
        return hashlib.sha256(repr(("moment-params-v1", self.__dict__)).encode()).hexdigest()


class ModelBRDF:
    """Paper Eq. 7-8 with kd added: what the OSL moment-model shader renders."""

    kind = "model"

    def __init__(self, params: MomentParams, grid=None):
        self.params = params
        self.kd = np.asarray(params.kd, float)
        grid = np.radians(np.linspace(0.0, 89.5, 180)) if grid is None else np.asarray(grid, float)
        m_t, s_t = truncated_params(params.mu_slope * grid, np.full_like(grid, params.sigma2))
        _, s_p = truncated_params(np.zeros(1), np.array([params.sigma2]))
        self.lobes = LobeTable(grid, m_t, s_t, np.full_like(grid, s_p[0]))
        self._key = params.content_key()

    def content_key(self):
        return self._key

    def evaluate(self, theta, phi, theta_o):
        m_t, s_t, s_p = self.lobes.at(theta_o)
        g = truncnorm_pdf(theta, m_t, s_t) * truncnorm_pdf(phi, 0.0, s_p)
        return self.kd + self.params.energy(theta_o) * g[:, None]

    def lobe_weight(self, theta_o):
        """Specular energy per view (avg channel), to share samples between strategies."""
        return self.params.energy(theta_o).mean(axis=1)

    def sample(self, theta_o, u1, u2):
        """(theta, phi) from the moment lobe itself (exact importance sampling of the model)."""
        m_t, s_t, s_p = self.lobes.at(theta_o)
        return truncnorm_sample(m_t, s_t, u1), truncnorm_sample(0.0, s_p, u2)

    def pdf(self, theta, phi, theta_o):
        """Density of ``sample`` per d theta d phi."""
        m_t, s_t, s_p = self.lobes.at(theta_o)
        return truncnorm_pdf(theta, m_t, s_t) * truncnorm_pdf(phi, 0.0, s_p)


class TableBRDF:
    """A MERL table, nearest-cell lookup (as MERL's reader); missing cells render as kd.

    ``profiles`` (the table's moment profiles, kd split on) give the per-view sampling lobe;
    computed when not given."""

    kind = "table"

    def __init__(self, table, profiles=None, kd=None):
        from ..file.merl import N_CELLS

        self.table = table
        if profiles is None:
            from ..profiles.compute import compute_profiles

            profiles = compute_profiles(table, max_order=2)
        self.profiles = profiles
        self.kd = np.asarray(profiles.kd if kd is None else kd, float)
        # A cell that was not measured has no known specular part: it renders as the kd floor
        # (zero would paint a dark rim wherever grazing cells are missing).
        self.values = np.ascontiguousarray(np.where(table.valid, table.rho, self.kd[:, None]).T, dtype=np.float32)
        if self.values.shape != (N_CELLS, 3):
            raise ValueError("not a MERL table")
        p = profiles["avg"]
        self.lobes = LobeTable.from_moments(profiles.theta_o, p["mu_theta"], p["sigma_tt"], p["sigma_pp"])
        self._alpha = np.nan_to_num(np.asarray(p["alpha"], float))
        kd_avg = float(np.mean(self.kd))
        self.half = HalfVectorSampler(lambda t, p, o: np.maximum(self.evaluate(t, p, o).mean(axis=1) - kd_avg, 0.0))
        self._key = None

    def content_key(self):
        if self._key is None:
            h = hashlib.sha256(b"merl-table-v1")
            h.update(self.values.tobytes())
            h.update(np.asarray(self.kd, "<f8").tobytes())
            self._key = h.hexdigest()
        return self._key

    def evaluate(self, theta, phi, theta_o):
        from ..file.merl import cell_indices_view

        to = np.asarray(theta_o, float)
        cells = cell_indices_view(theta, phi, np.sin(to), np.cos(to))
        return self.values[cells].astype(float)

    def lobe_weight(self, theta_o):
        return np.interp(np.asarray(theta_o, float), self.profiles.theta_o, self._alpha)

    def sample(self, theta_o, u1, u2):
        return self.half.sample(theta_o, u1, u2)

    def pdf(self, theta, phi, theta_o):
        return self.half.pdf(theta, phi, theta_o)


class HalfVectorSampler:
    """Importance sampling of a tabulated BRDF through its half vector.

    Measured (and microfacet) lobes are concentrated in theta_h, with a sharp core and heavy
    tails that a Gaussian of the same variance fits badly (it wastes samples in the core's
    shoulders and misses the tails). So, for each of 90 view rows theta_o, a distribution
    over the table's own theta_h rings (sqrt-spaced: fine at the mirror), each ring weighted
    by what it contributes: the specular part times cos(theta_i) times the Jacobian
    4 (w_o.h) of the reflection, averaged over the ring (directions below the horizon count
    zero), with a 5 % floor spread by solid angle. Inside a ring h is uniform; then
    w_i = reflect(w_o, h), whose density is p_h(h) / (4 w_o.h)."""

    FLOOR = 0.05

    def __init__(self, spec_fn, n_rows: int = 90, n_rings: int = 90, sub=(3, 24)):
        """``spec_fn(theta, phi, theta_o) -> (n,)``: the non-negative specular part to follow;
        ``n_rows`` view rows, ``n_rings`` theta_h rings, ``sub`` quadrature points per ring in
        cos(theta_h) and in phi_h (each checked against ``limits.RANGES``)."""
        from ..limits import check

        n_rows, n_rings = check("sampler_rows", n_rows, "n_rows"), check("sampler_rings", n_rings, "n_rings")
        if len(tuple(sub)) != 2:
            raise ValueError(f"sub: expected two counts (in cos theta_h and in phi_h), got {sub!r}")
        sub = tuple(check("sampler_sub", v, "sub") for v in sub)
        self.rows, self.n = n_rows, n_rings
        edges = (np.arange(n_rings + 1) / n_rings) ** 2 * HALF_PI
        self.cos_edges = np.cos(edges)
        self.ring = 2.0 * math.pi * (self.cos_edges[:-1] - self.cos_edges[1:])
        # quadrature inside each ring: midpoints in cos(theta_h) and in phi_h over [0, pi) (symmetry)
        nc, na = sub
        fc = (np.arange(nc) + 0.5) / nc
        cos_h = self.cos_edges[:-1, None] + fc[None, :] * (self.cos_edges[1:] - self.cos_edges[:-1])[:, None]
        a = (np.arange(na) + 0.5) / na * math.pi
        w = np.zeros((n_rows, n_rings))
        for j in range(n_rows):
            to = (j + 0.5) / n_rows * HALF_PI
            ch = np.repeat(cos_h.ravel(), na)
            aa = np.tile(a, cos_h.size)
            sh = np.sqrt(np.maximum(1 - ch * ch, 0.0))
            hx, hy, hz = sh * np.cos(aa), sh * np.sin(aa), ch
            ox, oz = math.sin(to), math.cos(to)
            dot = ox * hx + oz * hz
            ix, iy, iz = 2 * dot * hx - ox, 2 * dot * hy, 2 * dot * hz - oz
            up = (iz > 1e-9) & (dot > 0)
            th = np.arctan2(ix, np.maximum(iz, 1e-12))
            ph = np.arcsin(np.clip(iy, -1.0, 1.0))
            val = np.zeros_like(ch)
            if up.any():
                val[up] = spec_fn(th[up], ph[up], np.full(int(up.sum()), to)) * iz[up] * 4.0 * dot[up]
            w[j] = val.reshape(n_rings, nc * na).mean(axis=1) * self.ring
        tot = w.sum(axis=1, keepdims=True)
        uniform = self.ring / self.ring.sum()
        p = np.where(tot > 0, (1.0 - self.FLOOR) * w / np.where(tot > 0, tot, 1.0) + self.FLOOR * uniform, uniform)
        self.p = p / p.sum(axis=1, keepdims=True)  # (rows, rings)
        self.cdf = np.cumsum(self.p, axis=1)
        self.cdf[:, -1] = 1.0
        self._flat = (self.cdf + np.arange(n_rows)[:, None]).ravel()  # rows offset: one searchsorted

    def _row(self, theta_o):
        return np.clip((np.asarray(theta_o, float) / HALF_PI * self.rows).astype(np.int64), 0, self.rows - 1)

    def sample(self, theta_o, u1, u2):
        theta_o = np.asarray(theta_o, float)
        j = self._row(theta_o)
        u1 = np.clip(np.asarray(u1, float), 0.0, 1.0 - 1e-12)
        k = np.searchsorted(self._flat, j + u1, side="right") - j * self.n
        i = np.clip(k, 0, self.n - 1)
        lo = np.where(i > 0, self.cdf[j, np.maximum(i - 1, 0)], 0.0)
        r = np.clip((u1 - lo) / np.maximum(self.p[j, i], 1e-300), 0.0, 1.0)  # reuse the remainder
        cos_h = self.cos_edges[i] + r * (self.cos_edges[i + 1] - self.cos_edges[i])
        sin_h = np.sqrt(np.maximum(1.0 - cos_h * cos_h, 0.0))
        a = 2.0 * math.pi * np.asarray(u2, float)
        hx, hy, hz = sin_h * np.cos(a), sin_h * np.sin(a), cos_h
        ox, oz = np.sin(theta_o), np.cos(theta_o)
        dot = ox * hx + oz * hz
        ix, iy, iz = 2 * dot * hx - ox, 2 * dot * hy, 2 * dot * hz - oz
        # below the horizon: returned at the horizon with zero density of use (pdf says so)
        theta = np.arctan2(ix, np.maximum(iz, 1e-12))
        phi = np.arcsin(np.clip(iy, -1.0, 1.0))
        bad = iz <= 0.0
        theta = np.where(bad, np.nan, theta)
        return theta, phi

    def pdf(self, theta, phi, theta_o):
        """Density per d theta d phi of ``sample`` at view-centred (theta, phi)."""
        theta_o = np.asarray(theta_o, float)
        ct, st, cp, sp = np.cos(theta), np.sin(theta), np.cos(phi), np.sin(phi)
        ix, iy, iz = st * cp, sp, ct * cp
        ox, oz = np.sin(theta_o), np.cos(theta_o)
        hx, hy, hz = ix + ox, iy, iz + oz
        norm = np.sqrt(hx * hx + hy * hy + hz * hz)
        norm = np.where(norm > 0, norm, 1.0)
        cos_h = np.clip(hz / norm, -1.0, 1.0)
        dot = (ox * hx + oz * hz) / norm
        th = np.arccos(cos_h)
        i = np.clip((np.sqrt(th / HALF_PI) * self.n).astype(np.int64), 0, self.n - 1)
        p_h = self.p[self._row(theta_o), i] / self.ring[i]
        return np.where(dot > 0, p_h / (4.0 * np.maximum(dot, 1e-300)), 0.0) * cp
