"""``python -m addon.tools.bench_nodes [--quick] [names...]``: the artist's material outside OSL
(issue 28), engine only. For every measured material and its edits (σ̃² ×0.5, ×2, strength
0.5), the lobe mixture the nodes render (``core.material.lobes``) and the single Principled BSDF
(``core.material.principled``) against the edited table: BRDF error and directional-albedo error (as
each fit states them), the lobe fit's time, the table's near-mirror floor (the error no
setup of isotropic closures can go below, ``lobes.near_mirror_floor``) and the best error of
any view-dependent mix of Blender's closure shapes (``node_bound``), and the lobes' error over
it. Prints a markdown table and a summary.

``--reuse FILE``: the bound, floor and Principled figures of tables already measured (JSON lines
with name, edit, bound, floor, p_error, p_albedo; ``--write FILE`` writes them) are read, not
computed again: they do not depend on the lobe fit, and node_bound takes most of the run. A
figure a line lacks is computed (a changed bound: drop its key and run again)."""

from __future__ import annotations

import contextlib
import sys
import time

import numpy as np

EDITS = (("as measured", None), ("σ̃² ×0.5", ("sigma2", 0.5)), ("σ̃² ×2", ("sigma2", 2.0)), ("strength 0.5", None))
QUICK = ("rgl/paper_blue", "rgl/cm_white", "rgl/satin_gold", "rgl/ilm_l3_37_metallic", "nielsen/paintedmetal")


def edited_tables(table):
    """(label, table) for the table and its three edits (an edit that fails is reported)."""
    from ..core.edit import EditTargets, edit
    from ..core.fits.curves import fit_material
    from ..core.profiles.compute import compute_profiles

    prof = compute_profiles(table)
    fit = fit_material(prof)
    yield "as measured", table
    for label, targets in (
        ("σ̃² ×0.5", lambda f: EditTargets(sigma2=f["sigma2"] * 0.5)),
        ("σ̃² ×2", lambda f: EditTargets(sigma2=min(f["sigma2"] * 2.0, np.pi**2 / 12))),
        ("strength 0.5", lambda f: EditTargets(strength=0.5)),
    ):
        try:
            yield label, edit(table, targets(fit), prof, fit, remeasure=False).table
        except ValueError as exc:  # no specular lobe to edit
            yield label, exc


