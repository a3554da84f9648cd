"""Apply: re-synthesize the material's table from the sliders (off the main thread)."""

import hashlib
import json
import os

import bpy
import numpy as np

from ..addon.blender import material as artist
from ..addon.blender.jobs import BackgroundJob
from .common import analysed_material


def resolve_artist_shader(context, choice):
    """'approx', 'lobes', 'principled', 'osl' or None for the artist's material, from the panel's
    choice. Without OSL the default ('approx') fits both approximations and installs the one
    closer to the edited table in BRDF error, the error the panel states (BENCHMARKS.md, "The
    artist's material", counts how often each wins: the lobes on all 236 measured tables and
    edits, and on the demo's GGX edit in 3.4, 6.5 %)."""
    from ..addon.blender.preview.osl import osl_available

    if choice == "NONE":
        return None
    if choice == "PRINCIPLED":
        return "principled"
    if choice == "LOBES":
        return "lobes"
    ok = osl_available()[0]
    if choice == "OSL":
        return "osl" if ok else "approx"  # a .blend made where OSL was: the approximation here
    scene = context.scene
    osl_scene = (
        scene is not None
        and scene.render.engine == "CYCLES"
        and bool(getattr(getattr(scene, "cycles", None), "shading_system", False))
    )
    return "osl" if ok and osl_scene else "approx"


def edits_folder():
    from ..addon.core.profiles.integrate import default_cache_dir

    return os.path.join(default_cache_dir(), "edits")


