"""``python -m facecap.facecap_addon.bench.fusion_bench --out DIR``: video takes judged on footage nobody tuned on.

Two real faces perform Live Link Face recordings from a relaxed start (``landmark_bench``): ICT faces
(``shared/data/ict-facekit``: identities drawn from its identity modes) and the Face Cap head
(``shared/data/facecap-head``: a scanned head with its own ARKit shapes, not of the ICT family), each
filmed from the front and from 30 degrees to the side. Every clip goes through the landmark take onto
another ICT identity (the character), and what the Face Landmarker's blendshape head scored is kept
beside the solve, so that the fusion (``solvers/video/fusion.py``) can be fitted and judged.

The clips are kept apart by role (:data:`CLIPS`):

* **tune**: two ICT identities (seeds 21 and 22), windows of ``llf_alex_rom_3``: the only clips the
  per-shape fusion table is fitted on (``--fit`` writes ``solvers/video/fusion_table.json``);
* **tune-random**: the same identities firing every shape independently of the others (``random_performance``):
  with the tune and tune-rom clips, what the fusion map is fitted on (``--fit`` writes ``fusion_map.npz``, its
  ridge chosen by leaving each identity out);
* **report**: the ICT mean face and the Face Cap head (a face never tuned on), windows of
  ``llf_alex_rom_4`` (another recording): judged, never fitted;
* **tune-rom**: the tuning identities performing the ROM sheet ``facecap-24`` (``realism.rom``: imperfectly),
  from both cameras: the reference the performers' responses are read against (``--fit-rom`` writes it into
  the table, its gains kept);
* **calibrate**: each reported face performing the sheet from each reported camera (another session): its
  response (``solvers/video/response.py``) is fitted on this clip alone and judged on that face and camera's
  reported clips ("fused + ROM").

Each clip's landmarks, scores and unfused solve are cached in ``--out`` (a clip is rendered once).
"""

import argparse
import os
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...solvers.character.face_model import CM, ICT_AXES
from ...solvers.config import load_take_config
from ...solvers.io.weights import read_weights
from ...solvers.rom import sequence_poses
from ...solvers.tools.synthetic.realism.rom import rom_weights
from ...solvers.video.fusion import MAP_FILE_NAME, TABLE_FILE, FaceScores, FusionTable, fit_map, fit_table, fuse, \
    neutral_corrected
from ...solvers.video.response import ScoreResponse, fit_response
from ...solvers.video.landmarker_bundle import ENVIRONMENT, find_bundle
from ...solvers.video.landmarks import track_landmarks
from ...solvers.video.reading import Footage
from ..headless.headless import run_take
from ..headless.landmark_take import landmark_neutral
from ..render.face_footage import Shot, render_face_clip
from .landmark_bench import REGIONS, ict_arrays, ict_character, performance, shared_folder

HOLD = 45
CHARACTER_SEED = 7
#: The ROM clips (role "calibrate"): the sheet, filmed at this rate, with holds of 0.5-0.7 s, ramps of 0.15-0.25 s
#: and rests of 0.3-0.45 s after a lead-in of 1.2-1.5 s (a short session: about 870 frames to render).
ROM_SHEET, ROM_FPS = "facecap-24", 24.0
ROM_TIMING = ((1.2, 1.5), (0.15, 0.25), (0.5, 0.7), (0.3, 0.45))
#: The roles whose clips are ROM sessions: the tuning faces' (the reference the fusion table's faces give) and the
#: reported faces' (each performer's calibration on each camera).
ROM_ROLES = ("tune-rom", "calibrate")
#: Degrees of the ROM performer's slow head drift (yaw, pitch, roll).
ROM_HEAD_DEG = (3.0, 2.0, 1.0)
#: Live Link Face's eye angles per unit of eye-look weight (radians): yaw per (out - in), pitch per (down - up).
LOOK_YAW, LOOK_PITCH = 0.593, 0.544


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
    def name(self):
        if self.role == "tune-random":  # ``start`` is the draw's seed
            return f"{self.role}-{self.face}-{self.start}-az{self.azimuth:.0f}"
        if self.role in ROM_ROLES:  # a ROM session: ``recording`` is the sheet, ``start`` the session's seed
            return f"{self.role}-{self.face}-{self.recording}-{self.start}-az{self.azimuth:.0f}"
        return f"{self.role}-{self.face}-{Path(self.recording).stem[-5:]}-{self.start}-az{self.azimuth:.0f}"


