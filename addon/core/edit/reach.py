"""What a reciprocal table can show: per view, and over the (mu~, sigma~^2) plane.

A view's target is out of reach when no table can hold it:
- narrower than the table's cells at that lobe centre (``cell_variance_floor``);
- wider than any truncated Gaussian with that mean reaches (the truncated exponential is the
  limit: ``truncated.variance_cap``), unless the measured slice is already that wide;
- moved off the measured mean by more than ``MAX_SHIFT_SIGMAS`` of the lobe's own width: a
  reciprocal table's lobe is tied to the mirror (its image under the swap of w_i and w_o sits
  there too), so a narrow lobe cannot be carried far off it without a second ridge.

The slider-level region (``reachable_region``) is where at least ``MIN_REACHABLE`` of the counted
views are in reach; a request outside it is clamped to the nearest point inside.

Warp mode's region is the roughness edit's (``solve.roughness_region``: the material's curve
widened by the tilt's reach); this one serves model mode (the paper's sketch) and the tilt's
per-view targets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..fits.curves import LAMBERT_VARIANCE
from ..fits.truncated import variance_cap_fast as variance_cap
from ..geometry import HALF_PI

MAX_SHIFT_SIGMAS = 1.0
MIN_REACHABLE = 0.9
VIEW_RANGE = (math.radians(5.0), math.radians(80.0))
ENERGY_FRACTION = 0.05


def cell_variance_floor(theta_o, mean):
    """Per view, the smallest lobe variance a nearest-cell table can hold at that lobe centre.

    A cell's value is the lobe at the cell centre, so a lobe that falls between centres
    vanishes from the table. Near the lobe, moving the lit direction by d(theta) moves the
    half vector by d(theta)/2, and MERL's theta_h cells are square-root spaced: 2e-4 rad at
    the mirror, 0.035 rad at the pole. Half a cell width as the floor on sigma keeps a
    centre within one sigma of any lobe."""
    theta_h = np.clip(np.abs(np.asarray(theta_o, float) + np.asarray(mean, float)) / 2.0, 0.0, HALF_PI)
    step_h = np.maximum(2.0 * np.sqrt(theta_h / HALF_PI) * HALF_PI / 90.0, HALF_PI / 90.0**2)
    return (0.5 * 2.0 * step_h) ** 2


def counted_views(theta_o, alpha):
    """(V, C) mask of the views an edit is judged on: 5-80 deg, >= 5 % of the channel's peak energy."""
    theta_o = np.asarray(theta_o, float)
    alpha = np.nan_to_num(np.asarray(alpha, float))
    if alpha.ndim == 1:
        alpha = alpha[:, None]
    in_range = (theta_o >= VIEW_RANGE[0] - 1e-9) & (theta_o <= VIEW_RANGE[1] + 1e-9)
    peak = np.where(in_range[:, None], alpha, 0.0).max(axis=0, initial=0.0)
    return in_range[:, None] & (alpha >= ENERGY_FRACTION * peak[None, :]) & (peak[None, :] > 0)


def view_reachable(theta_o, mean, var_tt, var_pp, measured_mean, measured_var):
    """(V, C) bool: whether each view's target (mean, variances) can be held by a reciprocal table.

    ``measured_var`` is the measured average variance (sigma_tt + sigma_pp) / 2, the quantity
    compared (a lobe the table already holds stays in reach, even below the cell floor)."""
    theta_o = np.asarray(theta_o, float)[:, None] if np.ndim(theta_o) == 1 else np.asarray(theta_o, float)
    mean, var_tt, var_pp = (np.nan_to_num(np.asarray(a, float)) for a in (mean, var_tt, var_pp))
    mean, var_tt, var_pp = np.broadcast_arrays(mean, var_tt, var_pp)
    floor = cell_variance_floor(theta_o, mean)
    measured_var = np.nan_to_num(np.asarray(measured_var, float))
    avg = 0.5 * (var_tt + var_pp)
    # Measured slices are heavier-tailed than Gaussians: one may already be wider than the
    # truncated family's limit, and keeping that width is always in reach.
    cap = np.maximum(variance_cap(mean), measured_var * (1 + 1e-9))
    shift = np.abs(mean - np.nan_to_num(np.asarray(measured_mean, float)))
    width = np.sqrt(np.maximum(np.maximum(avg, measured_var), 0.0))
    return (avg >= np.minimum(floor, measured_var)) & (avg <= cap) & (shift <= MAX_SHIFT_SIGMAS * width + 1e-12)


