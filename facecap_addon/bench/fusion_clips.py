"""The fusion benchmark's clips and what is measured on them (``fusion_bench``: the roles, how they are rendered and
what they are for): each clip's name, role and frame rate, the cached columns of a clip, the region table and the
jitter of weights, and a ROM clip's response. Shared by the benchmark and its fits (``fusion_fit``)."""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...solvers.rom import sequence_poses
from ...solvers.video.follow import fit_follow
from ...solvers.video.fusion import FaceScores, neutral_corrected
from ...solvers.video.response import fit_response, fit_weights_response, relative
from ..render.face_footage import Shot
from .landmark_bench import REGIONS

#: Frames of a relaxed face before each performance (its neutral); the judged frames start after them.
HOLD = 45
#: The ROM clips (role "calibrate"): the sheet, filmed at this rate, with holds of 0.5-0.7 s, ramps of 0.15-0.25 s
#: and rests of 0.3-0.45 s after a lead-in of 1.2-1.5 s (a short session: about 870 frames to render).
ROM_SHEET, ROM_FPS = "facecap-24", 24.0
ROM_TIMING = ((1.2, 1.5), (0.15, 0.25), (0.5, 0.7), (0.3, 0.45))
#: The roles whose clips are ROM sessions: the tuning faces' (the reference the fusion table's faces give) and the
#: reported faces' (each performer's calibration on each camera).
ROM_ROLES = ("tune-rom", "calibrate")

@dataclass(frozen=True)
class Clip:
    """One rendered clip: its role, the face ("ict-mean", "ict-<seed>" or "facecap"), the recording's window and
    the camera's azimuth (degrees)."""

    role: str
    face: str
    recording: str
    start: int
    azimuth: float
    frames: int = 240

    @property
    def fps(self):
        """The clip's frame rate: a ROM session's :data:`ROM_FPS`, else the renderer's default (``Shot``)."""
        return ROM_FPS if self.role in ROM_ROLES else Shot().fps

    @property
    def name(self):
        if self.role == "tune-random":  # ``start`` is the draw's seed
            return f"{self.role}-{self.face}-{self.start}-az{self.azimuth:.0f}"
        if self.role in ROM_ROLES:  # a ROM session: ``recording`` is the sheet, ``start`` the session's seed
            return f"{self.role}-{self.face}-{self.recording}-{self.start}-az{self.azimuth:.0f}"
        if self.recording.startswith("edge-cases/"):  # another performer's: named by them (llf_<performer>_...)
            performer = Path(self.recording).stem.split("_")[1]
            return f"{self.role}-{self.face}-{performer}-{self.start}-az{self.azimuth:.0f}"
        return f"{self.role}-{self.face}-{Path(self.recording).stem[-5:]}-{self.start}-az{self.azimuth:.0f}"


#: Live Link Face recordings of two other performers (``../shared/data/realdata/edge-cases``: their rows are off the
#: frame grid, which the clips do not use; read by row): (recording, first row, frames at 30 frames/s). Jason
#: Miller's is tuned on (with Alex's ``llf_alex_rom_3``: the table and map learn two people's habits), the Sentien
#: recording's busiest stretch is reported (role report-others).
TUNING_OTHER = ("edge-cases/llf_jmtechart_MySlate_3.csv", 0, 160)
OTHERS = (("edge-cases/llf_sentien_recording.csv", 800, 240),)
#: The rest of the Sentien recording (rows 0-779 and 1300-1627: its reported window, rows 800-1279, and 20 rows
#: either side left out; role "tune-performers"): fitted on only by ``--performers``, which asks what a tuning
#: performer more or less does to each performer's clips; the shipped table and map never see them.
PERFORMER_WINDOWS = (("edge-cases/llf_sentien_recording.csv", 0, 390),
                     ("edge-cases/llf_sentien_recording.csv", 1300, 164))
#: The guide the reported faces follow (role "follow", ``solvers/video/follow.py``): the busiest 8 s of Alex's
#: ``llf_alex_rom_3`` outside the tuning windows (39 shapes above 0.3; chosen by that count alone).
GUIDE = ("llf_alex_rom_3.csv", 3540, 240)

