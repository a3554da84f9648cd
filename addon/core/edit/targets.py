"""The sliders and what they promise per view (SPEC §3 "Editing").

An edit is judged view by view: every view's re-measured energy, mean and covariance must
follow the sliders. ``view_targets`` turns the sliders into those per-view, per-channel goals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fits import LAMBERT_VARIANCE, MIN_SIGMA2, correlation_curve, energy_curve
from ..geometry import HALF_PI
from ..profiles import Profiles
from ..truncated import CAP_FRACTION, reachable_variance, variance_cap_fast

MODES = ("warp", "model")
# Model mode's mean is kept this far (relative) inside the horizon: a mean on the edge has no spread.
MODEL_EDGE = 0.02
# A model view is beyond the model when the truncation caps its variance by more than this.
BEYOND_MODEL = 0.01
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

    def is_identity(self) -> bool:
        return (
            self.mode == "warp"
            and self.strength == 1.0
            and tuple(self.colour) == (1.0, 1.0, 1.0)
            and self.grazing_boost == 1.0
            and self.mu_slope is None
            and self.sigma2 is None
            and not self.lock
        )

    def is_energy_only(self) -> bool:
        """Warp mode, only strength and colour moved: the specular part scales exactly."""
        return (
            self.mode == "warp"
            and self.mu_slope is None
            and self.sigma2 is None
            and not self.lock
            and self.grazing_boost == 1.0
        )


def resolve_targets(t: EditTargets, fit: dict):
    """Clamp slider values to their ranges; returns (mu, sigma2, warnings)."""
    warnings = []
    mu = fit["mu_slope"] if t.mu_slope is None else float(t.mu_slope)
    if not np.isfinite(mu):
        raise ValueError("mean slope must be finite")
    # The slider's range is [-1, 0] widened to hold the fitted slope (SPEC: measured ones go below -1).
    lo, hi = min(-1.0, fit["mu_slope"]), max(0.0, fit["mu_slope"])
    if t.mu_slope is not None and not lo <= mu <= hi:
        warnings.append(f"mean slope {mu:+.3f} clamped to [{lo:+.3f}, {hi:+.3f}]")
        mu = float(np.clip(mu, lo, hi))
    if t.lock:
        if t.correlation_a is None:
            raise ValueError("the correlation lock needs the quadratic's coefficient a (fit a set first)")
        s2 = float(correlation_curve(mu, t.correlation_a))
    else:
        s2 = fit["sigma2"] if t.sigma2 is None else float(t.sigma2)
    if not np.isfinite(s2):
        raise ValueError("variance must be finite")
    # Only a requested variance is clamped: left alone (None), the measured one is kept as it is,
    # even past pi^2/12 (broad measured lobes fit up to ~1.0). Clamping it made an energy-only
    # edit of nielsen/greencloth promise a 22 % narrower lobe at every view.
    if (t.sigma2 is not None or t.lock) and (s2 < MIN_SIGMA2 or s2 > LAMBERT_VARIANCE):
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
    """(views, 3), warp mode: alpha'_c = strength colour_c (alpha_b,c + boost (alpha_c - alpha_b,c))."""
    out = np.empty((len(prof.theta_o), 3))
    for i, ch in enumerate(RGB):
        a = np.nan_to_num(np.asarray(prof[ch]["alpha"], float))
        base = fit["channels"].get(ch, {}).get("alpha_b", 0.0) if fit.get("channels") else 0.0
        base = min(max(base, 0.0), float(a.min()) if a.size else 0.0)
        out[:, i] = t.strength * t.colour[i] * (base + t.grazing_boost * (a - base))
    return np.maximum(out, 0.0)


def model_energy(prof: Profiles, fit: dict, t: EditTargets) -> np.ndarray:
    """(views, 3), model mode: the fitted energy spline per channel, scaled like warp mode's."""
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
    (model mode: the model's lobe has its own shape)."""

    theta_o: np.ndarray  # (V,)
    alpha: np.ndarray  # (V, 3)
    mean: np.ndarray  # (V, 3) mu_theta
    var_tt: np.ndarray  # (V, 3)
    var_pp: np.ndarray  # (V, 3)
    shape: dict | None  # key -> (V, 3): skew_30, skew_03, kurt_40, kurt_04 (excess)
    mode: str = "warp"
    mu_slope: float = 0.0  # the sliders as resolved
    sigma2: float = 0.0
    # (V, 3) model mode: views where the model's own lobe cannot have the slider's variance (its
    # mean too near the horizon): listed as out of reach, not counted. None in warp mode.
    beyond: np.ndarray | None = None

    @property
    def variance(self):
        """(V, 3): the average of the two variances, the quantity sigma~^2 fits."""
        return 0.5 * (self.var_tt + self.var_pp)


SHAPE_KEYS = ("skew_30", "skew_03", "kurt_40", "kurt_04")


def _stack(prof, key):
    return np.stack([np.asarray(prof[ch][key], float) for ch in RGB], axis=1)


def model_view_moments(location, s2, fast=False):
    """Model mode's per-view mean and variance for lobe locations mu~' theta_o and variance
    sigma~^2' (any shape), and where the model cannot show that variance (``beyond``).
    ``fast``: the truncated limit read off its fine grid (the region's scans over the plane)."""
    mean = np.clip(location, -HALF_PI * (1.0 - MODEL_EDGE), HALF_PI * (1.0 - MODEL_EDGE))
    if fast:
        var = np.minimum(np.maximum(s2, 1e-14), CAP_FRACTION * variance_cap_fast(mean))
    else:
        var = reachable_variance(mean, s2)
    return mean, var, var < (1.0 - BEYOND_MODEL) * s2


def view_targets(prof: Profiles, fit: dict, t: EditTargets, mu: float, s2: float) -> ViewTargets:
    """The per-view targets of SPEC §3 for resolved sliders ``mu``, ``s2``.

    Warp: alpha' = s_c alpha (boost above alpha_b), mu' = mu + (mu~' - mu~) theta_o,
    Sigma' = (s2' / s2) Sigma, shape kept. Model: the fitted spline, mu~' theta_o, s2' on both axes."""
    theta = np.asarray(prof.theta_o, float)
    if t.mode == "model":
        # The model's slice is a truncated Gaussian on [-pi/2, pi/2] (Eq. 8): its mean is mu~' theta_o
        # kept inside the domain, and its variance sigma~^2' capped by the one truncated solver's
        # rule (``truncated.reachable_variance``), as the moment-model preview draws it. Near the
        # horizon no distribution has mu~' theta_o's mean with a wide variance.
        mean, var, beyond = (np.repeat(a[:, None], 3, axis=1) for a in model_view_moments(mu * theta, s2))
        return ViewTargets(theta, model_energy(prof, fit, t), mean, var, var, None, "model", mu, s2, beyond)
    ratio = s2 / fit["sigma2"]
    mean = _stack(prof, "mu_theta") + (mu - fit["mu_slope"]) * theta[:, None]
    return ViewTargets(
        theta,
        target_energy(prof, fit, t),
        mean,
        _stack(prof, "sigma_tt") * ratio,
        _stack(prof, "sigma_pp") * ratio,
        {k: _stack(prof, k) for k in SHAPE_KEYS},
        "warp",
        mu,
        s2,
    )