@dataclass
class ReachableRegion:
    """The sliders' reachable set for one material: sigma~^2 in [sigma2_min, sigma2_max], and at
    each sigma2 of the grid the reachable mean slopes [mu_min, mu_max] (NaN where none)."""

    sigma2: np.ndarray
    mu_min: np.ndarray
    mu_max: np.ndarray
    sigma2_min: float
    sigma2_max: float
    fitted: tuple = (0.0, 0.0)  # the material's (mu~, sigma~^2)
    notes: list = field(default_factory=list)
    # The material's curve under roughness edits, {"scales", "mu", "sigma2"} (warp mode's
    # region is built on it: ``solve.roughness_region``); None for the per-view region.
    curve: dict | None = None

    def curve_mu(self, s2):
        """The mean slope a roughness edit to variance ``s2`` re-fits to (None without a curve)."""
        if not self.curve:
            return None
        x = np.array([np.nan if v is None else v for v in self.curve["sigma2"]], float)
        y = np.array([np.nan if v is None else v for v in self.curve["mu"]], float)
        ok = np.isfinite(x) & np.isfinite(y) & (x > 0)
        if ok.sum() < 2:
            return None
        order = np.argsort(x[ok])
        return float(np.interp(math.log(max(s2, 1e-300)), np.log(x[ok][order]), y[ok][order]))

    def contains(self, mu, s2) -> bool:
        if not (self.sigma2_min <= s2 <= self.sigma2_max):
            return False
        lo, hi = self.mu_range(s2)
        return bool(np.isfinite(lo) and lo - 1e-9 <= mu <= hi + 1e-9)

    def mu_range(self, s2):
        """(lowest, highest) reachable mean slope at variance ``s2`` (interpolated in log s2)."""
        x = np.log(self.sigma2)
        ok = np.isfinite(self.mu_min)
        if not ok.any():
            return np.nan, np.nan
        xs = math.log(max(s2, 1e-300))
        return (float(np.interp(xs, x[ok], self.mu_min[ok])), float(np.interp(xs, x[ok], self.mu_max[ok])))

    def clamp(self, mu, s2):
        """The nearest reachable (mu, s2) (in mean slope and log variance), and whether it moved."""
        if self.contains(mu, s2):
            return mu, s2, False
        best, dist = (mu, s2), np.inf
        for k, v in enumerate(self.sigma2):
            if not np.isfinite(self.mu_min[k]):
                continue
            m = float(np.clip(mu, self.mu_min[k], self.mu_max[k]))
            d = (m - mu) ** 2 + (0.1 * math.log(v / s2)) ** 2  # 10 % in variance ~ 0.01 in slope
            if d < dist:
                best, dist = (m, float(v)), d
        return best[0], best[1], True

    def to_json(self) -> dict:
        clean = lambda a: [None if not np.isfinite(v) else float(v) for v in np.asarray(a, float)]  # noqa: E731
        return {
            "sigma2": clean(self.sigma2),
            "mu_min": clean(self.mu_min),
            "mu_max": clean(self.mu_max),
            "sigma2_min": self.sigma2_min,
            "sigma2_max": self.sigma2_max,
            "fitted": list(self.fitted),
            **({"curve": self.curve} if self.curve else {}),
        }

    @classmethod
    def from_json(cls, d: dict) -> "ReachableRegion":
        """The inverse of ``to_json``; ValueError when ``d`` is not a region (a stored copy may be
        damaged or edited)."""
        try:
            arrays = [
                np.array([np.nan if v is None else float(v) for v in d[k]]) for k in ("sigma2", "mu_min", "mu_max")
            ]
            smin, smax = float(d["sigma2_min"]), float(d["sigma2_max"])
            fitted = tuple(float(v) for v in d["fitted"])
        except (KeyError, TypeError, ValueError):
            raise ValueError("not a reachable region") from None
        n = len(arrays[0])
        if not (
            1 <= n <= 10_000
            and all(len(a) == n for a in arrays)
            and len(fitted) == 2
            and np.all(np.isfinite(arrays[0]))
            and np.all(arrays[0] > 0)
            and np.all(np.diff(arrays[0]) > 0)
            and math.isfinite(smin)
            and math.isfinite(smax)
            and 0 < smin <= smax
        ):
            raise ValueError("not a reachable region")
        curve = d.get("curve")
        if curve is not None:
            try:
                n_c = len(curve["scales"])
                if not (2 <= n_c <= 1000 and all(len(curve[k]) == n_c for k in ("mu", "sigma2"))):
                    raise ValueError
                for k in ("scales", "mu", "sigma2"):
                    for v in curve[k]:
                        if v is not None and not math.isfinite(float(v)):
                            raise ValueError
            except (KeyError, TypeError, ValueError):
                raise ValueError("not a reachable region") from None
        return cls(*arrays, smin, smax, fitted, curve=curve)

    def boundary(self):
        """(mu, sigma2) of the region's outline: up the lower mean-slope edge, down the upper one."""
        ok = np.isfinite(self.mu_min) & np.isfinite(self.mu_max)
        s2 = self.sigma2[ok]
        return (
            np.concatenate([self.mu_min[ok], self.mu_max[ok][::-1], self.mu_min[ok][:1]]),
            np.concatenate([s2, s2[::-1], s2[:1]]),
        )


