"""The roughness scale an edit asks for (SPEC §3 "Editing", step 4), and the material's curve.

The artist asks for a variance sigma~^2; the operator (``roughness.scale_roughness``) takes a
roughness scale s. sigma~^2(s), the variance the edited table re-fits to, is monotone in s but
not proportional to s^2 (masking and the horizon pull it), so s is solved for: a secant on
log sigma~^2 against log s, started from the material's curve, each step one synthesis and one
re-measure of the table it makes (the same measurement Apply reports).

The material's curve is (mu~, sigma~^2) at a ladder of scales: what the roughness edit of this
material reaches, drawn on the region plot; mu~ follows sigma~^2 along it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..fits.curves import fit_material
from ..profiles.compute import compute_profiles
from .reciprocal import Superseded
from .roughness import S_RANGE, Source, prepare, scale_roughness

# The ladder the curve is drawn on (s = 1: the table itself); its ends are the region's: 0.15 is
# about where a narrow measured lobe meets the table's theta_h cells, 6 where a lobe is near
# Lambertian. A request beyond them is clamped to them. Dense from x0.7 to x2 in scale (about
# sigma~^2 x0.5 to x2.4), where artists move the slider: mu~ is not monotone along the curve
# (ggx_glossy: -1.068, -1.073 at x1.5, -1.063 at x2), and from the ladder 1, 2.5 alone the
# panel's mean slope at sigma~^2 x1.5 was 0.015 off the table's.
CURVE_SCALES = (0.15, 0.4, 0.7, 1.0, 1.4, 2.0, 6.0)
SOLVE_TOLERANCE = 0.002  # relative, on sigma~^2: well inside the 1 % an edit promises
SOLVE_STEPS = 6
# Without the material's curve, the first guess: sigma~^2 grows about as s^1.2 on microfacet
# tables (ggx_glossy: s 0.577 halves it, s 1.98 doubles it), not as s^2 (the horizon and
# masking clip the widening lobe).
GUESS_EXPONENT = 1.2


def first_guess(sigma2: float, fitted_sigma2: float) -> float:
    return (sigma2 / fitted_sigma2) ** (1.0 / GUESS_EXPONENT)


def measure(table, theta_o, split=True):
    """(profiles, fit) of a table as a fresh analysis of it would measure them (its own floor)."""
    prof = compute_profiles(table, theta_o, split=split)
    return prof, fit_material(prof)


@dataclass
class MaterialCurve:
    """(mu~, sigma~^2) of the material with its roughness scaled by each of ``scales``."""

    scales: np.ndarray
    mu: np.ndarray
    sigma2: np.ndarray

    def usable(self):
        """The points on the curve's one branch through s = 1: finite, and sigma~^2 rising with s
        outward from the scale nearest 1 (a lobe narrowed below the table's resolution re-fits
        wider again; that point would make a wider request pick a narrower table)."""
        ok = np.isfinite(self.mu) & np.isfinite(self.sigma2) & (self.sigma2 > 0)
        order = np.argsort(self.scales)
        sc, s2, good = self.scales[order], self.sigma2[order], ok[order]
        mid = int(np.argmin(np.abs(np.log(np.maximum(sc, 1e-300)))))
        keep = np.zeros(len(sc), bool)
        keep[mid] = good[mid]
        for step in (1, -1):  # outward each way while sigma~^2 keeps moving with s
            last = mid
            k = mid + step
            while keep[mid] and 0 <= k < len(sc) and good[k] and (s2[k] - s2[last]) * step > 0:
                keep[k], last, k = True, k, k + step
        out = np.zeros(len(sc), bool)
        out[order] = keep
        return out

    def scale_for(self, sigma2: float) -> float:
        """The scale at which the curve reaches ``sigma2`` (log-log interpolation; clamped to
        the ladder's ends)."""
        ok = self.usable()
        x, y = np.log(self.sigma2[ok]), np.log(self.scales[ok])
        order = np.argsort(x)
        return float(np.exp(np.interp(math.log(max(sigma2, 1e-300)), x[order], y[order])))

    def mu_at(self, sigma2: float) -> float:
        """The mean slope the material re-fits to when its roughness is edited to ``sigma2``."""
        ok = self.usable()
        x = np.log(self.sigma2[ok])
        order = np.argsort(x)
        return float(np.interp(math.log(max(sigma2, 1e-300)), x[order], self.mu[ok][order]))

    def to_json(self) -> dict:
        clean = lambda a: [None if not np.isfinite(v) else float(v) for v in np.asarray(a, float)]  # noqa: E731
        return {"scales": clean(self.scales), "mu": clean(self.mu), "sigma2": clean(self.sigma2)}


def material_curve(
    src: Source, theta_o, split=True, scales=CURVE_SCALES, stop=None, fit1=None, pool=None
) -> MaterialCurve:
    """The material's curve: one synthesis and one re-measure per scale (``fit1``: the table's
    own fit, measured as ``measure`` does, stands for s = 1). ``pool``: an executor the scales
    are measured on side by side (each point reads ``src`` only)."""

    def point(s):
        if stop is not None and stop():
            raise Superseded
        if s == 1.0 and fit1 is not None:
            return fit1
        return measure(scale_roughness(src, float(s))[0], theta_o, split)[1]

    fits = list(pool.map(point, scales)) if pool is not None else [point(s) for s in scales]
    mu = [np.nan if f.get("mu_slope") is None else f["mu_slope"] for f in fits]
    s2 = [np.nan if f.get("sigma2") is None else f["sigma2"] for f in fits]
    return MaterialCurve(np.asarray(scales, float), np.asarray(mu, float), np.asarray(s2, float))


@dataclass
class ScaleSolution:
    scale: float
    table: object  # the MerlTable made at ``scale``
    profiles: object
    fit: dict
    steps: int
    converged: bool
    report: dict


def own(src: Source, theta_o, split=True, made=None):
    """(profiles, fit) of the source table itself, as ``measure`` makes them: measured once per
    source and views (``made``: a measurement of it already made, kept), handed out as copies.
    The source is kept by its table's content (``roughness_source``), so this is too."""
    import copy

    key = (np.asarray(theta_o, float).tobytes(), bool(split))
    if made is not None:
        src.measured[key] = made
    if key not in src.measured:
        src.measured[key] = measure(src.table, theta_o, split)
    return copy.deepcopy(src.measured[key])


def at_scale(src: Source, s: float, theta_o, split=True) -> ScaleSolution:
    """The table at a roughness scale asked for directly, and its measurement."""
    table, report = scale_roughness(src, float(s))
    prof, fit = own(src, theta_o, split) if s == 1.0 else measure(table, theta_o, split)
    return ScaleSolution(float(s), table, prof, fit, 1, True, report)


def solve_scale(src: Source, sigma2: float, theta_o, fitted_sigma2: float, split=True, start=None, stop=None):
    """The roughness scale whose table re-fits to ``sigma2``; a ``ScaleSolution`` carrying that
    table and its measurement. ``start``: a first guess (the curve's); ``fitted_sigma2`` is the
    source's own (s = 1)."""
    # A wider request is a larger scale, a narrower one a smaller: the solve stays on that side
    # of 1 (beyond the table's resolution sigma~^2 turns back, and a secant could cross to it).
    lo, hi = (1.0, S_RANGE[1]) if sigma2 > fitted_sigma2 else (S_RANGE[0], 1.0)
    target = math.log(sigma2)
    pts = [(0.0, math.log(fitted_sigma2))]  # (log s, log sigma~^2)
    s = float(np.clip(start if start is not None else first_guess(sigma2, fitted_sigma2), lo, hi))
    best = None
    for step in range(1, SOLVE_STEPS + 1):
        if stop is not None and stop():
            raise Superseded
        table, report = scale_roughness(src, s)
        prof, fit = measure(table, theta_o, split)
        got = fit.get("sigma2")
        if got is None or not got > 0:
            break
        err = abs(got / sigma2 - 1.0)
        if best is None or err < best[0]:
            best = (err, ScaleSolution(s, table, prof, fit, step, False, report))
        if err <= SOLVE_TOLERANCE:
            break
        pts.append((math.log(s), math.log(got)))
        (x0, y0), (x1, y1) = pts[-2], pts[-1]
        slope = (y1 - y0) / (x1 - x0) if x1 != x0 else 2.0
        if not slope > 0.05:  # sigma~^2 rises with s; a flat or inverted secant is noise
            slope = 2.0
        s_new = float(np.clip(math.exp(x1 + (target - y1) / slope), lo, hi))
        if s_new == s:
            break
        s = s_new
    if best is None:
        return None
    err, sol = best
    sol.converged = err <= SOLVE_TOLERANCE
    return sol


# The edit's view of one table (floor, microfacet reading, masking-free values): made once per
# analysed table and kept (one entry), so the solve's steps and the next edit reuse it.
_SOURCES: dict = {}


def roughness_source(table, prof):
    """``roughness.prepare`` for this table and analysis, kept by content."""
    import hashlib

    h = hashlib.blake2b(digest_size=20)
    for a in (table.rho, table.valid, np.asarray(prof.kd, float)):
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.data)
    h.update(repr(prof.split).encode())
    h.update(np.ascontiguousarray(np.asarray(prof.theta_o, float)).data)
    key = h.hexdigest()
    if _SOURCES.get("key") != key:
        kd = np.asarray(prof.kd, float) if prof.split else np.zeros(3)
        src = prepare(table, kd, split=prof.split, views=prof.theta_o)
        _SOURCES.clear()
        _SOURCES.update(key=key, src=src)
    return _SOURCES["src"]


def source_key():
    """The content key of the table ``roughness_source`` holds now (None before any)."""
    return _SOURCES.get("key")
