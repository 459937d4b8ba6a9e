"""``[calibration] video``: the performer's ROM filmed with the camera of a landmark take, which calibrates the
Face Landmarker's blendshape scores (``solvers/video/response.py``), and ``[calibration] sequence`` on a landmark
take without one: the take itself is the ROM."""

from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, FacecapError
from ..rom import SHEETS, sequence_poses
from .strategies import check_holds


@dataclass(frozen=True)
class VideoRom:
    """A ROM on camera: its footage ``path`` (None: the take itself), the sheet's ``poses`` and ``sheet`` (a
    built-in sheet's name, or "custom"), the frames of its neutral (first, last) if given, and ``holds``: ((pose
    label, middle frame), ...) where the user placed poses (``[calibration] holds``; None: found in the scores)."""

    path: str | None
    poses: tuple
    sheet: str
    neutral: tuple | None = None
    holds: tuple | None = None


def video_rom(path, data, video):
    """The take's VideoRom or None, from the parsed TOML ``data`` of a take whose video part is ``video`` (a
    LandmarkTake, another video take or None). On a landmark take ``[calibration] sequence`` is the ROM on
    camera's sheet and is taken out of ``data`` (the semantic solve's marker ROM does not look for it in the
    landmarks)."""
    cal = data.get("calibration", {})
    landmarks = video is not None and hasattr(video, "blendshapes")

    def fail(key, message):
        raise ConfigError(message, path=path, key=key)

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
    clip = cal.pop("video")
    if not isinstance(clip, str) or not clip.strip():
        fail("calibration.video", f"expected a path to the ROM's footage; got {clip!r}")
    sequence = cal.pop("sequence")
    clip = Path(clip).expanduser()
    clip = clip if clip.is_absolute() else (Path(path).parent / clip).resolve()
    poses = _poses(sequence, fail)
    return VideoRom(str(clip), poses, _sheet(sequence), _neutral(cal), _holds(cal, poses, fail))


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