CLIPS = tuple(
    [Clip("tune", f"ict-{seed}", "llf_alex_rom_3.csv", start, az)
     for seed in (21, 22) for start in (600, 2100) for az in (0.0, 30.0)]
    + [Clip("report", face, "llf_alex_rom_4.csv", start, az)
       for face in ("ict-mean", "facecap") for start in (1500, 2700) for az in (0.0, 30.0)]
    + [Clip("calibrate", face, ROM_SHEET, 38, az, frames=0)
       for az in (0.0, 30.0) for face in ("facecap", "ict-mean")]
    + [Clip("tune-rom", f"ict-{seed}", ROM_SHEET, 40 + seed, az, frames=0)
       for az in (0.0, 30.0) for seed in (21, 22)]
    + [Clip("tune-random", f"ict-{seed}", "random", 80 + seed + draw, az)
       for seed in (21, 22) for draw in (0, 10) for az in (0.0, 30.0)])
#: The roles the fusion map is fitted on: the tuning faces' performances, ROM sessions and random activations.
MAP_ROLES = ("tune", "tune-rom", "tune-random")
#: Directions a face cannot take at once: a random activation leaves out the one whose opposite is active.
OPPOSITE = {**{f"eyeLook{a}{s}": f"eyeLook{b}{s}" for s in ("Left", "Right")
               for a, b in (("In", "Out"), ("Out", "In"), ("Up", "Down"), ("Down", "Up"))},
            "jawLeft": "jawRight", "jawRight": "jawLeft", "mouthLeft": "mouthRight", "mouthRight": "mouthLeft"}


def face_arrays(face, shared):
    """(neutral, polygons, shape names, deltas) of ``face`` in facecap's axes (metres, Z up, looking down -Y)."""
    if face == "facecap":
        d = np.load(shared / "facecap-head" / "facecap_head.npz")
        to = ICT_AXES * CM
        return (d["neutral"].astype(np.float64) @ to.T, d["faces"], tuple(str(n) for n in d["names"]),
                np.einsum("kvi,ji->kvj", d["deltas"].astype(np.float64), to))
    neutral, quads, names, deltas, identity = ict_arrays(shared / "ict-facekit" / "ict_face.npz")
    if face != "ict-mean":
        seed = int(face.split("-")[1])
        neutral = neutral + np.einsum("i,ivd->vd", np.random.default_rng(seed).normal(size=20), identity[:20])
    return neutral, quads, names, deltas


def random_performance(names, seed, frames, *, fps=30.0):
    """Every judged shape fired at random, each independently of the others (``frames`` after :data:`HOLD` frames of
    a relaxed face): an event every 2-7 frames takes the next shape of a random order of them all (and half the
    time its other side) and eases it to a level of 0.3-1 for 6-20 frames, so that about five overlap; no habit ties
    one shape to another, unlike a performance or the ROM sheet's expressions. The fusion map learns from these what
    the head misreads. Returns (weights (F, K), head (F, 6), gaze (F, 2, 2)) as :func:`rom_performance` makes them."""
    rng = np.random.default_rng(seed)
    F = HOLD + frames
    judged = [k for k, n in enumerate(names) if n in set(judged_names())]
    index = {n: k for k, n in enumerate(names)}
    weights = np.zeros((F, len(names)))
    t, order = HOLD, []
    while t < F:
        if not order:  # every shape in turn, in a new random order each round: none is left out of a clip
            order = list(rng.permutation(judged))
        k = int(order.pop())
        ramp, hold = int(rng.integers(4, 9)), int(rng.integers(6, 21))
        up = 0.5 - 0.5 * np.cos(np.pi * np.arange(1, ramp + 1) / (ramp + 1))
        level = rng.uniform(0.3, 1.0) * np.r_[up, np.ones(hold), up[::-1]]
        span = slice(t, min(F, t + len(level)))
        side = names[k][:-4] + ("Right" if names[k].endswith("Left") else "Left")
        for kk in [k] + ([index[side]] if side in index and rng.random() < 0.5 else []):
            other = index.get(OPPOSITE.get(names[kk], ""))
            if other is None or not weights[span, other].any():
                weights[span, kk] = np.maximum(weights[span, kk], level[: span.stop - span.start])
        t += int(rng.integers(2, 8))
    head, gaze = _head_and_gaze(weights, names, rng, fps)
    return weights, head, gaze


