"""Whole-set analysis: profiles and fits of many MERL files, in parallel, with plots."""

from __future__ import annotations

import csv
import io
import math
import os
import time

import numpy as np

from ..core.file.names import distinct_name, material_name


def _weights_specs(item, problems):
    """A Neural-BRDF weights source with no material chosen: all of its materials, FILE:NAME."""
    from ..core.file.merl import MerlError
    from ..core.file.nbrdf import list_materials

    try:
        return [f"{item}:{name}" for name in list_materials(item)]
    except MerlError as exc:
        problems.append(str(exc))
        return []


def _qualify(paths):
    """Names per input; materials of different weights sets that share a name get the set's stem."""
    from ..core.file.sources import parse_source

    names = [material_name(p) for p in paths]
    count = {}
    for n in names:
        count[n] = count.get(n, 0) + 1
    out = {}
    for p, n in zip(paths, names):
        src, key = parse_source(p)
        if key and count[n] > 1:
            n = f"{os.path.splitext(os.path.basename(os.path.normpath(src)))[0]}/{key}"
        out[p] = n
    return out


def input_names(paths):
    """The material name of each input (as ``collect_inputs`` checked them to be unique)."""
    return [_qualify(paths)[p] for p in paths]


def collect_inputs(items):
    """Expand folders to their .binary files, weights sets to their materials; (paths, problems)."""
    from ..core.file.sources import is_weights_source, parse_source

    paths, problems = [], []
    for item in items:
        item = os.fspath(item)
        src, key = parse_source(item)
        if os.path.isdir(item):
            found = sorted(os.path.join(item, f) for f in os.listdir(item) if f.endswith(".binary"))
            if not found and any(f.endswith(".npy") for f in os.listdir(item)):
                found = _weights_specs(item, problems)  # a folder of Neural-BRDF .npy weights
            elif not found:
                problems.append(f"{item}: folder has no .binary files")
            paths.extend(found)
        elif key is not None:
            paths.append(item)
        elif os.path.exists(item) and is_weights_source(item):
            paths.extend(_weights_specs(item, problems))
        elif os.path.exists(item):
            paths.append(item)
        else:
            problems.append(f"{item}: no such file or folder")
    names = {}
    qualified = _qualify(paths)
    for p in paths:
        names.setdefault(qualified[p], []).append(p)
    for name, ps in names.items():
        if len(ps) > 1:
            problems.append(f"{ps[1]}: material name '{name}' is used by another input too ({ps[0]})")
    from ..core.file.names import collisions
    from ..core.limits import MAX_INPUTS

    for a, b in collisions(list(names)):
        problems.append(
            f"{names[b][0]}: material '{b}' would share its output file with '{a}' on a "
            f"case-insensitive file system; rename one"
        )
    if len(paths) > MAX_INPUTS:
        problems.insert(0, f"{items[0]}: {len(paths)} input files, the limit is {MAX_INPUTS}")
        paths = paths[:0]
    return paths, problems


def load_profiles(path, views=None, name=None, floor="min"):
    """Profiles of a material source (MERL file, FILE:NAME of weights), or a profiles JSON."""
    from ..core.file.nbrdf import read_table
    from ..core.profiles.compute import Profiles, compute_profiles

    if str(path).endswith(".json"):
        from ..core.file.merl import MerlError
        from ..core.file.safeio import UnsafePath, load_json
        from ..core.limits import MAX_PROFILES_JSON_BYTES

        try:
            data = load_json(path, MAX_PROFILES_JSON_BYTES, "profiles JSON")
        except UnsafePath as exc:
            raise MerlError(path, exc.fault) from None
        try:
            return Profiles.from_json(data, name=name or material_name(path))
        except (ValueError, KeyError, TypeError) as exc:
            raise MerlError(path, f"not a profiles JSON ({str(exc).splitlines()[0][:200]})") from None
    table = read_table(path)
    prof = compute_profiles(table, views, floor=floor)
    prof.name = name or material_name(path)
    return prof


