"""``python -m addon bench --only measured``: the 59 measured materials through ``analyze``.

Runs the command line's ``analyze`` on the two Neural-BRDF weights files of samples/measured
(decoding included: each worker decodes its network from the .npz, nothing cached), once per
diffuse floor, with plots (kept in out/bench-measured/, git-ignored), and prints the time, the
warnings, the fits and where the paper's model does not describe a material.

Model diagnostics (the project's own, thresholds set against the analytic single lobes):
- back-scatter: rho(w_i = w_o) / rho(w_i = n), both seen from 45 deg. One forward lobe between
  the normal and the mirror plus a constant kd gives at most 1 (analytic GGX 0.14-0.97, Phong
  and Lambertian 1.0); above 1.1 the material sends light back toward the viewer
  (retro-reflection), which no lobe on the normal-to-mirror line can do.
- grazing peak: in the plane of incidence seen from 30 deg, the specular part (robust floor)
  peaks within 10 deg of the horizon rather than near the mirror: forward scattering or sheen
  (or the networks' extrapolation at grazing, where they are least accurate).
- two scales: the same in-plane lobe is more than 4 times wider at a tenth of its peak than at
  half (a Gaussian 1.8, Phong 1.85, GGX 2.3-2.9): a sharp core on a broad base, several lobes.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BACKSCATTER_LIMIT = 1.1
TWO_SCALE_LIMIT = 4.0
GRAZING_PEAK_DEG = 80.0


def backscatter_ratio(table) -> float:
    from ..core.file.merl import lookup

    wo = np.array([[math.sin(math.pi / 4), 0.0, math.cos(math.pi / 4)]])
    back, _ = lookup(table, wo, wo)
    normal, _ = lookup(table, np.array([[0.0, 0.0, 1.0]]), wo)
    return float(back.mean() / max(normal.mean(), 1e-30))


def in_plane_lobe(table, kd, view_deg=30.0):
    """(peak angle in degrees, width at half, width at a tenth) of the in-plane specular part."""
    from ..core.file.merl import lookup

    to = math.radians(view_deg)
    ang = np.radians(np.linspace(-89.0, 89.0, 1781))
    wi = np.stack([np.sin(ang), np.zeros_like(ang), np.cos(ang)], -1)
    wo = np.broadcast_to([math.sin(to), 0.0, math.cos(to)], wi.shape)
    v, _ = lookup(table, wi, wo, interp="trilinear")
    s = np.clip(v - np.asarray(kd)[:, None], 0.0, None).mean(axis=0)
    k = int(np.argmax(s))
    if s[k] <= 0.0:
        return float("nan"), float("nan"), float("nan")

    def width(frac):
        above = s >= frac * s[k]
        lo = hi = k
        while lo > 0 and above[lo - 1]:
            lo -= 1
        while hi < len(s) - 1 and above[hi + 1]:
            hi += 1
        # At least one sample step, so a spike narrower than the step still has a width.
        return max(float(np.degrees(ang[hi] - ang[lo])), 0.1)

    return float(np.degrees(ang[k])), width(0.5), width(0.1)


def minimum_cell_angle(table) -> float:
    """Polar angle (degrees) of the lower direction of the cell that sets the paper's floor
    (the minimum over the 45 deg slice, channel by channel; the largest of the three)."""
    from ..core.profiles.compute import DIFFUSE_VIEW, _slice_lower_cosine
    from ..core.profiles.integrate import get_operator

    cells = np.asarray(get_operator(np.array([DIFFUSE_VIEW]), memo=False).view(0)[0])
    cosine = _slice_lower_cosine(cells)
    angles = []
    for c in range(3):
        v = np.where(table.valid[c, cells], table.rho[c, cells], np.inf)
        angles.append(math.degrees(math.acos(min(max(cosine[int(np.argmin(v))], -1.0), 1.0))))
    return max(angles)


def _analyze(inputs, out, floor):
    if os.path.isdir(out):
        shutil.rmtree(out)
    t, c = time.perf_counter(), os.times()
    res = subprocess.run(
        [sys.executable, "-m", "addon", "analyze", *inputs, "--out", out, "--floor", floor],
        cwd=ROOT,
        capture_output=True,
        text=True,
        env=dict(os.environ),
    )
    wall, c1 = time.perf_counter() - t, os.times()
    # CPU seconds of analyze and its workers: on a shared machine, steadier than the wall time.
    cpu = (c1.children_user - c.children_user) + (c1.children_system - c.children_system)
    noise = [ln for ln in res.stderr.splitlines() if not ln.startswith("analysing: ")]
    if res.returncode != 0:
        raise RuntimeError(f"analyze --floor {floor} failed ({res.returncode}): {' | '.join(noise[-3:])}")
    with open(os.path.join(out, "fits.json")) as fh:
        fits = json.load(fh)
    with open(os.path.join(out, "summary.csv")) as fh:
        rows = {r["material"]: r for r in csv.DictReader(fh)}
    nan = 0
    for name in rows:
        from ..core.file.names import distinct_name

        with open(os.path.join(out, "materials", distinct_name(name) + ".json")) as fh:
            prof = json.load(fh)["profiles"]
        upto = [i for i, t in enumerate(prof["theta_o"]) if t <= math.radians(85.0)]
        nan += any(prof["avg"][k][i] is None for k in ("alpha", "mu_theta", "sigma_tt") for i in upto)
    return (wall, cpu), noise, fits, rows, nan, res.stdout.strip().splitlines()[-1]


def bench_measured(quick=False):
    import samples

    from ..core.file import nbrdf
    from ..core.profiles.compute import ROBUST_MAX_ANGLE, ROBUST_PERCENTILE, diffuse_floor
    from ..core.profiles.integrate import default_views, get_operator

    get_operator(default_views())  # the slice operator is cached per machine; not what is timed
    sets = [os.path.join(samples.MEASURED_DIR, f) for f in samples.MEASURED_SETS.values()]
    names = samples.measured_names()
    # Decoding alone, in this process (the analyze runs below decode again, in their workers).
    dec_times, tables = [], {}
    for name in names:
        src, key = samples.measured_source(name)
        t, c = time.perf_counter(), time.process_time()
        tables[name] = nbrdf.decode(nbrdf.load_network(src, key))
        dec_times.append((time.perf_counter() - t, time.process_time() - c))
    out_root = os.path.join(ROOT, "out", "bench-measured")
    runs = {floor: _analyze(sets, os.path.join(out_root, floor), floor) for floor in ("min", "robust")}
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float("nan")

    # analyze names a material by its key, with the set's file stem where two sets share one.
    def row_name(name):
        key = name.split("/", 1)[1]
        if sum(n.split("/", 1)[1] == key for n in names) > 1:
            return f"{os.path.splitext(samples.MEASURED_SETS[name.split('/')[0]])[0]}/{key}"
        return key

    lines = [
        "### Measured materials: the whole set through `analyze`",
        "",
        f"{len(names)} materials ({len(sets)} weights files), `python -m addon analyze "
        f"samples/measured/*.npz --floor F` with plots, decoding included (each worker decodes its "
        f"network from the .npz; nothing cached), the slice operator already cached. "
        f"Load average {load:.1f} on {os.cpu_count()} cores when it finished.",
        "",
        "| floor | wall time (process) | CPU time (all processes) | analyze's own line "
        "| stderr lines (not progress) | NaN profiles ≤ 85° |",
        "|---|---|---|---|---|---|",
    ]
    for floor, ((wall, cpu), noise, _fits, _rows, nan, last) in runs.items():
        lines.append(f"| {floor} | {wall:.1f} s | {cpu:.1f} s | {last.split(';')[0]} | {len(noise)} | {nan} |")
    wall_d, cpu_d = np.array(dec_times).T
    lines += [
        "",
        f"Decoding one network into a MERL table (numpy, float32, chunks of {nbrdf.CHUNK} cells, one "
        f"process): median {1e3 * float(np.median(wall_d)):.0f} ms wall, {1e3 * float(np.median(cpu_d)):.0f} ms "
        f"CPU; {wall_d.sum():.1f} s wall for all {len(names)}.",
        "",
    ]
    for floor, (_wall, noise, _fits, _rows, _nan, _last) in runs.items():
        for ln in noise[:5]:
            lines.append(f"- stderr ({floor}): `{ln.strip()[:150]}`")
    lines += [
        "",
        "### Measured materials: fits, floors and the paper's model",
        "",
        f"kd: the average channel's floor, `min` the paper's minimum over the 45° slice, `robust` the "
        f"{100 * ROBUST_PERCENTILE:.0f}th area percentile of the slice's cells within "
        f"{math.degrees(ROBUST_MAX_ANGLE):.0f}° of the normal. Fits (μ̃, σ̃², α̃b, energy RMSE) per floor. "
        f"Diagnostics (module docstring of addon/tools/bench_measured.py): back-scatter ratio (> {BACKSCATTER_LIMIT}), "
        f"in-plane peak (grazing if beyond ±{GRAZING_PEAK_DEG:.0f}°), width ratio at 1/10 and 1/2 of the "
        f"peak (> {TWO_SCALE_LIMIT:g}).",
        "",
        "| material | kd min | paper min at | kd robust | μ̃ min | σ̃² min | α̃b min | μ̃ robust | σ̃² robust | α̃b robust "
        "| E-RMSE robust | back-scatter | in-plane peak | w10/w50 | outside the model |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    counts = {"back-scatter": [], "grazing peak": [], "two scales": [], "fit notes": []}
    kd_ratio, min_at = [], []
    for name in names:
        table = tables[name]
        rn = row_name(name)
        fmin, frob = runs["min"][2]["materials"][rn], runs["robust"][2]["materials"][rn]
        kmin = float(np.mean(diffuse_floor(table)))
        krob_c = diffuse_floor(table, method="robust")
        krob = float(np.mean(krob_c))
        kd_ratio.append(krob / max(kmin, 1e-12))
        back = backscatter_ratio(table)
        min_at.append(minimum_cell_angle(table))
        peak, w50, w10 = in_plane_lobe(table, krob_c)
        why = []
        if back > BACKSCATTER_LIMIT:
            why.append("back-scatter")
        if np.isfinite(peak) and abs(peak) >= GRAZING_PEAK_DEG:
            why.append("grazing peak")
        if np.isfinite(w50) and w10 / w50 > TWO_SCALE_LIMIT:
            why.append("two scales")
        if frob["outside_model"] or fmin["outside_model"] or frob["notes"]:
            why.append("fit notes: " + "; ".join(frob["notes"] or fmin["notes"]))
        for w in why:
            counts["fit notes" if w.startswith("fit notes") else w].append(name)

        def f(v, fmt):
            return "—" if v is None else format(v, fmt)

        lines.append(
            f"| {name} | {kmin:.4f} | {min_at[-1]:.0f}° | {krob:.4f} | {f(fmin['mu_slope'], '+.3f')} | {f(fmin['sigma2'], '.3f')} "
            f"| {fmin['alpha_b']:.3g} | {f(frob['mu_slope'], '+.3f')} | {f(frob['sigma2'], '.3f')} "
            f"| {frob['alpha_b']:.3g} | {frob['energy']['rmse']:.3f} | {back:.2f} | {peak:+.0f}° "
            f"| {w10 / w50:.1f} | {', '.join(why) or '—'} |"
        )
    inside = [n for n in names if all(n not in v for v in counts.values())]
    lines += [
        "",
        "Counts: "
        + "; ".join(f"{k} {len(v)}" for k, v in counts.items())
        + f"; none of these {len(inside)} ({', '.join(inside)}).",
        f"Robust / paper kd: median {np.median(kd_ratio):.3g}×, "
        f"{sum(r > 10 for r in kd_ratio)} of {len(names)} materials more than 10× higher. The cell that "
        f"sets the paper's minimum has a direction {'beyond 80°'} from the normal for "
        f"{sum(a > 80 for a in min_at)} of {len(names)} materials, beyond 85° for {sum(a > 85 for a in min_at)}.",
        "Correlation fits (σ̃² = a μ̃² + (a + π²/12) μ̃ + π²/12): "
        + ", ".join(
            f"{fl} a = {runs[fl][2]['correlation']['a']:.3f} (RMSE {runs[fl][2]['correlation']['rmse']:.3g})"
            for fl in runs
            if runs[fl][2].get("correlation", {}).get("a") is not None
        ),
    ]
    return lines
