"""Profile fits of paper Sec. 3.4: energy spline, mean slope, average variance, correlation.

Energy: alpha~(t) = alpha_b for t <= theta0; the cubic Hermite curve from (theta0, alpha_b,
slope 0) to (theta1, alpha1, slope m1) on [theta0, theta1]; the line alpha1 + m1 (t - theta1)
beyond. For fixed knots the curve is linear in (alpha_b, alpha1, m1), so the fit is a
variable projection: a bounded search over the two knots with an exact linear least-squares
solve inside. That keeps the knots ordered and inside [0, 90] deg whatever the data does,
and makes the joint fit (shared knots, per-material amplitudes) as cheap as one fit.
"""

from __future__ import annotations

import math

import numpy as np

LAMBERT_VARIANCE = math.pi**2 / 12
# The model's narrowest lobe: narrower than any MERL cell near the mirror, so a "mirror" for the
# table. Edit targets, the preview's model, the panel and the OSL shaders all clamp to it.
MIN_SIGMA2 = 1e-7
DEFAULT_RANGE = (0.0, math.radians(85.0))
KNOT_START = (math.radians(45.0), math.radians(75.0))
KNOT_BOUNDS = (0.0, math.radians(90.0))
MIN_KNOT_GAP = math.radians(1.0)


def _errors(residual):
    r = np.asarray(residual, dtype=float)
    if r.size == 0:
        return {"mae": None, "rmse": None}
    return {"mae": float(np.mean(np.abs(r))), "rmse": float(np.sqrt(np.mean(r * r)))}


def energy_basis(t, theta0, theta1):
    """Design matrix of the energy curve in (alpha_b, alpha1, m1): (..., n, 3).

    ``theta0``/``theta1`` may be arrays (a batch of knot pairs, shape (...,))."""
    t = np.asarray(t, dtype=float)
    theta0 = np.asarray(theta0, dtype=float)[..., None]
    theta1 = np.asarray(theta1, dtype=float)[..., None]
    span = np.maximum(theta1 - theta0, 1e-9)  # the fit keeps knots >= 1 deg apart; a fits file may not
    s = np.clip((t - theta0) / span, 0.0, 1.0)
    after = t > theta1
    h00 = np.where(after, 0.0, 2 * s**3 - 3 * s**2 + 1)
    h01 = np.where(after, 1.0, -2 * s**3 + 3 * s**2)
    h11 = np.where(after, t - theta1, (s**3 - s**2) * span)
    return np.stack([h00, h01, h11], axis=-1)


def energy_curve(t, alpha_b, theta0, theta1, alpha1, m1):
    """The energy curve at the views ``t`` (n,): (n,) for one channel, (n, c) when the
    amplitudes ``alpha_b``, ``alpha1``, ``m1`` are given per channel (each of shape (c,))."""
    return energy_basis(t, theta0, theta1) @ np.array([alpha_b, alpha1, m1], dtype=float)


def _solve(basis, y):
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return coef


def _knot_grid(step_deg=1.0):
    k = np.radians(np.arange(0.0, 90.0 + 1e-9, step_deg))
    a, b = np.meshgrid(k, k, indexing="ij")
    ok = b - a >= MIN_KNOT_GAP - 1e-12
    return a[ok], b[ok]


def _normal(t, theta0, theta1):
    """The basis (..., n, 3) at views ``t`` for a batch of knot pairs and its Gram matrices
    (..., 3, 3) for the normal equations. The tiny ridge only matters when no sample lies
    past theta0 (then alpha1 and m1 are unconstrained and any value fits)."""
    basis = energy_basis(t, theta0, theta1)
    gram = np.einsum("...ni,...nj->...ij", basis, basis)
    gram = gram + 1e-12 * np.trace(gram, axis1=-2, axis2=-1)[..., None, None] * np.eye(3)
    return basis, gram


_GRID: dict = {}
GRID_KEPT = 2  # view grids whose coarse-knot normal equations are kept (8 MB each at 81 views)


