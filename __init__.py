# SPDX-License-Identifier: GPL-3.0-or-later
"""FaceCap: performance-driven facial retargeting for Blender.

Inside Blender this package is ``bl_ext.<repo>.facecap``; outside it is ``facecap``
(``pip install -e .``). Only registration lives here: the settings first, then the operators that
read them, then the panels that draw both. The Blender layer is imported lazily so that
``import facecap.solvers`` never pulls in ``bpy``.
"""


def register():
    from . import operators  # bpy: only when Blender registers the add-on
    from .facecap_addon import registration  # bpy

    registration.register_properties()
    operators.register()
    registration.register_panels()


def unregister():
    from . import operators  # bpy: only when Blender registers the add-on
    from .facecap_addon import registration  # bpy

    registration.unregister_panels()
    operators.unregister()
    registration.unregister_properties()