def reachable_region(prof, fit, n_sigma=41, n_mu=161, mode="warp") -> ReachableRegion:
    """The region for one material's profiles and fit (warp or model targets)."""
    from ..limits import RANGES
    from .targets import MODES, EditTargets, follow_lobe, model_lobe, profile_lobes, view_targets

    n_sigma = RANGES["region_grid"].check(n_sigma, "n_sigma")
    n_mu = RANGES["region_grid"].check(n_mu, "n_mu")
    if mode not in MODES:
        raise ValueError(f"mode: must be one of {MODES}, got {mode!r}")

    theta = np.asarray(prof.theta_o, float)
    s0, m0 = float(fit["sigma2"]), float(fit["mu_slope"])
    grid = np.geomspace(max(s0 / 50.0, 1e-7), LAMBERT_VARIANCE, n_sigma)
    grid = np.unique(np.concatenate([grid, [s0]]))
    # The slider's range holds the fitted slope (measured ones go below -1).
    mus = np.linspace(min(-1.0, m0) - 0.05, max(0.0, m0), n_mu)
    base = view_targets(prof, fit, EditTargets(mode=mode), m0, s0)
    counted = counted_views(theta, base.alpha)
    # The reach test compares with what the table holds now: the measured means and variances.
    st = lambda k: np.stack([np.asarray(prof[c][k], float) for c in "rgb"], axis=1)  # noqa: E731
    mm, mv = st("mu_theta"), 0.5 * (st("sigma_tt") + st("sigma_pp"))
    lo, hi = np.full(len(grid), np.nan), np.full(len(grid), np.nan)
    n = counted.sum()
    lobes = profile_lobes(prof)
    for k, s2 in enumerate(grid):
        # All mean slopes at once: (mu, V, C).
        if mode == "warp":
            mean, var_tt, var_pp = follow_lobe(lobes, s2 / s0, (mus - m0)[:, None, None])
        else:
            mean, var = model_lobe(theta[None, :], m0, s0, mus[:, None], s2)
            mean, var_tt = np.repeat(mean[..., None], 3, axis=-1), np.repeat(var[..., None], 3, axis=-1)
            var_pp = var_tt
        r = view_reachable(theta, mean, var_tt, var_pp, mm[None], mv[None])
        ok_rows = (n > 0) & ((r & counted[None]).sum(axis=(1, 2)) >= MIN_REACHABLE * n)
        if ok_rows.any():
            lo[k], hi[k] = mus[ok_rows].min(), mus[ok_rows].max()
    have = np.isfinite(lo)
    smin = float(grid[have].min()) if have.any() else s0
    smax = float(grid[have].max()) if have.any() else s0
    return ReachableRegion(grid, lo, hi, smin, smax, (m0, s0))
