"""MediaPipe's face mesh, run frame by frame in OpenCV's DNN module (models: ``face_models``).

The pipeline is MediaPipe's own (``face_landmark_front_cpu`` with the iris refinement):

1. **detect** (only when no face is being followed): BlazeFace on the whole frame letterboxed to
   128x128, 896 SSD anchors, scores through a sigmoid, the best face by weighted non-maximum
   suppression; its region is the box around the eyes' line, 1.5 times larger, square.
2. **mesh**: the region, rotated so the eyes are level, resampled to 192x192; 468 points (x, y and a
   depth z on the same scale as x) and a face-presence score. The next frame's region is the box of
   these points (rotated by the eye corners 33 -> 263), 1.5 times larger: the face is followed without
   detecting it again until the score drops below ``presence``.
3. **iris**: each eye's region (its two corners, 2.3 times wider, square; the subject's left eye
   mirrored, as the model expects) resampled to 64x64 gives 71 eyelid and brow points, which replace
   the mesh's own around that eye (x and y; the mesh's depth is kept), and 5 iris points (centre
   first; their depth relative to the eyelids).

Points are in the frame's pixels (origin top-left); z is relative to the face (negative: towards the
camera), in pixels like x.
"""

from dataclasses import dataclass

import numpy as np

from .face_models import load_networks
from .reading import opencv

N_MESH = 468
N_POINTS = 478  # the mesh, then 5 iris points of the subject's right eye and 5 of the left (MediaPipe's order)

# The mesh indices the 71 eyelid / brow points of the iris model replace, per eye (MediaPipe's
# UpdateFaceLandmarksCalculator): the subject's right eye (corners 33, 133), then the left (362, 263).
EYE_CONTOUR = (
    (33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173, 130, 25, 110, 24, 23, 22, 26, 112,
     243, 247, 30, 29, 27, 28, 56, 190, 226, 31, 228, 229, 230, 231, 232, 233, 244, 113, 225, 224, 223, 222, 221,
     189, 35, 124, 46, 53, 52, 65, 143, 111, 117, 118, 119, 120, 121, 128, 245, 156, 70, 63, 105, 66, 107, 55, 193),
    (263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398, 359, 255, 339, 254, 253, 252,
     256, 341, 463, 467, 260, 259, 257, 258, 286, 414, 446, 261, 448, 449, 450, 451, 452, 453, 464, 342, 445, 444,
     443, 442, 441, 413, 265, 353, 276, 283, 282, 295, 372, 340, 346, 347, 348, 349, 350, 357, 465, 383, 300, 293,
     334, 296, 336, 285, 417),
)
EYE_CORNERS = ((33, 133), (362, 263))  # start -> end of each eye's region (the second eye is mirrored)
DETECT_SIZE, MESH_SIZE, IRIS_SIZE = 128, 192, 64


def anchors():
    """(896, 2) anchor centres of the short-range detector (strides 8 and 16; 2 and 6 per cell)."""
    out = []
    for stride, per_cell in ((8, 2), (16, 6)):
        n = DETECT_SIZE // stride
        ys, xs = np.mgrid[0:n, 0:n]
        centres = np.stack([(xs + 0.5) / n, (ys + 0.5) / n], axis=-1).reshape(-1, 2)
        out.append(np.repeat(centres, per_cell, axis=0))
    return np.concatenate(out)


