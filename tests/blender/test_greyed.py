"""A greyed-out sidebar button says why (issue 40: *Solve and Key* was greyed with no reason): every FaceCap
operator that cannot run in a scene names what is missing, the first thing to do first (``poll_message_set``:
the button's tooltip, and the error a script calling it anyway gets)."""

import bpy
import pytest

from test_operators import _import, take  # noqa: F401  (fixture)


def _why(call):
    with pytest.raises(RuntimeError) as exc:
        call()
    return str(exc.value)


def facecap_operators():
    return sorted(name for name in dir(bpy.ops.facecap) if not name.startswith("_"))


def test_every_operator_greyed_out_in_an_empty_scene_says_why(empty_scene):
    silent = []
    for name in facecap_operators():
        op = getattr(bpy.ops.facecap, name)
        if op.poll():
            continue
        message = _why(op)
        if message.endswith("poll() failed, context is incorrect"):  # Blender's words when poll gives none
            silent.append(name)
    assert silent == [], f"greyed out with no reason: {silent}"


def test_solve_and_key_says_what_to_do_first_step_by_step(take):
    s = bpy.context.scene.facecap
    assert s.target is None
    assert "Pick the Character first (Take panel)" in _why(bpy.ops.facecap.solve)
    s.target = take["obj"]
    assert "Bring in a take first (Take panel: Import Markers)" in _why(bpy.ops.facecap.solve)
    _import(take)
    for m in s.markers:
        m.stable = False
    s.auto_stable = False
    assert "Tick at least 3 stable markers or Suggest Stable Markers" in _why(bpy.ops.facecap.stabilise)
    assert "Solve and Key first" in _why(bpy.ops.facecap.retune)
