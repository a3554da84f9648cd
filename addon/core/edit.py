"""Moment editing (SPEC §3 "Editing"): re-synthesize a tabulated BRDF from slider targets.

Warp mode keeps the measured shape. At each view the measured specular slice is moved
along theta so its mean follows the new slope (the measured deviation from the line is
kept), scaled about its mean along theta and phi so the variances follow the new average
variance, and scaled in amplitude for the energy. An affine map leaves standardized moments
unchanged; clipping at the domain edge does not. But clipping a warped slice is just a
rectangle cut in the original slice's coordinates. So the measured slice is sampled once
per view on nodes graded around its mean, and the correction iterations (which move the
map until the clipped result hits the targets) are cheap weighted sums over those nodes.

Model mode synthesizes paper Eq. 7 with truncated Gaussians whose *truncated* mean and
variance equal the targets (Eq. 8 normalizes on the domain).

Tabulation: every MERL cell is a pair (w_i, w_o). The edited slice is evaluated with each
direction as the view and the two are averaged, so the table stays reciprocal. kd is added
back, and cells missing in the input stay missing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import erf

from .fits import LAMBERT_VARIANCE, correlation_curve, fit_material
from .geometry import HALF_PI, directions_from_half_diff, half_diff_from_directions, view_centred, view_centred_angles
from .merl import MerlTable, cell_centres, cell_indices, cell_indices_view
from .profiles import Profiles, compute_profiles, specular_values

MODES = ("warp", "model")


@dataclass
class EditTargets:
    """Slider values. ``None`` keeps the measured value (identity on that axis)."""

    strength: float = 1.0                 # overall energy scale
    colour: tuple = (1.0, 1.0, 1.0)       # per-channel energy scale
    grazing_boost: float = 1.0            # scale of the energy above the base alpha_b
    mu_slope: float | None = None         # in [-1, 0]
    sigma2: float | None = None           # in (0, pi^2/12]
    mode: str = "warp"
    lock: bool = False                    # sigma2 follows mu_slope along the correlation quadratic
    correlation_a: float | None = None    # the quadratic's a (from a set fit); needed with lock

    def is_identity(self) -> bool:
        return (self.mode == "warp" and self.strength == 1.0 and tuple(self.colour) == (1.0, 1.0, 1.0)
                and self.grazing_boost == 1.0 and self.mu_slope is None and self.sigma2 is None
                and not self.lock)


@dataclass
class EditResult:
    table: MerlTable
    target_mu_slope: float
    target_sigma2: float
    achieved_mu_slope: float | None
    achieved_sigma2: float | None
    max_albedo: np.ndarray            # per channel, over the sampled views
    warnings: list = field(default_factory=list)
    profiles: Profiles | None = None  # re-measured profiles of the output

    @property
    def energy_gain(self) -> bool:
        return bool(np.any(self.max_albedo > 1.0))


MIN_SIGMA2 = 1e-7  # narrower than any MERL cell near the mirror: a "mirror" for the table


def resolve_targets(t: EditTargets, fit: dict):
    """Clamp slider values to their ranges; returns (mu, sigma2, warnings)."""
    warnings = []
    mu = fit["mu_slope"] if t.mu_slope is None else float(t.mu_slope)
    if not np.isfinite(mu):
        raise ValueError("mean slope must be finite")
    if t.mu_slope is not None and not -1.0 <= mu <= 0.0:
        warnings.append(f"mean slope {mu:+.3f} clamped to [-1, 0]")
        mu = float(np.clip(mu, -1.0, 0.0))
    if t.lock:
        if t.correlation_a is None:
            raise ValueError("the correlation lock needs the quadratic's coefficient a (fit a set first)")
        s2 = float(correlation_curve(mu, t.correlation_a))
    else:
        s2 = fit["sigma2"] if t.sigma2 is None else float(t.sigma2)
    if not np.isfinite(s2):
        raise ValueError("variance must be finite")
    if s2 < MIN_SIGMA2 or s2 > LAMBERT_VARIANCE:
        if t.sigma2 is not None or t.lock:
            warnings.append(f"variance {s2:.3g} clamped to ({MIN_SIGMA2:g}, pi^2/12]")
        s2 = float(np.clip(s2, MIN_SIGMA2, LAMBERT_VARIANCE))
    for name, v in (("strength", t.strength), ("grazing boost", t.grazing_boost)):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"{name} must be a finite number >= 0")
    if len(t.colour) != 3 or not all(np.isfinite(c) and c >= 0 for c in t.colour):
        raise ValueError("colour must be three finite numbers >= 0")
    if t.mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}")
    return mu, s2, warnings


def target_energy(prof: Profiles, fit: dict, t: EditTargets) -> np.ndarray:
    """(views, 3): alpha'_c = strength colour_c (alpha_b,c + boost (alpha_c - alpha_b,c))."""
    out = np.empty((len(prof.theta_o), 3))
    for i, ch in enumerate("rgb"):
        a = np.nan_to_num(np.asarray(prof[ch]["alpha"], float))
        base = fit["channels"].get(ch, {}).get("alpha_b", 0.0) if fit.get("channels") else 0.0
        base = min(max(base, 0.0), float(a.min()) if a.size else 0.0)
        out[:, i] = t.strength * t.colour[i] * (base + t.grazing_boost * (a - base))
    return np.maximum(out, 0.0)