class BRDFMOMENTS_OT_apply_edit(BackgroundJob, bpy.types.Operator):
    """Re-synthesize a tabulated BRDF from the sliders and re-measure it (Esc cancels)"""

    bl_idname = "brdf_moments.apply_edit"
    bl_label = "Apply"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Re-synthesizing"

    material: bpy.props.StringProperty(name="Material", description="target material (default: active)")

    def start(self, context):
        from ..addon.core.edit import edit, scale_to_albedo
        from ..addon.core.file.merl import write_merl
        from ..addon.core.file.names import safe_name
        from ..addon.core.file.nbrdf import read_table
        from ..addon.core.file.sources import source_file
        from ..addon.core.fits.curves import fit_material
        from ..addon.core.profiles.compute import compute_profiles

        mat = analysed_material(context, self.material)
        state = mat.brdf_moments
        spec = bpy.path.abspath(state.source_path)
        source = source_file(spec)  # FILE of a FILE:NAME network source
        if not os.path.exists(source):
            raise ValueError(f"{source}: the source MERL file is missing; load it again to edit")
        targets = state.slider_targets()
        scale = state.scale_to_one
        floor = state.floor
        shader = resolve_artist_shader(context, state.artist_shader)
        from ..addon.core.material.lobes import closures_for, shadowing_for

        shadowing = shadowing_for(bpy.app.version)  # the Smith term this Blender's Cycles uses
        closures = closures_for(context.scene.render.engine)  # EEVEE: round lobes, no Velvet
        # Content-addressed output: the same file and sliders give the same name, and an
        # edit never overwrites another material's table (or the input).
        st = os.stat(source)
        key = json.dumps(
            [spec, st.st_size, st.st_mtime_ns, repr(targets), scale] + ([floor] if floor != "min" else []),
            sort_keys=True,
        )
        out = os.path.join(
            edits_folder(), f"{safe_name(mat.name)}-{hashlib.sha1(key.encode()).hexdigest()[:12]}.binary"
        )
        self._mat_name = mat.name
        # Edits still shown by a material are never evicted from the bounded cache.
        in_use = [m.brdf_moments.edited_path for m in bpy.data.materials if m.brdf_moments.edited_path]

        # The material's own analysis, fit and reachable region (stored at full precision by
        # Analyse): the edit starts from what the panel shows, the live preview edits from the
        # same, and the child does not analyse the file again.
        from .common import source_stamp

        if state.source_stamp and source_stamp(state.source_path) != state.source_stamp:
            raise ValueError(f"{source}: the file changed since it was analysed; analyse it again before Apply")
        stored_prof, stored_fit, region = state.profiles(), state.fit(), state.region()
        # the work writes the texture file; finish links it from the same place
        place = self._place = artist.texture_place(state.texture_storage)

        def work(report_progress):
            from ..addon.core.file import cachefs
            from ..addon.core.limits import EDITS_CACHE_MAX_BYTES, EDITS_CACHE_MAX_ENTRIES
            from ..addon.core.material.lobes import LobeFit

            table = read_table(spec)
            prof, fit = stored_prof, stored_fit
            if prof is None:  # not stored (cannot happen once analysed; kept for safety)
                prof = compute_profiles(table, floor=floor)
                fit = fit_material(prof)
            report_progress(1, 10)
            # keep: the live preview's synthesis of these sliders (inherited by this forked
            # child) is written as is, only re-measured here.
            res = edit(
                table,
                targets,
                prof,
                fit,
                region=region,
                keep=True,
                progress=lambda d, t: report_progress(1 + 8 * d // t, 10),
            )
            if scale:
                res = scale_to_albedo(res)
            cachefs.cache_folder(os.path.dirname(out))
            write_merl(res.table, out, source=source)
            cachefs.write_seal(out)
            cachefs.prune(os.path.dirname(out), EDITS_CACHE_MAX_ENTRIES, EDITS_CACHE_MAX_BYTES, keep=[out, *in_use])
            if res.profiles is None or scale:
                res.profiles = compute_profiles(
                    res.table, prof.theta_o, kd=prof.kd if prof.split else None, split=prof.split
                )
            from ..addon.core.edit.fidelity import report

            promise = json.dumps(report(res, prof, table), allow_nan=False)  # Export writes it beside the table
            # the least error any mix of Blender's closures reaches on the edited table is the
            # node_bound job's (6 s and more): the panel's button runs it after Apply. (Started
            # from Apply's finish in 3.4's window it failed within a second, cause not found yet.)
            principled = texture = bound = None  # texture: the written file's path
            if shader in ("lobes", "approx"):
                from ..addon.core.material.lobes import fit_lobes

                principled = fit_lobes(res.table, shadowing=shadowing, **closures)
            if shader in ("principled", "approx"):
                from ..addon.core.material.principled import fit_principled

                single = fit_principled(res.table)
                # Auto: the closer in the BRDF error the panel states
                if principled is None or single.error < principled.error:
                    principled = single
            elif shader == "osl":
                from ..addon.blender.preview.osl import table_texture_pixels

                kd = res.profiles.kd
                values = np.where(res.table.valid, res.table.rho, np.asarray(kd, float)[:, None]).T
                texture = artist.write_texture(place, "brdfm-table", table_texture_pixels(values, kd))
            if isinstance(principled, LobeFit):
                texture = artist.write_texture(place, "brdfm-lookup", artist.lookup_pixels(principled))
            report_progress(10, 10)
            res.table = None  # written to `out`; not sent back from the worker process (100 MB)
            return out, res, prof, fit, principled, texture, promise, bound

        from ..addon.blender import live

        live.pause(mat)  # once nothing can refuse the Apply: its child makes the same synthesis
        return work

    def ended(self, context, outcome):
        # A cancelled or failed Apply paused the live preview for nothing: it shows the
        # sliders' edit again (the kept synthesis, when the preview had made it, is reused).
        mat = bpy.data.materials.get(self._mat_name)
        if outcome != "finished" and mat is not None:
            from ..addon.blender import live

            live.slider_moved(mat)

    def finish(self, context, result):
        import math

        from ..addon.blender.state import pack_profiles, plot_image

        out, res, prof, fit, principled, texture, promise, bound = result
        said_bound = f", bound {100 * bound:.1f} %" if bound is not None else ""
        mat = bpy.data.materials[self._mat_name]
        state = mat.brdf_moments
        state.edited_path = out
        state.edited_profiles_data = pack_profiles(res.profiles)
        finite = lambda v: float(v) if v is not None and math.isfinite(v) else 0.0  # noqa: E731
        state.achieved_mu_slope = finite(res.achieved_mu_slope)
        state.achieved_sigma2 = finite(res.achieved_sigma2)
        state.max_albedo = [finite(v) for v in res.max_albedo]
        state.edit_warnings = "\n".join(res.warnings)
        state.edit_fidelity = res.fidelity.to_json() if res.fidelity is not None else ""
        state.edit_report = promise
        plot_image(mat, prof, fit, res.profiles, later=True)
        from ..addon.blender import live

        live.show_applied(mat, out)
        note = ""
        from ..addon.core.material.lobes import LobeFit

        if isinstance(principled, LobeFit):
            state.lobes_data = json.dumps(principled.as_dict())
            artist.apply_lobes(mat, principled, state.texture_storage, path=texture, place=self._place)
            state.artist_shader_used = "lobes"
            note = (
                f"; '{mat.name}' now renders {principled.n_lobes} lobes ({principled.describe()}) and a diffuse "
                f"lobe fitted to the edited table (approx., error {100 * principled.error:.1f} %{said_bound})"
            )
        elif principled is not None:
            state.principled_data = json.dumps({**principled.as_dict(), "bound": bound})
            artist.apply_principled(mat, principled, bound)
            state.artist_shader_used = "principled"
            note = (
                f"; '{mat.name}' now renders a Principled approximation (error {100 * principled.error:.1f} %"
                f"{said_bound})"
            )
        elif texture is not None:
            artist.apply_osl(mat, None, res, context.scene, path=texture, place=self._place)
            state.artist_shader_used = "osl"
            note = f"; '{mat.name}' now renders the edited table (OSL)"
        level = {"WARNING"} if res.warnings else {"INFO"}
        msg = (
            f"{mat.name}: reached μ̃ {state.achieved_mu_slope:+.3f} (announced {_said(res.announced[0], '+.3f')}), "
            f"σ̃² {state.achieved_sigma2:.4f} (announced {_said(res.announced[1], '.4f')}), "
            f"largest albedo {max(state.max_albedo):.3f}"
        )
        self.report(level, msg + note + ("; " + "; ".join(res.warnings) if res.warnings else ""))


def _said(value, fmt):
    return "—" if value is None else format(value, fmt)
