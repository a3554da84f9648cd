"""PNG plots of moment profiles (matplotlib, off-screen). Used by the CLI and the panel."""

from __future__ import annotations

import os

import numpy as np

CHANNEL_STYLE = {"r": ("#d62728", "R"), "g": ("#2ca02c", "G"), "b": ("#1f77b4", "B"), "avg": ("#222222", "average")}


def _figure(nrows, ncols, size):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False)
    return plt, fig, axes


def save_figure(fig, path, dpi=110):
    """Save atomically so a failed plot never leaves a broken PNG."""
    from ..core.file.atomic import atomic_path

    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")


def plot_profiles(prof, path, title=None, measured=None, announced=None):
    """One figure: energy, mean, variances, skewness, excess kurtosis against theta_o.
    ``measured``: the source's profiles, drawn beneath as thick grey lines (channel average), so
    an edited table's profiles read against what they came from; ``announced``: what an edit
    announced (channel average), drawn as a dashed orange line over them."""
    plt, fig, axes = _figure(2, 3, (13, 7.5))
    deg = np.degrees(prof.theta_o)
    panels = [
        ("alpha", [("alpha", "-")], "energy α", "α (dθ dφ integral)"),
        ("mean", [("mu_theta", "-"), ("mu_phi", ":")], "mean μθ (solid), μφ (dotted)", "rad"),
        ("var", [("sigma_tt", "-"), ("sigma_pp", "--")], "variance σθ² (solid), σφ² (dashed)", "rad²"),
        ("skew", [("skew_30", "-"), ("skew_12", "--")], "co-skewness γ30 (solid), γ12 (dashed)", "standardized"),
        (
            "kurt",
            [("kurt_40", "-"), ("kurt_22", "--"), ("kurt_04", ":")],
            "excess co-kurtosis γ40 (solid), γ22 (dashed), γ04 (dotted)",
            "standardized",
        ),
    ]
    for ax, (_, series, label, unit) in zip(axes.flat, panels):
        drawn = False
        # What the profiles read against, channel average: the measured ones beneath (thick grey),
        # an edit's announced ones over them (dashed orange).
        for other, name, style_kw in (
            (measured, "measured (avg)", {"color": "#b0b0b0", "lw": 3.2}),
            (announced, "announced (avg)", {"color": "#e07000", "lw": 1.0, "zorder": 5, "ls": (0, (4, 3))}),
        ):
            if other is None:
                continue
            for key, style in series:
                if key in other["avg"]:
                    kw = dict(style_kw)
                    fmt = () if "ls" in kw else (style,)
                    ax.plot(
                        np.degrees(other.theta_o),
                        other["avg"][key],
                        *fmt,
                        **kw,
                        label=name if style == "-" else None,
                    )
        for ch, (colour, name) in CHANNEL_STYLE.items():
            for key, style in series:
                if key not in prof[ch]:
                    continue
                ax.plot(
                    deg,
                    prof[ch][key],
                    style,
                    color=colour,
                    lw=1.4 if ch == "avg" else 1.0,
                    label=name if style == "-" else None,
                )
                drawn = True
        if series[0][0] == "mu_theta" and drawn:
            ax.plot(deg, -prof.theta_o, color="#999999", lw=0.8, ls="-.", label="mirror (−θo)")
            ax.plot(deg, 0 * deg, color="#bbbbbb", lw=0.8, ls="-.", label="Lambertian (0)")
        if series[0][0] == "sigma_tt" and drawn:
            ax.axhline(np.pi**2 / 12, color="#bbbbbb", lw=0.8, ls="-.", label="Lambertian π²/12")
        ax.set_title(label, fontsize=10)
        ax.set_xlabel("view elevation θo (degrees)")
        ax.set_ylabel(unit)
        ax.set_xlim(0, 90)
        ax.grid(alpha=0.3)
        if not drawn:
            ax.text(0.5, 0.5, "not computed (max order)", ha="center", va="center", transform=ax.transAxes)
        else:
            ax.legend(fontsize=7, loc="best")
    ax = axes.flat[5]
    ax.axis("off")
    kd = ", ".join(f"{v:.4g}" for v in prof.kd)
    lines = [
        f"material: {prof.name or '—'}",
        f"kd (diffuse floor): {kd}" if prof.split else "diffuse split: off",
        f"views: {len(deg)} from {deg[0]:.0f}° to {deg[-1]:.0f}°",
        f"interpolation: {prof.interp}",
    ]
    ax.text(0.02, 0.95, "\n".join(lines), va="top", family="monospace", fontsize=9, transform=ax.transAxes)
    fig.suptitle(title or f"Moment profiles — {prof.name}", fontsize=12)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