# --- warp mode -------------------------------------------------------------------------------

def _graded_nodes(centre, scale, n_panels=40, n_gauss=4, ratio=1.35):
    """Gauss nodes on [-pi/2, pi/2], panels growing geometrically away from ``centre``."""
    from .quadrature import graded_edges

    e = graded_edges(centre, -HALF_PI, HALF_PI, max(scale, 1e-6) / 4.0, ratio)
    xg, wg = np.polynomial.legendre.leggauss(n_gauss)
    half = 0.5 * np.diff(e)
    mid = 0.5 * (e[1:] + e[:-1])
    return (mid[:, None] + half[:, None] * xg).ravel(), (half[:, None] * wg).ravel()


class SliceSamples:
    """The measured specular slices on per-view nodes graded around each lobe (avg channel)."""

    def __init__(self, values, prof: Profiles):
        self.values = values
        self.theta_o = np.asarray(prof.theta_o, float)
        p = prof["avg"]
        self.mu = np.nan_to_num(np.asarray(p["mu_theta"], float), nan=0.0)
        self.var_t = np.nan_to_num(np.asarray(p["sigma_tt"], float), nan=LAMBERT_VARIANCE)
        self.var_p = np.nan_to_num(np.asarray(p["sigma_pp"], float), nan=LAMBERT_VARIANCE)
        nodes = []
        for k, to in enumerate(self.theta_o):
            t, wt = _graded_nodes(self.mu[k], math.sqrt(max(self.var_t[k], 1e-12)))
            q, wq = _graded_nodes(0.0, math.sqrt(max(self.var_p[k], 1e-12)))
            T, Q = np.meshgrid(t, q, indexing="ij")
            wi = view_centred(T, Q)
            wo = np.broadcast_to(view_centred(to, 0.0), wi.shape)
            rho = values[cell_indices(*half_diff_from_directions(wi, wo)), 3]
            nodes.append((T.ravel(), Q.ravel(), (np.outer(wt, wq) * rho).ravel()))
        self.nodes = nodes

    def warped_moments(self, k, mu_new, k_t, k_p):
        """alpha fraction kept, mean, var_theta, var_phi of the clipped warped slice at view k."""
        t, q, w = self.nodes[k]
        tw = mu_new + k_t * (t - self.mu[k])
        qw = k_p * q
        keep = (np.abs(tw) <= HALF_PI) & (np.abs(qw) <= HALF_PI)
        wk = w * keep
        m0 = wk.sum()
        total = w.sum()
        if m0 <= 0 or total <= 0:
            return 0.0, mu_new, 0.0, 0.0
        mt = (wk @ tw) / m0
        mp = (wk @ qw) / m0
        return m0 / total, mt, (wk @ (tw - mt) ** 2) / m0, (wk @ (qw - mp) ** 2) / m0


