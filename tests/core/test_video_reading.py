"""Footage reading: real video files and image sequences, ranges, downscale, progress and errors."""

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from facecap.solvers import FacecapError, InputFileError  # noqa: E402
from facecap.solvers.video.reading import Cancelled, Footage, write_video  # noqa: E402


def numbered_frames(n=12, w=64, h=48):
    """Frames whose top-left pixel encodes the frame number (robust to codec loss in flat areas)."""
    out = np.zeros((n, h, w), np.uint8)
    for i in range(n):
        out[i] = 10 + 20 * i
    return out


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    d = tmp_path_factory.mktemp("footage")
    frames = numbered_frames()
    paths = {}
    for name in ("lossless.avi", "mjpg.avi", "clip.mp4"):
        codec = "MJPG" if name == "mjpg.avi" else None
        write_video(d / name, frames, fps=25.0, codec=codec)
        paths[name] = d / name
    seq = d / "seq"
    seq.mkdir()
    for i, img in enumerate(frames):
        cv2.imwrite(str(seq / f"img_{i + 101:04d}.png"), img)
    paths["seq"] = seq
    return paths


def level(img):
    return (float(img.mean()) - 10) / 20


@pytest.mark.parametrize("name", ["lossless.avi", "mjpg.avi", "clip.mp4"])
def test_video_files_carry_fps_resolution_and_frames(clips, name):
    fo = Footage(clips[name])
    assert (fo.info.fps, fo.info.width, fo.info.height, fo.info.kind) == (25.0, 64, 48, "video")
    assert fo.info.frames == tuple(range(1, 13))  # frame 1 is the first frame, as in Blender
    frames, imgs = fo.read_all()
    assert imgs.shape == (12, 48, 64) and imgs.dtype == np.uint8
    assert [round(level(i)) for i in imgs] == list(range(12))


def test_range_step_scale_and_seek(clips):
    fo = Footage(clips["lossless.avi"], first=3, last=10, step=3, scale=0.5, frame_offset=1)
    assert fo.info.frames == (3, 6, 9)  # frame numbers = position in the file + 1 + offset
    assert (fo.info.work_width, fo.info.work_height) == (32, 24)
    got = [(f, round(level(img))) for f, img in fo]
    assert got == [(3, 1), (6, 4), (9, 7)]
    assert round(level(fo.frame(11))) == 9
    plain = Footage(clips["lossless.avi"], first=3, last=3)
    assert [(f, round(level(img))) for f, img in plain] == [(3, 2)]  # the third frame
    assert round(level(plain.frame(1))) == 0 and round(level(plain.frame(12))) == 11


@pytest.mark.parametrize("pattern", ["seq", "seq/img_%04d.png", "seq/img_*.png"])
def test_image_sequences_by_folder_printf_or_glob(clips, pattern):
    src = clips["seq"].parent / pattern
    fo = Footage(src, fps=30, first=5)
    assert fo.info.kind == "images" and fo.info.fps == 30.0
    assert fo.info.frames == tuple(range(5, 13))  # img_0101.png is frame 1: the first file, as in Blender
    assert [round(level(img)) for _, img in fo] == list(range(4, 12))


def test_progress_reports_and_cancels(clips):
    seen = []
    Footage(clips["lossless.avi"]).read_all(progress=lambda d, t: seen.append((d, t)))
    assert seen[0] == (1, 12) and seen[-1] == (12, 12)
    with pytest.raises(Cancelled, match="cancelled after 3 of 12"):
        Footage(clips["lossless.avi"]).read_all(progress=lambda d, t: d < 3)
    assert issubclass(Cancelled, FacecapError)


def test_unreadable_inputs_raise_input_file_errors(tmp_path, clips):
    with pytest.raises(InputFileError, match="file not found"):
        Footage(tmp_path / "missing.mp4")
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    with pytest.raises(InputFileError, match="cannot decode as video"):
        Footage(bad)
    with pytest.raises(InputFileError, match="no image files match"):
        Footage(tmp_path / "nothing_*.png")
    with pytest.raises(InputFileError, match=r"no frames in range 50\.\.60"):
        Footage(clips["lossless.avi"], first=50, last=60)
    with pytest.raises(FacecapError, match="`scale` must be in"):
        Footage(clips["lossless.avi"], scale=2)
    with pytest.raises(FacecapError, match=r"no frame 99 \(the video has frames 1\.\.12; frame 1 is the first\)"):
        Footage(clips["lossless.avi"]).frame(99)
    with pytest.raises(FacecapError, match="no frame 0"):
        Footage(clips["lossless.avi"]).frame(0)
