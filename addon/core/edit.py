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
from .merl import MerlTable, cell_centres, cell_indices
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


def solve_warp(samples: SliceSamples, mu_target, var_t_target, var_p_target, iters=30, tol=1e-7):
    """Per view: (mu_new, k_theta, k_phi, kept fraction, reached?) so the clipped warp hits targets."""
    n = len(samples.theta_o)
    out = np.zeros((n, 4))
    reached = np.ones(n, bool)
    for k in range(n):
        m, kt, kp = mu_target[k], math.sqrt(var_t_target[k] / max(samples.var_t[k], 1e-300)), \
            math.sqrt(var_p_target[k] / max(samples.var_p[k], 1e-300))
        frac = 1.0
        ok = False
        for _ in range(iters):
            frac, mt, vt, vp = samples.warped_moments(k, m, kt, kp)
            if frac <= 0 or vt <= 0 or vp <= 0:
                break
            et = mu_target[k] - mt
            if abs(et) < tol and abs(vt / var_t_target[k] - 1) < tol and abs(vp / var_p_target[k] - 1) < tol:
                ok = True
                break
            m = float(np.clip(m + et, -2 * np.pi, 2 * np.pi))
            kt = float(np.clip(kt * math.sqrt(var_t_target[k] / vt), 1e-6, 1e6))
            kp = float(np.clip(kp * math.sqrt(var_p_target[k] / vp), 1e-6, 1e6))
        else:
            frac, mt, vt, vp = samples.warped_moments(k, m, kt, kp)
            ok = abs(mu_target[k] - mt) < 1e-3 and abs(vt / var_t_target[k] - 1) < 1e-2 \
                and abs(vp / var_p_target[k] - 1) < 1e-2
        out[k] = (m, kt, kp, max(frac, 1e-300))
        reached[k] = ok
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


def _interp(theta_o, table_theta, values):
    return np.interp(np.clip(theta_o, table_theta[0], table_theta[-1]), table_theta, values)


def edit(table: MerlTable, targets: EditTargets, prof: Profiles | None = None, fit: dict | None = None,
         remeasure: bool = True, progress=None, max_rounds: int = 3) -> EditResult:
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

    mu_s, s2_s = mu_t, s2_t
    best = None
    for round_ in range(max_rounds):
        out, notes = synthesize(table, targets, prof, fit, mu_s, s2_s)
        new_prof = compute_profiles(out, prof.theta_o, kd=prof.kd if prof.split else None, split=prof.split)
        f = fit_material(new_prof)
        if f["mu_slope"] is None or f["sigma2"] is None:
            break
        err_mu, err_s2 = f["mu_slope"] - mu_t, f["sigma2"] / s2_t - 1.0
        score = abs(err_mu) / 0.01 + abs(err_s2) / 0.02
        if best is None or score < best[0]:
            best = (score, out, notes, new_prof, f)
        if abs(err_mu) < 0.005 and abs(err_s2) < 0.01:
            break
        mu_s = float(np.clip(mu_s - err_mu, -1.5, 0.5))
        s2_s = float(np.clip(s2_s / (1.0 + err_s2), MIN_SIGMA2, LAMBERT_VARIANCE))
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


def synthesize(table, targets, prof, fit, mu_s, s2_s):
    """One tabulation for synthesis targets (mean slope, average variance); returns (table, notes)."""
    notes = []
    theta = np.asarray(prof.theta_o, float)
    kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
    values = specular_values(table, kd, prof.split)
    alpha_new = target_energy(prof, fit, targets)  # (views, 3)
    p = prof["avg"]
    if targets.mode == "warp":
        samples = SliceSamples(values, prof)
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

        def evaluate(elev, th, ph):
            mu0 = _interp(elev, theta, samples.mu)
            m = _interp(elev, theta, params[:, 0])
            kt = _interp(elev, theta, params[:, 1])
            kp = _interp(elev, theta, params[:, 2])
            src_t = mu0 + (th - m) / kt
            src_p = ph / kp
            inside = (np.abs(src_t) <= HALF_PI) & (np.abs(src_p) <= HALF_PI)
            wi = view_centred(np.clip(src_t, -HALF_PI, HALF_PI), np.clip(src_p, -HALF_PI, HALF_PI))
            wo = view_centred(elev, 0.0 * elev)
            v = values[cell_indices(*half_diff_from_directions(wi, wo)), :3] * inside[:, None]
            g = np.stack([_interp(elev, theta, gain[:, c]) for c in range(3)], axis=1)
            return v * g / (kt * kp)[:, None]
    else:
        m, s, ok = solve_truncated(mu_s * theta, np.full_like(theta, s2_s))
        m_p, s_p, ok_p = solve_truncated(np.zeros(1), np.array([s2_s]))
        if not (ok.all() and ok_p.all()):
            notes.append("model: no truncated Gaussian has the target mean and variance at "
                         f"{int((~ok).sum())} view(s); the nearest reachable lobe is used")

        def evaluate(elev, th, ph):
            mm = _interp(elev, theta, m)
            ss = _interp(elev, theta, s)
            g = _truncated_gauss(th, mm, ss) * _truncated_gauss(ph, m_p[0], s_p[0])
            a = np.stack([_interp(elev, theta, alpha_new[:, c]) for c in range(3)], axis=1)
            return a * g[:, None]

    return _tabulate(table, evaluate, kd), notes


_PAIR_GEOMETRY = {}


def _pair_geometry():
    """Per cell: the view-frame angles of each direction seen from the other (cached).

    Material independent; 1.46 M cells x 6 float32 = 35 MB, computed once per process.
    """
    if "g" not in _PAIR_GEOMETRY:
        th, td, pd = cell_centres()
        wi, wo = directions_from_half_diff(th, td, pd)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        a = _view_frame(wo, wi)  # w_o as the view
        b = _view_frame(wi, wo)  # w_i as the view
        _PAIR_GEOMETRY["g"] = (above, *(np.asarray(x, np.float32) for x in a + b))
    return _PAIR_GEOMETRY["g"]


def _tabulate(table, evaluate, kd, progress=None, chunk=1 << 18):
    above, ae, at, ap, be, bt, bp = _pair_geometry()
    rho = np.zeros_like(table.rho)
    n = above.size
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        f = np.float64
        v = 0.5 * (evaluate(ae[sl].astype(f), at[sl].astype(f), ap[sl].astype(f))
                   + evaluate(be[sl].astype(f), bt[sl].astype(f), bp[sl].astype(f)))
        rho[:, sl] = np.where(above[sl, None], v, 0.0).T
        if progress:
            progress(sl.stop, n)
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
        cells, w = op.view(k)
        out[k] = full[cells].T @ np.asarray(w[:, -1], dtype=float)
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
