"""Headless command line: ``python -m addon COMMAND ...`` from the repository root.

Exit codes: 0 success, 2 bad input (one line on stderr naming the file and the fault).
"""

from __future__ import annotations

import argparse
import math
import os
import sys

# render's default: the baked path at the panel's bake (core.preview.live.FINAL_SAMPLES), and
# what it measured against the converged reference (bench_preview.render_default_error; the
# figures and the command are in BENCHMARKS.md).
RENDER_BAKE_SAMPLES = 128
RENDER_DEFAULT_ERROR = (
    "measured 1.0 % per pixel on the glossy GGX sample and 3.2 % on the near-mirror one against "
    "a 16384-spp Monte Carlo reference, its own noise included (target 5 %)"
)


class InputError(Exception):
    """Bad input from the user: reported as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    """Usage mistakes are bad input too: one line on stderr (--help has the usage), exit 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _guard(out, *inputs):
    """Refuse a bad destination before any work (atomic_path checks again when writing)."""
    from ..core.file.safeio import guard_output
    from ..core.file.sources import parse_source

    # FILE:NAME (a material of a weights set) reads FILE: that is the input to protect.
    return guard_output(out, [parse_source(p)[0] for p in inputs if p])


def _progress(label, always=False):
    """A progress bar on a terminal; with ``always``, plain lines at every tenth elsewhere."""
    if not sys.stderr.isatty():
        if not always:
            return None

        def lines(done, total):
            if done == total or done % max(1, total // 10) == 0:
                print(f"{label}: {done}/{total}", file=sys.stderr, flush=True)

        return lines

    def report(done, total):
        width = 30
        fill = int(width * done / max(total, 1))
        sys.stderr.write(f"\r{label} [{'#' * fill}{'.' * (width - fill)}] {done}/{total}")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return report


def _single_materials(specs):
    """A weights set named with no material is an error for commands that take materials one by one."""
    from ..core.file.nbrdf import load_network
    from ..core.file.sources import is_weights_source, parse_source

    for spec in specs:
        path, name = parse_source(spec)
        if name is None and os.path.isfile(path) and is_weights_source(path):
            load_network(path)  # raises, listing a few names, when the file holds several


def cmd_profiles(args):
    from ..core.file.atomic import write_json_atomic
    from ..core.file.nbrdf import read_table
    from ..core.profiles.compute import compute_profiles
    from ..core.profiles.integrate import default_views

    _guard(args.out, args.file)
    if args.plot:
        _guard(args.plot, args.file, args.out)
        if os.path.abspath(args.plot) == os.path.abspath(args.out):
            raise InputError(f"{args.plot}: --plot and --out name the same file; choose two names")
    table = read_table(args.file)
    views = default_views(args.elevations, args.max_elevation)
    prof = compute_profiles(
        table,
        views,
        max_order=args.max_order,
        split=not args.no_split,
        interp=args.interp,
        floor=args.floor,
        progress=_progress("building slice rules (once)"),
    )
    write_json_atomic(prof.to_json(), args.out)
    print(f"wrote {args.out}")
    if args.plot:
        from .plots import plot_profiles

        plot_profiles(prof, args.plot)
        print(f"wrote {args.plot}")
    return 0


def cmd_fit(args):
    from ..core.file.atomic import write_json_atomic
    from ..core.fits.curves import fit_set
    from .analyze import collect_inputs, input_names, load_profiles

    _single_materials(args.files)
    paths, problems = collect_inputs(args.files)
    if problems:
        raise InputError(problems[0])
    _guard(args.out, *paths)
    names = input_names(paths)
    profiles = {n: load_profiles(p, name=n, floor=args.floor) for n, p in zip(names, paths)}
    result = fit_set(profiles)
    write_json_atomic(result, args.out)
    for n in names:
        f = result["materials"][n]
        slope = "—" if f["mu_slope"] is None else f"{f['mu_slope']:+.4f}"
        s2 = "—" if f["sigma2"] is None else f"{f['sigma2']:.4f}"
        flag = "  (outside the paper's model)" if f["outside_model"] else ""
        print(
            f"{n}: alpha_b {f['alpha_b']:.4g}, knots {math.degrees(f['theta0']):.1f}°-"
            f"{math.degrees(f['theta1']):.1f}°, mu~ {slope}, sigma2~ {s2}{flag}"
        )
    if result.get("correlation", {}).get("a") is not None:
        c = result["correlation"]
        print(f"correlation: sigma2 = {c['a']:.4f} mu^2 {c['b']:+.4f} mu {c['c']:+.4f} (RMSE {c['rmse']:.3g})")
    print(f"wrote {args.out}")
    return 0


def cmd_analyze(args):
    from .analyze import analyze

    if os.path.lexists(args.out) and not os.path.isdir(args.out):
        raise InputError(f"{args.out}: exists and is not a folder; --out names the output folder")
    problems = analyze(
        args.inputs,
        args.out,
        workers=args.jobs,
        progress=_progress("analysing", always=True),
        plots=not args.no_plots,
        floor=args.floor,
    )
    for p in problems:
        print(f"error: {p}", file=sys.stderr)
    return 2 if problems else 0


def _rgb(text):
    try:
        parts = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R,G,B numbers: {text!r}") from None
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected three finite numbers R,G,B: {text!r}")
    from ..core.limits import RANGES

    try:
        return tuple(RANGES["colour"].check(v, label="value") for v in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{str(exc).split(': ', 1)[1]} (in {text!r})") from None


def _sigma2_arg(text):
    """--sigma2: an absolute variance, or a factor on the fitted one: x0.5 (also X, *, ×)."""
    import argparse

    from ..core.limits import RANGES

    t = text.strip()
    if t[:1] in ("x", "X", "*", "×"):
        try:
            v = float(t[1:])
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number after {t[:1]!r}: {text!r}") from None
        hi = RANGES["strength"].high
        if not (math.isfinite(v) and 0.0 < v <= hi):
            raise argparse.ArgumentTypeError(f"a factor must be above 0 and at most {hi:g}, got {text!r}")
        return ("times", v)
    return RANGES["sigma2"].parse(t)


def _mu_arg(text):
    """--mu: an absolute mean slope (-2 .. 0), or a move up written with a plus sign (+0.05: a
    mean slope is never above 0, so a signed plus is never an absolute one)."""
    t = text.strip()
    if t.startswith("+"):
        return _mu_by_arg(t)
    from ..core.limits import RANGES

    return RANGES["mu_slope"].parse(t)


def _mu_by_arg(text):
    """--mu-by: a signed relative move of the mean slope (-0.05 lowers it)."""
    import argparse

    from ..core.limits import MU_SLOPE_RANGE

    span = MU_SLOPE_RANGE[1] - MU_SLOPE_RANGE[0]
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and -span <= v <= span):
        raise argparse.ArgumentTypeError(f"must be within -{span:g} .. +{span:g}, got {text!r}")
    return ("plus", v)


def resolve_moves(args, fit):
    """(mu_slope, sigma2) as EditTargets takes them, relative moves made absolute on the fit."""
    mu = args.mu
    if args.mu_by is not None:
        mu = args.mu_by
    if isinstance(mu, tuple):
        if fit.get("mu_slope") is None:
            raise InputError(f"{args.file}: the material has no specular lobe to move")
        mu = fit["mu_slope"] + mu[1]
    s2 = args.sigma2
    if isinstance(s2, tuple):
        if fit.get("sigma2") is None:
            raise InputError(f"{args.file}: the material has no specular lobe to move")
        s2 = fit["sigma2"] * s2[1]
    from ..core.limits import RANGES

    try:
        if mu is not None:
            mu = RANGES["mu_slope"].check(mu, "--mu")
        if s2 is not None:
            s2 = RANGES["sigma2"].check(s2, "--sigma2")
    except ValueError as exc:
        raise InputError(f"{exc} (after the relative move on the fitted value)") from None
    return mu, s2


def _check_written(path, res, prof):
    """Read the written file back and measure it as the announcement was measured (a fresh
    analysis): what anyone loading it will see, printed beside what was announced."""
    from ..core.edit.fidelity import against_announcement
    from ..core.edit.scale import measure
    from ..core.file.merl import read_merl

    got_prof, got_fit = measure(read_merl(path), prof.theta_o, prof.split)
    got_prof.name = prof.name
    d = against_announcement(res.profiles, got_prof)
    print(
        f"re-read   mean slope {got_fit['mu_slope']:+.4f}  variance {got_fit['sigma2']:.5f}; per view against the "
        f"announcement ({d['judged']} views x channels, the worst): energy {100 * d['view_energy']:.2f} %, "
        f"variance {100 * d['view_var']:.2f} %, mean {d['view_mean']:.4f} rad"
    )
    return got_prof


def cmd_edit(args):
    from ..core.edit import EditTargets, edit
    from ..core.file.merl import write_merl
    from ..core.file.nbrdf import read_table
    from ..core.file.sources import parse_source

    _guard(args.out, args.file)
    if args.report:
        _guard(args.report, args.file, args.out)
    if args.plot:
        _guard(args.plot, args.file, args.out, *([args.report] if args.report else []))
    table = read_table(args.file)
    from ..core.fits.curves import fit_material
    from ..core.profiles.compute import compute_profiles

    prof = compute_profiles(table, floor=args.floor)  # the edit keeps this kd; the report compares with it
    fit = fit_material(prof)
    mu, s2 = resolve_moves(args, fit)
    colour = args.alpha or (1.0, 1.0, 1.0)
    targets = EditTargets(
        strength=args.alpha_scale if args.alpha_scale is not None else 1.0,
        colour=colour,
        grazing_boost=args.grazing_boost,
        mu_slope=mu,
        sigma2=s2,
        roughness=args.roughness,
        mode=args.mode,
    )
    bar, shown = _progress("edit: synthesis"), [0, 0]

    def on_round(done, total):
        shown[:] = [done, total]
        bar(done, total)

    try:
        res = edit(table, targets, prof, fit, progress=on_round if bar else None)
    finally:
        if bar and shown[0] < shown[1]:
            sys.stderr.write("\n")  # an error cut the rounds short: end the bar's line before it
    write_merl(res.table, args.out, source=parse_source(args.file)[0])
    if args.report:
        from ..core.edit.fidelity import report
        from ..core.file.atomic import write_json_atomic

        write_json_atomic(report(res, prof, table), args.report, (args.file,))
    said = lambda v, fmt: "—" if v is None else format(v, fmt)  # noqa: E731
    if res.operator is not None:
        print(
            f"request   variance {said(res.requested[1], '.5f')} (fitted {fit['sigma2']:.5f}); the mean slope follows"
        )
    elif res.requested is not None:
        print(f"request   mean slope {said(res.requested[0], '+.4f')}  variance {said(res.requested[1], '.5f')}")
    print(
        f"announced mean slope {said(res.announced[0], '+.4f')}  variance {said(res.announced[1], '.5f')}"
        + ("  (clamped: nothing to do)" if res.nothing_to_do else "  (clamped)" if res.clamped else "")
    )
    print(f"re-fit    mean slope {said(res.achieved_mu_slope, '+.4f')}  variance {said(res.achieved_sigma2, '.5f')}")
    print("largest directional albedo (r, g, b): " + ", ".join(f"{v:.4f}" for v in res.max_albedo))
    if res.region is not None:
        lo, hi = res.region.mu_range(res.target_sigma2)
        print(
            f"reachable: variance {res.region.sigma2_min:.4g} .. {res.region.sigma2_max:.4g}; "
            f"mean slope {lo:+.3f} .. {hi:+.3f} at variance {res.target_sigma2:.4g}"
            + (f" (request {res.requested[0]:+.4f}, {res.requested[1]:.5f} clamped)" if res.clamped else "")
        )
    if res.fidelity is not None:
        # Per view (SPEC §6): every view 5-80 deg holding >= 5 % of the peak energy, re-measured.
        for ch, c in res.fidelity.channels.items():
            print(
                f"per view {ch}: energy {100 * c.energy:.1f} %, variance ratio {100 * c.variance_median:.1f} % "
                f"median / {100 * c.variance_worst:.1f} % worst, mean {c.mean:.3f} rad, skew/kurt "
                f"{'—' if c.shape != c.shape else f'{100 * c.shape:.0f} %'} ({c.views} views"
                + (f", {len(c.excluded_deg)} out of reach" if c.excluded_deg else "")
                + ")"
            )
    got = _check_written(args.out, res, prof) if res.operator or args.plot else None
    if args.plot:
        from .plots import plot_profiles

        title = f"{prof.name or args.file}: the written table re-read (per channel) over measured (grey), announced dashed orange"
        plot_profiles(got, args.plot, title=title, measured=prof, announced=res.profiles)
        print(f"wrote {args.plot}")
    if res.operator:
        op = res.operator
        print(
            f"operator  roughness x{op['roughness_scale']:.4f}, floor (r, g, b) "
            + ", ".join(f"{v:.4g}" for v in op["floor"])
            + f", masking {op['masking']}, tilt {op['tilt']:+.4f}"
            + (", clamped" if op["clamped"] else "")
        )
    if res.timings:
        print("time: " + ", ".join(f"{k} {v:.2f} s" for k, v in res.timings.items()))
    for w in res.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(f"wrote {args.out}")
    return 0


def cmd_render(args):
    from .render_command import run, run_in_child

    if os.environ.get("BRDF_MOMENTS_RENDER_CHILD") == "1":
        return run(args, InputError)
    return run_in_child(args, InputError)


def cmd_bench(args):
    from . import bench

    return bench.main(args)


def _floor_option(parser):
    parser.add_argument(
        "--floor",
        choices=("min", "robust"),
        default="min",
        help="diffuse floor kd: min, the paper's minimum over the 45° slice (default); robust, "
        "the 5th percentile by area of its cells within 70° of the normal (for measured "
        "data, where one grazing cell near 0 sets the minimum)",
    )


def build_parser():
    from ..core import limits as L

    p = _Parser(prog="python -m addon", description="BRDF Moments: moment profiles of measured (MERL) BRDFs.")
    sub = p.add_subparsers(dest="command", required=True)

    sp = sub.add_parser("profiles", help="moment profiles of one MERL file, as JSON")
    sp.add_argument("file", help="MERL .binary file; or a Neural-BRDF network, FILE:NAME (.npz, .h5, folder of .npy)")
    sp.add_argument("--out", required=True, help="output JSON path")
    sp.add_argument(
        "--elevations",
        type=L.RANGES["elevations"].parse,
        default=90,
        help=f"number of view elevations (90, at most {L.MAX_ELEVATIONS})",
    )
    sp.add_argument(
        "--max-elevation",
        type=L.RANGES["max_elevation"].parse,
        default=89.0,
        help=f"largest elevation in degrees (89, {L.RANGES['max_elevation'].describe()})",
    )
    sp.add_argument(
        "--max-order",
        type=L.RANGES["max_order"].parse,
        default=L.MAX_ORDER,
        help=f"highest moment order ({L.MAX_ORDER})",
    )
    sp.add_argument("--no-split", action="store_true", help="do not remove the diffuse floor kd")
    sp.add_argument("--interp", choices=("nearest", "trilinear"), default="nearest")
    sp.add_argument("--plot", help="also write a PNG of the profiles")
    _floor_option(sp)
    sp.set_defaults(func=cmd_profiles)

    sf = sub.add_parser("fit", help="Sec. 3.4 fits of one or more materials, as JSON")
    sf.add_argument(
        "files",
        nargs="+",
        help="MERL .binary files (or profiles JSON written by 'profiles'); or a Neural-BRDF network, FILE:NAME (.npz, .h5, folder of .npy)",
    )
    sf.add_argument("--out", required=True, help="output JSON path")
    _floor_option(sf)
    sf.set_defaults(func=cmd_fit)

    sa = sub.add_parser("analyze", help="profiles, fits, plots and a summary table for a set of materials")
    sa.add_argument(
        "inputs",
        nargs="+",
        help="folders of .binary files, or files; a Neural-BRDF weights file or .npy folder means all its materials, FILE:NAME one",
    )
    sa.add_argument("--out", required=True, help="output folder")
    sa.add_argument(
        "--jobs",
        type=L.RANGES["jobs"].parse,
        default=None,
        help=f"worker processes (default: all cores, at most {L.MAX_JOBS})",
    )
    sa.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    _floor_option(sa)
    sa.set_defaults(func=cmd_analyze)

    se = sub.add_parser("edit", help="re-synthesize a MERL file from moment sliders")
    se.add_argument(
        "file",
        help="input MERL .binary file (never modified); or a Neural-BRDF network, FILE:NAME (.npz, .h5, folder of .npy)",
    )
    se.add_argument("--out", required=True, help="output MERL .binary path (must differ from the input)")
    energy = se.add_mutually_exclusive_group()
    energy.add_argument(
        "--alpha-scale",
        type=L.RANGES["strength"].parse,
        help=f"scale the energy by S ({L.RANGES['strength'].describe()})",
    )
    energy.add_argument(
        "--alpha", type=_rgb, help=f"per-channel energy scale R,G,B (each {L.RANGES['colour'].describe()})"
    )
    se.add_argument(
        "--grazing-boost",
        type=L.RANGES["grazing_boost"].parse,
        default=1.0,
        help=f"scale of the energy above the base (1, {L.RANGES['grazing_boost'].describe()})",
    )
    mu = se.add_mutually_exclusive_group()
    mu.add_argument(
        "--mu",
        type=_mu_arg,
        help=f"target mean slope ({L.RANGES['mu_slope'].describe()}), or a move up from the fitted one: +0.05",
    )
    mu.add_argument("--mu-by", type=_mu_by_arg, help="move the fitted mean slope by D (signed: -0.05 lowers it)")
    rough = se.add_mutually_exclusive_group()
    rough.add_argument(
        "--sigma2",
        type=_sigma2_arg,
        help=f"target average variance ({L.RANGES['sigma2'].describe()}, up to pi^2/12), or a factor on the "
        "fitted one: x0.5, x2 (a roughness edit: the mean slope follows it)",
    )
    rough.add_argument(
        "--roughness",
        type=L.RANGES["roughness"].parse,
        help=f"scale the microsurface's roughness by S directly ({L.RANGES['roughness'].describe()})",
    )
    se.add_argument("--mode", choices=("warp", "model"), default="warp")
    se.add_argument(
        "--report",
        help="also write the per-view promise and what the table re-measures to (JSON: theta_o, judged, "
        "out_of_reach, clamped, announced, target and achieved per channel)",
    )
    se.add_argument(
        "--plot",
        help="also write a PNG of the written table's profiles (re-read from the file, per channel) over the "
        "measured ones (grey), with the announced ones (dashed orange)",
    )
    _floor_option(se)
    se.set_defaults(func=cmd_edit)

    sr = sub.add_parser(
        "render",
        help="original (and edited) spheres rendered by Cycles (needs the bpy module)",
        description=(
            "Original (and edited) spheres under an HDRI, rendered by Cycles. The default is the accurate "
            f"path, the panel's: the table baked at {RENDER_BAKE_SAMPLES}+{RENDER_BAKE_SAMPLES} directions "
            f"per texel, {RENDER_DEFAULT_ERROR}. OSL (the table sampled in Cycles' own shader, noisy at few "
            "samples) only with --path osl, or --path auto where this Blender has OSL."
        ),
    )
    sr.add_argument(
        "file", help="MERL .binary file (the original); or a Neural-BRDF network, FILE:NAME (.npz, .h5, folder of .npy)"
    )
    sr.add_argument("--edited", help="edited MERL .binary file, shown to the right")
    sr.add_argument("--env", help="bundled HDRI name (default studio) or an .exr/.hdr path")
    sr.add_argument(
        "--path",
        choices=("auto", "osl", "baked"),
        default="baked",
        help="baked (default: the table's radiance baked by numpy, any engine; "
        f"{RENDER_DEFAULT_ERROR.replace('%', '%%')}), osl (Cycles with OSL, noisy at its default samples), "
        "or auto (OSL where Cycles has it, else baked)",
    )
    sr.add_argument(
        "--mode",
        choices=("tabulated", "model"),
        default="tabulated",
        help="OSL mode: the table itself, or its fitted moment model",
    )
    sr.add_argument(
        "--size",
        type=L.RANGES["size"].parse,
        default=256,
        help=f"image width and height in pixels (256, at most {L.MAX_RENDER_SIZE})",
    )
    sr.add_argument(
        "--samples",
        type=L.RANGES["samples"].parse,
        default=16,
        help=f"Cycles samples per pixel (16, at most {L.MAX_SAMPLES})",
    )
    sr.add_argument(
        "--lobe-samples",
        type=L.RANGES["lobe_samples"].parse,
        default=16,
        help=f"OSL directions per shading point (16, at most {L.MAX_LOBE_SAMPLES})",
    )
    sr.add_argument(
        "--bake-samples",
        type=L.RANGES["bake_samples"].parse,
        default=RENDER_BAKE_SAMPLES,
        help=f"baked path directions per texel ({RENDER_BAKE_SAMPLES}, the panel's; at most {L.MAX_BAKE_SAMPLES})",
    )
    sr.add_argument("--out", required=True, help="output .png (display-referred) or .exr (linear radiance)")
    sr.set_defaults(func=cmd_render)

    sb = sub.add_parser("bench", help="benchmark tables (run time against error)")
    sb.add_argument("--quick", action="store_true", help="fewer repetitions and views")
    sb.add_argument(
        "--only",
        nargs="*",
        help="sections to run (closed, tables, memory, fits, rule, edit, preview, measured, artist)",
    )
    sb.set_defaults(func=cmd_bench)
    return p


def main(argv=None):
    from ..core.file.merl import MerlError
    from ..core.file.safeio import display_path, run_scope

    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    try:
        with run_scope():  # every file read is an input: no write of this run may replace it
            return args.func(args)
    except KeyboardInterrupt:
        # Writers clean up on the way out (atomic_path, temp_folder): nothing is left behind.
        if sys.stderr.isatty():
            sys.stderr.write("\n")  # end a progress bar's line first
        print(f"interrupted: {args.command} stopped; no partial output was left", file=sys.stderr)
        return 130
    except RecursionError:
        print(f"error: {args.command}: input nested too deeply", file=sys.stderr)
    except MemoryError:
        print(f"error: {args.command}: not enough memory for this input", file=sys.stderr)
    except MerlError as exc:
        print(f"error: {exc}", file=sys.stderr)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
    except (OSError, ValueError) as exc:
        name = getattr(exc, "filename", None)
        msg = f"{display_path(name)}: {exc.strerror}" if name and getattr(exc, "strerror", None) else str(exc)
        print(f"error: {msg}", file=sys.stderr)
    return 2
