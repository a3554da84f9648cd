"""The map's bright texels grouped into clusters by direction, for the bake's light samples.

Drawn by power alone, most light samples of a texel land below its horizon or far outside its
lobe: on Blender's studio map that made them the larger part of a near-mirror bake's noise. A
texel instead weighs each cluster by a cheap guess at what the cluster gives *it*: the
cluster's power times the BRDF near the cluster (see ``weights``). Inside a cluster, texels go
by power. A share of every texel's samples still goes by power alone, so that no light is ever
left out because the guess was low: the estimate stays unbiased whatever the guess.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import HALF_PI
from ..limits import check
from .envmap import _direction

POWER_SHARE = 0.15  # the defensive share drawn by power alone


def light_clusters(bright, count=32):
    """The ``LightClusters`` of a ``BrightTexels`` set, kept on the set (so they go when its
    map goes)."""
    count = check("light_clusters", count, "count")
    per = bright.__dict__.setdefault("_clusters", {})
    if count not in per:
        per[count] = LightClusters(bright, count)
    return per[count]


class LightClusters:
    def __init__(self, bright, count=32, iterations=12, seed=0):
        env = bright.env
        self.bright = bright
        row, col = np.divmod(bright.texels, env.width)
        zt = env.z_edges
        dirs = _direction((col + 0.5) / env.width, 0.5 * (zt[row] + zt[row + 1]))
        power = np.asarray(bright.p, float)
        label, axes = _kmeans(dirs, power, min(int(count), bright.size), iterations, seed)
        self.count = len(axes)
        self.axes = axes
        self.label = label  # slot -> cluster
        self.power = np.bincount(label, weights=power, minlength=self.count)
        self.share = power / np.maximum(self.power[label], 1e-300)  # a slot's share of its cluster
        # the cone around each axis that holds its texels whole (plus a texel's half diagonal)
        reach = np.arccos(np.clip(np.sum(dirs * axes[label], axis=1), -1.0, 1.0))
        self.half_angle = np.zeros(self.count)
        np.maximum.at(self.half_angle, label, reach + 0.75 * math.pi / env.height)
        # members by cluster, each cluster a run; along a run a cumulative share from c to c + 1
        self.order = np.argsort(label, kind="stable")
        lab = label[self.order]
        self._first = np.searchsorted(lab, np.arange(self.count))
        self._last = np.r_[self._first[1:], len(lab)] - 1
        csum = np.cumsum(self.share[self.order])
        before = np.concatenate([[0.0], csum])[self._first]
        span = np.maximum(csum[self._last] - before, 1e-300)
        self._run = lab + (csum - before[lab]) / span[lab]

    def weights(self, brdf, n, t, b, theta_o, spread=0.0):
        """(T, clusters) probabilities of choosing each cluster, for texels with normal n,
        view-centred frame (t, b, n) and view angle theta_o; ``spread`` (T,) is how far (rad)
        the normals the choice serves stray from n (near a sphere's rim, a pixel's normals
        differ by degrees, and a lobe pressed against the horizon turns with them).

        A cluster's guess is the largest value at three points: its axis and its points
        nearest to the mirror direction and to the lobe's peak (a shifted lobe, as a
        model-mode edit makes, peaks away from the mirror). A guess too low costs noise, so
        it errs high."""
        st, ct = np.sin(theta_o), np.cos(theta_o)
        peak = np.clip(brdf.lobes.at(theta_o)[0], -HALF_PI, HALF_PI)
        targets = (
            -st[:, None] * t + ct[:, None] * n,  # the mirror direction
            np.sin(peak)[:, None] * t + np.cos(peak)[:, None] * n,
        )  # the lobe's peak
        spread = np.broadcast_to(np.asarray(spread, float), (len(n),))
        # a turn of the normal by s turns the mirror direction by up to 2 s
        reach = self.half_angle[None, :] + 2.0 * spread[:, None]
        axes = np.broadcast_to(self.axes[None], (len(n), self.count, 3))
        points = [axes] + [self._nearest(r, reach) for r in targets]
        gap = np.arccos(np.clip(n @ self.axes.T, -1.0, 1.0)) - self.half_angle[None, :] - spread[:, None]
        best_cos = np.maximum(np.cos(np.maximum(gap, 0.0)), 0.0)
        # two guesses, each normalized per texel and given half the rest: the table itself
        # (sharp, right for narrow lobes, but a few points can all miss a lobe that is
        # pressed against the horizon) and the lobe sampler's density (smooth, blurs a
        # narrow lobe)
        guess = np.zeros((len(n), self.count))
        for fn, scale in ((self._brdf_at, best_cos), (self._lobe_at, 1.0)):
            g = self.power[None, :] * scale * np.max([fn(brdf, w, t, b, n, theta_o) for w in points], axis=0)
            total = g.sum(axis=1, keepdims=True)
            guess += 0.5 * np.where(total > 0, g / np.where(total > 0, total, 1.0), self.power[None, :])
        return (1.0 - POWER_SHARE) * guess + POWER_SHARE * self.power[None, :]

    def sample(self, weights, texel, u1, u2, u3):
        """Directions drawn for texels ``texel`` (indices into the rows of ``weights``): a
        cluster by the texel's weights, a member by power (both from u1: its remainder picks
        the member, which keeps the stratification), uniform in solid angle in the member.
        Returns (directions (n, 3), pdf per sr)."""
        cdf = np.cumsum(weights, axis=1)
        cdf[:, -1] = 1.0
        k = self.count
        flat = (cdf + np.arange(len(weights))[:, None]).ravel()
        u1 = np.clip(np.asarray(u1, float), 0.0, 1.0 - 1e-12)
        c = np.clip(np.searchsorted(flat, texel + u1, side="right") - texel * k, 0, k - 1)
        p_c = weights[texel, c]
        lo = np.where(c > 0, cdf[texel, np.maximum(c - 1, 0)], 0.0)
        rest = np.clip((u1 - lo) / np.maximum(p_c, 1e-300), 0.0, 1.0 - 1e-12)
        m = np.clip(np.searchsorted(self._run, c + rest, side="right"), self._first[c], self._last[c])
        slot = self.order[m]
        env = self.bright.env
        row, col = np.divmod(self.bright.texels[slot], env.width)
        zt = env.z_edges
        d = _direction(
            (col + np.asarray(u2, float)) / env.width, zt[row] + np.asarray(u3, float) * (zt[row + 1] - zt[row])
        )
        return d, p_c * self.share[slot] / self.bright.omega[slot]

    def lookup_pdf(self, weights, texel, d):
        """(radiance of the bright set at directions d, zero outside it; the density per sr with
        which ``sample`` draws them for those texels)."""
        slot = self.bright.slot[self.bright.env.texel(d)]
        inside = slot >= 0
        s = np.where(inside, slot, 0)
        rad = np.where(inside[:, None], self.bright.radiance[s], 0.0)
        pdf = np.where(inside, weights[texel, self.label[s]] * self.share[s] / self.bright.omega[s], 0.0)
        return rad, pdf

    def _nearest(self, r, reach):
        """(T, clusters, 3): the direction nearest to r (T, 3) in each cluster's cone of half
        angle ``reach`` (T, clusters)."""
        ca = r @ self.axes.T
        step = np.minimum(np.arccos(np.clip(ca, -1.0, 1.0)), reach)
        perp = r[:, None, :] - ca[..., None] * self.axes[None, :, :]
        norm = np.linalg.norm(perp, axis=2, keepdims=True)
        perp = np.where(norm > 1e-12, perp / np.maximum(norm, 1e-12), 0.0)
        return np.cos(step)[..., None] * self.axes[None] + np.sin(step)[..., None] * perp

    def _brdf_at(self, brdf, w, t, b, n, theta_o):
        """The specular part (mean over channels, at least 0) at world directions w (T, K, 3)."""
        theta, phi = self._local(w, t, b, n)
        f = brdf.evaluate(theta.ravel(), phi.ravel(), np.repeat(theta_o, w.shape[1])) - brdf.kd[None, :]
        return np.maximum(f.mean(axis=1), 0.0).reshape(theta.shape)

    def _lobe_at(self, brdf, w, t, b, n, theta_o):
        """The lobe sampler's density per steradian at world directions w (T, K, 3): the
        BRDF times the cosine, smoothed over its half-vector rings, so that a guess made at a
        few points still sees a sharp lobe near them."""
        theta, phi = self._local(w, t, b, n)
        q = brdf.pdf(theta.ravel(), phi.ravel(), np.repeat(theta_o, w.shape[1]))
        return (q / np.maximum(np.cos(phi.ravel()), 1e-6)).reshape(theta.shape)

    @staticmethod
    def _local(w, t, b, n):
        """View-centred (theta, phi) of world directions w (T, K, 3); below the horizon they
        are put on it."""
        lx, ly, lz = (np.einsum("tkc,tc->tk", w, v) for v in (t, b, n))
        return np.arctan2(lx, np.maximum(lz, 1e-6)), np.arcsin(np.clip(ly, -1.0, 1.0))


def _kmeans(dirs, power, k, iterations, seed):
    """Spherical k-means weighted by power, from a seeded draw by power: (labels, unit axes),
    empty clusters dropped."""
    rng = np.random.default_rng(seed)
    p = power / power.sum() if power.sum() > 0 else None
    nonzero = int(np.count_nonzero(power)) if p is not None else len(dirs)
    axes = dirs[rng.choice(len(dirs), min(k, nonzero), replace=False, p=p)].copy()
    for _ in range(iterations + 1):
        label = np.argmax(dirs @ axes.T, axis=1)
        sums = np.zeros_like(axes)
        np.add.at(sums, label, dirs * power[:, None])
        norm = np.linalg.norm(sums, axis=1)
        axes = np.where(norm[:, None] > 0, sums / np.maximum(norm, 1e-300)[:, None], axes)
    label = np.argmax(dirs @ axes.T, axis=1)
    used = np.unique(label)
    remap = np.full(len(axes), -1)
    remap[used] = np.arange(len(used))
    return remap[label], axes[used]
