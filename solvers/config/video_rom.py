"""``[calibration] video``: the performer's ROM filmed with the camera of a landmark take, which calibrates the
Face Landmarker's blendshape scores (``solvers/video/response.py``), and ``[calibration] sequence`` on a landmark
take without one: the take itself is the ROM. Or, with ``[calibration] guide`` instead of the sequence, the clip
follows a guide performance whose weights are known, and joins the fusion map (``solvers/video/follow.py``)."""

from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, FacecapError
from ..rom import SHEETS, sequence_poses
from .strategies import check_holds


@dataclass(frozen=True)
class VideoRom:
    """A ROM on camera: its footage ``path`` (None: the take itself), the sheet's ``poses`` and ``sheet`` (a
    built-in sheet's name, or "custom"), the frames of its neutral (first, last) if given, and ``holds``: ((pose
    label, middle frame), ...) where the user placed poses (``[calibration] holds``; None: found in the scores).
    A guide followed instead (``[calibration] guide``): ``guide`` its weights file, ``guide_start`` the clip's frame
    number where its first frame is performed (None: found), ``guide_fps`` its frame rate (None: the file's), and
    no poses."""

    path: str | None
    poses: tuple
    sheet: str
    neutral: tuple | None = None
    holds: tuple | None = None
    guide: str | None = None
    guide_start: float | None = None
    guide_fps: float | None = None


def video_rom(path, data, video):
    """The take's VideoRom or None, from the parsed TOML ``data`` of a take whose video part is ``video`` (a
    LandmarkTake, another video take or None). On a landmark take ``[calibration] sequence`` is the ROM on
    camera's sheet and is taken out of ``data`` (the semantic solve's marker ROM does not look for it in the
    landmarks)."""
    cal = data.get("calibration", {})
    landmarks = video is not None and hasattr(video, "blendshapes")

    def fail(key, message):
        raise ConfigError(message, path=path, key=key)

    if "guide" in cal:
        return _follow(path, cal, landmarks and video.blendshapes != "ignore", fail)
    if "video" not in cal:
        if not (landmarks and "sequence" in cal and "markers" not in cal) or video.blendshapes == "ignore":
            return None
        # on a landmark take the sequence is the scores' ROM: the marker ROM's hold finder does not find the poses
        # in face-mesh landmarks (3 holds for the 24 poses of a rendered facecap-24 clip, refused as ambiguous)
        sequence = cal.pop("sequence")
        poses = _poses(sequence, fail)
        return VideoRom(None, poses, _sheet(sequence), _neutral(cal), _holds(cal, poses, fail))
    if not landmarks:
        fail("calibration.video", "the ROM on camera calibrates a landmark take's blendshape scores: give [source] "
                                  "video with [tracking] method = \"landmarks\"")
    if video.blendshapes == "ignore":
        fail("calibration.video", "the ROM on camera calibrates the blendshape scores, and [tracking] blendshapes = "
                                  "\"ignore\" leaves them out")
    for other in ("markers", "poses", "basis"):
        if other in cal:
            fail(f"calibration.{other}", "give the ROM filmed ([calibration] video with sequence, its holds found "
                                         f"in the blendshape scores) or a marker calibration ({other}), not both")
    if "sequence" not in cal:
        fail("calibration.sequence", "missing: the sheet the ROM on camera performs (\"facecap-24\", \"arkit-51\" "
                                     "or a list of poses; docs/rom.md)")
    clip = _file(path, cal.pop("video"), "calibration.video", "the ROM's footage", fail)
    sequence = cal.pop("sequence")
    poses = _poses(sequence, fail)
    return VideoRom(clip, poses, _sheet(sequence), _neutral(cal), _holds(cal, poses, fail))


def _follow(path, cal, scores, fail):
    """The VideoRom of a guide followed (``[calibration] guide``, with ``video`` or the take itself)."""
    if not scores:
        fail("calibration.guide", "following a guide calibrates the fusion of a landmark take's blendshape scores: "
                                  "give [source] video with [tracking] method = \"landmarks\" and the scores fused")
    for other in ("sequence", "holds", "markers", "poses", "basis"):
        if other in cal:
            fail(f"calibration.{other}", f"give a guide followed ([calibration] guide) or {other}, not both")
    guide = _file(path, cal.pop("guide"), "calibration.guide", "the guide's weights (a Live Link Face CSV or "
                                                                "another ARKit weights file)", fail)
    clip = _file(path, cal.pop("video"), "calibration.video", "the footage", fail) if "video" in cal else None
    start = cal.pop("guide_start", None)
    if start is not None and (isinstance(start, bool) or not isinstance(start, (int, float)) or start < 1):
        fail("calibration.guide_start", f"expected the clip's frame number (1 or more) where the guide's first frame "
                                        f"is performed; got {start!r}")
    fps = cal.pop("guide_fps", None)  # its type and range checked with the other [calibration] keys
    return VideoRom(clip, (), "guide", _neutral(cal), None, guide, None if start is None else float(start),
                    None if fps is None else float(fps))


def _file(path, value, key, what, fail):
    """``value`` (a config's path string) resolved against the config's folder."""
    if not isinstance(value, str) or not value.strip():
        fail(key, f"expected a path to {what}; got {value!r}")
    value = Path(value).expanduser()
    return str(value if value.is_absolute() else (Path(path).parent / value).resolve())


def _poses(sequence, fail):
    try:
        return sequence_poses(sequence, where="")
    except FacecapError as exc:  # the key is said by fail()
        fail("calibration.sequence", str(exc).lstrip(": "))


def _holds(cal, poses, fail):
    """``[calibration] holds`` of the ROM on camera (taken out of ``cal``: the marker ROM does not read them)."""
    holds = cal.pop("holds", None)
    return None if holds is None else check_holds(holds, poses, fail)


def _sheet(sequence):
    return sequence if isinstance(sequence, str) and sequence in SHEETS else "custom"


def _neutral(cal):
    neutral = cal.get("neutral")  # checked with the other [calibration] keys
    return tuple(neutral) if isinstance(neutral, list) and len(neutral) == 2 else None