# --- sets of materials (paper Figures 4-7) -------------------------------------------------


def material_colours(names):
    """One colour per material, stable across every plot of a set (sorted-name order)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"] if len(names) <= 20 else matplotlib.colormaps["turbo"]
    order = sorted(names)
    n = max(len(order) - 1, 1)
    return {name: cmap(i % 20) if len(order) <= 20 else cmap(i / n) for i, name in enumerate(order)}


ORDER_PANELS = {
    0: ("Order 0: energy", [("alpha", "α")], "α"),
    1: ("Order 1: mean", [("mu_theta", "μθ"), ("mu_phi", "μφ (near zero)")], "rad"),
    2: ("Order 2: covariance", [("sigma_tt", "σθ²"), ("sigma_pp", "σφ²"), ("sigma_tp", "Σ11 (near zero)")], "rad²"),
    3: (
        "Order 3: co-skewness",
        [("skew_30", "γ30"), ("skew_12", "γ12"), ("skew_21", "γ21 (near zero)"), ("skew_03", "γ03 (near zero)")],
        "standardized",
    ),
    4: (
        "Order 4: excess co-kurtosis",
        [
            ("kurt_40", "γ40"),
            ("kurt_22", "γ22"),
            ("kurt_04", "γ04"),
            ("kurt_31", "γ31 (near zero)"),
            ("kurt_13", "γ13 (near zero)"),
        ],
        "standardized",
    ),
}


LEGEND_ROWS = 40


def _legend_columns(n):
    return max(1, -(-n // LEGEND_ROWS))


def _legend_outside(fig, colours):
    from matplotlib.lines import Line2D

    names = sorted(colours)
    handles = [Line2D([], [], color=colours[n], lw=2) for n in names]
    fig.legend(
        handles,
        names,
        loc="center right",
        fontsize=7 if len(names) <= LEGEND_ROWS else 6,
        ncol=_legend_columns(len(names)),
        frameon=False,
    )


def _set_legend(fig, ax, n, ncol=1):
    """A legend in the axes for a few materials; beside them, in columns, for a large set
    (59 names inside a 5-inch axes would hide the data and defeat tight_layout)."""
    if n <= 16:
        ax.legend(fontsize=7, ncol=ncol)
        fig.tight_layout()
        return
    cols = -(-(n + 3) // 34)
    w, h = fig.get_size_inches()
    fig.set_size_inches(w + 2.1 * cols, h)
    ax.legend(fontsize=6, ncol=cols, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0.0)
    fig.tight_layout()


def plot_set_profiles(profiles, folder, channel="avg"):
    """Figures 4 and 5: every material's profile, one figure per moment order."""
    colours = material_colours(list(profiles))
    paths = []
    for order, (title, keys, unit) in ORDER_PANELS.items():
        keys = [k for k in keys if all(k[0] in p[channel] for p in profiles.values())]
        if not keys:
            continue
        cols = _legend_columns(len(colours))
        width = 4.2 * len(keys) + 2.0 * cols
        plt, fig, axes = _figure(1, len(keys), (width, 3.8 if cols == 1 else 4.6))
        for ax, (key, label) in zip(axes.flat, keys):
            for name, p in profiles.items():
                ax.plot(np.degrees(p.theta_o), p[channel][key], color=colours[name], lw=1.0)
            ax.set_title(label)
            ax.set_xlabel("view elevation θo (degrees)")
            ax.set_ylabel(unit)
            ax.set_xlim(0, 90)
            ax.grid(alpha=0.3)
        fig.suptitle(f"{title} — {len(profiles)} materials ({channel} channel)")
        fig.tight_layout(rect=(0, 0, 1.0 - 2.0 * cols / width, 1))
        _legend_outside(fig, colours)
        path = os.path.join(folder, f"profiles_order{order}.png")
        save_figure(fig, path)
        plt.close(fig)
        paths.append(path)
    return paths