def _grid_normal(t):
    """``_normal`` over the whole 1-degree knot grid (``_knot_grid``): the same for every fit
    on one view grid, so kept (read-only) by the views; most of a fit's time was making it."""
    key = (len(t), np.asarray(t, float).tobytes())
    kept = _GRID.get(key)  # one lookup: another thread (the region's) may clear the dict meanwhile
    if kept is None:
        basis, gram = _normal(t, *_knot_grid(1.0))
        basis.flags.writeable = gram.flags.writeable = False
        if len(_GRID) >= GRID_KEPT:
            _GRID.clear()
        kept = _GRID[key] = (basis, gram)
    return kept


def _joint_cost(theta0, theta1, series, weights):
    """Weighted residual sum of squares after the inner linear solve; batched over knots
    (``theta0`` None: the whole 1-degree grid, ``_knot_grid(1.0)``, in its order).

    Materials sharing one view grid (the usual case) share the basis and its Gram matrix,
    so they are solved together: one 3x3 solve per knot pair for all of them."""
    groups = {}
    for (t, y), w in zip(series, weights):
        key = (len(t), t.tobytes())
        groups.setdefault(key, (t, [], []))
        groups[key][1].append(y)
        groups[key][2].append(w)
    total = 0.0
    for t, ys, ws in groups.values():
        Y = np.stack(ys, axis=1)  # (n, M)
        w = np.asarray(ws)  # (M,)
        basis, gram = _grid_normal(t) if theta0 is None else _normal(t, theta0, theta1)
        bty = np.einsum("...ni,nm->...im", basis, Y)  # (..., 3, M)
        coef = np.linalg.solve(gram, bty)  # (..., 3, M)
        # |y - B c|^2 = y.y - 2 c.(B^T y) + c.(G c)
        rss = (
            np.einsum("nm,nm->m", Y, Y)
            - 2 * np.einsum("...im,...im->...m", coef, bty)
            + np.einsum("...im,...ij,...jm->...m", coef, gram, coef)
        )
        total = total + np.maximum(rss, 0.0) @ w
    return total


def fit_energy_joint(series, fit_range=DEFAULT_RANGE):
    """Energy fit with knots shared by all materials: ``series`` is a list of (theta_o, alpha).

    Returns (theta0, theta1, [per-material dict]). Each material's residual is weighted by
    1/mean(alpha)^2 so a bright material does not dictate the shared knots.
    """
    prepared, weights, scales = [], [], []
    for t, y in series:
        t, y = np.asarray(t, float), np.asarray(y, float)
        keep = np.isfinite(y) & (t >= fit_range[0] - 1e-12) & (t <= fit_range[1] + 1e-12)
        t, y = t[keep], y[keep]
        if len(t) < 4:
            raise ValueError("energy fit needs at least 4 finite samples in the fit range")
        # Fit y / mean|y|: the same as weighting by 1/mean|y|^2, without squaring an energy
        # of 1e-200 (or 1e30) out of floating-point range.
        scale = float(np.mean(np.abs(y)))
        scale = scale if scale > 0 else 1.0
        prepared.append((t, y / scale))
        scales.append(scale)
        weights.append(1.0)
    # Tie-break toward the paper's starting knots: a flat profile fits equally well with any
    # knots, and then the reported knots should be the conventional ones, not an accident.
    a0, a1 = _knot_grid(1.0)
    signal = sum(w * float(y @ y) for (_, y), w in zip(prepared, weights))
    # Above the solver's rounding (~1e-12 of the signal), far below any real difference in fit.
    penalty = 1e-9 * signal * ((a0 - KNOT_START[0]) ** 2 + (a1 - KNOT_START[1]) ** 2)
    costs = _joint_cost(None, None, prepared, weights) + penalty
    i = int(np.argmin(costs))
    best = (a0[i], a1[i])
    best = _refine_knots(best, prepared, weights)
    out = []
    for (t, y), scale in zip(prepared, scales):
        basis = energy_basis(t, *best)
        alpha_b, alpha1, m1 = _solve(basis, y)
        fit = {"alpha_b": float(alpha_b * scale), "alpha1": float(alpha1 * scale), "m1": float(m1 * scale)}
        fit.update({k: v * scale for k, v in _errors(basis @ np.array([alpha_b, alpha1, m1]) - y).items()})
        out.append(fit)
    return float(best[0]), float(best[1]), out


