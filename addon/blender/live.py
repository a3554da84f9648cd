"""The preview image in the panel, and its live update while a slider moves (SPEC §4).

A slider move (after a short debounce) starts a worker thread running ``core.preview.live.work``:
a draft synthesis of the edit and a quarter-resolution bake of it, written into the edited half
of the preview image; then the full synthesis and its full-resolution bake replace it. A newer slider move makes the worker drop what it was doing. Apply makes the same edit and
re-measures it, and Build Preview shows that.

Headless (``blender -b``, the bpy module) there is no event loop for timers:
``update_now(material)`` does the same work in place and returns the seconds it took.
"""

from __future__ import annotations

import threading
import time

import bpy
import numpy as np

from ..core.preview.live import FINAL_SAMPLES, source_table, work
from . import lifecycle
from .images import label_image

DEBOUNCE = 0.1  # seconds of quiet after a slider move before the work starts
POLL = 0.05
LABELS = {"live": "live", "refined": "refined", "applied": "applied"}


def moves_text(targets, fit) -> str:
    """The moves an edit makes, in the sliders' terms, for the edited sphere's label (the font
    has no combining tilde: sigma~^2 is written σ²)."""
    parts = []
    if targets.roughness is not None:
        parts.append(f"roughness×{targets.roughness:.2f}")
    elif targets.sigma2 is not None and fit.get("sigma2") and f"{targets.sigma2 / fit['sigma2']:.2f}" != "1.00":
        parts.append(f"σ²×{targets.sigma2 / fit['sigma2']:.2f}")
    # a move that shows as 0.00 is none (a slider held at -1 for a fitted -1.002)
    if targets.mu_slope is not None and fit.get("mu_slope") is not None:
        move = f"{targets.mu_slope - fit['mu_slope']:+.2f}"
        if move not in ("+0.00", "-0.00"):
            parts.append(f"μ{move}")
    if targets.strength != 1.0:
        parts.append(f"α×{targets.strength:.2f}")
    if tuple(targets.colour) != (1.0, 1.0, 1.0):
        parts.append("tint")
    if targets.grazing_boost != 1.0:
        parts.append(f"grazing×{targets.grazing_boost:.2f}")
    return " ".join(parts) or "no moves"


def sphere_label(moves: str, stage: str, width: int) -> str:
    """'<moves> <stage>' if it fits ``width`` pixels at the label's scale, else the moves alone
    (``label_image`` drops further words that do not fit)."""
    from .plot_font import text_width

    full = f"{moves} {LABELS[stage]}"
    return full if text_width(full) <= width else moves


def preview_image_name(mat):
    return f"BRDF Moments preview: {mat.name}"