def solve_warp(samples: SliceSamples, mu_target, var_t_target, var_p_target):
    """Per view: (mu_new, k_theta, k_phi, kept fraction), and whether the targets were reached.

    A bounded least-squares solve on the clipped warp's moments. Plain fixed-point steps run
    away where clipping puts a target out of reach (a wider lobe loses more mass, which
    makes it narrower again), so the map stays within a factor 4 of the unclipped answer and
    half a radian of the target mean, and the closest point is used.
    """
    from scipy.optimize import least_squares

    n = len(samples.theta_o)
    out = np.zeros((n, 4))
    reached = np.zeros(n, bool)
    for k in range(n):
        vt0, vp0 = max(samples.var_t[k], 1e-300), max(samples.var_p[k], 1e-300)
        x0 = np.array([mu_target[k], 0.5 * math.log(var_t_target[k] / vt0), 0.5 * math.log(var_p_target[k] / vp0)])

        def residual(x):
            frac, mt, vt, vp = samples.warped_moments(k, x[0], math.exp(x[1]), math.exp(x[2]))
            if frac <= 0 or vt <= 0 or vp <= 0:
                return np.array([1e3, 1e3, 1e3])
            # The mean is what the slope slider moves: it weighs most where not all can be met.
            return np.array([(mt - mu_target[k]) / 0.002, math.log(vt / var_t_target[k]) / 0.02,
                             math.log(vp / var_p_target[k]) / 0.02])

        r0 = residual(x0)
        if np.all(np.abs(r0) < 1e-4):
            x = x0
        else:
            lo = x0 - np.array([0.5, math.log(4.0), math.log(4.0)])
            hi = x0 + np.array([0.5, math.log(4.0), math.log(4.0)])
            sol = least_squares(residual, x0, bounds=(lo, hi), diff_step=1e-4, xtol=1e-10, ftol=1e-10,
                                max_nfev=60)
            x = sol.x if np.sum(sol.fun ** 2) <= np.sum(r0 ** 2) else x0
        r = residual(x)
        frac = samples.warped_moments(k, x[0], math.exp(x[1]), math.exp(x[2]))[0]
        out[k] = (x[0], math.exp(x[1]), math.exp(x[2]), max(frac, 0.25))  # gain capped at 4x
        reached[k] = bool(abs(r[0]) < 2.5 and np.all(np.abs(r[1:]) < 0.5))  # 0.005 rad, 1 % variances
    return out, reached


# --- model mode ------------------------------------------------------------------------------

def _trunc_moments(m, s):
    """Mean and variance of N(m, s^2) truncated to [-pi/2, pi/2] (vectorized)."""
    a, b = (-HALF_PI - m) / s, (HALF_PI - m) / s
    z = 0.5 * (erf(b / math.sqrt(2)) - erf(a / math.sqrt(2)))
    pa, pb = np.exp(-0.5 * a * a) / math.sqrt(2 * math.pi), np.exp(-0.5 * b * b) / math.sqrt(2 * math.pi)
    z = np.maximum(z, 1e-300)
    mean = m + s * (pa - pb) / z
    var = s * s * (1 + (a * pa - b * pb) / z - ((pa - pb) / z) ** 2)
    return mean, var


def solve_truncated(mean_t, var_t, iters=60):
    """(m, s) of the untruncated Gaussian whose truncation has this mean and variance."""
    mean_t = np.asarray(mean_t, float)
    var_t = np.broadcast_to(np.asarray(var_t, float), mean_t.shape)
    m = mean_t.copy()
    s = np.sqrt(var_t)
    for _ in range(iters):
        mt, vt = _trunc_moments(m, s)
        # Bounded: an unreachable target (a wide lobe centred at the horizon) must give the
        # nearest finite lobe, never a runaway centre or width.
        m = np.clip(m + (mean_t - mt), -2.0 * np.pi, 2.0 * np.pi)
        s = np.clip(s * np.sqrt(np.clip(var_t / np.maximum(vt, 1e-300), 0.25, 4.0)), 1e-4, 1e3)
    mt, vt = _trunc_moments(m, s)
    ok = (np.abs(mt - mean_t) < 1e-6) & (np.abs(vt / var_t - 1) < 1e-4)
    return m, s, ok


def _truncated_gauss(x, m, s):
    a, b = (-HALF_PI - m) / s, (HALF_PI - m) / s
    z = s * math.sqrt(2 * math.pi) * 0.5 * (erf(b / math.sqrt(2)) - erf(a / math.sqrt(2)))
    inside = np.abs(x) <= HALF_PI
    return np.where(inside, np.exp(-0.5 * ((x - m) / s) ** 2) / np.maximum(z, 1e-300), 0.0)


# --- tabulation ------------------------------------------------------------------------------