def _refine_knots(start, series, weights, zooms=((1.0, 0.05), (0.05, 0.0025))):
    """Zoom the batched knot grid around the best pair: (half-width, step) in degrees."""
    lo, hi = KNOT_BOUNDS
    signal = sum(w * float(y @ y) for (_, y), w in zip(series, weights))
    best = np.asarray(start, float)
    for half, step in zooms:
        d = np.radians(np.arange(-half, half + 1e-9, step))
        a, b = np.meshgrid(best[0] + d, best[1] + d, indexing="ij")
        a, b = a.ravel(), b.ravel()
        ok = (a >= lo) & (b <= hi) & (b - a >= MIN_KNOT_GAP)
        a, b = a[ok], b[ok]
        pen = 1e-9 * signal * ((a - KNOT_START[0]) ** 2 + (b - KNOT_START[1]) ** 2)
        i = int(np.argmin(_joint_cost(a, b, series, weights) + pen))
        best = np.array([a[i], b[i]])
    return float(best[0]), float(best[1])


def fit_energy(theta_o, alpha, fit_range=DEFAULT_RANGE):
    t0, t1, (fit,) = fit_energy_joint([(theta_o, alpha)], fit_range)
    return dict(fit, theta0=t0, theta1=t1)


def fit_energy_channels(theta_o, alphas, theta0, theta1, fit_range=DEFAULT_RANGE):
    """Per-channel amplitudes with the knots of the average fit: this is the colour."""
    t = np.asarray(theta_o, float)
    keep_t = (t >= fit_range[0] - 1e-12) & (t <= fit_range[1] + 1e-12)
    out = {}
    for ch, y in alphas.items():
        y = np.asarray(y, float)
        keep = keep_t & np.isfinite(y)
        basis = energy_basis(t[keep], theta0, theta1)
        coef = _solve(basis, y[keep]) if keep.sum() >= 3 else np.zeros(3)
        fit = {"alpha_b": float(coef[0]), "alpha1": float(coef[1]), "m1": float(coef[2])}
        fit.update(_errors(basis @ coef - y[keep]))
        out[ch] = fit
    return out


def fit_mean_slope(theta_o, mu_theta, fit_range=DEFAULT_RANGE):
    """Least-squares slope through the origin: mu_theta ~ mu_slope * theta_o."""
    t, y = _in_range(theta_o, mu_theta, fit_range)
    den = float(t @ t)
    if len(t) == 0 or den == 0.0:
        return {"mu_slope": None, "mae": None, "rmse": None}
    slope = float(t @ y) / den
    return dict({"mu_slope": slope}, **_errors(slope * t - y))


def fit_variance(theta_o, sigma_tt, sigma_pp, fit_range=DEFAULT_RANGE):
    """Least-squares constant for the average variance (sigma_tt + sigma_pp) / 2."""
    t, y = _in_range(theta_o, 0.5 * (np.asarray(sigma_tt, float) + np.asarray(sigma_pp, float)), fit_range)
    if len(t) == 0:
        return {"sigma2": None, "mae": None, "rmse": None}
    c = float(np.mean(y))
    return dict({"sigma2": c}, **_errors(c - y))


def _in_range(theta_o, y, fit_range):
    t, y = np.asarray(theta_o, float), np.asarray(y, float)
    keep = np.isfinite(y) & (t >= fit_range[0] - 1e-12) & (t <= fit_range[1] + 1e-12)
    return t[keep], y[keep]


