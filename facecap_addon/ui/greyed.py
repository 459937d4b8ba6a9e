"""Why a sidebar button is greyed out: each operator's ``poll`` names what it needs, and the first need not met
becomes the button's tooltip (``poll_message_set``, Blender 3.0 on), so an artist reads "Pick the Character
first" instead of guessing. The same words end the error of a script that calls the operator anyway."""

from ..scene import tuning_scene

#: What a button may need: (does the scene have it?, what to do when it does not). ``s`` is ``Scene.facecap``.
NEEDS = {
    "character": (lambda s: s.target is not None,
                  "Pick the Character first (Take panel): the mesh with shape keys the take drives"),
    "shape keys": (lambda s: _shape_keys(s) is not None,
                   "The Character has no shape keys: pick the mesh that has them (Take panel)"),
    "take": (lambda s: s.marker_collection is not None,
             "Bring in a take first (Take panel): Import Markers, Selected Empties or Clip Tracks"),
    "take or weights": (lambda s: s.marker_collection is not None or s.strategy == "parallel",
                        "Bring in a take first (Take panel: Import Markers), or choose the Parallel strategy to "
                        "solve from phone weights"),
    "stable set": (lambda s: s.auto_stable or sum(m.stable for m in s.markers) >= 3,
                   "Tick at least 3 stable markers or Suggest Stable Markers (Stabilise panel)"),
    "solve": (lambda s: tuning_scene.solved(s),  # on the shape keys, or on the rig's controls with a rig preset
              "Solve and Key first: there is no solve on the Character (or its rig) yet"),
    "tuning frames": (lambda s: len(s.tuning_frames) > 0,
                      "Add corrected frames first: Add Current Frame or Add Edited Frames (Tune panel)"),
    "shapes": (lambda s: len(s.shapes) > 0, "Refresh Shapes first (Solve panel: Shapes)"),
    "mapping strategy": (lambda s: s.strategy in ("calibrated", "refine", "parallel"),
                         "Only the Calibrated, Refine and Parallel strategies map channels to shapes"),
}


def _shape_keys(s):
    return getattr(getattr(s.target, "data", None), "shape_keys", None)


def needs(cls, context, *names):
    """``poll`` for an operator that needs each of ``names`` (keys of ``NEEDS``): True when the scene has them
    all; else False with the first missing one's advice as the greyed button's tooltip."""
    s = context.scene.facecap
    for name in names:
        ok, advice = NEEDS[name]
        if not ok(s):
            cls.poll_message_set(advice)
            return False
    return True


def unless(cls, condition, advice):
    """``poll`` for a need of one operator's own: ``condition``, or False with ``advice`` as the tooltip."""
    if not condition:
        cls.poll_message_set(advice)
    return bool(condition)