def _view_frame(w_view, w_lit):
    """Elevation of the view and the view-centred angles of the lit direction in its frame."""
    elev = np.arccos(np.clip(w_view[:, 2], -1.0, 1.0))
    az = np.arctan2(w_view[:, 1], w_view[:, 0])
    c, s = np.cos(-az), np.sin(-az)
    x = c * w_lit[:, 0] - s * w_lit[:, 1]
    y = s * w_lit[:, 0] + c * w_lit[:, 1]
    lit = np.stack((x, y, w_lit[:, 2]), axis=-1)
    theta, phi = view_centred_angles(lit)
    return elev, theta, phi


def edit(table: MerlTable, targets: EditTargets, prof: Profiles | None = None, fit: dict | None = None,
         remeasure: bool = True, progress=None, max_rounds: int = 5) -> EditResult:
    """Re-synthesize ``table`` for the slider ``targets``. Never modifies ``table``.

    The reciprocal symmetrization moves the moments (a lobe seen with the roles swapped sits
    elsewhere), so synthesis runs in rounds: tabulate, re-measure, move the synthesis
    targets by the error, until the re-measured mean slope and variance hit the sliders or
    stop improving. What was reached is reported either way.
    """
    if prof is None:
        prof = compute_profiles(table)
    if fit is None:
        fit = fit_material(prof)
    if fit.get("mu_slope") is None or fit.get("sigma2") is None:
        raise ValueError(f"{table.name}: the material has no specular lobe to edit (all its energy is in kd)")
    mu_t, s2_t, warnings = resolve_targets(targets, fit)
    if targets.is_identity():
        out = table.copy()
        out.path = None
        return _finish(out, targets, mu_t, s2_t, warnings, prof, remeasure)
    if (targets.mode == "warp" and targets.mu_slope is None and targets.sigma2 is None and not targets.lock
            and targets.grazing_boost == 1.0):
        # Energy only: the specular part scales exactly, per channel.
        kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
        spec = np.maximum(table.rho - kd[:, None], 0.0)
        gain = targets.strength * np.asarray(targets.colour, float)[:, None]
        rho = np.where(table.valid, np.minimum(table.rho, kd[:, None]) + gain * spec, 0.0)
        return _finish(MerlTable(rho, table.valid.copy(), None), targets, mu_t, s2_t, warnings, prof, remeasure)

    kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
    values = specular_values(table, kd, prof.split)
    samples = SliceSamples(values, prof) if targets.mode == "warp" else None
    # Secant steps on the mean slope and on log(variance), each against its own error.
    x = np.array([mu_t, math.log(s2_t)])
    goal = np.array([mu_t, math.log(s2_t)])
    prev = None
    best = None
    for round_ in range(max_rounds):
        out, notes = synthesize(table, targets, prof, fit, x[0], math.exp(x[1]), values, samples)
        new_prof = compute_profiles(out, prof.theta_o, kd=prof.kd if prof.split else None, split=prof.split)
        f = fit_material(new_prof)
        if f["mu_slope"] is None or f["sigma2"] is None or f["sigma2"] <= 0:
            break
        y = np.array([f["mu_slope"], math.log(f["sigma2"])])
        err = y - goal
        score = abs(err[0]) / 0.01 + abs(math.expm1(err[1])) / 0.02
        if best is None or score < best[0]:
            best = (score, out, notes, new_prof, f)
        if abs(err[0]) < 0.003 and abs(err[1]) < 0.006:
            break
        slope = np.ones(2)
        if prev is not None:
            dx, dy = x - prev[0], y - prev[1]
            with np.errstate(divide="ignore", invalid="ignore"):
                sec = dy / dx
            slope = np.where(np.isfinite(sec) & (np.abs(dx) > 1e-9) & (sec > 0.2) & (sec < 5.0), sec, 1.0)
        prev = (x.copy(), y)
        x = x - err / slope
        x[0] = float(np.clip(x[0], -1.6, 0.6))
        x[1] = float(np.clip(x[1], math.log(MIN_SIGMA2), math.log(LAMBERT_VARIANCE)))
        if progress:
            progress(round_ + 1, max_rounds)
    if best is None:
        raise ValueError(f"{table.name}: the edit left no specular energy to measure")
    _, out, notes, new_prof, f = best
    warnings += notes
    if abs(f["mu_slope"] - mu_t) >= 0.01 or abs(f["sigma2"] / s2_t - 1.0) >= 0.02:
        warnings.append(f"target not reachable for a reciprocal table: reached mean slope {f['mu_slope']:+.3f} "
                        f"(target {mu_t:+.3f}) and variance {f['sigma2']:.4g} (target {s2_t:.4g})")
    res = _finish(out, targets, mu_t, s2_t, warnings, prof, remeasure=False)
    res.achieved_mu_slope, res.achieved_sigma2, res.profiles = f["mu_slope"], f["sigma2"], new_prof
    return res