@dataclass(frozen=True)
class Region:
    """A square region of the frame: centre (pixels), side (pixels), rotation (radians, y down)."""

    cx: float
    cy: float
    size: float
    angle: float

    def to_frame(self, uv, side):
        """Points ``uv`` (..., 2) of the ``side`` x ``side`` crop -> frame pixels."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        d = (np.asarray(uv, np.float64) / side - 0.5) * self.size
        return np.stack([self.cx + c * d[..., 0] - s * d[..., 1], self.cy + s * d[..., 0] + c * d[..., 1]], -1)

    def crop(self, image, side, *, mirror=False):
        """The region resampled to ``side`` x ``side`` (edges replicated), mirrored left-right if asked."""
        cv2 = opencv()
        c, s = np.cos(self.angle), np.sin(self.angle)
        k = self.size / side
        ax = np.array([c, s]) * k * (-1.0 if mirror else 1.0)  # frame step per crop column
        ay = np.array([-s, c]) * k  # per crop row
        origin = np.array([self.cx, self.cy]) - (ax + ay) * (side / 2 - 0.5)
        m = np.array([[ax[0], ay[0], origin[0]], [ax[1], ay[1], origin[1]]])
        return cv2.warpAffine(image, m, (side, side), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderMode=cv2.BORDER_REPLICATE)


def region_around(points, start, end, scale):
    """The square region of ``points`` (N, 2): their box's centre, ``scale`` x its longer side, rotated
    so ``start`` -> ``end`` is level (MediaPipe's DetectionsToRects + RectTransformation)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    d = np.asarray(end, float) - np.asarray(start, float)
    return Region(float(lo[0] + hi[0]) / 2, float(lo[1] + hi[1]) / 2, float(max(hi - lo)) * scale,
                  float(np.arctan2(d[1], d[0])))


@dataclass(frozen=True)
class FaceFrame:
    """One frame's face: ``points`` (478, 3) pixels (x, y, z) or None, ``presence`` the mesh model's
    face score in [0, 1], ``detected``: the detector ran on this frame (no face was being followed)."""

    points: np.ndarray
    presence: float
    detected: bool


class FaceMesh:
    """Follows one face through frames: ``FaceMesh()(frame_bgr) -> FaceFrame``.

    ``presence``: the mesh score below which the face counts as lost (the frame is a gap and the next
    one detects again); ``min_detection``: the detector's score threshold. ``iris``: run the iris
    model (eyelids and gaze); without it the iris points are the mean of each eye's contour.
    """

    def __init__(self, *, models=None, presence=0.5, min_detection=0.5, iris=True):
        self.nets = load_networks(models)
        self.presence, self.min_detection, self.iris = float(presence), float(min_detection), bool(iris)
        self.anchors = anchors()
        self.region = None  # the region followed from the last frame

    def reset(self):
        """Forget the followed face (the next frame detects)."""
        self.region = None

    def __call__(self, image):
        """``image``: (H, W, 3) BGR uint8 (a grey (H, W) frame is used as it is, in three channels)."""
        face, rgb = self.follow(image)
        if face.points is not None:
            self.finish(rgb, face.points)
        return face

    def follow(self, image):
        """The face mesh of ``image`` (detected when none is followed), eyes not refined yet:
        ``(FaceFrame, the RGB frame for`` :meth:`finish` ``)``. The next frame's region comes from this
        mesh, so :meth:`finish` of this frame can run beside :meth:`follow` of the next."""
        rgb = self._rgb(image)
        detected = self.region is None
        if detected:
            self.region = self.detect(rgb)
            if self.region is None:
                return FaceFrame(None, 0.0, True), rgb
        points, presence = self.mesh(rgb, self.region)
        if presence < self.presence:
            self.region = None
            return FaceFrame(None, presence, detected), rgb
        self.region = region_around(points[:N_MESH, :2], points[33, :2], points[263, :2], 1.5)
        return FaceFrame(points, presence, detected), rgb

    def finish(self, rgb, points):
        """Eyelids and irises of a followed face's ``points`` (in place): the iris model, or without it
        the middle of each eye's lids."""
        if self.iris:
            self.refine_eyes(rgb, points)
        else:
            for k, contour in enumerate(EYE_CONTOUR):
                points[N_MESH + 5 * k: N_MESH + 5 * k + 5] = points[list(contour[:16])].mean(axis=0)

    @staticmethod
    def _rgb(image):
        cv2 = opencv()
        if image.ndim == 2:
            return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[2] == 4 else cv2.COLOR_BGR2RGB)

    def _run(self, role, tensor):
        net = self.nets[role]
        net.setInput(np.ascontiguousarray(tensor.transpose(2, 0, 1)[None], dtype=np.float32))
        return [o.reshape(-1) for o in net.forward(net.getUnconnectedOutLayersNames())]

    def detect(self, rgb):
        """The best face's :class:`Region`, or None."""
        cv2 = opencv()
        h, w = rgb.shape[:2]
        k = DETECT_SIZE / max(h, w)
        sw, sh = max(1, round(w * k)), max(1, round(h * k))
        board = np.zeros((DETECT_SIZE, DETECT_SIZE, 3), np.float32)
        px, py = (DETECT_SIZE - sw) // 2, (DETECT_SIZE - sh) // 2
        board[py: py + sh, px: px + sw] = cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_AREA) / 127.5 - 1.0
        outs = self._run("detector", board)
        scores_raw, boxes = (outs[0], outs[1]) if outs[0].size == len(self.anchors) else (outs[1], outs[0])
        boxes = boxes.reshape(len(self.anchors), 16) / DETECT_SIZE
        scores = 1.0 / (1.0 + np.exp(-np.clip(scores_raw.astype(np.float64), -100, 100)))
        keep = scores >= self.min_detection
        if not keep.any():
            return None
        a = self.anchors[keep]
        b, s = boxes[keep], scores[keep]
        centre = b[:, :2] + a
        half = b[:, 2:4] / 2
        keys = b[:, 4:].reshape(-1, 6, 2) + a[:, None, :]
        best = int(np.argmax(s))
        lo, hi = centre - half, centre + half
        inter = np.prod(np.clip(np.minimum(hi, hi[best]) - np.maximum(lo, lo[best]), 0, None), axis=1)
        union = np.prod(hi - lo, axis=1) + np.prod(hi[best] - lo[best]) - inter
        group = inter / np.maximum(union, 1e-12) > 0.3  # weighted NMS: the best face's overlapping boxes
        wts = s[group] / s[group].sum()
        to_px = np.array([DETECT_SIZE, DETECT_SIZE]) / k
        shift = np.array([px, py]) / k
        box_c = wts @ centre[group] * to_px - shift
        box_wh = wts @ (2 * half[group]) * to_px
        eyes = np.einsum("g,gkd->kd", wts, keys[group]) * to_px - shift
        d = eyes[1] - eyes[0]  # the subject's right eye -> left eye
        return Region(float(box_c[0]), float(box_c[1]), float(max(box_wh)) * 1.5, float(np.arctan2(d[1], d[0])))

    def mesh(self, rgb, region):
        """((478, 3) points with the mesh filled in, presence score) in ``region``."""
        crop = region.crop(rgb, MESH_SIZE).astype(np.float32) / 255.0
        outs = self._run("mesh", crop)
        raw, flag = (outs[0], outs[1]) if outs[0].size == 3 * N_MESH else (outs[1], outs[0])
        raw = raw.reshape(N_MESH, 3)
        points = np.zeros((N_POINTS, 3))
        points[:N_MESH, :2] = region.to_frame(raw[:, :2], MESH_SIZE)
        points[:N_MESH, 2] = raw[:, 2] / MESH_SIZE * region.size
        return points, float(1.0 / (1.0 + np.exp(-np.clip(float(flag[0]), -100, 100))))

    def refine_eyes(self, rgb, points):
        """Eyelids (71 points per eye) and irises (5 per eye) from the iris model, in place."""
        for k, ((i0, i1), contour) in enumerate(zip(EYE_CORNERS, EYE_CONTOUR)):
            mirror = k == 1
            p0, p1 = points[i0, :2], points[i1, :2]
            region = region_around(np.stack([p0, p1]), p0, p1, 2.3)
            crop = region.crop(rgb, IRIS_SIZE, mirror=mirror).astype(np.float32) / 255.0
            outs = self._run("iris", crop)
            eye, iris = (outs[0], outs[1]) if outs[0].size == 213 else (outs[1], outs[0])
            eye, iris = eye.reshape(71, 3), iris.reshape(5, 3)
            lids = list(contour[:16])
            lid_depth = points[lids, 2].mean()  # the mesh's depth, kept: the iris model's is relative to its crop
            for pts, rows, depth in ((eye, list(contour), None), (iris, slice(N_MESH + 5 * k, N_MESH + 5 * k + 5),
                                                                   lid_depth)):
                uv = pts[:, :2].copy()
                if mirror:
                    uv[:, 0] = IRIS_SIZE - uv[:, 0]
                points[rows, :2] = region.to_frame(uv, IRIS_SIZE)
                if depth is not None:
                    points[rows, 2] = depth + (pts[:, 2] - eye[:16, 2].mean()) / IRIS_SIZE * region.size