def _head_and_gaze(weights, names, rng, fps):
    """A slow head drift (:data:`ROM_HEAD_DEG`) and the eyes' turn from the eye-look weights as Live Link Face
    relates them: (head (F, 6), gaze (F, 2, 2))."""
    F = len(weights)
    t = np.arange(F) / fps
    head = np.zeros((F, 6))
    for axis, deg in enumerate(ROM_HEAD_DEG):
        f1, f2 = rng.uniform(0.05, 0.2, size=2)
        head[:, axis] = np.radians(deg) * 0.5 * (np.sin(2 * np.pi * f1 * t + rng.uniform(0, 6.3))
                                                 + np.sin(2 * np.pi * f2 * t + rng.uniform(0, 6.3)))
    w = lambda n: weights[:, names.index(n)] if n in names else np.zeros(F)  # noqa: E731
    gaze = np.zeros((F, 2, 2))  # the subject's right eye, then left: yaw towards their left, pitch down
    gaze[:, 0, 0] = LOOK_YAW * (w("eyeLookInRight") - w("eyeLookOutRight"))
    gaze[:, 1, 0] = LOOK_YAW * (w("eyeLookOutLeft") - w("eyeLookInLeft"))
    gaze[:, 0, 1] = LOOK_PITCH * (w("eyeLookDownRight") - w("eyeLookUpRight"))
    gaze[:, 1, 1] = LOOK_PITCH * (w("eyeLookDownLeft") - w("eyeLookUpLeft"))
    return head, gaze


def rom_performance(names, seed):
    """A ROM session of :data:`ROM_SHEET` performed imperfectly (``realism.rom``: 80-100 % of each asked shape,
    neighbours leaking in, wobbling holds) at :data:`ROM_FPS`: (weights (F, K) on ``names``, head (F, 6), gaze
    (F, 2, 2) from the eye-look weights as Live Link Face relates them, {"performed", "holds", "given"})."""
    rng = np.random.default_rng(seed)
    weights, performed, holds, given = rom_weights(names, sequence_poses(ROM_SHEET), rng, fps=ROM_FPS,
                                                   timing=ROM_TIMING)
    head, gaze = _head_and_gaze(weights, names, rng, ROM_FPS)
    return weights, head, gaze, {"performed": np.array(performed), "holds": holds, "given": given}


def prepare(clip, out, character, *, log=print):
    """Render ``clip``, run its landmark take onto ``character`` (unfused) and cache what the fusion needs:
    ``<out>/<name>.npz`` with the truth, the solve, the blendshape scores and the take's neutral frames (a ROM
    clip also keeps its session's truth: the poses performed, their holds and the weights given)."""
    cached = out / f"{clip.name}.npz"
    if cached.is_file():
        return dict(np.load(cached))
    shared = shared_folder() / "data"
    neutral, polygons, names, deltas = face_arrays(clip.face, shared)
    extra, shot = {}, Shot(distance=0.5, azimuth=clip.azimuth)
    if clip.role in ROM_ROLES:
        weights, head, gaze, extra = rom_performance(names, clip.start)
        shot = Shot(distance=0.5, azimuth=clip.azimuth, fps=ROM_FPS)
    elif clip.role == "tune-random":
        weights, head, gaze = random_performance(names, clip.start, clip.frames)
    else:
        weights, head, gaze = performance(shared / "realdata" / "llf" / clip.recording, names, start=clip.start,
                                          frames=clip.frames, hold=HOLD)
    video = out / f"{clip.name}.mp4"
    t = time.perf_counter()
    if not video.is_file():  # rendered under another name first: a clip cut short is never taken as whole
        part = video.with_name(video.stem + "-part.mp4")
        log(f"{clip.name}: rendering {len(weights)} frames")
        render_face_clip(part, neutral, polygons, deltas, weights, head=head, gaze=gaze, shot=shot)
        part.replace(video)
    t_render = time.perf_counter() - t
    solved = out / f"{clip.name}.csv"
    config = out / f"{clip.name}.toml"
    config.write_text(f'[target]\nblend = "{character}"\nobject = "ICT"\n[source]\nvideo = "{video.name}"\n'
                      f'[tracking]\nmethod = "landmarks"\nblendshapes = "ignore"\n[output]\nweights = "{solved.name}"\n',
                      encoding="utf-8")
    run_take(load_take_config(config), quiet=True)
    found = track_landmarks(video)
    s = read_weights(solved)
    data = {"truth": weights, "truth_names": np.array(names), "solved": s.values, "solved_names": np.array(s.names),
            "scores": found.blendshapes, "score_names": np.array(found.blendshape_names),
            "neutral": landmark_neutral(found), "render_s": t_render, **extra}
    np.savez(cached, **data)
    if clip.role in ("tune", "tune-random"):
        video.unlink()  # the npz keeps what the fusion needs; a reported clip's video is kept for the speed
    log(f"{clip.name}: rendered in {t_render:.0f} s")
    return data


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
    """{region: weights RMSE, "visible": over every judged shape} (shapes the truth lacks left out)."""
    out, every = {}, []
    for region, shapes in REGIONS.items():
        errs = [np.nanmean((got[:, names.index(s)] - truth[:, names.index(s)]) ** 2) for s in shapes
                if np.isfinite(truth[:, names.index(s)]).any()]
        every += errs
        out[region] = float(np.sqrt(np.mean(errs)))
    out["visible"] = float(np.sqrt(np.mean(every)))
    peaks = []
    for side in ("Left", "Right"):
        j = names.index(f"eyeBlink{side}")
        closed = truth[:, j] > 0.7
        peaks.append(float(np.nanmax(got[closed, j])) if closed.any() else float("nan"))
    out["blink_peak"] = float(np.nanmin(peaks)) if np.isfinite(peaks).any() else float("nan")
    return out