CLIPS = tuple(
    [Clip("tune", f"ict-{seed}", "llf_alex_rom_3.csv", start, az)
     for seed in (21, 22) for start in (600, 2100) for az in (0.0, 30.0)]
    + [Clip("tune", f"ict-{seed}", TUNING_OTHER[0], TUNING_OTHER[1], az, frames=TUNING_OTHER[2])
       for seed in (21, 22) for az in (0.0, 30.0)]
    + [Clip("report", face, "llf_alex_rom_4.csv", start, az)
       for face in ("ict-mean", "facecap") for start in (1500, 2700) for az in (0.0, 30.0)]
    + [Clip("calibrate", face, ROM_SHEET, 38, az, frames=0)
       for az in (0.0, 30.0) for face in ("facecap", "ict-mean")]
    + [Clip("tune-rom", f"ict-{seed}", ROM_SHEET, 40 + seed, az, frames=0)
       for az in (0.0, 30.0) for seed in (21, 22)]
    + [Clip("tune-random", f"ict-{seed}", "random", 80 + seed + draw, az)
       for seed in (21, 22) for draw in (0, 10) for az in (0.0, 30.0)]
    + [Clip("report-others", face, recording, start, az, frames=frames)
       for face in ("ict-mean", "facecap") for recording, start, frames in OTHERS for az in (0.0, 30.0)]
    + [Clip("follow", face, GUIDE[0], GUIDE[1], az, frames=GUIDE[2]) for face in ("ict-mean", "facecap")
       for az in (0.0, 30.0)]
    + [Clip("tune-follow", f"ict-{seed}", GUIDE[0], GUIDE[1], az, frames=GUIDE[2]) for seed in (21, 22)
       for az in (0.0, 30.0)]
    + [Clip("tune-performers", f"ict-{seed}", recording, start, az, frames=frames)
       for recording, start, frames in PERFORMER_WINDOWS for seed in (21, 22) for az in (0.0, 30.0)])
#: The roles whose clips follow the guide: the reported faces' (judged) and the tuning faces' (how much such a clip
#: weighs in the map is chosen on these: ``fusion_fit.follow_weight_check``).
FOLLOW_ROLES = ("follow", "tune-follow")
#: The roles the fusion map is fitted on: the tuning faces' performances, ROM sessions and random activations.
MAP_ROLES = ("tune", "tune-rom", "tune-random")


def performer(clip):
    """Who performs a clip of a Live Link Face recording ("alex", "jmtechart", "sentien"), or None (the ROM sessions
    and random activations are nobody's habits)."""
    if not clip.recording.endswith(".csv"):
        return None
    return Path(clip.recording).stem.split("_")[1]


def columns(data, names):
    """(truth, solve, corrected scores) (F, len(names)) of a cached clip on ARKit ``names``, from the hold on
    (NaN where a side has no such shape)."""
    def pick(values, have):
        have = [str(n) for n in have]
        out = np.full((len(values), len(names)), np.nan)
        for j, n in enumerate(names):
            if n in have:
                out[:, j] = values[:, have.index(n)]
        return out

    corrected = neutral_corrected(data["scores"], data["neutral"])
    return (pick(data["truth"], data["truth_names"])[HOLD:], pick(data["solved"], data["solved_names"])[HOLD:],
            pick(corrected, data["score_names"])[HOLD:])


def judged_names():
    return [n for shapes in REGIONS.values() for n in shapes]


def region_rmse(got, truth, names):
    """{region: weights RMSE, "visible": over every judged shape (shapes the truth lacks left out), "blink_peak",
    "jitter", "pinned", "shapes": {shape: its mean squared error}}."""
    out, every, per_shape = {}, [], {}
    for region, shapes in REGIONS.items():
        known = [s for s in shapes if np.isfinite(truth[:, names.index(s)]).any()]
        errs = [np.nanmean((got[:, names.index(s)] - truth[:, names.index(s)]) ** 2) for s in known]
        per_shape.update({s: float(e) for s, e in zip(known, errs)})
        every += errs
        out[region] = float(np.sqrt(np.mean(errs)))
    out["visible"] = float(np.sqrt(np.mean(every)))
    peaks = []
    for side in ("Left", "Right"):
        j = names.index(f"eyeBlink{side}")
        closed = truth[:, j] > 0.7
        peaks.append(float(np.nanmax(got[closed, j])) if closed.any() else float("nan"))
    out["blink_peak"] = float(np.nanmin(peaks)) if np.isfinite(peaks).any() else float("nan")
    judged = got[:, [names.index(s) for shapes in REGIONS.values() for s in shapes]]
    out["jitter"] = jitter(judged)
    out["pinned"] = pinned(judged)
    out["shapes"] = per_shape  # each judged shape's mean squared error (what carries the visible RMSE)
    return out