def _work(path, floor="min"):
    from ..core.file.merl import MerlError
    from ..core.fits.curves import fit_material

    t = time.perf_counter()
    try:
        prof = load_profiles(path, floor=floor)
    except MerlError as exc:
        return path, None, None, str(exc), 0.0
    fit = fit_material(prof)
    return path, prof.to_json(), fit, None, time.perf_counter() - t


def _ignore_sigint():
    # Ctrl-C reaches every process of the terminal's group: the parent alone handles it (it
    # stops the pool), so workers print no tracebacks.
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_parallel(paths, workers=None, progress=None, floor="min"):
    """(path, profiles_json, fit, error, seconds) per input, in input order."""
    import functools

    from ..core.profiles.integrate import default_views, get_operator

    get_operator(default_views())  # build or load once, before forking: children share it
    workers = workers or os.cpu_count() or 1
    results = {}
    if workers > 1 and len(paths) > 1:
        import multiprocessing as mp

        ctx = mp.get_context("fork")
        with ctx.Pool(workers, initializer=_ignore_sigint) as pool:
            for done, res in enumerate(pool.imap_unordered(functools.partial(_work, floor=floor), paths), 1):
                results[res[0]] = res
                if progress:
                    progress(done, len(paths))
    else:
        for done, p in enumerate(paths, 1):
            results[p] = _work(p, floor)
            if progress:
                progress(done, len(paths))
    return [results[p] for p in paths]


SUMMARY_FIELDS = (
    "material",
    "alpha_b",
    "theta0_deg",
    "theta1_deg",
    "alpha1",
    "m1",
    "energy_rmse",
    "mu_slope",
    "mean_rmse",
    "sigma2",
    "variance_rmse",
    "alpha_b_r",
    "alpha_b_g",
    "alpha_b_b",
    "kd_r",
    "kd_g",
    "kd_b",
    "outside_model",
    "notes",
)


def summary_rows(profiles, fits):
    rows = []
    for name in sorted(fits):
        f, p = fits[name], profiles[name]
        ch = f.get("channels", {})
        rows.append(
            {
                "material": name,
                "alpha_b": f["alpha_b"],
                "theta0_deg": math.degrees(f["theta0"]),
                "theta1_deg": math.degrees(f["theta1"]),
                "alpha1": f["alpha1"],
                "m1": f["m1"],
                "energy_rmse": f["energy"]["rmse"],
                "mu_slope": f["mu_slope"],
                "mean_rmse": f["mean"]["rmse"],
                "sigma2": f["sigma2"],
                "variance_rmse": f["variance"]["rmse"],
                "alpha_b_r": ch.get("r", {}).get("alpha_b"),
                "alpha_b_g": ch.get("g", {}).get("alpha_b"),
                "alpha_b_b": ch.get("b", {}).get("alpha_b"),
                "kd_r": float(p.kd[0]),
                "kd_g": float(p.kd[1]),
                "kd_b": float(p.kd[2]),
                "outside_model": f["outside_model"],
                "notes": "; ".join(f["notes"]),
            }
        )
    return rows


def write_text_atomic(text, path):
    from ..core.file.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
        fh.write(text)


def _plot_group(args):
    from . import plots as P

    group, profiles, fits, out_dir = args
    if group == 0:
        P.plot_set_profiles(profiles, out_dir)
    else:
        P.plot_fits(profiles, fits["materials"], os.path.join(out_dir, "fits.png"))
        P.plot_energy_spline(profiles, fits["materials"], fits.get("joint"), os.path.join(out_dir, "energy_spline.png"))
        P.plot_correlation(fits["materials"], fits.get("correlation"), os.path.join(out_dir, "correlation.png"))


