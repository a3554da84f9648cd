"""Profile plots as pixels, for the panel: numpy only, so they also draw in Blenders
whose Python has no matplotlib (Debian's 3.4). Three stacked charts share the θo axis
(0 to 90°): energy α per channel with the fitted spline, mean μθ with the fitted line
μ̃ θo, and the average variance with the fitted constant σ̃². Dashed curves are the
edited material, when there is one. Titles, ticks, the θo axis and a legend are drawn in.
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

    def polyline(self, x, y, colour, width=1.2, dashed=False, dash=12):
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
            keep = (s // dash) % 2 == 0  # 12 px dashes: legible at full size; the panel's charts use 4
            xs, ys = xs[keep], ys[keep]
        self.dot(xs, ys, colour, radius=width / 2)

    def rect(self, x0, y0, x1, y1, colour):
        self.px[y0 : y1 + 1, x0] = colour
        self.px[y0 : y1 + 1, x1] = colour
        self.px[y0, x0 : x1 + 1] = colour
        self.px[y1, x0 : x1 + 1] = colour


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
    from ..core.fits.curves import energy_curve

    ab, a1, m1 = (float(f[k]) for k in keys)
    return energy_curve(theta, ab, float(fit["theta0"]), float(fit["theta1"]), a1, m1)


TEXT = (0.85, 0.85, 0.85)


def _tick(v):
    return f"{v:.3g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.2e}"


def profile_plot(prof, fit=None, edited=None, width=900, height=780):
    """RGBA float32 (height, width, 4), row 0 at the top; and the y ranges of the three charts.

    Titles, y ticks, the θo axis and a legend are drawn into the image (``plot_font``);
    measured curves are thick and solid, edited ones thick and dashed, fits thin and solid
    (orange where the curve is one channel: the mean and the variance)."""
    from .plot_font import ADVANCE, draw_text, text_width

    c = Canvas(width, height)
    s = max(1, int(round(width / 450)))  # text scale: 5x7 glyphs at 2x on the 900-wide plot
    line_h = 9 * s
    theta = np.asarray(prof.theta_o, float)
    fine = np.linspace(0.0, math.radians(89.0), 180)
    left, right, top_margin, gap = 8 * ADVANCE * s + 8, 10, 3 * line_h + 6, line_h + 14
    bottom_margin = 2 * line_h + 10
    chart_h = (height - top_margin - bottom_margin - 2 * gap) // 3
    x0, x1 = left, width - right - 1
    charts = []

    def var_avg(p):
        return 0.5 * (np.asarray(p["avg"]["sigma_tt"], float) + np.asarray(p["avg"]["sigma_pp"], float))

    series = [
        (
            "energy",
            "energy α (r, g, b)",
            [(prof[ch]["alpha"], CHANNEL_COLOURS[ch]) for ch in "rgb"],
            [(np.asarray(edited[ch]["alpha"], float), CHANNEL_COLOURS[ch]) for ch in "rgb"] if edited else [],
            [(energy_spline(fine, fit, (fit.get("channels") or {}).get(ch)), CHANNEL_COLOURS[ch]) for ch in "rgb"]
            if fit
            else [],
            False,
        ),
        (
            "mean",
            "mean μθ (rad), fit μ~ θo",
            [(prof["avg"]["mu_theta"], CHANNEL_COLOURS["avg"])],
            [(edited["avg"]["mu_theta"], CHANNEL_COLOURS["avg"])] if edited else [],
            [(fit["mu_slope"] * fine, FIT_COLOUR)] if fit and fit.get("mu_slope") is not None else [],
            True,
        ),
        (
            "variance",
            "variance (σθ² + σφ²)/2 (rad²), fit σ~²",
            [(var_avg(prof), CHANNEL_COLOURS["avg"])],
            [(var_avg(edited), CHANNEL_COLOURS["avg"])] if edited else [],
            [(np.full_like(fine, fit["sigma2"]), FIT_COLOUR)] if fit and fit.get("sigma2") is not None else [],
            True,
        ),
    ]
    # legend, on top: the three styles
    lx, ly = x0, 6
    for label, dashed, w, colour in (
        ("measured", False, 2.0 * s, TEXT),
        ("edited", True, 2.0 * s, TEXT),
        ("fit (thin)", False, 1.0 * s, FIT_COLOUR),
    ):
        c.clip = (0, 0, width - 1, height - 1)
        c.polyline(np.array([lx, lx + 36 * s]), np.array([ly + line_h // 2] * 2), colour, width=w, dashed=dashed)
        draw_text(c.px, lx + 40 * s, ly, label, TEXT, s)
        lx += 40 * s + text_width(label, s) + 24 * s
    for k, (name, title, measured, edit_curves, fitted, zero) in enumerate(series):
        top = top_margin + k * (chart_h + gap)
        bottom = top + chart_h
        lo, hi = _range([m for m, _ in measured] + [e for e, _ in edit_curves], include_zero=zero)
        charts.append((name, lo, hi))

        def px(t, v):
            return x0 + (np.asarray(t) / math.radians(90.0)) * (x1 - x0), bottom - (np.asarray(v, float) - lo) / (
                hi - lo
            ) * (bottom - top)

        c.clip = (0, 0, width - 1, height - 1)
        draw_text(c.px, x0, top - line_h - 2, title, TEXT, s)
        for deg in (15, 30, 45, 60, 75):  # vertical grid every 15 degrees
            gx = int(round(px(math.radians(deg), lo)[0]))
            c.px[top:bottom, gx] = GRID
        if lo < 0.0 < hi:
            gy = int(round(px(0.0, 0.0)[1]))
            c.px[gy, x0:x1] = GRID
        for v in (lo, 0.5 * (lo + hi), hi):  # y ticks: bottom, middle, top
            gy = int(round(px(0.0, v)[1]))
            c.px[gy, x0 - 4 : x0] = FRAME
            label = _tick(v)
            draw_text(c.px, x0 - 6 - text_width(label, s), min(max(gy - 3 * s, 0), height - 7 * s), label, TEXT, s)
        c.rect(x0, top, x1, bottom, FRAME)
        c.clip = (x0 + 1, top + 1, x1 - 1, bottom - 1)
        for values, colour in fitted:
            c.polyline(*px(fine, values), FIT_COLOUR if name != "energy" else colour, width=1.0 * s, dashed=False)
        for values, colour in measured:
            c.polyline(*px(theta, values), colour, width=2.0 * s)
        for values, colour in edit_curves:
            c.polyline(*px(np.asarray(edited.theta_o, float), values), colour, width=2.0 * s, dashed=True)
        if k == len(series) - 1:  # the shared θo axis under the last chart
            c.clip = (0, 0, width - 1, height - 1)
            for deg in (0, 15, 30, 45, 60, 75, 90):
                gx = int(round(px(math.radians(deg), lo)[0]))
                c.px[bottom : bottom + 4, gx] = FRAME
                label = f"{deg}"
                draw_text(c.px, gx - text_width(label, s) // 2, bottom + 6, label, TEXT, s)
            axis = "view elevation θo (degrees)"
            draw_text(c.px, (x0 + x1 - text_width(axis, s)) // 2, bottom + 8 + line_h, axis, TEXT, s)
    return c.px, charts


CHART_KINDS = ("energy", "mean", "variance")


def _short_tick(v):
    """A tick label of at most 7 characters (the panel's charts are ~200 px wide)."""
    if v == 0:
        return "0"
    text = f"{v:.2g}"
    return text if len(text) <= 7 else f"{v:.0e}"


def profile_chart(prof, fit=None, edited=None, kind="energy", size=200):
    """One of the three profile charts alone, as a square RGBA float32 image of ``size`` pixels
    (row 0 on top), drawn for the panel at the size it is shown: 5x7 text at 1:1, a short
    title, a one-line legend, y ticks at the bottom, middle and top, and the θo axis."""
    from .plot_font import draw_text, text_width

    if kind not in CHART_KINDS:
        raise ValueError(f"unknown chart {kind!r}")
    size = int(size)
    c = Canvas(size, size)
    line_h = 9
    theta = np.asarray(prof.theta_o, float)
    fine = np.linspace(0.0, math.radians(89.0), 180)

    def var_avg(p):
        return 0.5 * (np.asarray(p["avg"]["sigma_tt"], float) + np.asarray(p["avg"]["sigma_pp"], float))

    if kind == "energy":
        title = "energy α (r, g, b)"
        measured = [(prof[ch]["alpha"], CHANNEL_COLOURS[ch]) for ch in "rgb"]
        edit_curves = [(edited[ch]["alpha"], CHANNEL_COLOURS[ch]) for ch in "rgb"] if edited else []
        fitted = (
            [(energy_spline(fine, fit, (fit.get("channels") or {}).get(ch)), CHANNEL_COLOURS[ch]) for ch in "rgb"]
            if fit
            else []
        )
        zero = False
    elif kind == "mean":
        title = "mean μθ (rad)"
        measured = [(prof["avg"]["mu_theta"], CHANNEL_COLOURS["avg"])]
        edit_curves = [(edited["avg"]["mu_theta"], CHANNEL_COLOURS["avg"])] if edited else []
        fitted = [(fit["mu_slope"] * fine, FIT_COLOUR)] if fit and fit.get("mu_slope") is not None else []
        zero = True
    else:
        title = "variance σ² (rad²)"
        measured = [(var_avg(prof), CHANNEL_COLOURS["avg"])]
        edit_curves = [(var_avg(edited), CHANNEL_COLOURS["avg"])] if edited else []
        fitted = [(np.full_like(fine, fit["sigma2"]), FIT_COLOUR)] if fit and fit.get("sigma2") is not None else []
        zero = True
    lo, hi = _range([np.asarray(m, float) for m, _ in measured + edit_curves], include_zero=zero)
    ticks = [_short_tick(v) for v in (lo, 0.5 * (lo + hi), hi)]
    x0 = max(text_width(t) for t in ticks) + 8
    x1 = size - 7
    top, bottom = 2 * line_h + 8, size - 2 * line_h - 8

    def px(t, v):
        return (
            x0 + (np.asarray(t, float) / math.radians(90.0)) * (x1 - x0),
            bottom - (np.asarray(v, float) - lo) / (hi - lo) * (bottom - top),
        )

    c.clip = (0, 0, size - 1, size - 1)
    draw_text(c.px, 4, 3, title, TEXT, 1)
    # legend, the second line: what solid, dashed and thin mean (from the left edge: it needs the room)
    lx, ly = 4, 3 + line_h
    legend = [("measured", False, 2.0, TEXT)] + ([("edited", True, 2.0, TEXT)] if edited else [])
    legend.append(("fit", False, 1.0, FIT_COLOUR if kind != "energy" else TEXT))
    for label, dashed, w, colour in legend:
        c.polyline(np.array([lx, lx + 10.0]), np.array([ly + 3.5] * 2), colour, width=w, dashed=dashed, dash=3)
        draw_text(c.px, lx + 13, ly, label, TEXT, 1)
        lx += 13 + text_width(label) + 7
    for deg in (30, 60):
        gx = int(round(float(px(math.radians(deg), lo)[0])))
        c.px[top:bottom, gx] = GRID
    if lo < 0.0 < hi:
        gy = int(round(float(px(0.0, 0.0)[1])))
        c.px[gy, x0:x1] = GRID
    for v, label in zip((lo, 0.5 * (lo + hi), hi), ticks):
        gy = int(round(float(px(0.0, v)[1])))
        c.px[gy, x0 - 3 : x0] = FRAME
        draw_text(c.px, x0 - 5 - text_width(label), min(max(gy - 3, 0), size - 7), label, TEXT, 1)
    c.rect(x0, top, x1, bottom, FRAME)
    for deg in (0, 30, 60, 90):
        gx = int(round(float(px(math.radians(deg), lo)[0])))
        c.px[bottom : bottom + 3, gx] = FRAME
        label = f"{deg}"
        draw_text(c.px, min(max(gx - text_width(label) // 2, 0), size - text_width(label)), bottom + 5, label, TEXT, 1)
    axis = "θo (°)"
    draw_text(c.px, (x0 + x1 - text_width(axis)) // 2, bottom + 6 + line_h, axis, TEXT, 1)
    c.clip = (x0 + 1, top + 1, x1 - 1, bottom - 1)
    for values, colour in fitted:
        c.polyline(*px(fine, values), colour, width=1.0)
    for values, colour in measured:
        c.polyline(*px(theta, values), colour, width=2.0)
    for values, colour in edit_curves:
        c.polyline(*px(np.asarray(edited.theta_o, float), values), colour, width=2.0, dashed=True, dash=4)
    return c.px


REGION_FILL = (0.25, 0.42, 0.62)
REGION_EDGE = (0.45, 0.7, 1.0)
SLIDER_COLOUR = (1.0, 1.0, 1.0)
HORIZON_COLOUR = (0.35, 0.85, 0.45)  # what the table re-fits to (the material's horizon curve)
CLAMP_COLOUR = (1.0, 0.35, 0.3)
CORRELATION_COLOUR = (0.7, 0.7, 0.7)


SET_COLOUR = (0.62, 0.62, 0.62)


def _set_ranges(points, x_lo, x_hi, y_lo, y_hi):
    """The axis ranges widened for an analysed set's points, and the points that then fit.

    The plot is about this material's region: a set's outlier (a near-mirror at 10^-5, a slope
    of -3) would otherwise squash the region into a corner. So a set may widen the mean-slope
    axis by at most half its span on each side and the log-variance axis by at most one decade
    each way; points beyond are left off and counted in the legend ("set (N; k off)")."""
    pts = np.asarray(points, float).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1) & (pts[:, 1] > 0)]
    if not len(pts):
        return x_lo, x_hi, y_lo, y_hi, pts
    span = x_hi - x_lo
    mu, ly = pts[:, 0], np.log10(pts[:, 1])
    ok = (mu >= x_lo - 0.5 * span) & (mu <= x_hi + 0.5 * span) & (ly >= y_lo - 1.0) & (ly <= y_hi + 1.0)
    if ok.any():
        x_lo, x_hi = min(x_lo, float(mu[ok].min()) - 0.05), max(x_hi, float(mu[ok].max()) + 0.05)
        y_lo, y_hi = min(y_lo, float(ly[ok].min()) - 0.05), max(y_hi, float(ly[ok].max()) + 0.05)
    return x_lo, x_hi, y_lo, y_hi, pts[ok]


def region_plot(
    region,
    slider=None,
    used=None,
    correlation_a=None,
    width=600,
    height=420,
    set_points=None,
    compact=False,
    horizon=None,
):
    """The reachable region on the (mean slope, variance) plane, as RGBA float32 (row 0 on top).

    The region (filled, outlined), the correlation quadratic with coefficient ``correlation_a``
    (dashed), an analysed set's materials ``set_points`` ((mean slope, variance) pairs: small
    grey dots), the fitted point (orange), the sliders (white ring) and, when the sliders lie
    outside, the nearest reachable point Apply will use (red, joined to the sliders). ``horizon``
    ((mean slopes, variances), the last point the sliders'): what the table re-fits to as the
    variance request runs over its range at the sliders' mean slope, the material's own horizon
    curve (SPEC §3), with the sliders' point on it (green). The variance axis is logarithmic:
    regions span two decades. ``compact``: the panel's chart
    (about 200 px): a short title and axis label, the legend wrapped over as many lines as it needs."""
    from ..core.fits.curves import LAMBERT_VARIANCE, correlation_curve
    from .plot_font import ADVANCE, draw_text, text_width

    c = Canvas(width, height)
    s = max(1, int(round(width / 450)))
    line_h = 9 * s
    mu_b, s2_b = region.boundary()
    m_fit, s_fit = region.fitted
    pts_mu = [
        v for v in np.concatenate([mu_b, [m_fit, -1.0, 0.0], [p[0] for p in (slider, used) if p]]) if np.isfinite(v)
    ]
    x_lo, x_hi = min(pts_mu) - 0.05, max(pts_mu) + 0.05
    s2_all = [
        v
        for v in np.concatenate([region.sigma2, [s_fit, LAMBERT_VARIANCE], [p[1] for p in (slider, used) if p]])
        if np.isfinite(v) and v > 0
    ]
    y_lo, y_hi = math.log10(min(s2_all)) - 0.05, math.log10(max(s2_all)) + 0.05
    n_set = 0 if set_points is None else len(set_points)
    x_lo, x_hi, y_lo, y_hi, shown = _set_ranges(set_points if n_set else [], x_lo, x_hi, y_lo, y_hi)
    left, right, bottom = 7 * ADVANCE * s + 10, 12, height - 2 * line_h - 14
    if compact:  # the y ticks' own width, not room for the longest possible one
        decades = range(math.ceil(y_lo), math.floor(y_hi) + 1)
        left, right = max([text_width(_tick(10.0**e), s) for e in decades] or [4 * ADVANCE * s]) + 10, 8
    x0, x1 = left, width - right - 1
    items = [("fit", FIT_COLOUR), ("sliders", SLIDER_COLOUR), ("Apply" if compact else "Apply uses", CLAMP_COLOUR)]
    if horizon is not None:
        items.append(("delivers", HORIZON_COLOUR))
    if correlation_a is not None and np.isfinite(correlation_a):
        items.append(
            ((f"corr. a={correlation_a:.3g}" if compact else f"correlation a={correlation_a:.3g}"), CORRELATION_COLOUR)
        )
    if n_set:
        off = n_set - len(shown)
        items.append((f"set ({n_set}; {off} off)" if off else f"set ({n_set})", SET_COLOUR))
    # the legend's lines, [(x, label, colour)] each, wrapped at the right edge
    start = 4 if compact else x0
    legend, lx = [[]], start
    for label, colour in items:
        w = 12 * s + text_width(label, s)
        if legend[-1] and lx + w > width - 4:
            legend.append([])
            lx = start
        legend[-1].append((lx, label, colour))
        lx += w + (10 if compact else 16) * s
    top = max(3 * line_h + 8, 6 + (1 + len(legend)) * (line_h + 2) + 6)

    def px(mu, s2):
        mu, s2 = np.asarray(mu, float), np.maximum(np.asarray(s2, float), 1e-300)
        return (
            x0 + (mu - x_lo) / (x_hi - x_lo) * (x1 - x0),
            bottom - (np.log10(s2) - y_lo) / (y_hi - y_lo) * (bottom - top),
        )

    # the region, row by row: each pixel row is one variance
    for row in range(top + 1, bottom):
        s2 = 10.0 ** (y_lo + (bottom - row) / (bottom - top) * (y_hi - y_lo))
        if not region.sigma2_min <= s2 <= region.sigma2_max:
            continue
        lo, hi = region.mu_range(s2)
        if not (np.isfinite(lo) and np.isfinite(hi)):
            continue
        a, b = (int(round(float(v))) for v in (px(lo, s2)[0], px(hi, s2)[0]))
        a, b = max(a, x0 + 1), min(b, x1 - 1)
        if b >= a:
            c.px[row, a : b + 1, :3] = 0.55 * c.px[row, a : b + 1, :3] + 0.45 * np.asarray(REGION_FILL)
    c.clip = (0, 0, width - 1, height - 1)
    title = "reachable (μ~, σ~²)" if compact else "reachable (mean slope, variance) for this material"
    draw_text(c.px, 4 if compact else x0, 6, title, TEXT, s)
    for mu in (-1.5, -1.0, -0.5, 0.0):  # x ticks
        if x_lo <= mu <= x_hi:
            gx = int(round(float(px(mu, 1.0)[0])))
            c.px[top:bottom, gx] = GRID
            c.px[bottom : bottom + 4, gx] = FRAME
            label = f"{mu:g}"
            draw_text(c.px, gx - text_width(label, s) // 2, bottom + 6, label, TEXT, s)
    for e in range(math.ceil(y_lo), math.floor(y_hi) + 1):  # y ticks: decades
        gy = int(round(float(px(0.0, 10.0**e)[1])))
        c.px[gy, x0:x1] = GRID
        label = _tick(10.0**e)
        draw_text(c.px, x0 - 6 - text_width(label, s), min(max(gy - 3 * s, 0), height - 7 * s), label, TEXT, s)
    axis = "μ~ (x), σ~² (y, log)" if compact else "mean slope μ~ (x), variance σ~² (y, log)"
    draw_text(c.px, (x0 + x1 - text_width(axis, s)) // 2, bottom + 8 + line_h, axis, TEXT, s)
    c.rect(x0, top, x1, bottom, FRAME)
    c.clip = (x0 + 1, top + 1, x1 - 1, bottom - 1)
    c.polyline(*px(mu_b, s2_b), REGION_EDGE, width=1.5 * s)
    if correlation_a is not None and np.isfinite(correlation_a):
        mus = np.linspace(x_lo, x_hi, 200)
        curve = correlation_curve(mus, correlation_a)
        c.polyline(*px(mus, np.where(curve > 0, curve, np.nan)), CORRELATION_COLOUR, width=1.0 * s, dashed=True)
    if horizon is not None:  # the material's curve, under the set's dots (a set's materials lie on it)
        hm, hs = (np.asarray(a, float) for a in horizon)
        c.polyline(*px(hm[:-1], hs[:-1]), HORIZON_COLOUR, width=1.5 * s)
    if len(shown):  # under the markers: the fit and the sliders stay legible in a dense set
        c.dot(*px(shown[:, 0], shown[:, 1]), SET_COLOUR, radius=2.0 * s, alpha=0.9)
    if slider and used and (abs(slider[0] - used[0]) > 1e-9 or abs(slider[1] - used[1]) > 1e-12):
        c.polyline(*px([slider[0], used[0]], [slider[1], used[1]]), CLAMP_COLOUR, width=1.0 * s)
        c.dot(*px(used[0], used[1]), CLAMP_COLOUR, radius=4.0 * s)
    if horizon is not None and np.isfinite(hm[-1]) and np.isfinite(hs[-1]):
        c.dot(*px(hm[-1:], hs[-1:]), HORIZON_COLOUR, radius=3.5 * s)
    c.dot(*px(m_fit, s_fit), FIT_COLOUR, radius=4.0 * s)
    if slider:
        x, y = px(slider[0], slider[1])
        ang = np.linspace(0.0, 2 * math.pi, 60)
        c.dot(x + 6.0 * s * np.cos(ang), y + 6.0 * s * np.sin(ang), SLIDER_COLOUR, radius=0.8 * s)
    # the legend, from the second line
    c.clip = (0, 0, width - 1, height - 1)
    for k, line in enumerate(legend):
        ly = 6 + (k + 1) * (line_h + 2)
        for lx, label, colour in line:
            c.dot(np.array([lx + 4.0 * s]), np.array([ly + line_h / 2.0]), colour, radius=3.0 * s)
            draw_text(c.px, lx + 12 * s, ly, label, TEXT, s)
    return c.px