def print_shapes(rows, method="fused", top=8):
    """Per face, the shapes that carry most of ``method``'s visible RMSE: each one's RMSE over the face's clips and its
    share of their summed squared error (what a change must move to move the figure)."""
    for face in ("ict", "facecap"):
        mine = [m[method]["shapes"] for c, m in rows.items() if f"-{face}" in c and method in m]
        if not mine:
            continue
        mse = {s: float(np.mean([m[s] for m in mine if s in m])) for s in mine[0]}
        total = sum(mse.values())
        worst = sorted(mse, key=mse.get, reverse=True)[:top]
        print(f"{face} {method}, the shapes carrying it: " + ", ".join(
            f"{s} {np.sqrt(mse[s]):.2f} ({100 * mse[s] / total:.0f} %)" for s in worst))


def pinned(weights):
    """The share (%) of a clip's judged weights (F, K) at their upper bound 1: a shape held flat at its full extent,
    which an animator sees (a performance's truth: 0 %). NaN samples left out."""
    w = np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(w)
    return float(100.0 * np.mean(w[ok] >= 0.999)) if ok.any() else float("nan")


def jitter(weights):
    """How rough weights (F, K) are over time: the mean |second difference| (NaN frames left out): what an animator
    sees as chatter (a performance's truth: about 0.004 at 30 frames/s)."""
    second = np.abs(np.diff(np.asarray(weights, dtype=np.float64), 2, axis=0))
    return float(np.nanmean(second)) if np.isfinite(second).any() else float("nan")


def rom_fit(out, clip, reference=None):
    """The ResponseFit of the cached ROM ``clip`` (``response.fit_response``; relative to ``reference``)."""
    data = dict(np.load(out / f"{clip.name}.npz"))
    return fit_response(data["scores"], [str(n) for n in data["score_names"]], data["neutral"],
                        sequence_poses(ROM_SHEET), fps=ROM_FPS, reference=reference, sheet=ROM_SHEET)


#: The solve's shapes its ROM response leaves alone: the lids' locks already read them against the take's own neutral.
LID_LOCKED = ("eyeBlinkLeft", "eyeBlinkRight", "eyeWideLeft", "eyeWideRight")


def solve_rom_fit(out, clip, reference=None, found=None):
    """The landmark solve's own response on the cached ROM ``clip`` (a ScoreResponse on its shapes: its weights at
    the poses the scores found, ``response.fit_weights_response``), relative to ``reference`` (the tuning faces',
    :func:`fusion_fit.fit_solve_reference`) when given; ``found``: the clip's score fit (:func:`rom_fit`), if made."""
    data = dict(np.load(out / f"{clip.name}.npz"))
    found = rom_fit(out, clip) if found is None else found
    own = fit_weights_response(data["solved"], [str(n) for n in data["solved_names"]], data["neutral"], found.frames,
                               sequence_poses(ROM_SHEET), sheet=ROM_SHEET, keep=LID_LOCKED)
    return own if reference is None else relative(own, reference)


def calibration_clip(clip, role="calibrate"):
    """The ROM clip (role "calibrate", or the guide followed: "follow") of the reported ``clip``'s face and camera,
    or None."""
    for c in CLIPS:
        if c.role == role and c.face == clip.face and c.azimuth == clip.azimuth:
            return c
    return None


def follow_seed(clip):
    """The seed of a guide-following clip's imperfections (its face and camera)."""
    tuning = int(clip.face.split("-")[1]) if clip.role == "tune-follow" else 0
    return 70 + 2 * int(clip.face == "facecap") + int(clip.azimuth > 0) + 10 * tuning


def follow_fit(out, clip, table, clips=None):
    """The FollowFit of the cached clip ``clip`` (role "follow") into ``table``'s map (``follow.fit_follow``)."""
    data = dict(np.load(out / f"{clip.name}.npz"))
    scores = FaceScores(data["scores"], tuple(str(n) for n in data["score_names"]), data["neutral"], fps=clip.fps)
    return fit_follow(data["guide"], [str(n) for n in data["guide_names"]], float(data["guide_fps"]), data["solved"],
                      tuple(str(n) for n in data["solved_names"]), scores, table=table, guide_label=clip.recording,
                      clips=clips)