def synthesize(table, targets, prof, fit, mu_s, s2_s, values=None, samples=None):
    """One tabulation for synthesis targets (mean slope, average variance); returns (table, notes).

    ``values``/``samples`` (the specular table and its slice samples) may be passed in so
    that correction rounds do not recompute them."""
    notes = []
    theta = np.asarray(prof.theta_o, float)
    kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
    if values is None:
        values = specular_values(table, kd, prof.split)
    alpha_new = target_energy(prof, fit, targets)  # (views, 3)
    p = prof["avg"]
    if targets.mode == "warp":
        samples = samples or SliceSamples(values, prof)
        deviation = np.nan_to_num(np.asarray(p["mu_theta"], float)) - fit["mu_slope"] * theta
        ratio = s2_s / fit["sigma2"]
        # The node sampling is coarser than the profile integrator: express the targets as
        # changes from the node-sampled original, so a no-op edit solves to the identity map.
        base = np.array([samples.warped_moments(k, samples.mu[k], 1.0, 1.0) for k in range(len(theta))])
        mu_target = base[:, 1] + (mu_s * theta + deviation - samples.mu)
        vt_target = np.maximum(base[:, 2] * ratio, 1e-14)
        vp_target = np.maximum(base[:, 3] * ratio, 1e-14)
        params, reached = solve_warp(samples, mu_target, vt_target, vp_target)
        if not reached.all():
            bad = np.degrees(theta[~reached])
            notes.append(f"warp: clipping by the hemisphere keeps {len(bad)} view(s) "
                         f"({bad.min():.0f}-{bad.max():.0f} deg) off their per-view targets")
        alpha_old = np.stack([np.nan_to_num(np.asarray(prof[c]["alpha"], float)) for c in "rgb"], axis=1)
        # Energy factor per channel: the warp keeps a fraction of the mass, the rest is clipped.
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.where(alpha_old > 1e-12 * max(alpha_old.max(), 1e-300),
                            alpha_new / (alpha_old * np.maximum(params[:, 3:4], 1e-3)), 0.0)

        def evaluate(side, sel):
            kt = side.interp(params[:, 1], sel)
            kp = side.interp(params[:, 2], sel)
            src_t = side.interp(samples.mu, sel) + (side.theta[sel] - side.interp(params[:, 0], sel)) / kt
            src_p = side.phi[sel] / kp
            inside = (np.abs(src_t) <= HALF_PI) & (np.abs(src_p) <= HALF_PI)
            cells = cell_indices_view(np.clip(src_t, -HALF_PI, HALF_PI), np.clip(src_p, -HALF_PI, HALF_PI),
                                      side.sin_e[sel], side.cos_e[sel])
            scale = inside / (kt * kp)
            return np.stack([values[cells, c] * side.interp(gain[:, c], sel) * scale for c in range(3)])

    else:
        m, s, ok = solve_truncated(mu_s * theta, np.full_like(theta, s2_s))
        m_p, s_p, ok_p = solve_truncated(np.zeros(1), np.array([s2_s]))
        if not (ok.all() and ok_p.all()):
            notes.append("model: no truncated Gaussian has the target mean and variance at "
                         f"{int((~ok).sum())} view(s); the nearest reachable lobe is used")

        def evaluate(side, sel):
            g = _truncated_gauss(side.theta[sel], side.interp(m, sel), side.interp(s, sel)) \
                * _truncated_gauss(side.phi[sel], m_p[0], s_p[0])
            return np.stack([side.interp(alpha_new[:, c], sel) * g for c in range(3)])

    return _tabulate(table, evaluate, kd, theta), notes


_PAIR_GEOMETRY = {}


