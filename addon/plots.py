"""PNG plots of moment profiles (matplotlib, off-screen). Used by the CLI and the panel."""

from __future__ import annotations

import os
import tempfile

import numpy as np

CHANNEL_STYLE = {"r": ("#d62728", "R"), "g": ("#2ca02c", "G"), "b": ("#1f77b4", "B"), "avg": ("#222222", "average")}


def _figure(nrows, ncols, size):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False)
    return plt, fig, axes


def save_figure(fig, path, dpi=110):
    """Save atomically (temp file + rename) so a failed plot never leaves a broken PNG."""
    path = os.path.abspath(path)
    folder = os.path.dirname(path)
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".png", dir=folder)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=dpi, format="png")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def plot_profiles(prof, path, title=None):
    """One figure: energy, mean, variances, skewness, excess kurtosis against theta_o."""
    plt, fig, axes = _figure(2, 3, (13, 7.5))
    deg = np.degrees(prof.theta_o)
    panels = [
        ("alpha", [("alpha", "-")], "energy α", "α (dθ dφ integral)"),
        ("mean", [("mu_theta", "-"), ("mu_phi", ":")], "mean μθ (solid), μφ (dotted)", "rad"),
        ("var", [("sigma_tt", "-"), ("sigma_pp", "--")], "variance σθ² (solid), σφ² (dashed)", "rad²"),
        ("skew", [("skew_30", "-"), ("skew_12", "--")], "co-skewness γ30 (solid), γ12 (dashed)", "standardized"),
        ("kurt", [("kurt_40", "-"), ("kurt_22", "--"), ("kurt_04", ":")],
         "excess co-kurtosis γ40 (solid), γ22 (dashed), γ04 (dotted)", "standardized"),
    ]
    for ax, (_, series, label, unit) in zip(axes.flat, panels):
        drawn = False
        for ch, (colour, name) in CHANNEL_STYLE.items():
            for key, style in series:
                if key not in prof[ch]:
                    continue
                ax.plot(deg, prof[ch][key], style, color=colour, lw=1.4 if ch == "avg" else 1.0,
                        label=name if style == "-" else None)
                drawn = True
        if series[0][0] == "mu_theta" and drawn:
            ax.plot(deg, -prof.theta_o, color="#999999", lw=0.8, ls="-.", label="mirror (−θo)")
            ax.plot(deg, 0 * deg, color="#bbbbbb", lw=0.8, ls="-.", label="Lambertian (0)")
        if series[0][0] == "sigma_tt" and drawn:
            ax.axhline(np.pi ** 2 / 12, color="#bbbbbb", lw=0.8, ls="-.", label="Lambertian π²/12")
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
    lines = [f"material: {prof.name or '—'}", f"kd (diffuse floor): {kd}" if prof.split else "diffuse split: off",
             f"views: {len(deg)} from {deg[0]:.0f}° to {deg[-1]:.0f}°", f"interpolation: {prof.interp}"]
    ax.text(0.02, 0.95, "\n".join(lines), va="top", family="monospace", fontsize=9, transform=ax.transAxes)
    fig.suptitle(title or f"Moment profiles — {prof.name}", fontsize=12)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path