def fit(out, *, log=print):
    """Fit the fusion table on the tuning clips in ``out``; returns it (not saved) and the constant baseline."""
    names = judged_names()
    parts = [columns(dict(np.load(out / f"{c.name}.npz")), names) for c in CLIPS if c.role == "tune"]
    truth, solved, corrected = (np.concatenate(p) for p in zip(*parts))
    tuned = [c.name for c in CLIPS if c.role == "tune"]
    table = fit_table(np.nan_to_num(truth), solved, corrected, names,
                      measured_on={"clips": tuned, "frames": int(len(truth)),
                                   "command": "python -m facecap.facecap_addon.bench.fusion_bench --out DIR --fit"})
    log(f"fusion table fitted on {len(tuned)} clips, {len(truth)} frames")
    return table, np.nanmean(truth, axis=0)


#: The ridges the fusion map is chosen among (per clip, towards the per-shape table).
MAP_RIDGES = (3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3)


def fit_cross(out, table, *, log=print):
    """The fusion map on the tuning faces' clips, performances and ROM sessions alike (``tune`` and ``tune-rom``):
    its ridge chosen by leaving each tuning identity out in turn (the median visible RMSE of its clips, the larger
    ridge on a tie to 3 decimals); returns (the map, what it was measured on)."""
    names = judged_names()
    clips = [c for c in CLIPS if c.role in MAP_ROLES]
    parts = {c.name: columns(dict(np.load(out / f"{c.name}.npz")), names) for c in clips}
    faces = sorted({c.face for c in clips})
    scores = {}
    for lam in MAP_RIDGES:
        errs = []
        for face in faces:
            held = [c for c in clips if c.face == face]
            cross = fit_map([parts[c.name] for c in clips if c.face != face], names, lam)
            tab = replace(table, map=cross)
            for c in held:
                truth, solved, corrected = parts[c.name]
                errs.append(region_rmse(_map_only(tab, solved, corrected, names), truth, names)["visible"])
        scores[lam] = round(float(np.median(errs)), 3)
    best = min(scores.values())
    lam = max(k for k, v in scores.items() if v == best)
    log("fusion map: leave-one-identity-out visible RMSE per ridge " + ", ".join(f"{k:g}: {v:.3f}"
                                                                                for k, v in scores.items())
        + f"; chosen {lam:g}")
    measured = {"map_clips": [c.name for c in clips], "map_ridge": lam, "map_ridge_cv": {f"{k:g}": v for k, v in
                                                                                          scores.items()}}
    return fit_map(list(parts.values()), names, lam), measured


def _map_only(table, solved, corrected, names):
    """The fused weights of cached columns (on the map's ``names``, the scores already corrected) through
    ``table``'s map, every input had (NaN read as 0)."""
    S = len(names)
    W = table.map.weights(table, np.ones(S, bool), np.ones(S, bool))
    return np.clip(np.nan_to_num(np.concatenate([corrected, solved], axis=1)) @ W, 0.0, 1.0)