def _plot_all(profiles, fits, out_dir, workers):
    """Two groups of plots of about equal cost, in two processes when there are two cores."""
    jobs = [(g, profiles, fits, out_dir) for g in (0, 1)]
    if (workers or os.cpu_count() or 1) > 1:
        import multiprocessing as mp

        with mp.get_context("fork").Pool(2, initializer=_ignore_sigint) as pool:
            pool.map(_plot_group, jobs)
    else:
        for j in jobs:
            _plot_group(j)


def _publish(out_dir, inputs, docs, fits, summary, profiles, workers):
    """Write every result into a staging folder inside ``out_dir``, then move each into place:
    an error or Ctrl-C before the moves leaves nothing (the staging folder is removed)."""
    from ..core.file.atomic import temp_folder, write_json_atomic
    from ..core.file.safeio import guard_output

    finals = list(docs) + ["fits.json", "summary.csv"]
    if profiles is not None:
        from .plots import ORDER_PANELS

        finals += [f"profiles_order{o}.png" for o in ORDER_PANELS] + [
            "fits.png",
            "energy_spline.png",
            "correlation.png",
        ]
    for rel in finals:
        guard_output(os.path.join(out_dir, rel), inputs)
    os.makedirs(os.path.join(out_dir, "materials"), exist_ok=True)
    with temp_folder(out_dir, ".tmp-brdfm-analyze-") as stage:
        os.mkdir(os.path.join(stage, "materials"))
        for rel, doc in docs.items():
            write_json_atomic(doc, os.path.join(stage, rel))
        write_json_atomic(fits, os.path.join(stage, "fits.json"))
        write_text_atomic(summary, os.path.join(stage, "summary.csv"))
        if profiles is not None:
            _plot_all(profiles, fits, stage, workers)
        for rel in sorted(os.listdir(stage)) + [
            os.path.join("materials", n) for n in sorted(os.listdir(os.path.join(stage, "materials")))
        ]:
            src = os.path.join(stage, rel)
            if os.path.isfile(src) and not rel.startswith("."):
                os.replace(src, guard_output(os.path.join(out_dir, rel), inputs))


def analyze(items, out_dir, workers=None, progress=None, plots=True, log=print, floor="min"):
    """Profiles, fits, per-material JSON, summary CSV and plots for a set. Returns problems."""
    from ..core.fits.curves import fit_set
    from ..core.profiles.compute import Profiles

    paths, problems = collect_inputs(items)
    bad_names = {p.split(":")[0] for p in problems}
    paths = [p for p in paths if p not in bad_names]
    if not paths:
        return problems or ["no input files"]
    qualified = _qualify(paths)
    t0 = time.perf_counter()
    results = run_parallel(paths, workers, progress, floor=floor)
    profiles, per_fit, seconds, docs = {}, {}, [], {}
    for path, pj, fit, err, sec in results:
        if err:
            problems.append(err)
            continue
        name = qualified[path]
        profiles[name] = Profiles.from_json(pj, name=name)
        per_fit[name] = fit
        seconds.append(sec)
        docs[os.path.join("materials", distinct_name(name) + ".json")] = {
            "material": name,
            "source": os.path.abspath(path),
            "profiles": pj,
            "fit": fit,
        }
    if not profiles:
        return problems
    fits = fit_set(profiles, materials=per_fit)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=SUMMARY_FIELDS)
    writer.writeheader()
    for row in summary_rows(profiles, fits["materials"]):
        writer.writerow({k: ("" if v is None else (f"{v:.6g}" if isinstance(v, float) else v)) for k, v in row.items()})
    from ..core.file.sources import parse_source

    inputs = [parse_source(p)[0] for p in paths]  # FILE:NAME reads FILE: that is the input to guard
    _publish(out_dir, inputs, docs, fits, buf.getvalue(), profiles if plots else None, workers)
    log(
        f"analysed {len(profiles)} material(s) in {time.perf_counter() - t0:.1f} s "
        f"(median {np.median(seconds):.2f} s each on one core); results in {out_dir}"
    )
    return problems
