"""Every bpy class of the extension, registered in one place (order matters: property
groups before the types that point to them, operators before the panels that draw them)."""

import importlib

import bpy

from . import lifecycle, panel, state
from ...operators import (
    analyse,
    apply_edit,
    build_preview,
    clear_set,
    export,
    load_merl,
    load_set,
    reset_sliders,
    restore_material,
    show_image,
)

OPERATORS = (
    load_merl.BRDFMOMENTS_OT_load_merl,
    analyse.BRDFMOMENTS_OT_analyse,
    reset_sliders.BRDFMOMENTS_OT_reset_sliders,
    apply_edit.BRDFMOMENTS_OT_apply_edit,
    restore_material.BRDFMOMENTS_OT_restore_material,
    export.BRDFMOMENTS_OT_export,
    build_preview.BRDFMOMENTS_OT_build_preview,
    show_image.BRDFMOMENTS_OT_show_image,
    load_set.BRDFMOMENTS_OT_load_set,
    clear_set.BRDFMOMENTS_OT_clear_set,
)
CLASSES = (*state.CLASSES, *OPERATORS, *panel.CLASSES)


@bpy.app.handlers.persistent
def _file_loaded(*_args):
    """A reopened .blend: plots redrawn from the stored profiles, OSL edits find their texture,
    and the edits' shared setup built ahead of the first slider move or Apply, as after Analyse."""
    from . import material
    from .jobs import warm_up

    views = set()
    for mat in bpy.data.materials:
        st = getattr(mat, "brdf_moments", None)
        if st is not None and st.analysed and st.profiles_data:
            try:
                # In a window drawn in a thread (a 0.2 s plot on the main thread stalled a job
                # in the windowed lane); the stored image shows until it is in.
                state.plot_image(mat, later=True)
                if st.fit().get("mu_slope") is not None:
                    views.add(tuple(st.profiles().theta_o))
            except (ValueError, RuntimeError):
                pass
    for theta_o in sorted(views)[:1]:  # one set of views is kept per process (solve._rings)
        warm_up(theta_o)
    material.relink_textures()


# What the main thread imports lazily while jobs run (a job's finish, the panel, the live
# preview): imported once here instead, so that no job waits on a cold disk or a compile.
PRELOAD = (
    "..core.edit",
    "..core.edit.fidelity",
    "..core.fits",
    "..core.merl",
    "..core.nbrdf",
    "..core.principled",
    "..core.render",
    ".images",
    ".live",
    ".material",
    ".plot_font",
    ".plot_image",
    ".preview",
    ".preview.osl",
)


def register():
    for name in PRELOAD:
        importlib.import_module(name, __package__)
    # multiprocessing (the job runner's), imported here and not inside some later script run by
    # blender -P: its alias of that script's __main__ would crash Blender's exit (see lifecycle).
    lifecycle.import_multiprocessing()
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    state.attach()
    if _file_loaded not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(_file_loaded)


# What the last unregister found still running (tests read it).
LAST_SHUTDOWN: dict = {}


def unregister():
    if _file_loaded in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_file_loaded)
    # Jobs, timers and threads first: none of them may reach for a class or property that is
    # about to go (a timer after this would find no Material.brdf_moments).
    LAST_SHUTDOWN.clear()
    LAST_SHUTDOWN.update(lifecycle.shutdown())
    state.detach()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
