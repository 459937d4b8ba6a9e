"""Reading footage through OpenCV: video files (mp4, mov, avi, mkv) and image sequences.

Frames come out as 8-bit grayscale arrays (tracking and flow work on luminance), or BGR with
``color=True`` (face landmarks). Frame numbers
follow the project's one convention: **frame 1 is the first frame of the footage**, as in Blender
and in marker files (video: position in the file + 1; image sequence: number in the file name minus
the first file's number + 1, so a missing file stays a missing frame), plus ``frame_offset``.
``scale`` < 1 downsamples for speed; :class:`FootageInfo` keeps both the source
and the working resolution so results can be reported in source pixels.
"""

import glob
import os
import queue
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import Cancelled, FacecapError, InputFileError, needs  # Cancelled: video's callers import it here
from ..io.limits import check_input_file

VIDEO_EXTENSIONS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv")
PREFETCH = 8  # frames decoded ahead by the reader thread
#: Largest video file (or image of a sequence) opened, bytes: far beyond any face take's footage
MAX_VIDEO_BYTES = 1 << 40
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr", ".webp", ".pgm", ".ppm")


@dataclass(frozen=True)
class FootageInfo:
    """What was read and how.

    ``width``/``height`` are the source resolution, ``work_width``/``work_height`` the resolution
    of the frames handed out (after ``scale``). ``frames`` are the frame numbers that will be read.
    """

    path: str
    kind: str  # "video" or "images"
    fps: float
    width: int
    height: int
    scale: float
    work_width: int
    work_height: int
    frames: tuple

    @property
    def n_frames(self):
        return len(self.frames)


def opencv():
    """OpenCV (Blender has it only from the extension zip)."""
    with needs("cv2", "Video input (tracking, flow)"):
        import cv2  # OpenCV: imported on first use
    return cv2


def report_progress(progress, done, total, what="frames"):
    """Call ``progress(done, total)``; a False return cancels with :class:`Cancelled`."""
    if progress is not None and progress(done, total) is False:
        raise Cancelled(f"cancelled after {done} of {total} {what}")


class Job:
    """Long work that advances a frame at a time and can stop between frames.

    ``steps`` is a generator that yields the frame number after each processed frame (``None``
    for a frame only read, e.g. cached for the backward pass) and returns the result. Blender's
    modal operators call :meth:`step` from a timer; :meth:`run` goes to the end with a progress
    callback (the CLI, ``bpy.ops`` in background mode). Nothing is written by a job: callers
    write the result, so a cancelled job leaves no partial output.
    """

    def __init__(self, steps, total, *, info=None, what="frames"):
        self._steps = steps
        self.info = info  # FootageInfo of what is read
        self.total = int(total)
        self.what = what
        self.done = 0  # frames processed
        self.frame = None  # last frame number processed
        self.result = None
        self.cancelled = False

    @property
    def finished(self):
        return self.result is not None

    def then(self, finish):
        """This job, its result passed through ``finish`` when the last step ends."""
        steps = self._steps

        def finishing():
            return finish((yield from steps))

        self._steps = finishing()
        return self

    @property
    def fraction(self):
        return self.done / max(self.total, 1)

    def step(self, max_frames=1, *, seconds=None):
        """Process up to ``max_frames`` frames (or until ``seconds`` have passed); True when finished."""
        if self.cancelled:
            raise Cancelled(f"cancelled at frame {self.frame}")
        if self.result is not None:
            return True
        end = None if seconds is None else time.perf_counter() + float(seconds)
        count = 0
        while count < max_frames or (end is not None and time.perf_counter() < end):
            try:
                frame = next(self._steps)
            except StopIteration as stop:
                self.result = stop.value
                return True
            if frame is not None:
                self.done += 1
                self.frame = frame
                count += 1
        return False

    def cancel(self):
        """Stop: close the generator (and with it the footage reader). Safe to call twice."""
        if self.result is None and not self.cancelled:
            self.cancelled = True
            self._steps.close()

    def message(self):
        """``"cancelled at frame N (k of T frames)"``."""
        return f"cancelled at frame {self.frame} ({self.done} of {self.total} {self.what} done)"

    def run(self, progress=None):
        """Run to the end; ``progress(done, total)`` returning False cancels with :class:`Cancelled`."""
        try:
            while not self.step():
                if progress is not None and progress(self.done, self.total) is False:
                    self.cancel()
                    raise Cancelled(self.message())
        except BaseException:
            self.cancel()
            raise
        return self.result


