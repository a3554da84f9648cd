"""The sliders and what they promise per view (SPEC §3 "Editing").

An edit is judged view by view: every view's re-measured energy, mean and covariance must
follow the sliders. ``view_targets`` turns the sliders into those per-view, per-channel goals.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..fits import truncated
from ..fits.curves import LAMBERT_VARIANCE, MIN_SIGMA2, correlation_curve, energy_curve, fit_mean_slope, fit_variance
from ..limits import TARGET_FIELDS, check_targets
from ..profiles.compute import Profiles

MODES = ("warp", "model")
RGB = ("r", "g", "b")


@dataclass
class EditTargets:
    """Slider values. ``None`` keeps the measured value (identity on that axis)."""

    strength: float = 1.0  # overall energy scale
    colour: tuple = (1.0, 1.0, 1.0)  # per-channel energy scale
    grazing_boost: float = 1.0  # scale of the energy above the base alpha_b
    mu_slope: float | None = None  # in [-1, 0]
    sigma2: float | None = None  # in (0, pi^2/12]
    mode: str = "warp"
    lock: bool = False  # sigma2 follows mu_slope along the correlation quadratic
    correlation_a: float | None = None  # the quadratic's a (from a set fit); needed with lock
    roughness: float | None = None  # a roughness scale asked for directly (instead of sigma2)

    def is_identity(self) -> bool:
        return (
            self.mode == "warp"
            and self.strength == 1.0
            and tuple(self.colour) == (1.0, 1.0, 1.0)
            and self.grazing_boost == 1.0
            and self.mu_slope is None
            and self.sigma2 is None
            and self.roughness is None
            and not self.lock
        )

    def is_energy_only(self) -> bool:
        """Warp mode, only strength and colour moved: the specular part scales exactly."""
        return (
            self.mode == "warp"
            and self.mu_slope is None
            and self.sigma2 is None
            and self.roughness is None
            and not self.lock
            and self.grazing_boost == 1.0
        )


def _check(t: EditTargets):
    """The sliders inside their declared ranges (``core.limits``), else ValueError naming one."""
    return check_targets(t, TARGET_FIELDS)


def resolve_targets(t: EditTargets, fit: dict):
    """The sliders as the edit will use them; returns (mu, sigma2, warnings).

    A value outside its declared range (``core.limits.RANGES``: NaN, inf, negative energies,
    1e308, a variance above pi^2/12) is refused, ValueError naming the parameter: the same
    check the command line and the panel make. Inside it, a mean slope beyond the slider's
    range for this material and a variance below MIN_SIGMA2 are clamped, with a warning."""
    _check(t)
    if t.mode not in MODES:
        raise ValueError(f"mode: must be one of {MODES}, got {t.mode!r}")
    warnings = []
    mu = fit["mu_slope"] if t.mu_slope is None else float(t.mu_slope)
    if not np.isfinite(mu):
        raise ValueError("the material's fitted mean slope is not finite")
    # The slider's range is [-1, 0] widened to hold the fitted slope (SPEC: measured ones go below -1).
    lo, hi = min(-1.0, fit["mu_slope"]), max(0.0, fit["mu_slope"])
    if t.mu_slope is not None and not lo <= mu <= hi:
        warnings.append(f"mean slope {mu:+.3f} clamped to [{lo:+.3f}, {hi:+.3f}]")
        mu = float(np.clip(mu, lo, hi))
    if t.lock:
        if t.correlation_a is None:
            raise ValueError(
                "correlation_a: the correlation lock needs the quadratic's coefficient a (fit a set first)"
            )
        s2 = float(correlation_curve(mu, t.correlation_a))
    else:
        s2 = fit["sigma2"] if t.sigma2 is None else float(t.sigma2)
    if not np.isfinite(s2):
        raise ValueError("the material's fitted variance is not finite")
    # Only a requested variance is clamped: left alone (None), the measured one is kept as it is,
    # even past pi^2/12 (broad measured lobes fit up to ~1.0). Clamping it made an energy-only
    # edit of nielsen/greencloth promise a 22 % narrower lobe at every view.
    if (t.sigma2 is not None or t.lock) and (s2 < MIN_SIGMA2 or s2 > LAMBERT_VARIANCE):
        warnings.append(f"variance {s2:.3g} clamped to ({MIN_SIGMA2:g}, pi^2/12]")
        s2 = float(np.clip(s2, MIN_SIGMA2, LAMBERT_VARIANCE))
    return mu, s2, warnings


def target_energy(prof: Profiles, fit: dict, t: EditTargets) -> np.ndarray:
    """(views, 3), warp mode: alpha'_c = strength colour_c (alpha_b,c + boost (alpha_c - alpha_b,c))."""
    _check(t)
    out = np.empty((len(prof.theta_o), 3))
    for i, ch in enumerate(RGB):
        a = np.nan_to_num(np.asarray(prof[ch]["alpha"], float))
        base = fit["channels"].get(ch, {}).get("alpha_b", 0.0) if fit.get("channels") else 0.0
        base = min(max(base, 0.0), float(a.min()) if a.size else 0.0)
        out[:, i] = t.strength * t.colour[i] * (base + t.grazing_boost * (a - base))
    return np.maximum(out, 0.0)