def plot_fits(profiles, fits, path, channel="avg"):
    """Figure 6: measured and fitted profiles (energy, mean, average variance), their errors,
    and insets with the best, an intermediate and the worst fit by RMSE."""
    from ..core.fits.curves import energy_curve

    colours = material_colours(list(profiles))
    names = [n for n in sorted(profiles) if fits[n]["energy"]["rmse"] is not None]
    plt, fig, axes = _figure(3, 3, (15, 11))
    rows = [
        ("energy α", "energy", "α"),
        ("mean μθ", "mean", "rad"),
        ("average variance (σθ²+σφ²)/2", "variance", "rad²"),
    ]

    def measured(name, row):
        p = profiles[name][channel]
        if row == 0:
            return p["alpha"]
        if row == 1:
            return p["mu_theta"]
        return 0.5 * (np.asarray(p["sigma_tt"]) + np.asarray(p["sigma_pp"]))

    def fitted(name, row, t):
        f = fits[name]
        if row == 0:
            return energy_curve(t, f["alpha_b"], f["theta0"], f["theta1"], f["alpha1"], f["m1"])
        if row == 1:
            return (f["mu_slope"] or 0.0) * t
        return np.full_like(t, f["sigma2"] or 0.0)

    for r, (title, key, unit) in enumerate(rows):
        ax_m, ax_f, ax_e = axes[r]
        for name in names:
            t = np.asarray(profiles[name].theta_o)
            ax_m.plot(np.degrees(t), measured(name, r), color=colours[name], lw=1.0)
            ax_f.plot(np.degrees(t), fitted(name, r, t), color=colours[name], lw=1.0)
        for ax, kind in ((ax_m, "measured"), (ax_f, "fitted")):
            ax.set_title(f"{title}: {kind}")
            ax.set_xlabel("view elevation θo (degrees)")
            ax.set_ylabel(unit)
            ax.grid(alpha=0.3)
        mae = np.array([fits[n][key]["mae"] for n in names])
        rmse = np.array([fits[n][key]["rmse"] for n in names])
        x = np.arange(len(names))
        if len(names) <= 30:
            ax_e.bar(x - 0.2, mae, 0.4, color="#1f77b4", label="MAE")
            ax_e.bar(x + 0.2, rmse, 0.4, color="#9467bd", label="RMSE")
            ax_e.set_xticks(x, names, rotation=90, fontsize=6 if len(names) > 20 else 8)
        else:
            # Too many names to read: errors against rank (the insets name best/middle/worst).
            order = np.argsort(rmse)
            ax_e.plot(x, mae[order], ".", color="#1f77b4", label="MAE")
            ax_e.plot(x, rmse[order], ".", color="#9467bd", label="RMSE")
            ax_e.set_xlabel("materials, ranked by RMSE")
        ax_e.set_title(f"{title}: fit errors")
        ax_e.set_ylabel(unit)
        ax_e.legend(fontsize=8)
        if names:
            lo, hi = ax_f.get_ylim()
            ax_f.set_ylim(lo, lo + (hi - lo) * 1.75)  # headroom: the insets sit above the curves
            ranked = sorted(names, key=lambda n: fits[n][key]["rmse"])
            picks = [("best", ranked[0]), ("intermediate", ranked[len(ranked) // 2]), ("worst", ranked[-1])]
            for i, (label, name) in enumerate(picks):
                inset = ax_f.inset_axes([0.02 + 0.33 * i, 0.62, 0.3, 0.34])
                t = np.asarray(profiles[name].theta_o)
                inset.plot(np.degrees(t), measured(name, r), color="#444444", lw=0.9)
                inset.plot(np.degrees(t), fitted(name, r, t), color=colours[name], lw=1.2, ls="--")
                inset.set_title(f"{label}: {name}", fontsize=6)
                inset.tick_params(labelsize=5)
    fig.suptitle("Fitted moment profiles (inset: measured grey, fitted dashed)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_energy_spline(profiles, fits, joint, path, channel="avg"):
    """Figure 7a: energy profiles normalised by alpha_b, the fitted splines and the knots."""
    from ..core.fits.curves import energy_curve

    colours = material_colours(list(profiles))
    plt, fig, axes = _figure(1, 1, (8.5, 5.5))
    ax = axes[0, 0]
    t = np.radians(np.linspace(0, 89, 300))
    for name in sorted(profiles):
        f = fits[name]
        if f["energy"]["rmse"] is None or not f["alpha_b"]:
            continue
        p = profiles[name]
        ax.plot(
            np.degrees(p.theta_o),
            np.asarray(p[channel]["alpha"]) / f["alpha_b"],
            ".",
            ms=2,
            color=colours[name],
            alpha=0.5,
        )
        ax.plot(
            np.degrees(t),
            energy_curve(t, f["alpha_b"], f["theta0"], f["theta1"], f["alpha1"], f["m1"]) / f["alpha_b"],
            color=colours[name],
            lw=1.2,
            label=name,
        )
    if joint:
        for k, ls in (("theta0", "--"), ("theta1", ":")):
            ax.axvline(
                np.degrees(joint[k]),
                color="k",
                ls=ls,
                lw=1,
                label=f"joint {'θ0' if k == 'theta0' else 'θ1'} = {np.degrees(joint[k]):.1f}°",
            )
    ax.set_xlabel("view elevation θo (degrees)")
    ax.set_ylabel("α / α̃b (relative energy)")
    ax.set_title("Energy: constant base α̃b, Hermite boost from θ0 (slope 0) to θ1, then a line")
    ax.grid(alpha=0.3)
    _set_legend(fig, ax, len(fits), ncol=2)
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_correlation(fits, correlation, path):
    """Figure 7b: fitted mean slope against average variance, with the constrained quadratic."""
    from ..core.fits.curves import LAMBERT_VARIANCE, correlation_curve

    colours = material_colours(list(fits))
    plt, fig, axes = _figure(1, 1, (7.5, 5.5))
    ax = axes[0, 0]
    for name in sorted(fits):
        f = fits[name]
        if f["mu_slope"] is None or f["sigma2"] is None:
            continue
        marker = "x" if f["outside_model"] else "o"
        ax.plot(f["mu_slope"], f["sigma2"], marker, color=colours[name], ms=6, label=name)
    if correlation and correlation.get("a") is not None:
        mu = np.linspace(-1, 0, 200)
        a = correlation["a"]
        ax.plot(
            mu,
            correlation_curve(mu, a),
            "k-",
            lw=1.4,
            label=f"σ̃² = {a:.3f} μ̃² {correlation['b']:+.3f} μ̃ + π²/12  (RMSE {correlation['rmse']:.3g})",
        )
    ax.plot([-1, 0], [0, LAMBERT_VARIANCE], "ks", ms=7, mfc="none", label="mirror (−1, 0), Lambertian (0, π²/12)")
    ax.set_xlabel("mean slope μ̃ (−1 mirror … 0 Lambertian)")
    ax.set_ylabel("average variance σ̃² (rad²)")
    ax.set_title("Mean–variance correlation (× = outside the paper's model)")
    ax.grid(alpha=0.3)
    _set_legend(fig, ax, len(fits))
    save_figure(fig, path)
    plt.close(fig)
    return path


def plot_material_curves(curves, correlation, path):
    """Where roughness edits take each material in the (mu~, sigma~^2) plane: one line per
    material through its fitted point (dot), over the paper's correlation quadratic fitted to
    the same materials' own points."""
    from ..core.fits.curves import LAMBERT_VARIANCE, correlation_curve

    plt, fig, axes = _figure(1, 1, (8.0, 6.0))
    ax = axes[0, 0]
    for name in sorted(curves):
        mu, s2, fitted = curves[name]
        line = ax.plot(mu, s2, "-", lw=1.0, alpha=0.75)
        ax.plot([fitted[0]], [fitted[1]], "o", ms=3.5, color=line[0].get_color())
    if correlation and correlation.get("a") is not None:
        m = np.linspace(-1.3, 0, 300)
        c = correlation_curve(m, correlation["a"])
        ax.plot(
            m, np.where(c > 0, c, np.nan), "k--", lw=1.6, label=f"the paper's quadratic, a = {correlation['a']:.3f}"
        )
    ax.plot([-1, 0], [0, LAMBERT_VARIANCE], "ks", ms=7, mfc="none", label="mirror (−1, 0), Lambertian (0, π²/12)")
    ax.set_yscale("log")
    ax.set_xlabel("mean slope μ̃")
    ax.set_ylabel("average variance σ̃² (rad², log)")
    ax.set_title(f"{len(curves)} measured materials under roughness edits (×0.5 … ×2 in σ̃²; dot: as measured)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="lower right", fontsize=8)
    save_figure(fig, path)
    plt.close(fig)
    return path
