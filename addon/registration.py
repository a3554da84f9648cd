"""Every bpy class of the extension, registered in one place (order matters)."""

import bpy

from . import panel, state
from ..operators import load_merl

CLASSES = (*state.CLASSES, load_merl.BRDFMOMENTS_OT_load_merl, panel.MATERIAL_PT_brdf_moments)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    state.attach()


def unregister():
    state.detach()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