class _Side:
    """One orientation of every cell: the view's elevation and the lit direction's
    view-centred angles, plus interpolation weights into the profile's view grid."""

    def __init__(self, elev, theta, phi):
        self.elev, self.theta, self.phi = elev, theta, phi
        self.sin_e, self.cos_e = np.sin(elev), np.cos(elev)
        self.grid = None

    def weights(self, grid):
        if self.grid is None or len(self.grid) != len(grid) or np.any(self.grid != grid):
            e = np.clip(self.elev, grid[0], grid[-1])
            i = np.clip(np.searchsorted(grid, e, side="right") - 1, 0, max(len(grid) - 2, 0))
            span = np.diff(grid)[i] if len(grid) > 1 else np.ones_like(e)
            self.i = i
            self.f = np.clip((e - grid[i]) / np.where(span > 0, span, 1.0), 0.0, 1.0) if len(grid) > 1 else 0 * e
            self.grid = np.array(grid)
        return self

    def interp(self, values, sel):
        v = np.asarray(values, float)
        if len(v) == 1:
            return np.full(len(sel), v[0])
        i, f = self.i[sel], self.f[sel]
        return v[i] + f * (v[i + 1] - v[i])


def _pair_geometry():
    """Per cell, both orientations (cached; material independent, computed once)."""
    if "g" not in _PAIR_GEOMETRY:
        th, td, pd = cell_centres()
        wi, wo = directions_from_half_diff(th, td, pd)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        _PAIR_GEOMETRY["g"] = (above, _Side(*_view_frame(wo, wi)), _Side(*_view_frame(wi, wo)))
    return _PAIR_GEOMETRY["g"]


def _tabulate(table, evaluate, kd, grid):
    above, side_a, side_b = _pair_geometry()
    active = np.flatnonzero(above & table.valid.any(axis=0))  # missing cells stay missing: skip them
    v = 0.5 * (evaluate(side_a.weights(grid), active) + evaluate(side_b.weights(grid), active))
    rho = np.zeros_like(table.rho)
    rho[:, active] = v
    rho += kd[:, None]
    valid = table.valid.copy()
    rho = np.where(valid, rho, 0.0)
    if not np.isfinite(rho).all() or rho.max(initial=0.0) > 1e30:
        raise ValueError("synthesis produced non-finite or absurd values; the slider targets are out of reach")
    return MerlTable(rho, valid, None)


def directional_albedo(table: MerlTable, views=None) -> np.ndarray:
    """(views, 3): integral of rho cos(theta_i) over the hemisphere for each view."""
    from .integrate import default_views, get_operator

    views = default_views(30, 89.0) if views is None else np.asarray(views, float)
    op = get_operator(views, memo=False)
    full = np.where(table.valid, table.rho, 0.0).T
    out = np.empty((len(views), 3))
    for k in range(len(views)):
        cells, w = op.albedo_view(k)
        out[k] = full[cells].T @ np.asarray(w, dtype=float)
    return out


def _finish(out, targets, mu_t, s2_t, warnings, prof, remeasure):
    albedo = directional_albedo(out).max(axis=0)
    if np.any(albedo > 1.0):
        warnings.append(f"the edited material reflects more than it receives (largest directional albedo "
                        f"{albedo.max():.3f} > 1); scale it down with scale_to_albedo")
    achieved_mu = achieved_s2 = None
    new_prof = None
    if remeasure:
        new_prof = compute_profiles(out, prof.theta_o, kd=prof.kd if prof.split else None, split=prof.split)
        f = fit_material(new_prof)
        achieved_mu, achieved_s2 = f["mu_slope"], f["sigma2"]
    return EditResult(out, mu_t, s2_t, achieved_mu, achieved_s2, albedo, warnings, new_prof)


def scale_to_albedo(result: EditResult, limit: float = 1.0) -> EditResult:
    """Scale the edited table down so its largest directional albedo is ``limit`` (kd too)."""
    peak = float(result.max_albedo.max())
    if peak <= limit:
        return result
    f = limit / peak
    t = MerlTable(result.table.rho * f, result.table.valid.copy(), None)
    return EditResult(t, result.target_mu_slope, result.target_sigma2, result.achieved_mu_slope,
                      result.achieved_sigma2, result.max_albedo * f,
                      [w for w in result.warnings if "reflects more" not in w], result.profiles)
