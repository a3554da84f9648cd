"""Profile plots as pixels, for the panel: numpy only, so they also draw in Blenders
whose Python has no matplotlib (Debian's 3.4). Three stacked charts share the θo axis
(0 to 90°): energy α per channel with the fitted spline, mean μθ with the fitted line
μ̃ θo, and the average variance with the fitted constant σ̃². Dashed curves are the
edited material, when there is one. The panel prints the axis ranges beside the image.
"""

from __future__ import annotations

import math

import numpy as np

BACKGROUND = (0.16, 0.16, 0.16, 1.0)
FRAME = (0.45, 0.45, 0.45, 1.0)
GRID = (0.24, 0.24, 0.24, 1.0)
CHANNEL_COLOURS = {"r": (0.95, 0.35, 0.3), "g": (0.4, 0.85, 0.4), "b": (0.4, 0.6, 1.0), "avg": (0.92, 0.92, 0.92)}
FIT_COLOUR = (1.0, 0.75, 0.2)


class Canvas:
    def __init__(self, width, height):
        self.w, self.h = width, height
        self.px = np.empty((height, width, 4), np.float32)
        self.px[:] = BACKGROUND
        self.clip = (0, 0, width - 1, height - 1)  # drawing stays inside this box

    def dot(self, x, y, colour, radius=1.0, alpha=1.0):
        """Soft round dots at float pixel positions (row 0 is the top)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        r = int(math.ceil(radius + 1))
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                xi, yi = np.round(x).astype(int) + dx, np.round(y).astype(int) + dy
                d = np.hypot(xi - x, yi - y)
                a = np.clip(radius + 0.5 - d, 0.0, 1.0) * alpha
                cx0, cy0, cx1, cy1 = self.clip
                ok = (xi >= cx0) & (xi <= cx1) & (yi >= cy0) & (yi <= cy1) & (a > 0)
                xi, yi, a = xi[ok], yi[ok], a[ok][:, None]
                self.px[yi, xi, :3] = self.px[yi, xi, :3] * (1 - a) + np.asarray(colour[:3]) * a

    def polyline(self, x, y, colour, width=1.2, dashed=False):
        x, y = np.asarray(x, float), np.asarray(y, float)
        ok = np.isfinite(x) & np.isfinite(y)
        xs, ys = [], []
        for i in range(len(x) - 1):
            if not (ok[i] and ok[i + 1]):
                continue
            n = max(2, int(math.hypot(x[i + 1] - x[i], y[i + 1] - y[i]) * 2))
            t = np.linspace(0.0, 1.0, n)
            xs.append(x[i] + t * (x[i + 1] - x[i]))
            ys.append(y[i] + t * (y[i + 1] - y[i]))
        if not xs:
            return
        xs, ys = np.concatenate(xs), np.concatenate(ys)
        if dashed:
            s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(xs), np.diff(ys)))])
            keep = (s // 5) % 2 == 0
            xs, ys = xs[keep], ys[keep]
        self.dot(xs, ys, colour, radius=width / 2)

    def rect(self, x0, y0, x1, y1, colour):
        self.px[y0:y1 + 1, x0] = colour
        self.px[y0:y1 + 1, x1] = colour
        self.px[y0, x0:x1 + 1] = colour
        self.px[y1, x0:x1 + 1] = colour


def _range(values, include_zero=False):
    v = np.concatenate([np.asarray(a, float).ravel() for a in values])
    v = v[np.isfinite(v)]
    if include_zero:
        v = np.append(v, 0.0)
    if v.size == 0:
        return 0.0, 1.0
    lo, hi = float(v.min()), float(v.max())
    if hi - lo < 1e-12:
        lo, hi = lo - 0.5 * max(abs(lo), 1e-3), hi + 0.5 * max(abs(hi), 1e-3)
    pad = 0.05 * (hi - lo)
    return lo - pad, hi + pad


def energy_spline(theta, fit, channel_fit=None):
    """The Sec. 3.4 energy curve (constant, Hermite, line) for one set of parameters."""
    f = channel_fit or fit
    keys = ("alpha_b", "alpha1", "m1")
    if any(f.get(k) is None for k in keys) or fit.get("theta0") is None or fit.get("theta1") is None:
        return np.full_like(theta, np.nan)
    ab, a1, m1 = (float(f[k]) for k in keys)
    t0, t1 = float(fit["theta0"]), float(fit["theta1"])
    out = np.full_like(theta, ab)
    mid = (theta > t0) & (theta <= t1)
    h = max(t1 - t0, 1e-9)
    s = (theta[mid] - t0) / h
    h00, h01, h11 = 2 * s ** 3 - 3 * s ** 2 + 1, -2 * s ** 3 + 3 * s ** 2, s ** 3 - s ** 2
    out[mid] = h00 * ab + h01 * a1 + h11 * h * m1
    out[theta > t1] = a1 + m1 * (theta[theta > t1] - t1)
    return out


def profile_plot(prof, fit=None, edited=None, width=480, height=420):
    """RGBA float32 (height, width, 4), row 0 at the top; and the y ranges of the three charts."""
    c = Canvas(width, height)
    theta = np.asarray(prof.theta_o, float)
    fine = np.linspace(0.0, math.radians(89.0), 180)
    margin, gap = 8, 10
    chart_h = (height - 2 * margin - 2 * gap) // 3
    x0, x1 = margin, width - margin - 1
    charts = []

    def var_avg(p):
        return 0.5 * (np.asarray(p["avg"]["sigma_tt"], float) + np.asarray(p["avg"]["sigma_pp"], float))

    series = [
        ("energy", [(prof[ch]["alpha"], CHANNEL_COLOURS[ch]) for ch in "rgb"],
         [(np.asarray(edited[ch]["alpha"], float), CHANNEL_COLOURS[ch]) for ch in "rgb"] if edited else [],
         [(energy_spline(fine, fit, (fit.get("channels") or {}).get(ch)), CHANNEL_COLOURS[ch]) for ch in "rgb"]
         if fit else [], False),
        ("mean", [(prof["avg"]["mu_theta"], CHANNEL_COLOURS["avg"])],
         [(edited["avg"]["mu_theta"], CHANNEL_COLOURS["avg"])] if edited else [],
         [(fit["mu_slope"] * fine, FIT_COLOUR)] if fit and fit.get("mu_slope") is not None else [], True),
        ("variance", [(var_avg(prof), CHANNEL_COLOURS["avg"])],
         [(var_avg(edited), CHANNEL_COLOURS["avg"])] if edited else [],
         [(np.full_like(fine, fit["sigma2"]), FIT_COLOUR)] if fit and fit.get("sigma2") is not None else [], True),
    ]
    for k, (name, measured, edit_curves, fitted, zero) in enumerate(series):
        top = margin + k * (chart_h + gap)
        bottom = top + chart_h
        lo, hi = _range([m for m, _ in measured] + [e for e, _ in edit_curves], include_zero=zero)
        charts.append((name, lo, hi))

        def px(t, v):
            return x0 + (np.asarray(t) / math.radians(90.0)) * (x1 - x0), bottom - (np.asarray(v, float) - lo) / (hi - lo) * (bottom - top)

        for deg in (15, 30, 45, 60, 75):  # vertical grid every 15 degrees
            gx = int(round(px(math.radians(deg), lo)[0]))
            c.px[top:bottom, gx] = GRID
        if lo < 0.0 < hi:
            gy = int(round(px(0.0, 0.0)[1]))
            c.px[gy, x0:x1] = GRID
        c.rect(x0, top, x1, bottom, FRAME)
        c.clip = (x0 + 1, top + 1, x1 - 1, bottom - 1)
        for values, colour in fitted:
            c.polyline(*px(fine, values), FIT_COLOUR if name != "energy" else colour, width=1.0, dashed=False)
        for values, colour in measured:
            c.polyline(*px(theta, values), colour, width=2.0)
        for values, colour in edit_curves:
            c.polyline(*px(np.asarray(edited.theta_o, float), values), colour, width=2.0, dashed=True)
    return c.px, charts