def rom_fit(out, clip, reference=None):
    """The ResponseFit of the cached ROM ``clip`` (``response.fit_response``; relative to ``reference``)."""
    data = dict(np.load(out / f"{clip.name}.npz"))
    return fit_response(data["scores"], [str(n) for n in data["score_names"]], data["neutral"],
                        sequence_poses(ROM_SHEET), fps=ROM_FPS, reference=reference, sheet=ROM_SHEET)


def fit_reference(out, *, log=print):
    """The tuning faces' ROM response (``FusionTable.reference``): each "tune-rom" clip fitted alone, then per score
    the median gain and offset over the clips that calibrated it; the identity for a score fewer than half of them
    calibrated (it does not respond on these faces)."""
    rom_clips = [c for c in CLIPS if c.role == "tune-rom" and (out / f"{c.name}.npz").is_file()]
    fits = [rom_fit(out, c).response for c in rom_clips]
    names = fits[0].names
    changed = np.array([[n in f.changed() for n in names] for f in fits])
    gains, offsets = np.stack([f.gain for f in fits]), np.stack([f.offset for f in fits])
    keep = changed.sum(axis=0) * 2 > len(fits)
    gain, offset = np.ones(len(names)), np.zeros(len(names))
    with warnings.catch_warnings():  # a kept score calibrated on some clips only: the median of those
        warnings.simplefilter("ignore", RuntimeWarning)
        gain[keep] = np.nanmedian(np.where(changed, gains, np.nan)[:, keep], axis=0)
        offset[keep] = np.nanmedian(np.where(changed, offsets, np.nan)[:, keep], axis=0)
    log(f"ROM reference fitted on {len(fits)} clips: {int(keep.sum())} scores")
    return ScoreResponse(names, gain, offset, ROM_SHEET), [c.name for c in rom_clips]


def calibration_clip(clip):
    """The ROM clip (role "calibrate") of the reported ``clip``'s face and camera, or None."""
    for c in CLIPS:
        if c.role == "calibrate" and c.face == clip.face and c.azimuth == clip.azimuth:
            return c
    return None


def evaluate(out, table, constant, role="report"):
    """{clip: {method: region table}} for the clips of ``role``: the landmark solve, the corrected scores, the
    fusion per shape (the table alone), the fusion through the map, the latter with the performer's response from the ROM clip of the same face and camera (when it is
    in ``out``) and a constant (the tuning clips' mean weights on every frame)."""
    names = judged_names()
    rows = {}
    for clip in CLIPS:
        if clip.role != role:
            continue
        data = dict(np.load(out / f"{clip.name}.npz"))
        truth, solved, corrected = columns(data, names)
        rom = calibration_clip(clip)
        methods = {"fused per shape": (None, False), "fused": (None, True)}
        if rom is not None and (out / f"{rom.name}.npz").is_file():
            methods["fused + ROM"] = (rom_fit(out, rom, table.reference).response, True)
        row = {"landmarks": region_rmse(solved, truth, names),
               "scores": region_rmse(np.where(np.isfinite(corrected), corrected, solved), truth, names)}
        for method, (response, cross) in methods.items():
            fused, _ = fuse(data["solved"], tuple(str(n) for n in data["solved_names"]),
                            FaceScores(data["scores"], tuple(str(n) for n in data["score_names"]), data["neutral"],
                                       response=response), table=table, cross=cross)
            row[method] = region_rmse(columns({**data, "solved": fused}, names)[1], truth, names)
        row["constant"] = region_rmse(np.broadcast_to(constant, truth.shape), truth, names)
        rows[clip.name] = row
    return rows


