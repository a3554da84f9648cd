"""The glue's bpy classes and handlers, registered in one place. The extension's entry point
(the top-level ``__init__.py``) gathers the operators, a floor above, and hands them in.

Order matters: property groups before the types that point to them, operators before the
panels that draw them."""

import importlib

import bpy

from . import lifecycle, panel, state


def classes(operators):
    """Every class to register, in order: the state, then ``operators``, then the panels."""
    return (*state.CLASSES, *operators, *panel.CLASSES)


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


@bpy.app.handlers.persistent
def _file_loading(*_args):
    """Before another file is opened: the add-on's drawing and baking threads are ended and what
    they drew for this file dropped (lifecycle.file_loading)."""
    lifecycle.file_loading()


# What the main thread imports lazily while jobs run (a job's finish, the panel, the live
# preview): imported once here instead, so that no job waits on a cold disk or a compile.
PRELOAD = (
    "..core.edit",
    "..core.edit.fidelity",
    "..core.edit.scale",
    "..core.fits.curves",
    "..core.file.merl",
    "..core.file.nbrdf",
    "..core.material.lobes",
    "..core.material.principled",
    "..core.preview",
    ".images",
    ".live",
    ".material",
    ".plot_font",
    ".plot_image",
    ".preview",
    ".preview.osl",
)


def register(operators):
    for name in PRELOAD:
        importlib.import_module(name, __package__)
    # multiprocessing (the job runner's), imported here and not inside some later script run by
    # blender -P: its alias of that script's __main__ would crash Blender's exit (see lifecycle).
    lifecycle.import_multiprocessing()
    for cls in classes(operators):
        bpy.utils.register_class(cls)
    state.attach()
    panel.attach()
    if _file_loaded not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(_file_loaded)
    if _file_loading not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_file_loading)


# What the last unregister found still running (tests read it).
LAST_SHUTDOWN: dict = {}


def unregister(operators):
    if _file_loaded in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_file_loaded)
    if _file_loading in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_file_loading)
    # Jobs, timers and threads first: none of them may reach for a class or property that is
    # about to go (a timer after this would find no Material.brdf_moments).
    LAST_SHUTDOWN.clear()
    LAST_SHUTDOWN.update(lifecycle.shutdown())
    panel.detach()  # the charts' pictures and their timer
    state.detach()
    for cls in reversed(classes(operators)):
        bpy.utils.unregister_class(cls)
