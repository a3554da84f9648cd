"""What the operators share: finding the material they act on, and the analysis job."""

import bpy


def target_material(context, name=""):
    """The material named ``name``, else the one the UI is showing (Properties editor or the
    active object's active material)."""
    if name:
        mat = bpy.data.materials.get(name)
        if mat is None:
            raise ValueError(f"no material named {name!r}")
        return mat
    mat = getattr(context, "material", None)
    if mat is None and getattr(context, "object", None) is not None:
        mat = context.object.active_material
    if mat is None:
        raise ValueError("no material to work on: select an object with a material")
    return mat


def material_or_report(op, context, analysed=False):
    """The operator's material (``op.material``, else the one the UI shows), or None after
    reporting why there is none in one line (the operators' shared first step)."""
    try:
        return (analysed_material if analysed else target_material)(context, op.material)
    except ValueError as exc:
        op.report({"ERROR"}, str(exc))
        return None


def analysed_material(context, name=""):
    mat = target_material(context, name)
    if not mat.brdf_moments.analysed:
        raise ValueError(f"{mat.name}: load and analyse a MERL file first")
    return mat


def analysis_work(path, floor="min"):
    """A function of ``report_progress`` that reads, analyses and fits ``path`` (no bpy)."""
    from ..addon.core.file.nbrdf import read_table
    from ..addon.core.file.sources import source_exists
    from ..addon.core.fits.curves import fit_material
    from ..addon.core.profiles.compute import compute_profiles

    path = bpy.path.abspath(path) if path.startswith("//") else path
    if not path:
        raise ValueError("no MERL file chosen")
    if not source_exists(path):
        raise ValueError(f"{path}: no such file")

    def work(report_progress):
        table = read_table(path)  # a MERL file, or FILE:NAME of a Neural-BRDF network
        report_progress(1, 100)
        # The slice operator is built once per machine (minutes), then memory-mapped: the
        # progress bar matters on that first run.
        prof = compute_profiles(
            table, floor=floor, progress=lambda done, total: report_progress(1 + 97 * done // total, 100)
        )
        fit = fit_material(prof)
        regions = {}
        if fit.get("mu_slope") is not None and fit.get("sigma2") is not None:
            from ..addon.core.edit.reach import reachable_region
            from ..addon.core.edit.solve import roughness_region

            # Once per analysis, stored: the panel shows it and says, before Apply, what the
            # edit reaches. Warp mode's is the material's curve under roughness edits and the
            # tilt's reach (a few syntheses); model mode's the paper's sketch (0.1 s).
            warp = roughness_region(table, prof, fit)  # None: no lobe to read (Apply says so)
            regions = {"model": reachable_region(prof, fit, mode="model").to_json()}
            if warp is not None:
                regions["warp"] = warp.to_json()
        report_progress(100, 100)
        return table.name, prof, fit, regions

    return work


def source_stamp(path) -> str:
    """The analysed file's (size, mtime_ns) as JSON ('' when it cannot be read)."""
    import json
    import os

    from ..addon.core.file.sources import source_file

    try:
        st = os.stat(source_file(bpy.path.abspath(path)))
    except (OSError, ValueError):
        return ""
    return json.dumps([st.st_size, st.st_mtime_ns])


def store_analysis(mat, path, result) -> str:
    """Write an analysis into the material (and its plot); returns the line to report."""
    import json

    from ..addon.blender.state import plot_image, region_image

    name, prof, fit, regions = result
    state = mat.brdf_moments
    # Analysing the same file again keeps the last edit and the sliders; another file starts afresh.
    again = state.analysed and bpy.path.abspath(state.source_path) == bpy.path.abspath(path)
    state.source_path = path
    state.store_analysis(prof, fit, keep_sliders=again)
    state.source_stamp = source_stamp(path)
    state.region_data = json.dumps(regions)
    state.refresh_announcement()
    if not again:
        state.edited_path = ""
        state.edited_profiles_data = ""
        state.edit_warnings = ""
        state.edit_fidelity = ""
        state.edit_report = ""
        state.principled_data = ""
        state.lobes_data = ""
    plot_image(mat, prof, fit, edited=None if again else False, later=True)
    region_image(mat, later=True)
    if fit.get("mu_slope") is not None:
        from ..addon.blender.jobs import warm_up

        warm_up(prof.theta_o)  # ready for the first slider move and Apply
    return f"Analysed {name}: μ̃ {state.fit_mu_slope:+.3f}, σ̃² {state.fit_sigma2:.4f}"