def fit_correlation(mu_slopes, sigma2s):
    """sigma2 ~ a mu^2 + b mu + c through (-1, 0) and (0, pi^2/12): c = pi^2/12, b = a + c."""
    mu = np.asarray(mu_slopes, float)
    s2 = np.asarray(sigma2s, float)
    keep = np.isfinite(mu) & np.isfinite(s2)
    mu, s2 = mu[keep], s2[keep]
    c = LAMBERT_VARIANCE
    if len(mu) == 0:
        return {"a": None, "b": None, "c": c, "n": 0, "mae": None, "rmse": None}
    g = mu * mu + mu
    y = s2 - c * (1.0 + mu)
    den = float(g @ g)
    a = float(g @ y) / den if den > 0 else 0.0
    out = {"a": a, "b": a + c, "c": c, "n": int(len(mu))}
    out.update(_errors(correlation_curve(mu, a) - s2))
    return out


def correlation_curve(mu, a):
    c = LAMBERT_VARIANCE
    mu = np.asarray(mu, float)
    return a * mu * mu + (a + c) * mu + c


def fit_material(prof, fit_range=DEFAULT_RANGE, channel="avg") -> dict:
    """Every Sec. 3.4 fit of one material's profiles (a ``profiles.Profiles``)."""
    t = np.asarray(prof.theta_o, float)
    p = prof[channel]
    notes = []
    alpha = np.asarray(p["alpha"], float)
    fit = {"channel": channel, "range": [float(fit_range[0]), float(fit_range[1])]}
    in_range = (t >= fit_range[0] - 1e-12) & (t <= fit_range[1] + 1e-12)
    if not np.any(np.isfinite(alpha[in_range]) & (alpha[in_range] > 0)):
        notes.append("no specular energy in the fit range: nothing to fit")
        fit.update(
            {
                "alpha_b": 0.0,
                "theta0": KNOT_START[0],
                "theta1": KNOT_START[1],
                "alpha1": 0.0,
                "m1": 0.0,
                "energy": {"mae": None, "rmse": None},
                "mu_slope": None,
                "mean": {"mae": None, "rmse": None},
                "sigma2": None,
                "variance": {"mae": None, "rmse": None},
                "channels": {},
                "outside_model": True,
                "notes": notes,
            }
        )
        return fit
    e = fit_energy(t, alpha, fit_range)
    fit.update({k: e[k] for k in ("alpha_b", "theta0", "theta1", "alpha1", "m1")})
    fit["energy"] = {"mae": e["mae"], "rmse": e["rmse"]}
    m = fit_mean_slope(t, p["mu_theta"], fit_range)
    fit["mu_slope"] = m["mu_slope"]
    fit["mean"] = {"mae": m["mae"], "rmse": m["rmse"]}
    v = fit_variance(t, p["sigma_tt"], p["sigma_pp"], fit_range)
    fit["sigma2"] = v["sigma2"]
    fit["variance"] = {"mae": v["mae"], "rmse": v["rmse"]}
    fit["channels"] = fit_energy_channels(
        t, {ch: prof[ch]["alpha"] for ch in ("r", "g", "b")}, e["theta0"], e["theta1"], fit_range
    )
    outside = False
    if fit["mu_slope"] is not None and fit["mu_slope"] > 0.0:
        outside = True
        notes.append(
            f"mean slope {fit['mu_slope']:+.3f} > 0: the lobe sits on the view side "
            "(retro-reflection), outside the paper's model (slope in [-1, 0])"
        )
    elif fit["mu_slope"] is not None and fit["mu_slope"] < -1.0:
        # Microfacet lobes do this (the 1/cos factors favour grazing incidence); the fit is
        # still meaningful, only the slider range [-1, 0] will clamp it.
        notes.append(f"mean slope {fit['mu_slope']:+.3f} is beyond the mirror (-1)")
    if fit["sigma2"] is not None and fit["sigma2"] > LAMBERT_VARIANCE * 1.0001:
        notes.append(f"average variance {fit['sigma2']:.4f} exceeds the Lambertian pi^2/12")
    dark = [ch for ch, c in fit["channels"].items() if abs(c["alpha_b"]) < 1e-6 * max(abs(e["alpha_b"]), 1e-300)]
    if dark:
        notes.append(f"channel(s) {', '.join(dark)} carry almost no specular energy")
    fit["outside_model"] = outside
    fit["notes"] = notes
    return fit