def model_energy(prof: Profiles, fit: dict, t: EditTargets) -> np.ndarray:
    """(views, 3), model mode: the fitted energy spline per channel, scaled like warp mode's."""
    _check(t)
    theta = np.asarray(prof.theta_o, float)
    out = np.zeros((len(theta), 3))
    for i, ch in enumerate(RGB):
        c = (fit.get("channels") or {}).get(ch)
        if not c:
            continue
        curve = energy_curve(theta, c["alpha_b"], fit["theta0"], fit["theta1"], c["alpha1"], c["m1"])
        base = c["alpha_b"]
        out[:, i] = t.strength * t.colour[i] * (base + t.grazing_boost * (curve - base))
    return np.maximum(out, 0.0)


@dataclass
class ViewTargets:
    """Per view and channel (r, g, b): what the edited table's re-measured slice must show.

    ``shape`` holds the standardized moments to keep (warp mode: the measured ones), or None
    (model mode: the model's lobe has its own shape). ``avg_mean``/``avg_var`` are the same rule
    applied to the average channel's profiles (what the synthesis steers on and the announced
    sliders are fitted to)."""

    theta_o: np.ndarray  # (V,)
    alpha: np.ndarray  # (V, 3)
    mean: np.ndarray  # (V, 3) mu_theta
    var_tt: np.ndarray  # (V, 3)
    var_pp: np.ndarray  # (V, 3)
    shape: dict | None  # key -> (V, 3): skew_30, skew_03, kurt_40, kurt_04 (excess)
    mode: str = "warp"
    mu_slope: float = 0.0  # the sliders as resolved (the request)
    sigma2: float = 0.0
    avg_mean: np.ndarray | None = None  # (V,) average channel
    avg_var: np.ndarray | None = None  # (V,) average channel, (var_tt + var_pp) / 2

    @property
    def variance(self):
        """(V, 3): the average of the two variances, the quantity sigma~^2 fits."""
        return 0.5 * (self.var_tt + self.var_pp)


SHAPE_KEYS = ("skew_30", "skew_03", "kurt_40", "kurt_04")


def _stack(prof, key):
    return np.stack([np.asarray(prof[ch][key], float) for ch in RGB], axis=1)


@dataclass
class Lobes:
    """Each view's lobe read as a Gaussian truncated by the horizon (``read_lobes``): on theta
    about its centre, on phi about 0, fitted to the measured mean and variances."""

    theta_o: np.ndarray
    mean: np.ndarray
    var_tt: np.ndarray
    var_pp: np.ndarray
    ok: np.ndarray  # a lobe was measured there (finite, positive variances)
    centre: np.ndarray
    width: np.ndarray
    width_phi: np.ndarray
    clipped: tuple  # the fitted lobes' own clipped (mean, var_tt, var_pp)


_LOBES: dict = {}


def read_lobes(theta_o, mean, var_tt, var_pp) -> Lobes:
    """Invert the truncated Gaussian (``truncated.solve``) at every view: the one slow step of the
    rule, so it is kept per content (a few entries) and the edits only run the forward moments."""
    import hashlib

    arrays = np.broadcast_arrays(*(np.asarray(a, float) for a in (theta_o, mean, var_tt, var_pp)))
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(repr(a.shape).encode())
        h.update(np.ascontiguousarray(a).data)
    key = h.hexdigest()
    if key in _LOBES:
        return _LOBES[key]
    theta, mean, var_tt, var_pp = arrays
    ok = np.isfinite(mean) & np.isfinite(var_tt) & np.isfinite(var_pp) & (var_tt > 0) & (var_pp > 0)
    m = np.where(ok, mean, 0.0)
    vt, vp = np.where(ok, var_tt, 1.0), np.where(ok, var_pp, 1.0)
    centre, width, _ = truncated.solve(m, vt)
    _, width_phi, _ = truncated.solve(np.zeros_like(vp), vp)
    m0, v0 = truncated.moments(centre, width)
    _, w0 = truncated.moments(np.zeros_like(width_phi), width_phi)
    lobes = Lobes(theta, mean, var_tt, var_pp, ok, centre, width, width_phi, (m0, v0, w0))
    if len(_LOBES) >= 8:
        _LOBES.pop(next(iter(_LOBES)))
    _LOBES[key] = lobes
    return lobes