def bench_nodes(names, principled=True, out=print, reuse=None, write=None):
    import json

    import samples

    from ..core.file.merl import read_merl
    from ..core.material.lobes import fit_lobes, near_mirror_floor
    from ..core.material.node_bound import node_bound
    from ..core.material.principled import fit_principled

    known = {}
    if reuse:
        with open(reuse) as fh:
            for line in fh:
                d = json.loads(line)
                known[(d["name"], d["edit"])] = d
    sink = open(write, "a") if write else None
    out(
        "| material | edit | lobes: BRDF error | best any closures | lobes over it | lobes: albedo error "
        "| lobes | Principled: BRDF | Principled: albedo | near-mirror floor | fit time |"
    )
    out("|---|---|---|---|---|---|---|---|---|---|---|")
    errs, albs, times, perrs, palbs, floors, bounds, autos = [], [], [], [], [], [], [], []
    for name in names:
        table = read_merl(samples.sample_path(name))
        for label, t in edited_tables(table):
            if isinstance(t, Exception):
                out(f"| {name} | {label} | not editable: {t} | | | | | | |")
                continue
            t0 = time.perf_counter()
            f = fit_lobes(t)
            took = time.perf_counter() - t0
            d = dict(known.get((name, label), {}), name=name, edit=label)
            fresh = {k for k in ("bound", "floor", "p_error") if k not in d}  # what FILE lacks
            if "bound" in fresh:
                d["bound"] = node_bound(t)
            if "floor" in fresh:
                d["floor"] = near_mirror_floor(t)
            if "p_error" in fresh and principled:
                p = fit_principled(t)
                d.update(p_error=p.error, p_albedo=p.albedo_error)
            if fresh and sink is not None:
                sink.write(json.dumps(d) + "\n")
                sink.flush()
            floors.append(d["floor"])
            bounds.append(d["bound"])
            errs.append(f.error)
            albs.append(f.albedo_error)
            times.append(took)
            pe = pa = ""
            if principled and d.get("p_error") is not None:
                perrs.append(d["p_error"])
                palbs.append(d["p_albedo"])
                pe, pa = f"{d['p_error']:.1%}", f"{d['p_albedo']:.1%}"
                autos.append(min(f.error, d["p_error"]))  # Auto: the closer in BRDF error
            gap = 100.0 * (f.error - bounds[-1])
            out(
                f"| {name} | {label} | {f.error:.1%} | {bounds[-1]:.1%} | {gap:+.1f} | {f.albedo_error:.1%} "
                f"| {f.describe()} | {pe} | {pa} | {floors[-1]:.1%} | {took:.2f} s |"
            )
            sys.stdout.flush()
    e, a = np.array(errs), np.array(albs)
    g = e - np.array(bounds)
    out("")
    out(
        f"Lobes over their tables' node_bound: median {100 * np.median(g):+.1f} points, worst {100 * g.max():+.1f}; "
        f"within 5 points on {int(np.sum(g <= 0.05))} of {len(g)} tables; BRDF error at most 10 %: "
        f"{int(np.sum(e <= 0.10))}."
    )
    if autos:
        out(f"Auto (the closer of lobes and Principled in BRDF error): median {np.median(autos):.1%}.")
    out(
        f"Lobes over {len(e)} tables: BRDF error median {np.median(e):.1%}, 90th percentile "
        f"{np.percentile(e, 90):.1%}, worst {e.max():.1%}; albedo error median {np.median(a):.1%}, worst "
        f"{a.max():.1%}; fit time median {np.median(times):.2f} s, worst {max(times):.2f} s."
    )
    fl = np.array(floors)
    out(
        f"Near-mirror floor (no setup of isotropic closures goes below it) over the same: median {np.median(fl):.1%}, worst "
        f"{fl.max():.1%}; above 30 %: {int(np.sum(fl > 0.3))} tables, above 10 %: {int(np.sum(fl > 0.1))}."
    )
    bd = np.array(bounds)
    out(
        f"Best any view-dependent mix of the closures reaches (node_bound) over the same: median {np.median(bd):.1%}, "
        f"90th percentile {np.percentile(bd, 90):.1%}, worst {bd.max():.1%}; at most 10 %: {int(np.sum(bd <= 0.1))} "
        f"tables, above 30 %: {int(np.sum(bd > 0.3))}."
    )
    if perrs:
        out(
            f"Principled over the same: BRDF error median {np.median(perrs):.1%}, worst {max(perrs):.1%}; "
            f"albedo error median {np.median(palbs):.1%}, worst {max(palbs):.1%}."
        )


def main(argv=None):
    """Engine figures by default; ``--render [--eevee] [--model] [--under-bound] [names...]``: the
    rendered check (``bench_artist.bench_nodes_render``, needs Blender: the bpy module, or
    Debian's ``blender -b`` with ``--python-expr``, arguments after ``--``)."""
    import json

    import samples

    from ..script_args import script_args

    argv = script_args() if argv is None else list(argv)

    def option(name):
        if name in argv:
            i = argv.index(name)
            value = argv[i + 1]
            del argv[i : i + 2]
            return value
        return None

    reuse, write = option("--reuse"), option("--write")
    names = [a for a in argv if not a.startswith("--")]
    if "--render" in argv:
        from .bench_artist import RENDER_NAMES, bench_nodes_render, render_cases

        known = {}
        if reuse:
            with open(reuse) as fh:
                known = {(d["name"], d["edit"]): d["bound"] for d in map(json.loads, fh)}
        with open(write, "a") if write else contextlib.nullcontext() as sink:
            cases = render_cases(names or RENDER_NAMES, not names, "--under-bound" in argv, known, sink)
        bench_nodes_render(eevee="--eevee" in argv, cases=cases, model="--model" in argv)
        return
    quick = "--quick" in argv
    if not names:
        names = list(QUICK) if quick else samples.measured_names()
    bench_nodes(names, principled="--no-principled" not in argv, reuse=reuse, write=write)


if __name__ == "__main__":
    main(sys.argv[1:])