def fit_set(profiles_by_name: dict, fit_range=DEFAULT_RANGE, materials: dict | None = None) -> dict:
    """Fits for a set of materials: per material, joint knots and the correlation (2+ materials).

    ``materials`` may hold per-material fits already made (e.g. by parallel workers)."""
    materials = dict(materials or {})
    for name, p in profiles_by_name.items():
        if name not in materials:
            materials[name] = fit_material(p, fit_range)
    out = {"materials": materials}
    usable = [n for n, f in materials.items() if f["energy"]["mae"] is not None]
    if len(profiles_by_name) >= 2 and usable:
        series = [(profiles_by_name[n].theta_o, profiles_by_name[n]["avg"]["alpha"]) for n in usable]
        t0, t1, per = fit_energy_joint(series, fit_range)
        out["joint"] = {
            "theta0": t0,
            "theta1": t1,
            "materials": dict(zip(usable, per)),
            "mae": float(np.mean([f["mae"] for f in per])),
            "rmse": float(np.sqrt(np.mean([f["rmse"] ** 2 for f in per]))),
        }
        inside = [n for n in usable if not materials[n]["outside_model"] and materials[n]["sigma2"] is not None]
        pts = [(materials[n]["mu_slope"], materials[n]["sigma2"]) for n in inside]
        corr = fit_correlation([p[0] for p in pts], [p[1] for p in pts])
        corr["materials"] = inside
        out["correlation"] = corr
    return out


def _set_number(value, where):
    """A fitted scalar of a set's fits.json: a finite number, or None (nothing fitted)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where} is {type(value).__name__}, not a number")
    if not math.isfinite(value):  # 1e999 parses to inf (NaN/Infinity literals never get this far)
        raise ValueError(f"{where} is {value}, not a finite number")
    return float(value)


def set_points(doc, max_materials=None):
    """The (name, mu_slope, sigma2) of each material of an analysed set (``analyze``'s fits.json,
    as parsed JSON) that has both fits, in the file's order; and the set's correlation ``a``,
    or None when the file has none (one material, or none inside the model). ValueError (one
    line) for a document that is not such a file, or holds more than ``max_materials``."""
    from ..limits import MAX_SET_MATERIALS

    limit = MAX_SET_MATERIALS if max_materials is None else max_materials
    if not isinstance(doc, dict) or not isinstance(doc.get("materials"), dict):
        raise ValueError("not a set's fits.json (no 'materials' object; write one with 'python -m addon analyze')")
    materials = doc["materials"]
    if len(materials) > limit:
        raise ValueError(f"{len(materials)} materials, the limit is {limit}")
    points = []
    for name, fit in materials.items():
        if not isinstance(fit, dict) or "mu_slope" not in fit or "sigma2" not in fit:
            raise ValueError(f"material {name[:80]!r} has no 'mu_slope' and 'sigma2' fits")
        mu = _set_number(fit["mu_slope"], f"material {name[:80]!r}: mu_slope")
        s2 = _set_number(fit["sigma2"], f"material {name[:80]!r}: sigma2")
        if mu is not None and s2 is not None:
            points.append((name, mu, s2))
    if not points:
        raise ValueError("no material of the set has both a mean slope and a variance fit")
    corr = doc.get("correlation")
    a = None
    if corr is not None:
        if not isinstance(corr, dict) or "a" not in corr:
            raise ValueError("the 'correlation' entry has no coefficient 'a'")
        a = _set_number(corr["a"], "correlation a")
    return points, a


def load_set_points(path):
    """``set_points`` of the fits.json at ``path``, read through ``safeio.load_json`` (a regular
    file of at most ``limits.MAX_SET_JSON_BYTES``, no NaN/Infinity); UnsafePath or ValueError,
    one line naming the file, for anything else."""
    from ..file.safeio import UnsafePath, load_json
    from ..limits import MAX_SET_JSON_BYTES

    doc = load_json(path, MAX_SET_JSON_BYTES, "fits JSON")
    try:
        return set_points(doc)
    except ValueError as exc:
        raise UnsafePath(path, str(exc)) from None
