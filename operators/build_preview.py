"""Build Preview: original and edited spheres side by side under an HDRI, as an image in the
panel (and at full size in an Image Editor), without touching the artist's window.

The spheres also live in their own scene ("BRDF Moments Preview": Cycles, OSL or baked), which
the artist can render or open; Build Preview never switches the window to it.

It runs as a job (progress, Esc cancels): the baked path's numpy bakes run off the main
thread; the OSL path's Cycles render runs on the main thread after them (bpy is not
thread-safe). By default the spheres show the tables themselves; the moment model is offered
only as a labelled sketch.
"""

import os

import bpy
import numpy as np

from ..addon.blender.images import label_image
from ..addon.blender.jobs import BackgroundJob
from ..addon.blender.live import preview_image_name, write_preview_image
from ..addon.core.limits import MAX_RENDER_SIZE, MAX_SAMPLES
from ..addon.core.preview.live import FINAL_SAMPLES
from .common import analysed_material

SCENE = "BRDF Moments Preview"
BAKE_SAMPLES = FINAL_SAMPLES


class BRDFMOMENTS_OT_build_preview(BackgroundJob, bpy.types.Operator):
    """Render original and edited on labelled spheres into an image (Esc cancels)"""

    bl_idname = "brdf_moments.build_preview"
    bl_label = "Build Preview"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Preview"

    material: bpy.props.StringProperty(name="Material", description="source material (default: active)")
    path: bpy.props.EnumProperty(
        name="Path",
        default="AUTO",
        items=[
            ("AUTO", "Auto", "OSL where this Cycles has it, else baked"),
            ("OSL", "OSL", ""),
            ("BAKED", "Baked", ""),
        ],
    )
    mode: bpy.props.EnumProperty(
        name="Shows",
        default="TABULATED",
        items=[
            ("TABULATED", "Tabulated", "the tables themselves"),
            ("MODEL", "Sketch (moment model)", "the fits' moment model (paper Eq. 7): a sketch, not the material"),
        ],
    )
    env: bpy.props.StringProperty(name="Environment", description="bundled HDRI name or file (empty: default)")
    size: bpy.props.IntProperty(
        name="Size",
        default=256,
        min=16,
        max=MAX_RENDER_SIZE,
        description="sphere size in pixels; the render is two spheres wide",
    )
    samples: bpy.props.IntProperty(name="Samples", default=16, min=1, max=MAX_SAMPLES)
    render_to: bpy.props.StringProperty(
        name="Render to",
        subtype="FILE_PATH",
        description="also render a still here (.png display-referred, .exr linear)",
    )
    use_panel_settings: bpy.props.BoolProperty(default=False, options={"HIDDEN"})

    def start(self, context):
        from ..addon.blender.preview import bake_cache, load_environment, resolve_environment
        from ..addon.blender.preview.build import resolve_path
        from ..addon.core.file.cachefs import check_sealed
        from ..addon.core.file.merl import read_merl
        from ..addon.core.file.nbrdf import read_table
        from ..addon.core.file.safeio import guard_output
        from ..addon.core.file.sources import source_exists, source_file
        from ..addon.core.limits import check_int
        from ..addon.core.preview import TableBRDF, sphere_layout

        mat = analysed_material(context, self.material)
        state = mat.brdf_moments
        if self.use_panel_settings:
            self.path, self.mode, self.env, self.size = (
                state.preview_path,
                state.preview_mode,
                state.preview_env,
                state.preview_size,
            )
        from ..addon.blender.preview import OSLUnavailable

        try:
            # Auto is the baked path: the accurate one (OSL tabulated is noisier at the same time)
            path = resolve_path("baked" if self.path == "AUTO" else self.path.lower())
        except OSLUnavailable as exc:
            raise ValueError(str(exc)) from None
        mode = self.mode.lower()
        sketch = mode == "model"
        size = check_int(self.size, "Size", 16, MAX_RENDER_SIZE)  # a script may set any int
        self._samples = check_int(self.samples, "Samples", 1, MAX_SAMPLES)
        source = bpy.path.abspath(state.source_path)  # a MERL file, or FILE:NAME of a network
        edited_path = state.edited_path if state.edited_path and os.path.isfile(state.edited_path) else ""
        have_source = source_exists(source)
        if not sketch and not have_source:
            raise ValueError(f"{source}: the source MERL file is missing; load it again, or preview the sketch")
        prof, eprof = state.profiles(), state.edited_profiles()
        params, eparams = state.model_params(), state.model_params(edited=True)
        env_path = resolve_environment(self.env or None)
        if self.render_to:  # refused now, before any work: the still may not replace an input
            guard_output(bpy.path.abspath(self.render_to), [source_file(source), edited_path, env_path])
        env = load_environment(env_path) if path == "baked" else None  # bpy: main thread
        layout = sphere_layout(2 * size, size, 2)
        cache = bake_cache()
        notes = []
        if not sketch and not edited_path:
            notes.append("no edit applied yet: both spheres show the original table")
        self._job = dict(
            mat=mat.name,
            path=path,
            mode=mode,
            env_path=env_path,
            layout=layout,
            notes=notes,
            labels=["measured", _edited_label(state) if edited_path or sketch else "measured"]
            + (["(sketch)"] if sketch else []),
        )

        def work(report_progress):
            if edited_path:  # its checksum read off the main thread (35 MB: 0.2-0.3 s)
                check_sealed(edited_path, "edited table (Apply's cache)")
            if sketch:
                srcs = [params, eparams]
            else:
                orig = TableBRDF(read_table(source), prof)
                srcs = [orig, TableBRDF(read_merl(edited_path), eprof) if edited_path else orig]
            report_progress(1, 4)
            if path == "baked":
                from ..addon.blender.preview.build import brdf_of

                for k, src in enumerate(srcs):
                    cache.get(brdf_of(src), env, layout.diameter, BAKE_SAMPLES)
                    report_progress(2 + k, 4)
            report_progress(4, 4)
            return srcs

        return work

    def finish(self, context, srcs):
        try:
            self._finish(context, srcs)
        except RuntimeError as exc:  # Cycles could not render, OSL could not load: a report
            raise ValueError(str(exc).strip() or type(exc).__name__) from None

    def _finish(self, context, srcs):
        from ..addon.blender.preview import build_preview, render_still
        from ..addon.blender.preview.build import bake_cache, brdf_of

        job = self._job
        mat = bpy.data.materials[job["mat"]]
        state = mat.brdf_moments
        layout = job["layout"]
        scene = bpy.data.scenes.get(SCENE) or bpy.data.scenes.new(SCENE)
        # The scene is built (and re-baked from the cache the job filled) but never shown in
        # the artist's window: the result goes into an image.
        info = build_preview(
            scene,
            srcs[0],
            srcs[1],
            path=job["path"],
            mode=job["mode"],
            env=job["env_path"],
            size=(layout.width, layout.height),
            samples=self._samples,
            bake_samples=BAKE_SAMPLES,
        )
        state.preview_material = info.materials[-1]
        if job["path"] == "baked":
            from ..addon.blender.preview import load_environment

            env = load_environment(job["env_path"])
            tiles = []
            for src in srcs:
                rgb, cov, _ = bake_cache().get(brdf_of(src), env, layout.diameter, BAKE_SAMPLES)
                tiles.append(np.dstack([rgb * cov[..., None], cov]))
            rgba = layout.compose(tiles)
        else:
            import tempfile

            from ..addon.blender.preview.osl import cache_dir

            os.makedirs(cache_dir(), exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix="preview-", suffix=".exr", dir=cache_dir())
            os.close(fd)
            try:
                render_still(scene, tmp, quiet=True)
                img = bpy.data.images.load(tmp)
                try:
                    w, h = img.size
                    buf = np.empty(w * h * 4, np.float32)
                    img.pixels.foreach_get(buf)
                finally:
                    bpy.data.images.remove(img)
                rgba = buf.reshape(h, w, 4)[::-1].copy()
            finally:
                os.remove(tmp)
        labels = job["labels"]
        if len(labels) == 3:
            labels = [f"{labels[0]} {labels[2]}", f"{labels[1]} {labels[2]}"]
        write_preview_image(mat, label_image(rgba, layout, labels))
        what = "sketch (moment model)" if job["mode"] == "model" else "tabulated"
        text = f"Preview ({info.path}, {what}) in the image '{preview_image_name(mat)}'"
        if self.render_to:
            from ..addon.core.file.safeio import guard_output
            from ..addon.core.file.sources import source_file

            out = bpy.path.abspath(self.render_to)
            guard_output(
                out, [info.environment, source_file(bpy.path.abspath(state.source_path)), state.edited_path]
            )  # checked again: the map, the tables are inputs
            render_still(scene, out, labels=labels)
            text += f", rendered to {out}"
        self.report({"INFO"}, text + "".join(f"; {n}" for n in info.notes + job["notes"]))


def _edited_label(state):
    """The edited sphere's label: the moves the sliders make, in their own terms."""
    from ..addon.blender.live import moves_text

    try:
        return moves_text(state.slider_targets(), state.fit())
    except ValueError:  # a slider outside its range: Apply says which
        return "edited"