def upsample(tile, d):
    d0 = tile.shape[0]
    idx = np.minimum((np.arange(d) * d0) // d, d0 - 1)
    return tile[idx][:, idx]


# --- the image ---------------------------------------------------------------------------------


def write_preview_image(mat, rgba):
    """The preview as a float image (linear radiance; ``rgba`` rows top first), kept in the .blend,
    and its thumbnail for the panel (an icon of the add-on's own, icons.py)."""
    from .icons import put_thumbnail
    from .images import keep_image

    img = keep_image(preview_image_name(mat), rgba, float_buffer=True)
    put_thumbnail(mat.name, rgba)
    return img


def read_preview_image(mat):
    img = bpy.data.images.get(preview_image_name(mat))
    if img is None:
        return None
    w, h = img.size
    buf = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(buf)
    return buf.reshape(h, w, 4)[::-1].copy()


SHOWN: dict = {}  # material name -> the stage of the edited sphere in its preview now


def replace_sphere(mat, k, rgb, cov, label, stage=None):
    """Sphere ``k`` of the preview image replaced by a (D, D) bake; the other sphere is kept.
    ``stage`` (live, refined, applied) is kept in ``SHOWN``: the label may be too narrow to say."""
    from ..core.preview import sphere_layout

    rgba = read_preview_image(mat)
    if rgba is None:
        return None
    h, w = rgba.shape[:2]
    layout = sphere_layout(w, h, 2)
    d, left, top = layout.diameter, layout.lefts[k], layout.top
    if rgb.shape[0] != d:
        rgb, cov = upsample(rgb, d), upsample(cov[..., None], d)[..., 0]
    rgba[top : top + d, left : left + d] = np.dstack([rgb * cov[..., None], cov])
    label_image(rgba, layout, [label if j == k else None for j in range(layout.count)])  # only this sphere's
    if stage is not None:
        SHOWN[mat.name] = stage
    return write_preview_image(mat, rgba)


# --- the work ----------------------------------------------------------------------------------


def _job(mat):
    """What the worker needs, read on the main thread; None when there is no live preview."""
    from ..core.file.sources import source_exists
    from ..core.preview import sphere_layout
    from .preview import load_environment, resolve_environment

    state = mat.brdf_moments
    img = bpy.data.images.get(preview_image_name(mat))
    source = bpy.path.abspath(state.source_path)
    if img is None or not state.analysed or state.preview_mode != "TABULATED" or not source_exists(source):
        return None
    try:
        targets = state.slider_targets()
    except ValueError:
        return None  # a slider outside its declared range: Apply says which
    w, h = img.size
    layout = sphere_layout(w, h, 2)
    fit = state.fit()
    return dict(
        moves=moves_text(targets, fit),
        cell=w // 2,
        mat=mat.name,
        source=source,
        targets=targets,
        prof=state.profiles(),
        fit=fit,
        region=state.region(),  # Apply's: so that its synthesis is the one kept here
        env=load_environment(resolve_environment(state.preview_env or None)),
        d=layout.diameter,
    )


def _work(job, stale=lambda: False, post=lambda stage, rgb, cov: None):
    work(
        source_table(job["source"]),
        job["targets"],
        job["prof"],
        job["fit"],
        job["env"],
        job["d"],
        stale,
        post,
        region=job["region"],
    )


def update_now(mat, refine=False):
    """The live update in place (headless, tests, the benchmark): seconds to the first image."""
    job = _job(mat)
    if job is None:
        return None
    t0 = time.perf_counter()
    first = []

    def post(stage, rgb, cov):
        replace_sphere(mat, 1, rgb, cov, sphere_label(job["moves"], stage, job["cell"]), stage)
        if not first:
            first.append(time.perf_counter() - t0)

    _work(job, stale=lambda: bool(first) and not refine, post=post)
    return first[0] if first else None


# --- in a window: debounce, a worker thread, results applied by a timer ---------------------------

_GEN = {}  # material name -> generation (each slider move bumps it)
_POSTED = []  # (material name, generation, stage, rgb, cov) from the worker
_LOCK = threading.Lock()


def slider_moved(mat):
    if bpy.app.background or bpy.data.images.get(preview_image_name(mat)) is None:
        return
    name = mat.name
    _GEN[name] = _GEN.get(name, 0) + 1
    gen = _GEN[name]

    def kick():
        if _GEN.get(name) != gen:
            return None  # a newer move will kick
        m = bpy.data.materials.get(name)
        job = _job(m) if m is not None else None
        if job is None:
            return None

        def post(stage, rgb, cov):
            with _LOCK:
                _POSTED.append((name, gen, stage, rgb, cov, sphere_label(job["moves"], stage, job["cell"])))

        _start(lambda: _work(job, stale=lambda: _GEN.get(name) != gen, post=post))
        return None

    lifecycle.register_timer(kick, first_interval=DEBOUNCE)


def _start(task):
    """``task`` in the live preview's worker thread; its posted images applied by a timer."""

    def run():
        try:
            task()
        except Exception as exc:  # noqa: BLE001 - a failed live update leaves the last image
            print(f"BRDF Moments: live preview: {type(exc).__name__}: {exc}")

    lifecycle.start_thread(run, "brdf_moments: live preview", stop=_stop_all)
    lifecycle.register_timer(_apply_posted, first_interval=POLL)


@lifecycle.on_file_load
@lifecycle.on_shutdown
def _stop_all():
    """Unregister, or another file is opened: every live work in flight becomes stale (it stops
    at its next stage) and nothing it posted is applied."""
    for name in list(_GEN):
        _GEN[name] += 1
    with _LOCK:
        _POSTED.clear()
    SHOWN.clear()


def pause(mat):
    """An Apply of this material starts: the live work in flight is dropped at its next stage
    (the Apply's child makes the same synthesis; both at once share two cores: 9.4 s against
    4.6-7 s measured in the window). ``show_applied`` puts the Apply's table in the preview."""
    if not bpy.app.background:
        _GEN[mat.name] = _GEN.get(mat.name, 0) + 1


def show_applied(mat, path):
    """The table an Apply wrote, baked at full resolution into the preview's edited sphere: it is
    read back, not synthesized again. Dropped if a slider moves meanwhile."""
    if bpy.app.background:
        return
    job = _job(mat)
    if job is None:
        return
    name, gen = mat.name, _GEN.get(mat.name, 0)

    def task():
        from ..core.file.merl import read_merl
        from ..core.preview import TableBRDF, bake_sphere

        rgb, cov = bake_sphere(TableBRDF(read_merl(path), job["prof"]), job["env"], job["d"], FINAL_SAMPLES, 0)
        with _LOCK:
            _POSTED.append((name, gen, "applied", rgb, cov, sphere_label(job["moves"], "applied", job["cell"])))

    _start(task)


def _apply_posted():
    with _LOCK:
        posted = list(_POSTED)
        _POSTED.clear()
    for name, gen, stage, rgb, cov, label in posted:
        mat = bpy.data.materials.get(name)
        if mat is None or _GEN.get(name) != gen and stage != "live":
            continue
        replace_sphere(mat, 1, rgb, cov, label, stage)
    busy = any(t.name == "brdf_moments: live preview" and t.is_alive() for t in threading.enumerate())
    return POLL if busy or posted else None
