# SPDX-License-Identifier: GPL-3.0-or-later
"""FaceCap: performance-driven facial retargeting for Blender.

Inside Blender this package is ``bl_ext.<repo>.facecap``; outside it is ``facecap``
(``pip install -e .``). Only registration lives here, and it imports the Blender layer
lazily so that ``import facecap.solvers`` never pulls in ``bpy``.
"""


def register():
    from .facecap_addon import registration

    registration.register()


def unregister():
    from .facecap_addon import registration

    registration.unregister()
