"""Every bpy class of the extension, registered in one place (order matters: property
groups before the types that point to them, operators before the panels that draw them)."""

import bpy

from . import panel, state
from ..operators import analyse, apply_edit, build_preview, export, load_merl, reset_sliders

OPERATORS = (
    load_merl.BRDFMOMENTS_OT_load_merl,
    analyse.BRDFMOMENTS_OT_analyse,
    reset_sliders.BRDFMOMENTS_OT_reset_sliders,
    apply_edit.BRDFMOMENTS_OT_apply_edit,
    export.BRDFMOMENTS_OT_export,
    build_preview.BRDFMOMENTS_OT_build_preview,
)
CLASSES = (*state.CLASSES, *OPERATORS, *panel.CLASSES)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    state.attach()


def unregister():
    state.detach()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
