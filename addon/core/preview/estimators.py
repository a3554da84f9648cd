"""Outgoing radiance of the preview spheres: the fast bake and the converged reference.

Both integrate L_o = int rho(w_i, w_o) L(w_i) cos(theta_i) dw_i per pixel, averaged over the
pixel's area (what a box-filtered render converges to), for the same BRDF lookups and the
same piecewise-constant environment. They differ in how:

* ``render_reference``: plain Monte Carlo with a fixed seed. Each sample picks one of three
  strategies (environment by energy, the moment lobe, cosine) and is weighted by the
  mixture density (one-sample MIS, balance heuristic), so it is unbiased for any material
  and any map. The full BRDF, kd included, goes through the samples; the map is looked up
  unfiltered.
* ``bake_sphere``: the kd floor times the irradiance (a deterministic sum over the map), plus
  the rest of the BRDF by quasi-Monte Carlo over the texel. The map's bright texels are
  integrated by MIS of the BRDF's sampler (with a little cosine sampling for energy outside
  it) and of light samples, which each texel draws by what the lights give it
  (``lights.py``); the dim rest by the BRDF samples alone, looking the map up prefiltered to
  each sample's footprint (filtered importance sampling). Deterministic for a seed, low
  noise, slightly biased by the prefilter; the bias shrinks as the sample count grows.
"""

from __future__ import annotations

import math

import numpy as np

from ..limits import check
from .envmap import LUMINANCE
from .lights import light_clusters
from .scene import local_frames, sphere_points, texel_positions, touched_texels

CHUNK = 1 << 18  # samples per vectorized block: bounds memory at a few hundred MB
LIGHT_CLUSTERS = 32  # groups of the map's bright texels a texel chooses among (lights.py)


def _to_world(theta, phi, t, b, n):
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    return (st * cp)[:, None] * t + sp[:, None] * b + (ct * cp)[:, None] * n


def _cosine_sample(u1, u2):
    """Cosine-weighted hemisphere directions as view-centred (theta, phi)."""
    r = np.sqrt(u1)
    a = 2.0 * math.pi * u2
    x, y, z = r * np.cos(a), r * np.sin(a), np.sqrt(np.maximum(1.0 - u1, 0.0))
    return np.arctan2(x, z), np.arcsin(np.clip(y, -1.0, 1.0))


def _measure(theta, phi):
    """cos(theta_i) times the solid-angle Jacobian: cos t cos^2 p (see lobe.py)."""
    cp = np.cos(phi)
    return np.cos(theta) * cp * cp


# --- the bake ---------------------------------------------------------------------------------