class Footage:
    """Frames of a video file or an image sequence, read lazily.

    Parameters
    ----------
    source : str or Path
        A video file, a folder of images, a glob (``shots/img_*.png``) or a printf pattern
        (``shots/img_%04d.png``).
    first, last : int, optional
        Inclusive frame-number range to read (default: everything).
    step : int
        Read every ``step``-th frame.
    scale : float
        Downscale factor in (0, 1]; frames are resized with area interpolation.
    fps : float, optional
        Frame rate for image sequences (default 24), or to override a video's.
    frame_offset : int
        Added to every frame number (default 0: the first frame is frame 1). The add-on passes
        ``clip.frame_start - 1`` so frame numbers are scene frames.
    color : bool
        Hand out (H, W, 3) BGR frames instead of grey ones (face landmarks need colour).
    """

    def __init__(self, source, *, first=None, last=None, step=1, scale=1.0, fps=None, frame_offset=0, color=False):
        self.cv2 = opencv()
        self.color = bool(color)
        self.path = Path(source)
        if int(step) != step or step < 1:
            raise FacecapError(f"`step` must be a positive integer; got {step}")
        if not (0 < float(scale) <= 1.0):
            raise FacecapError(f"`scale` must be in (0, 1]; got {scale}")
        if fps is not None and not (np.isfinite(fps) and fps > 0):
            raise FacecapError(f"`fps` must be positive; got {fps}")
        self.step, self.scale, self.frame_offset = int(step), float(scale), int(frame_offset)
        self._images = None
        if self._is_image_source():
            self._open_images()
            native_fps = 24.0
            kind = "images"
        else:
            native_fps, kind = self._open_video(), "video"
        all_frames = self._all_frames()
        lo = all_frames[0] if first is None else int(first)
        hi = all_frames[-1] if last is None else int(last)
        if lo > hi:
            raise FacecapError(f"{self.path}: first frame {lo} is after last frame {hi}")
        chosen = [f for f in all_frames if lo <= f <= hi][:: self.step]
        if not chosen:
            raise InputFileError(self.path, f"no frames in range {lo}..{hi} "
                                 f"(the footage has {all_frames[0]}..{all_frames[-1]})")
        ww = max(1, int(round(self._width * self.scale)))
        wh = max(1, int(round(self._height * self.scale)))
        self.info = FootageInfo(str(self.path), kind, float(fps or native_fps), self._width, self._height,
                                self.scale, ww, wh, tuple(chosen))

    # -- opening -------------------------------------------------------------------------------
    def _is_image_source(self):
        text = str(self.path)
        return self.path.is_dir() or "%" in text or any(c in text for c in "*?[") or \
            self.path.suffix.lower() in IMAGE_EXTENSIONS

    def _open_images(self):
        text = str(self.path)
        if self.path.is_dir():
            files = [p for p in sorted(self.path.iterdir()) if p.suffix.lower() in IMAGE_EXTENSIONS]
        elif "%" in text:
            rx = re.escape(text)
            rx = re.sub(r"%0?(\d*)d", lambda m: r"(\d+)", rx.replace(r"\%", "%"))
            files = [Path(p) for p in sorted(glob.glob(re.sub(r"%0?\d*d", "*", text))) if re.fullmatch(rx, p)]
        elif any(c in text for c in "*?["):
            files = [Path(p) for p in sorted(glob.glob(text))]
        else:
            if not self.path.exists():
                raise InputFileError(self.path, "file not found")
            files = [self.path]
        files = [p for p in files if p.suffix.lower() in IMAGE_EXTENSIONS]
        if not files:
            raise InputFileError(self.path, "no image files match")
        numbers = [_trailing_number(p.stem) for p in files]
        if None in numbers or len(set(numbers)) != len(numbers):
            numbers = list(range(len(files)))
        order = np.argsort(numbers, kind="stable")
        base = 1 - min(numbers) + self.frame_offset  # the first file is frame 1
        self._images = {numbers[i] + base: files[i] for i in order}
        first = self._read_image(files[order[0]])
        self._height, self._width = first.shape[:2]

    def _open_video(self):
        cv2 = self.cv2
        if not self.path.exists():
            raise InputFileError(self.path, "file not found")
        if self.path.is_dir():
            raise InputFileError(self.path, "is a directory with no images")
        check_input_file(self.path, limit=MAX_VIDEO_BYTES)  # not a FIFO or a device: OpenCV would wait on it
        cap = cv2.VideoCapture(str(self.path))
        ok = cap.isOpened()
        ok_frame = ok and cap.read()[0]
        if not ok_frame:
            cap.release()
            raise InputFileError(self.path, "cannot decode as video (unsupported codec or not a video file)")
        self._width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        self._height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        fps = cap.get(cv2.CAP_PROP_FPS)
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        cap.release()
        if count <= 0:  # some containers do not say: count by decoding
            cap = cv2.VideoCapture(str(self.path))
            count = 0
            while cap.grab():
                count += 1
            cap.release()
        self._count = count
        return float(fps) if fps and np.isfinite(fps) and fps > 0 else 24.0

    def _all_frames(self):
        if self._images is not None:
            return sorted(self._images)
        return [i + 1 + self.frame_offset for i in range(self._count)]

    def _read_image(self, path):
        check_input_file(path, limit=MAX_VIDEO_BYTES)
        img = self.cv2.imread(str(path), self.cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputFileError(path, "cannot read as an image")
        return img

    # -- frames --------------------------------------------------------------------------------
    def _prepare(self, img, where):
        cv2 = self.cv2
        if self.color:
            if img.ndim == 2:
                img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
            elif img.shape[2] == 4:
                img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
        elif img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
        if img.dtype != np.uint8:
            if img.dtype.kind == "f":
                img = np.clip(img * 255.0, 0, 255)
            else:
                img = img / (np.iinfo(img.dtype).max / 255.0)
            img = img.astype(np.uint8)
        if img.shape[:2] != (self._height, self._width):
            raise InputFileError(where, f"frame size {img.shape[1]}x{img.shape[0]} differs from "
                                        f"{self._width}x{self._height}")
        if self.scale != 1.0:
            img = cv2.resize(img, (self.info.work_width, self.info.work_height), interpolation=cv2.INTER_AREA)
        return img

    def __len__(self):
        return self.info.n_frames

    def __iter__(self):
        """Yield ``(frame_number, gray uint8 image)`` for every chosen frame.

        Frames are decoded by a background thread a few frames ahead (OpenCV releases the GIL while
        decoding), so decoding overlaps with whatever the caller does with each frame.
        """
        q = queue.Queue(maxsize=PREFETCH)
        stop = threading.Event()
        done = object()

        def produce():
            try:
                for item in self._frames():
                    while not stop.is_set():
                        try:
                            q.put(item, timeout=0.1)
                            break
                        except queue.Full:
                            continue
                    if stop.is_set():
                        return
                q.put(done)
            except BaseException as exc:  # handed to the consumer, raised there
                q.put(exc)

        worker = threading.Thread(target=produce, name="facecap-decode", daemon=True)
        worker.start()
        try:
            while True:
                item = q.get()
                if item is done:
                    return
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            stop.set()
            while worker.is_alive():
                try:
                    q.get_nowait()
                except queue.Empty:
                    worker.join(0.05)

    def _frames(self):
        if self._images is not None:
            for f in self.info.frames:
                yield f, self._prepare(self._read_image(self._images[f]), self._images[f])
            return
        cv2 = self.cv2
        wanted = set(self.info.frames)
        last = self.info.frames[-1]
        cap = cv2.VideoCapture(str(self.path))
        try:
            first_index = self.info.frames[0] - 1 - self.frame_offset  # 0-based position in the file
            if first_index > 0:
                cap.set(cv2.CAP_PROP_POS_FRAMES, first_index)
                pos = int(cap.get(cv2.CAP_PROP_POS_FRAMES))
                if pos != first_index:  # container cannot seek exactly: decode from the start
                    cap.release()
                    cap = cv2.VideoCapture(str(self.path))
                    first_index = 0
            f = first_index + 1 + self.frame_offset
            while f <= last:
                if f in wanted:
                    ok, img = cap.read()
                    if not ok:
                        raise InputFileError(self.path, f"cannot decode frame {f}")
                    yield f, self._prepare(img, self.path)
                elif not cap.grab():
                    raise InputFileError(self.path, f"cannot decode frame {f}")
                f += 1
        finally:
            cap.release()

    def frame(self, number):
        """One frame by number (must be in the footage, not necessarily in the chosen range)."""
        if self._images is not None:
            if number not in self._images:
                raise FacecapError(f"{self.path}: no frame {number}")
            return self._prepare(self._read_image(self._images[number]), self._images[number])
        index = int(number) - 1 - self.frame_offset  # 0-based position in the file
        if not 0 <= index < self._count:
            raise FacecapError(f"{self.path}: no frame {number} (the video has frames "
                               f"{1 + self.frame_offset}..{self._count + self.frame_offset}; frame 1 is the first)")
        cap = self.cv2.VideoCapture(str(self.path))
        try:
            cap.set(self.cv2.CAP_PROP_POS_FRAMES, index)
            if int(cap.get(self.cv2.CAP_PROP_POS_FRAMES)) != index:
                cap.release()
                cap = self.cv2.VideoCapture(str(self.path))
                for _ in range(index):
                    cap.grab()
            ok, img = cap.read()
            if not ok:
                raise InputFileError(self.path, f"cannot decode frame {number}")
            return self._prepare(img, self.path)
        finally:
            cap.release()

    def read_all(self, *, progress=None):
        """All chosen frames as ``(frames (F,), images (F, H, W) uint8)``."""
        frames, images = [], []
        total = len(self)
        for i, (f, img) in enumerate(self):
            frames.append(f)
            images.append(img)
            report_progress(progress, i + 1, total)
        return np.asarray(frames, dtype=np.float64), np.stack(images)


def open_footage(source, **options):
    """A :class:`Footage` for ``source`` (see its parameters)."""
    return Footage(source, **options)


def _trailing_number(stem):
    m = re.search(r"(\d+)(?!.*\d)", stem)
    return None if m is None else int(m.group(1))


def write_video(path, images, *, fps=30.0, codec=None):
    """Write grayscale or BGR uint8 ``images`` (F, H, W[, 3]) as a video file; returns the codec used.

    ``codec`` defaults to lossless FFV1 for .avi/.mkv (falls back to MJPG if the build lacks it)
    and mp4v for .mp4/.mov.
    """
    cv2 = opencv()
    path = Path(path)
    images = np.asarray(images)
    if images.ndim not in (3, 4) or images.dtype != np.uint8:
        raise FacecapError(f"`images` must be uint8 of shape (F, H, W[, 3]); got {images.dtype} {images.shape}")
    color = images.ndim == 4
    h, w = images.shape[1:3]
    if codec is None:
        candidates = ["mp4v"] if path.suffix.lower() in (".mp4", ".mov", ".m4v") else ["FFV1", "MJPG"]
    else:
        candidates = [codec]
    os.makedirs(path.parent, exist_ok=True)
    for cc in candidates:
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*cc), float(fps), (w, h), color)
        if writer.isOpened():
            break
    else:
        raise FacecapError(f"{path}: this OpenCV build cannot write {', '.join(candidates)}")
    try:
        for img in images:
            writer.write(img)
    finally:
        writer.release()
    return cc
