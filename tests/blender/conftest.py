"""Blender test fixtures: an isolated user folder, the add-on registered once, a fresh scene per test."""

import atexit
import os
import shutil
import tempfile

# Point Blender's user folders at a temporary directory *before* bpy is imported.
_USER = tempfile.mkdtemp(prefix="facecap-blender-user-")
atexit.register(shutil.rmtree, _USER, ignore_errors=True)
for _var in (
    "BLENDER_USER_RESOURCES",
    "BLENDER_USER_CONFIG",
    "BLENDER_USER_SCRIPTS",
    "BLENDER_USER_EXTENSIONS",
    "BLENDER_USER_DATAFILES",
):
    os.environ.setdefault(_var, os.path.join(_USER, _var.lower()))

import bpy  # noqa: E402
import pytest  # noqa: E402

import facecap  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def registered_addon():
    facecap.register()
    yield
    facecap.unregister()


@pytest.fixture
def empty_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene


@pytest.fixture(autouse=True)
def renders_in_children_only():
    """The pytest process never renders (``tests/render_child.py``): one abort of software OpenGL here would end
    the whole run. Checked after each test, once its monkeypatches are undone."""
    from facecap.facecap_addon.render import render_state

    yield
    assert not render_state.STATE["rendered_here"], ("this test rendered in the pytest process: render in a forked "
                                                    "child (render_child.in_child)")
