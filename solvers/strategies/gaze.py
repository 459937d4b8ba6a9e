"""Gaze from eye angles: ARKit's eyeLook weights from a capture's eye rotations (Live Link Face records both).

ARKit's gaze weights are, to within its own rounding, linear in the eye angles: on the two Live Link Face
recordings in the shared corpus ``out - in`` follows the yaw with correlation 0.999 at 1.65 per radian and
``up - down`` the pitch with 0.996 at 1.79 per radian (yaw > 0: the gaze turns to the subject's right; pitch
> 0: down), plus small offsets at rest. A take that has eye angles but no gaze channels gets them from here.
"""

import numpy as np

#: ARKit gaze weight per radian of eye yaw and of eye pitch (measured, see the module docstring).
PER_RADIAN_YAW, PER_RADIAN_PITCH = 1.65, 1.79
#: What ARKit reports at zero angles (measured on the same recordings): the eyes turned in by 0.105, up by 0.036.
IN_AT_REST, UP_AT_REST = 0.105, 0.036
GAZE = ("eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeLookDownLeft",
        "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight", "eyeLookDownRight")


def gaze_from_eye_angles(eyes):
    """The eight ARKit gaze weights (F, 8) in ``GAZE`` order from eye angles (F, 6): left yaw, pitch, roll,
    right yaw, pitch, roll, in radians (Live Link Face's ``LeftEyeYaw`` ... ``RightEyeRoll``)."""
    eyes = np.asarray(eyes, dtype=np.float64)
    out = np.empty((eyes.shape[0], 8))
    for side, (yaw, pitch) in enumerate(((eyes[:, 0], eyes[:, 1]), (eyes[:, 3], eyes[:, 4]))):
        turn = PER_RADIAN_YAW * yaw * (1.0 if side else -1.0) - IN_AT_REST  # > 0: outwards (left eye: to the left)
        lift = UP_AT_REST - PER_RADIAN_PITCH * pitch  # > 0: up
        out[:, 4 * side:4 * side + 4] = np.stack([np.maximum(-turn, 0), np.maximum(turn, 0), np.maximum(lift, 0),
                                                  np.maximum(-lift, 0)], axis=1)
    return np.clip(out, 0.0, 1.0)