def speed(video, log=print):
    """Frames per second of the landmarks with the blendshape head (the bundle), decoding included, beside the
    older models and decoding alone, in the same run (medians of 3; this machine's cores are shared)."""
    def rate(run):
        times = []
        for _ in range(3):
            t = time.perf_counter()
            n = run()
            times.append(time.perf_counter() - t)
        return n / float(np.median(times))

    decode = rate(lambda: sum(1 for _ in Footage(video, color=True)))
    bundle = rate(lambda: len(track_landmarks(video).found))
    older = rate(lambda: len(track_landmarks(video, bundle=None).found))
    log(f"speed on {video.name} ({os.cpu_count()} cores): Face Landmarker with its blendshape head {bundle:.0f} "
        f"frames/s, the older face mesh + iris models {older:.0f} frames/s, decoding alone {decode:.0f} frames/s")
    return bundle, older, decode


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m facecap.facecap_addon.bench.fusion_bench")
    parser.add_argument("--out", required=True, help="folder of the cached clips (rendered once)")
    parser.add_argument("--role", choices=("tune", "report", "tune-rom", "calibrate", "tune-random"), action="append",
                        help="only these clips")
    parser.add_argument("--speed", action="store_true", help="also time the landmarks on a reported clip")
    parser.add_argument("--fit", action="store_true", help="fit the fusion table and its map on the tuning clips and "
                                                          "write them (solvers/video/fusion_table.json, fusion_map.npz)")
    parser.add_argument("--fit-rom", action="store_true", help="fit the table's ROM reference on the tuning faces' ROM "
                                                              "clips (role tune-rom) and write it, the gains kept")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if find_bundle() is None:  # the shared copy, as the tests use it
        os.environ[ENVIRONMENT] = str(shared_folder() / "data" / "mediapipe" / "face_landmarker.task")
    character = out / "character.blend"
    if not character.is_file():
        neutral, quads, names, deltas, identity = ict_arrays(shared_folder() / "data" / "ict-facekit" / "ict_face.npz")
        ict_character(character, neutral, quads, names, deltas, identity, CHARACTER_SEED)
    for clip in CLIPS:
        if args.role is None or clip.role in args.role:
            prepare(clip, out, character)
    if args.fit:
        table, constant = fit(out)
        cross, measured = fit_cross(out, table)
        table = replace(table, reference=FusionTable.load().reference, map=cross,
                        measured_on={**FusionTable.load().measured_on, **table.measured_on, **measured})
        table.save()
        cross.save(TABLE_FILE.with_name(MAP_FILE_NAME))
    else:
        table, constant = FusionTable.load(), fit(out, log=lambda _m: None)[1]
    if args.fit_rom:
        reference, rom_clips = fit_reference(out)
        measured = {**table.measured_on, "rom_clips": rom_clips,
                    "rom_command": "python -m facecap.facecap_addon.bench.fusion_bench --out DIR --fit-rom"}
        table = replace(table, measured_on=measured, reference=reference)
        table.save()
    rows = evaluate(out, table, constant)
    print_tables(rows)
    videos = sorted(out.glob("report-*.mp4"))
    if videos and args.speed:
        speed(videos[0])
    return 0


def print_tables(rows):
    """Per clip and method the region RMSEs, then the medians and worst cases over the clips."""
    keys = list(REGIONS) + ["visible", "blink_peak"]
    print("| clip | method | " + " | ".join(keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for clip, methods in rows.items():
        for method, table in methods.items():
            print(f"| {clip} | {method} | " + " | ".join(f"{table[k]:.3f}" for k in keys) + " |")
    for face in ("ict", "facecap"):
        mine = [m for c, m in rows.items() if f"-{face}" in c]
        for method in dict.fromkeys(k for m in mine for k in m):
            vis = [m[method]["visible"] for m in mine if method in m]
            brows = [m[method]["brows"] for m in mine if method in m]
            blink = [m[method]["blink_peak"] for m in mine if method in m]
            print(f"{face} {method} ({len(vis)} clips): visible median {np.median(vis):.3f} worst {np.max(vis):.3f}; "
                  f"brows median {np.median(brows):.3f} worst {np.max(brows):.3f}; blink peak worst "
                  f"{np.nanmin(blink):.2f}")
    print()
    print("| face | method | " + " | ".join(REGIONS) + " | visible | blink peak |")
    print("|---|---|" + "---|" * (len(REGIONS) + 2))
    for face in ("ict", "facecap"):  # per region the median over the face's clips and (in brackets) the worst
        mine = [m for c, m in rows.items() if f"-{face}" in c]
        for method in dict.fromkeys(k for m in mine for k in m):
            have = [m[method] for m in mine if method in m]
            cells = [f"{np.median([h[r] for h in have]):.3f} ({max(h[r] for h in have):.3f})"
                     for r in list(REGIONS) + ["visible"]]
            blink = [h["blink_peak"] for h in have]
            print(f"| {face} | {method} ({len(have)} clips) | " + " | ".join(cells)
                  + f" | {np.nanmedian(blink):.2f} ({np.nanmin(blink):.2f}) |")


if __name__ == "__main__":
    raise SystemExit(main())