def follow_lobe(lobes: Lobes, ratio, shift):
    """SPEC §3 "Targets follow physics": each view's moments after its *unclipped* lobe is edited.

    The width of each view's lobe (``read_lobes``) is scaled by sqrt(``ratio``); its centre's
    offset from the mirror (-theta_o), the pull of the material's smooth envelope on a lobe of
    variance s^2, which is proportional to s^2, scales by ``ratio`` too; the centre then moves by
    ``shift`` * theta_o. The lobe is clipped again, and the change of the clipped moments is
    carried onto the measured ones (a difference for the mean, ratios for the variances), so an
    identity edit returns the measured moments exactly. Far from the horizon a pure shift gives
    mu + shift * theta_o and a pure scaling ratio * Sigma. ``ratio`` and ``shift`` broadcast
    against the views (a leading axis scans many edits at once); NaN (no lobe) stays NaN."""
    L = lobes
    ratio = np.asarray(ratio, float)
    scale = np.sqrt(ratio)
    moved = -L.theta_o + (L.centre + L.theta_o) * ratio + np.asarray(shift, float) * L.theta_o
    m1, v1 = truncated.moments(moved, L.width * scale)
    _, w1 = truncated.moments(np.zeros_like(L.width_phi), L.width_phi * scale)
    m0, v0, w0 = L.clipped
    return (
        np.where(L.ok, L.mean + (m1 - m0), np.nan),
        np.where(L.ok, L.var_tt * (v1 / v0), np.nan),
        np.where(L.ok, L.var_pp * (w1 / w0), np.nan),
    )


def profile_lobes(prof: Profiles) -> Lobes:
    """``read_lobes`` of r, g, b stacked (V, 3)."""
    theta = np.asarray(prof.theta_o, float)
    return read_lobes(theta[:, None], _stack(prof, "mu_theta"), _stack(prof, "sigma_tt"), _stack(prof, "sigma_pp"))


def model_lobe(theta_o, mu_fit, s2_fit, mu, s2):
    """Model mode's per-view (mean, variance): the model's lobe (Eq. 7-8, centre mu~ theta_o, width
    sigma~^2, unclipped) edited by the same rule as warp mode's lobes, then clipped by the horizon."""
    theta_o = np.asarray(theta_o, float)
    ratio = s2 / s2_fit
    centre = -theta_o + (mu_fit + 1.0) * theta_o * ratio + (np.asarray(mu, float) - mu_fit) * theta_o
    return truncated.moments(centre, np.full(centre.shape, math.sqrt(s2)))


def view_targets(prof: Profiles, fit: dict, t: EditTargets, mu: float, s2: float) -> ViewTargets:
    """The per-view targets of SPEC §3 for resolved sliders ``mu``, ``s2`` (the request).

    Warp: alpha' = s_c alpha (boost above alpha_b); mean and variances by ``follow_lobe`` with the
    sigma~^2 ratio and the mean-slope move; shape kept. Model: the fitted spline, and the model's
    lobe edited by the same rule (``model_lobe``) on both axes."""
    _check(t)
    if not (np.isfinite(mu) and np.isfinite(s2) and s2 > 0):
        raise ValueError(f"mu, s2: the resolved point must be finite with s2 > 0, got ({mu!r}, {s2!r})")
    theta = np.asarray(prof.theta_o, float)
    if t.mode == "model":
        mean, var = model_lobe(theta, fit["mu_slope"], fit["sigma2"], mu, s2)
        rep = lambda a: np.repeat(a[:, None], 3, axis=1)  # noqa: E731
        return ViewTargets(
            theta, model_energy(prof, fit, t), rep(mean), rep(var), rep(var), None, "model", mu, s2, mean, var
        )
    ratio, shift = s2 / fit["sigma2"], mu - fit["mu_slope"]
    mean, var_tt, var_pp = follow_lobe(profile_lobes(prof), ratio, shift)
    alpha = target_energy(prof, fit, t)
    avg_mean, avg_var = mixture(alpha, mean, var_tt, var_pp)
    shape = {k: _stack(prof, k) for k in SHAPE_KEYS}
    return ViewTargets(theta, alpha, mean, var_tt, var_pp, shape, "warp", mu, s2, avg_mean, avg_var)


def mixture(alpha, mean, var_tt, var_pp):
    """The average channel's (mean, average variance) per view from the channels' (V, 3): its
    slice is the channels' mean, so its moments are their energy-weighted mixture (a colour edit
    changes the weights, and so the average channel's mean). NaN where no channel has a lobe."""
    ok = np.isfinite(mean) & np.isfinite(var_tt) & np.isfinite(var_pp) & (alpha > 0)
    w = np.where(ok, alpha, 0.0)
    total = w.sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = w / total[:, None]
        m = np.where(ok, mean, 0.0)
        centre = (w * m).sum(axis=1)
        tt = (w * (np.where(ok, var_tt, 0.0) + (m - centre[:, None]) ** 2)).sum(axis=1)
        pp = (w * np.where(ok, var_pp, 0.0)).sum(axis=1)
    none = total <= 0
    return np.where(none, np.nan, centre), np.where(none, np.nan, 0.5 * (tt + pp))


def announced(vt: ViewTargets):
    """(mu~, sigma~^2) the written table re-fits to when it meets its targets: the Sec. 3.4 fits
    of the average channel's targets, the same fits Analyse makes of a material. The request is
    what the artist sets; this is what the panel and the command line show beside it (SPEC §3:
    when sigma~^2 moves, the re-fitted mu~ moves with it, along the material's horizon curve)."""
    mu = fit_mean_slope(vt.theta_o, vt.avg_mean)["mu_slope"]
    s2 = fit_variance(vt.theta_o, vt.avg_var, vt.avg_var)["sigma2"]
    return (None if mu is None else float(mu)), (None if s2 is None else float(s2))