def bake_sphere(
    brdf,
    env,
    diameter: int,
    lobe_samples: int = 64,
    seed: int = 0,
    light_samples: int | None = None,
    cosine_share: float | None = None,
):
    """Bake one sphere: returns (radiance (D, D, 3), coverage (D, D)), rows top first.

    radiance is the mean over the covered part of each texel (not premultiplied); coverage
    the covered fraction. Per texel, ``lobe_samples`` directions from the BRDF's sampler and
    ``light_samples`` (default as many) from the map's bright texels, each at its own
    QMC position in the texel. The map is split (``Environment.split``): the bright texels
    are integrated by multi-sample MIS of both strategies, unfiltered (unbiased); the dim
    rest by the BRDF samples alone with prefiltered lookups (smooth, so nearly unbiased).
    Light samples pick among clusters of bright texels by what each cluster gives the texel
    (``lights.LightClusters``), not by power alone."""
    d = check("diameter", diameter)
    k = check("bake_samples", lobe_samples, "lobe_samples")
    kb = k if light_samples is None else check("light_samples", light_samples)
    seed = check("seed", seed)
    beta = (
        (0.0 if brdf.kind == "model" else 0.15)
        if cosine_share is None
        else check("share", cosine_share, "cosine_share")
    )
    bright, residual = env.split()
    if bright.size == 0:
        kb = 0
    bb, aa = np.nonzero(touched_texels(d))
    if kb:
        # each 2 x 2 block of texels chooses among the light clusters at its centre (the far
        # corner of its first texel): a quarter of the cost of a choice per texel, and a
        # choice only steers the samples, the estimate stays unbiased
        clusters = light_clusters(bright, LIGHT_CLUSTERS)
        h = (d + 1) // 2
        blocks = np.unique(bb // 2 * h + aa // 2)
        jb, ja = np.divmod(blocks, h)
        _, _, t0, b0, n0, to0, _ = _texel_samples(d, 2 * ja, 2 * jb, np.ones((len(blocks), 1, 2)))
        corners = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])
        n_c = _texel_samples(d, 2 * ja, 2 * jb, np.broadcast_to(corners, (len(blocks), 4, 2)))[4]
        spread = np.arccos(np.clip(np.sum(n_c.reshape(-1, 4, 3) * n0[:, None], axis=2), -1.0, 1.0)).max(axis=1)
        block_choice = np.zeros((h, h, clusters.count))
        block_choice[jb, ja] = clusters.weights(brdf, n0, t0, b0, to0, spread)
    rng = np.random.default_rng(seed)
    pts_a = _sobol(4, k, rng)
    pts_b = _sobol(5, kb, rng) if kb else None
    shift_a = rng.random((len(aa), 4))
    shift_b = rng.random((len(aa), 5)) if kb else None
    radiance = np.zeros((d, d, 3))
    coverage = np.zeros((d, d))
    per = max(1, CHUNK // (k + kb))
    for s in range(0, len(aa), per):
        a, b = aa[s : s + per], bb[s : s + per]
        if kb:
            choice = block_choice[b // 2, a // 2]
        # BRDF-sampled directions: the residual (prefiltered) and their share of the lights
        ua = (pts_a[None] + shift_a[s : s + per, None]) % 1.0
        inside, u, t, bt, n, theta_o, cov = _texel_samples(d, a, b, ua)
        theta, phi, q = _brdf_directions(brdf, theta_o, u[:, 2], u[:, 3], beta)
        ok = np.isfinite(theta) & inside
        theta = np.where(ok, theta, 0.0)
        meas = _measure(theta, phi)
        dirs = _to_world(theta, phi, t, bt, n)
        f = brdf.evaluate(theta, phi, theta_o) - brdf.kd[None, :]
        footprint = np.cos(phi) / (k * q)  # sr covered by one of k samples (dw = cos p dt dp)
        g = f * np.where(ok, meas, 0.0)[:, None]
        contrib = g * residual.lookup_filtered(dirs, footprint) / (k * q)[:, None]
        if bright.size:
            if kb:
                lb, pb = clusters.lookup_pdf(choice, np.repeat(np.arange(len(a)), k), dirs)
            else:
                lb, pb = bright.lookup_pdf(dirs)
            w = k * q + kb * pb * np.cos(phi)  # both densities per d theta d phi
            contrib += g * lb / w[:, None]
        acc = contrib.reshape(len(a), k, 3).sum(axis=1)
        if kb:
            # light-sampled directions
            ub = (pts_b[None] + shift_b[s : s + per, None]) % 1.0
            inside, u, t, bt, n, theta_o, _ = _texel_samples(d, a, b, ub)
            dirs, pb = clusters.sample(choice, np.repeat(np.arange(len(a)), kb), u[:, 2], u[:, 3], u[:, 4])
            lx, ly, lz = np.sum(dirs * t, 1), np.sum(dirs * bt, 1), np.sum(dirs * n, 1)
            up = (lz > 0.0) & inside
            theta = np.arctan2(lx, np.maximum(lz, 1e-300))
            phi = np.arcsin(np.clip(ly, -1.0, 1.0))
            qb = _brdf_density(brdf, theta, phi, theta_o, beta)
            lb, _ = bright.lookup_pdf(dirs)
            f = brdf.evaluate(theta, phi, theta_o) - brdf.kd[None, :]
            # per steradian: f L cos / (k q / cos p + kb p_light)
            w = k * qb / np.maximum(np.cos(phi), 1e-300) + kb * pb
            contrib = f * lb * np.where(up, lz / np.maximum(w, 1e-300), 0.0)[:, None]
            acc += contrib.reshape(len(a), kb, 3).sum(axis=1)
        radiance[b, a] = acc / np.maximum(cov, 1e-300)[:, None]
        coverage[b, a] = cov
    if np.any(brdf.kd):
        # kd times the irradiance (E is smooth: its value at the texel centre is the texel's mean)
        radiance += brdf.kd[None, None, :] * env.irradiance_map(d)
    radiance[coverage == 0] = 0.0
    return radiance.astype(np.float32), coverage.astype(np.float32)


def _sobol(dim, n, rng):
    from scipy.stats import qmc  # 0.9 s to import: on the first bake (a worker thread), not at import

    return qmc.Sobol(dim, scramble=True, seed=rng).random(1 << max(0, math.ceil(math.log2(n))))[:n]


def _texel_samples(d, a, b, u):
    """Sample points u (T, K, dims) placed in texels (a, b), flattened texel-major.

    Points off the sphere (edge texels only) are moved onto its rim and flagged, so every
    texel keeps K samples and sums are plain reshapes. Returns (inside, uniforms, t, b, n,
    theta_o, covered fraction (T,))."""
    x, z = texel_positions(d, a[:, None], b[:, None], u[..., 0], u[..., 1])
    x, z = x.ravel(), z.ravel()
    inside = x * x + z * z < 1.0
    r = np.maximum(np.sqrt(x * x + z * z) / (1.0 - 1e-6), 1.0)
    _, n, _ = sphere_points(x / r, z / r)
    t, bt, theta_o = local_frames(n)
    cov = inside.reshape(u.shape[:2]).mean(axis=1)
    return inside, u.reshape(-1, u.shape[2]), t, bt, n, theta_o, cov


def _brdf_directions(brdf, theta_o, u1, u2, beta):
    """(theta, phi, q): the BRDF's sampler with probability 1 - beta, else cosine (a defensive
    share for energy the sampler misses); q is the mixture density per d theta d phi. theta
    is NaN where a reflected half vector fell below the horizon."""
    use_cos = u1 < beta
    v1 = np.clip(np.where(use_cos, u1 / max(beta, 1e-300), (u1 - beta) / max(1.0 - beta, 1e-300)), 0.0, 1.0 - 1e-12)
    theta, phi = brdf.sample(theta_o, v1, u2)
    if beta > 0:
        th_c, ph_c = _cosine_sample(v1, u2)
        theta = np.where(use_cos, th_c, theta)
        phi = np.where(use_cos, ph_c, phi)
    ok = np.isfinite(theta)
    q = _brdf_density(brdf, np.where(ok, theta, 0.0), phi, theta_o, beta)
    return theta, phi, np.maximum(q, 1e-300)


def _brdf_density(brdf, theta, phi, theta_o, beta):
    q = (1.0 - beta) * brdf.pdf(theta, phi, theta_o)
    return q + beta * _measure(theta, phi) / math.pi if beta > 0 else q


# --- the reference ---------------------------------------------------------------------------


def reference_sphere(brdf, env, diameter: int, spp: int = 1024, seed: int = 0, shares=None, diffuse_grid: int = 4):
    """Converged estimate for one sphere: (premultiplied radiance (D, D, 3), coverage).

    The kd floor is integrated deterministically: kd E(n) on a ``diffuse_grid``^2 grid of
    positions per pixel, E summed over the map (``Environment.irradiance``). The rest,
    rho - kd, by Monte Carlo with independent random numbers: each sample takes a random
    position in the pixel and one of three strategies with probabilities ``shares`` =
    (environment by energy, the BRDF's sampler, cosine), weighted by the mixture density."""
    d = check("diameter", diameter)
    spp = check("spp", spp)
    rng = np.random.default_rng(check("seed", seed))
    g = check("diffuse_grid", diffuse_grid)
    shares = (0.4, 0.45, 0.15) if shares is None else [check("share", v, "shares") for v in shares]
    if len(shares) != 3 or sum(shares) <= 0:
        raise ValueError(f"shares: expected three shares (environment, lobe, cosine) with a positive sum, got {shares}")
    c_env, c_lobe, c_cos = (v / sum(shares) for v in shares)
    bb, aa = np.nonzero(touched_texels(d))
    total = np.zeros((d, d, 3))
    hits = np.zeros((d, d))
    spec_on = spp > 0 and bool(
        np.any(brdf.lobe_weight(np.radians(np.arange(0.0, 90.0, 5.0))) > 0) or brdf.kind == "table"
    )
    per = max(1, CHUNK // max(spp, 1))
    for s in range(0, len(aa) if spec_on else 0, per):
        a, b = aa[s : s + per], bb[s : s + per]
        pa, pb = np.repeat(a, spp), np.repeat(b, spp)
        u = rng.random((len(pa), 6))
        x, z = texel_positions(d, pa, pb, u[:, 0], u[:, 1])
        inside, n, _ = sphere_points(x, z)
        sel = np.flatnonzero(inside)
        n, uu = n[sel], u[sel]
        t, bt, theta_o = local_frames(n)
        strategy = np.where(uu[:, 2] < c_env, 0, np.where(uu[:, 2] < c_env + c_lobe, 1, 2))
        dirs = np.empty((len(sel), 3))
        e = strategy == 0
        if e.any():
            dirs[e], _ = env.sample(uu[e, 3], uu[e, 4], uu[e, 5])
        lb = strategy == 1
        if lb.any():
            th, ph = brdf.sample(theta_o[lb], uu[lb, 3], uu[lb, 4])
            below = ~np.isfinite(th)
            d_l = _to_world(np.where(below, 0.0, th), ph, t[lb], bt[lb], n[lb])
            d_l[below] = -n[lb][below]  # below the horizon: contributes nothing
            dirs[lb] = d_l
        cs = strategy == 2
        if cs.any():
            th, ph = _cosine_sample(uu[cs, 3], uu[cs, 4])
            dirs[cs] = _to_world(th, ph, t[cs], bt[cs], n[cs])
        lx, ly, lz = np.sum(dirs * t, 1), np.sum(dirs * bt, 1), np.sum(dirs * n, 1)
        above = lz > 0.0
        theta = np.arctan2(lx, np.maximum(lz, 1e-300))
        phi = np.arcsin(np.clip(ly, -1.0, 1.0))
        cp = np.cos(phi)
        pdf = (
            c_env * env.pdf(dirs)
            + c_cos * np.maximum(lz, 0.0) / math.pi
            + c_lobe * brdf.pdf(theta, phi, theta_o) / np.maximum(cp, 1e-300)
        )
        f = brdf.evaluate(theta, phi, theta_o) - brdf.kd[None, :]
        w = np.where(above, lz / np.maximum(pdf, 1e-300), 0.0)
        np.add.at(total.reshape(-1, 3), pb[sel] * d + pa[sel], f * env.lookup(dirs) * w[:, None])
    total /= max(spp, 1)
    # coverage and the kd term on a regular sub-pixel grid (deterministic)
    off = (np.arange(g) + 0.5) / g
    jx, jy = np.meshgrid(off, off)
    jx, jy = jx.ravel(), jy.ravel()
    for s in range(0, len(aa), max(1, 4096 // (g * g))):
        a, b = aa[s : s + 4096 // (g * g)], bb[s : s + 4096 // (g * g)]
        x, z = texel_positions(d, a[:, None], b[:, None], jx[None, :], jy[None, :])
        inside, n, _ = sphere_points(x.ravel(), z.ravel())
        inside = inside.reshape(x.shape)
        hits[b, a] = inside.mean(axis=1)
        if np.any(brdf.kd):
            e_irr = np.zeros((inside.size, 3))
            e_irr[inside.ravel()] = env.irradiance(n[inside.ravel()])
            total[b, a] += brdf.kd[None, :] * e_irr.reshape(len(a), g * g, 3).mean(axis=1)
    return total.astype(np.float32), hits.astype(np.float32)


# --- whole images -----------------------------------------------------------------------------


def _check_row(layout, brdfs):
    """One BRDF per sphere of the layout, at most (a layout from ``sphere_layout``)."""
    n = len(brdfs)
    if not 1 <= n <= layout.count:
        raise ValueError(f"brdfs: expected 1 to {layout.count} (the layout's spheres), got {n}")


def render_reference(layout, brdfs, env, spp: int = 1024, seed: int = 0):
    """(H, W, 4) premultiplied RGBA of the row of spheres, converged by Monte Carlo."""
    spp, seed = check("spp", spp), check("seed", seed)
    _check_row(layout, brdfs)
    tiles = []
    for i, brdf in enumerate(brdfs):
        rgb, cov = reference_sphere(brdf, env, layout.diameter, spp, seed + 7919 * i)
        tiles.append(np.dstack([rgb, cov]))
    return layout.compose(tiles)


def render_baked(layout, brdfs, env, lobe_samples: int = 64, seed: int = 0, light_samples: int | None = None):
    """(H, W, 4) premultiplied RGBA: what the baked path shows (texel = pixel)."""
    lobe_samples, seed = check("bake_samples", lobe_samples, "lobe_samples"), check("seed", seed)
    _check_row(layout, brdfs)
    tiles = []
    for i, brdf in enumerate(brdfs):
        rgb, cov = bake_sphere(brdf, env, layout.diameter, lobe_samples, seed + 7919 * i, light_samples)
        tiles.append(np.dstack([rgb * cov[..., None], cov]))
    return layout.compose(tiles)


def relative_rmse(image, reference, mask):
    """Per-pixel relative RMSE over the masked pixels (RGB): sqrt(mean((x - r)^2 / (r^2 + e^2)))
    with e = 1e-3 of the reference's mean (it only guards black pixels). Every pixel counts by
    its relative error, as the eye sees it on a tone-mapped image."""
    a = np.asarray(image, float)[mask][:, :3]
    r = np.asarray(reference, float)[mask][:, :3]
    e = 1e-3 * max(float(np.mean(np.abs(r))), 1e-300)
    return float(np.sqrt(np.mean((a - r) ** 2 / (r * r + e * e))))


def normalized_rmse(image, reference, mask):
    """RMSE over the masked pixels (RGB) divided by the reference's RMS there: dominated by the
    brightest pixels (highlights, grazing Fresnel)."""
    a = np.asarray(image, float)[mask][:, :3]
    r = np.asarray(reference, float)[mask][:, :3]
    return float(np.sqrt(np.mean((a - r) ** 2)) / max(np.sqrt(np.mean(r * r)), 1e-300))


def lit_pixel_errors(image, reference, mask, share=0.05):
    """Per-pixel relative error |x - r| / |r| (RGB vectors) over the masked pixels whose reference
    luminance is at least ``share`` of the brightest masked pixel's; returns (errors, count).
    Pixels far darker than the sphere's peak carry noise and stray light as large relative
    errors that no one sees on a tone-mapped image (issue 37.2); and a colour's dark channel
    (paper_blue's red) counts by its part of the pixel, not by its own ratio."""
    share = check("share", share)
    lum = np.asarray(reference, float)[..., :3] @ LUMINANCE
    peak = float(lum[mask].max()) if np.any(mask) else 0.0
    lit = mask & (lum >= share * peak) & (lum > 0.0)
    a = np.asarray(image, float)[lit][:, :3]
    r = np.asarray(reference, float)[lit][:, :3]
    return np.linalg.norm(a - r, axis=1) / np.linalg.norm(r, axis=1), int(lit.sum())
