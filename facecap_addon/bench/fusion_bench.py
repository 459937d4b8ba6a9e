"""``python -m facecap.facecap_addon.bench.fusion_bench --out DIR``: video takes judged on footage nobody tuned on.

Two real faces perform Live Link Face recordings from a relaxed start (``landmark_bench``): ICT faces
(``shared/data/ict-facekit``: identities drawn from its identity modes) and the Face Cap head
(``shared/data/facecap-head``: a scanned head with its own ARKit shapes, not of the ICT family), each
filmed from the front and from 30 degrees to the side. Every clip goes through the landmark take onto
another ICT identity (the character), and what the Face Landmarker's blendshape head scored is kept
beside the solve, so that the fusion (``solvers/video/fusion.py``) can be fitted and judged.

The clips are kept apart by role (:data:`CLIPS`):

* **tune**: two ICT identities (seeds 21 and 22), windows of Alex's ``llf_alex_rom_3`` and Jason Miller's
  recording (``TUNING_OTHER``): the only clips the per-shape fusion table and the lids' slope against the gaze are
  fitted on (``--fit`` writes ``solvers/video/fusion_table.json``);
* **tune-random**: the same identities firing every shape independently of the others (``random_performance``):
  with the tune and tune-rom clips, what the fusion map is fitted on (``--fit`` writes ``fusion_map.npz``, its
  ridge chosen by leaving a tuning identity and a tuning performer out together);
* **report**: the ICT mean face and the Face Cap head (a face never tuned on), windows of
  ``llf_alex_rom_4`` (another recording): judged, never fitted;
* **report-others**: the same faces and cameras performing a third performer's recording (``OTHERS``, the Sentien
  recording): judged, never fitted; the reported clips above are Alex's, whom the tuning clips also perform, so
  these say what the fusion learnt of the two tuning performers;
* **tune-rom**: the tuning identities performing the ROM sheet ``facecap-24`` (``realism.rom``: imperfectly),
  from both cameras: the reference the performers' responses are read against (``--fit-rom`` writes it into
  the table, its gains kept);
* **calibrate**: each reported face performing the sheet from each reported camera (another session): its
  response (``solvers/video/response.py``) is fitted on this clip alone and judged on that face and camera's
  reported clips ("fused + ROM");
* **follow**: each reported face following a guide (``GUIDE``: 8 s of a tuning recording, performed late and
  imperfectly: :func:`follow_performance`) from each reported camera: the clip, with the guide's weights (not what
  the face performed) as its truth, joins the map for that face and camera (``solvers/video/follow.py``), judged
  on its reported clips ("fused + guide followed");
* **tune-performers**: the tuning identities performing the rest of the Sentien recording (``PERFORMER_WINDOWS``,
  outside its reported window): never in the shipped fit; ``--performers`` refits with and without each tuning
  performer, Sentien's windows standing in for a third, and judges every performer's clips (what the uncalibrated
  figures owe to the performer being tuned on).

Each clip's landmarks, scores and unfused solve are cached in ``--out`` (a clip is rendered once).
"""

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ...solvers.character.face_model import CM, ICT_AXES
from ...solvers.config import load_take_config
from ...solvers.io.weights import read_weights
from ...solvers.rom import sequence_poses
from ...solvers.tools.synthetic.realism.rom import rom_weights
from ...solvers.video.follow import NOT_FOLLOWED
from ...solvers.video.fusion import MAP_FILE_NAME, TABLE_FILE, FaceScores, FusionTable, fuse
from ...solvers.video.landmarker_bundle import ENVIRONMENT, find_bundle
from ...solvers.video.landmarks import track_landmarks
from ...solvers.video.reading import Footage
from ..headless.headless import run_take
from ..headless.landmark_take import landmark_neutral
from ..render.face_footage import Shot, render_face_clip
from .fusion_clips import (
    CLIPS,
    FOLLOW_ROLES,
    HOLD,
    MAP_ROLES,
    ROM_FPS,
    ROM_ROLES,
    ROM_SHEET,
    ROM_TIMING,
    calibration_clip,
    columns,
    follow_fit,
    follow_seed,
    judged_names,
    print_shapes,
    region_rmse,
    rom_fit,
    solve_rom_fit,
)
from .fusion_fit import (PERFORMERS_READ, fit, fit_cross, fit_reference, fit_solve_reference, follow_weight_check,
                         lid_gaze_check, performers_check, smoothing_check)
from .landmark_bench import REGIONS, ict_arrays, ict_character, performance, shared_folder

CHARACTER_SEED = 7
#: Degrees of the ROM performer's slow head drift (yaw, pitch, roll).
ROM_HEAD_DEG = (3.0, 2.0, 1.0)
#: Live Link Face's eye angles per unit of eye-look weight (radians): yaw per (out - in), pitch per (down - up).
LOOK_YAW, LOOK_PITCH = 0.593, 0.544


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


#: How a performer follows a guide (:func:`follow_performance`): a reaction time (seconds), a slow wander of the
#: timing about it (seconds, amplitude), each shape's amplitude against the guide's (a factor) and the frames the
#: imitation is smoothed over (Gaussian sigma): what lag and imperfection the guide's placement must survive.
FOLLOW_LAG_S, FOLLOW_WANDER_S, FOLLOW_GAIN, FOLLOW_SIGMA = (0.15, 0.35), 0.1, (0.8, 1.2), 1.0


#: A performer's own blinks while following a guide: seconds between them (uniform), and the frames a blink takes to
#: close, stay closed and open; their eyes on the screen: a fixation every so many seconds, within this much of a
#: full look sideways and up or down.
OWN_BLINK_S, OWN_BLINK_FRAMES, OWN_FIXATION_S, OWN_LOOK = (1.5, 5.0), (2, 1, 3), (0.4, 1.2), (0.12, 0.08)
#: The model of a follower a cached guide-following clip was rendered with (an older cache's copied the guide's eyes:
#: such a clip is rendered again).
FOLLOWER = "own-eyes"


def own_eyes(performed, names, rng, fps):
    """Write into ``performed`` (F, K) on ``names`` what a performer's eyes do while they follow a guide on a screen
    (:data:`NOT_FOLLOWED`): their own blinks, both eyes at once, and fixations about the screen's middle
    (:data:`OWN_BLINK_S`...): what they do not take from the guide."""
    F = len(performed)
    column = {n: k for k, n in enumerate(names)}
    close, hold, reopen = OWN_BLINK_FRAMES
    shape = np.r_[np.linspace(0, 1, close + 1)[1:], np.ones(hold), np.linspace(1, 0, reopen + 1)[1:]]
    blink = np.zeros(F)
    t = rng.uniform(0.2, OWN_BLINK_S[1]) * fps
    while t < F:
        start = int(t)
        span = shape[: F - start] * rng.uniform(0.85, 1.0)
        blink[start:start + len(span)] = np.maximum(blink[start:start + len(span)], span)
        t += rng.uniform(*OWN_BLINK_S) * fps
    side = np.zeros(F)  # towards the subject's left
    down = np.zeros(F)
    t = 0.0
    while t < F:
        start = int(t)
        side[start:], down[start:] = rng.uniform(-OWN_LOOK[0], OWN_LOOK[0]), rng.uniform(-OWN_LOOK[1], OWN_LOOK[1])
        t += rng.uniform(*OWN_FIXATION_S) * fps
    own = {"eyeBlinkLeft": blink, "eyeBlinkRight": blink,
           "eyeLookOutLeft": np.maximum(side, 0), "eyeLookInRight": np.maximum(side, 0),
           "eyeLookInLeft": np.maximum(-side, 0), "eyeLookOutRight": np.maximum(-side, 0),
           "eyeLookDownLeft": np.maximum(down, 0), "eyeLookDownRight": np.maximum(down, 0),
           "eyeLookUpLeft": np.maximum(-down, 0), "eyeLookUpRight": np.maximum(-down, 0)}
    for name, values in own.items():
        if name in column:
            performed[:, column[name]] = values


def follow_performance(recording, names, start, frames, seed, *, fps=30.0):
    """A performer following ``frames`` of a Live Link Face ``recording`` from its frame ``start`` (the guide),
    after :data:`HOLD` frames of a relaxed face: late by a reaction time with a slow wander, each shape (both sides
    alike) at its own share of the guide's amplitude, smoothed a little (:data:`FOLLOW_LAG_S`...), but for the eyes:
    their own blinks, and looks about the screen the guide plays on (:func:`own_eyes`). Returns
    (weights (F, K) on ``names``, head (F, 6), gaze (F, 2, 2), {"guide", "guide_names", "guide_fps", "lag_s"}): the
    guide as a performer would be given it (its own weights, on time), beside what the face performed."""
    from scipy.ndimage import gaussian_filter1d  # scipy: on first use (the other clips never smooth)

    rng = np.random.default_rng(seed)
    track = read_weights(recording)
    step = max(1, int(round(track.fps / fps)))
    guide = np.nan_to_num(track.values[start:start + step * frames:step])
    lag = rng.uniform(*FOLLOW_LAG_S)
    tail = int(np.ceil((FOLLOW_LAG_S[1] + FOLLOW_WANDER_S) * fps)) + 15
    t = np.arange(frames + tail) / fps
    when = t - lag - FOLLOW_WANDER_S * np.sin(2 * np.pi * rng.uniform(0.05, 0.12) * t + rng.uniform(0, 6.3))
    gain = {}
    performed = np.zeros((HOLD + frames + tail, len(names)))
    for k, name in enumerate(names):
        if name in track.names and name not in NOT_FOLLOWED:  # the eyes: their own (:func:`own_eyes`)
            g = gain.setdefault(name.removesuffix("Left").removesuffix("Right"), rng.uniform(*FOLLOW_GAIN))
            column = guide[:, track.names.index(name)]
            performed[HOLD:, k] = np.clip(g * np.interp(when * fps, np.arange(frames), column, left=0.0, right=0.0),
                                          0.0, 1.0)
    own_eyes(performed[HOLD:], names, rng, fps)
    performed[HOLD:] = gaussian_filter1d(performed[HOLD:], FOLLOW_SIGMA, axis=0, mode="nearest")
    head, gaze = _head_and_gaze(performed, names, rng, fps)
    return performed, head, gaze, {"guide": guide, "guide_names": np.array(track.names), "guide_fps": fps,
                                   "lag_s": lag, "follower": np.array(FOLLOWER)}


def prepare(clip, out, character, *, log=print):
    """Render ``clip``, run its landmark take onto ``character`` (unfused) and cache what the fusion needs:
    ``<out>/<name>.npz`` with the truth, the solve, the blendshape scores and the take's neutral frames (a ROM
    clip also keeps its session's truth: the poses performed, their holds and the weights given)."""
    cached = out / f"{clip.name}.npz"
    video = out / f"{clip.name}.mp4"
    if cached.is_file():
        data = dict(np.load(cached))
        if clip.role not in FOLLOW_ROLES or str(data.get("follower", "")) == FOLLOWER:
            return data
        log(f"{clip.name}: cached with an earlier model of a follower (who copied the guide's eyes): rendered again")
        video.unlink(missing_ok=True)
    shared = shared_folder() / "data"
    neutral, polygons, names, deltas = face_arrays(clip.face, shared)
    extra, shot = {}, Shot(distance=0.5, azimuth=clip.azimuth)
    if clip.role in ROM_ROLES:
        weights, head, gaze, extra = rom_performance(names, clip.start)
        shot = Shot(distance=0.5, azimuth=clip.azimuth, fps=ROM_FPS)
    elif clip.role == "tune-random":
        weights, head, gaze = random_performance(names, clip.start, clip.frames)
    elif clip.role in FOLLOW_ROLES:
        weights, head, gaze, extra = follow_performance(shared / "realdata" / "llf" / clip.recording, names,
                                                        clip.start, clip.frames, follow_seed(clip))
    else:
        recording = shared / "realdata" / (clip.recording if "/" in clip.recording else f"llf/{clip.recording}")
        weights, head, gaze = performance(recording, names, start=clip.start,
                                          frames=clip.frames, hold=HOLD)
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
                      f'[tracking]\nmethod = "landmarks"\nblendshapes = "ignore"\n'
                      f'[output]\nweights = "{solved.name}"\n',
                      encoding="utf-8")
    run_take(load_take_config(config), quiet=True)
    found = track_landmarks(video)
    s = read_weights(solved)
    data = {"truth": weights, "truth_names": np.array(names), "solved": s.values, "solved_names": np.array(s.names),
            "scores": found.blendshapes, "score_names": np.array(found.blendshape_names),
            "neutral": landmark_neutral(found), "render_s": t_render, **extra}
    np.savez(cached, **data)
    if clip.role in ("tune", "tune-random", "tune-follow", "tune-performers"):
        video.unlink()  # the npz keeps what the fusion needs; a reported clip's video is kept for the speed
    log(f"{clip.name}: rendered in {t_render:.0f} s")
    return data


def evaluate(out, table, constant, role="report", solve_reference=None):
    """{clip: {method: region table}} for the clips of ``role``: the landmark solve, the corrected scores, the
    fusion per shape (the table alone), the fusion through the map, the latter with the performer's response from
    the ROM clip of the same face and camera (when it is in ``out``; with ``solve_reference``, also with the
    landmark solve's own response on that clip: measured, not what a take does) and a constant (the tuning clips'
    mean weights on every frame)."""
    names = judged_names()
    rows, follows, roms = {}, {}, {}
    for clip in CLIPS:
        if clip.role != role:
            continue
        data = dict(np.load(out / f"{clip.name}.npz"))
        truth, solved, corrected = columns(data, names)
        rom = calibration_clip(clip)
        methods = {"fused per shape": (None, False, True), "fused, not smoothed": (None, True, False),
                   "fused": (None, True, True)}
        solve_response = {}
        if rom is not None and (out / f"{rom.name}.npz").is_file():
            if rom.name not in roms:  # fitted once per face and camera, not per reported clip
                found = rom_fit(out, rom, table.reference)
                roms[rom.name] = (found.response, None if solve_reference is None else
                                  solve_rom_fit(out, rom, solve_reference, found))
            response, solve = roms[rom.name]
            methods["fused + ROM"] = (response, True, True)
            if solve is not None:
                methods["fused + ROM, solve too"] = (response, True, True)
                solve_response["fused + ROM, solve too"] = solve
        guide = calibration_clip(clip, "follow")
        performer = None
        if guide is not None and (out / f"{guide.name}.npz").is_file():
            if guide.name not in follows:  # fitted once per face and camera, not per reported clip
                follows[guide.name] = follow_fit(out, guide, table)
            performer = follows[guide.name].performer
            methods["fused + guide followed"] = (None, True, True)
        row = {"landmarks": region_rmse(solved, truth, names),
               "scores": region_rmse(np.where(np.isfinite(corrected), corrected, solved), truth, names)}
        for method, (response, cross, smooth) in methods.items():
            solved_names = tuple(str(n) for n in data["solved_names"])
            weights = solve_response[method](data["solved"], solved_names) if method in solve_response else \
                data["solved"]
            fused, _ = fuse(weights, solved_names,
                            FaceScores(data["scores"], tuple(str(n) for n in data["score_names"]), data["neutral"],
                                       response=response, fps=clip.fps, smoothing=smooth,
                                       performer=performer if method == "fused + guide followed" else None),
                            table=table, cross=cross)
            row[method] = region_rmse(columns({**data, "solved": fused}, names)[1], truth, names)
        if constant is not None:
            row["constant"] = region_rmse(np.broadcast_to(constant, truth.shape), truth, names)
        row["truth"] = region_rmse(truth, truth, names)  # its jitter: how rough a real performance is
        rows[clip.name] = row
    return rows


def follow_check(out, table, log=print):
    """Where each guide-following clip placed its guide against where the face performed it (:data:`HOLD` and the
    reaction time: the frame the wander centres on)."""
    for clip in CLIPS:
        if clip.role != "follow" or not (out / f"{clip.name}.npz").is_file():
            continue
        fit = follow_fit(out, clip, table)
        lag = float(np.load(out / f"{clip.name}.npz")["lag_s"])
        log(f"{clip.name}: {fit.summary}; performed from frame {HOLD + 1} with a reaction time of {lag:.2f} s "
            f"({HOLD + lag * clip.fps:.1f} frames in)")


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
    parser.add_argument("--role", choices=("tune", "report", "tune-rom", "calibrate", "tune-random", "report-others",
                                           "follow", "tune-follow", "tune-performers"),
                        action="append",
                        help="only these clips")
    parser.add_argument("--speed", action="store_true", help="also time the landmarks on a reported clip")
    parser.add_argument("--fit", action="store_true",
                        help="fit the lids' slope against the gaze, the fusion table and its map on the tuning clips, "
                             "write them (solvers/video/fusion_table.json, fusion_map.npz) and compare the lids read "
                             "with and without the slope there")
    parser.add_argument("--smoothing", action="store_true", help="compare the fused weights' smoothing widths on the "
                                                                "tuning clips (how fusion.SMOOTHING_S was chosen)")
    parser.add_argument("--fit-rom", action="store_true", help="fit the table's ROM reference on the tuning faces' ROM "
                                                              "clips (role tune-rom) and write it, the gains kept")
    parser.add_argument("--follow-weight", action="store_true",
                        help="compare what a clip following the guide weighs in the map, on the tuning faces (how "
                             "follow.FOLLOW_SHARE was chosen)")
    parser.add_argument("--performers", action="store_true",
                        help="refit the table and map on each set of tuning performers (with and without each, the "
                             "Sentien recording's other windows as a third) and judge every performer's clips")
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
        if args.role is None or clip.role in args.role or (args.performers and clip.role in PERFORMERS_READ):
            prepare(clip, out, character)
    if args.fit:
        table, constant = fit(out)
        cross, measured = fit_cross(out, table)
        table = replace(table, reference=FusionTable.load().reference, map=cross,
                        measured_on={**FusionTable.load().measured_on, **table.measured_on, **measured})
        table.save()
        cross.save(TABLE_FILE.with_name(MAP_FILE_NAME))
        lid_gaze_check(out, table)
    else:  # the constant baseline needs the tuning clips; without them in ``out`` its row is left out
        tuning = [c for c in CLIPS if c.role in MAP_ROLES]
        have = all((out / f"{c.name}.npz").is_file() for c in tuning)
        table, constant = FusionTable.load(), fit(out, log=lambda _m: None)[1] if have else None
    if args.fit_rom:
        reference, rom_clips = fit_reference(out)
        measured = {**table.measured_on, "rom_clips": rom_clips,
                    "rom_command": "python -m facecap.facecap_addon.bench.fusion_bench --out DIR --fit-rom"}
        table = replace(table, measured_on=measured, reference=reference)
        table.save()
    if args.smoothing:
        smoothing_check(out, table)
    if args.follow_weight:
        follow_weight_check(out, table)
    if args.performers:
        performers_check(out, table.reference)
    solve_reference = fit_solve_reference(out)
    rows = evaluate(out, table, constant, solve_reference=solve_reference)
    print_tables(rows)
    others = [c for c in CLIPS if c.role == "report-others"]
    if all((out / f"{c.name}.npz").is_file() for c in others):
        print(f"\nOther performers ({', '.join(sorted({c.recording for c in others}))}): the same faces and cameras")
        print_tables(evaluate(out, table, constant, role="report-others", solve_reference=solve_reference))
    follow_check(out, table)
    videos = sorted(out.glob("report-*.mp4"))
    if videos and args.speed:
        speed(videos[0])
    return 0


def print_tables(rows):
    """Per clip and method the region RMSEs, then the medians and worst cases over the clips."""
    keys = list(REGIONS) + ["visible", "blink_peak", "jitter", "pinned"]
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
            jit = [m[method]["jitter"] for m in mine if method in m]
            pin = [m[method]["pinned"] for m in mine if method in m]
            print(f"{face} {method} ({len(vis)} clips): visible median {np.median(vis):.3f} worst {np.max(vis):.3f}; "
                  f"brows median {np.median(brows):.3f} worst {np.max(brows):.3f}; blink peak worst "
                  f"{np.nanmin(blink):.2f}; jitter median {np.median(jit):.4f}; at 1: median {np.median(pin):.2f} % "
                  f"worst {np.max(pin):.2f} %")
    print_shapes(rows)
    print()
    print("| face | method | " + " | ".join(REGIONS) + " | visible | blink peak | jitter |")
    print("|---|---|" + "---|" * (len(REGIONS) + 3))
    for face in ("ict", "facecap"):  # per region the median over the face's clips and (in brackets) the worst
        mine = [m for c, m in rows.items() if f"-{face}" in c]
        for method in dict.fromkeys(k for m in mine for k in m):
            have = [m[method] for m in mine if method in m]
            cells = [f"{np.median([h[r] for h in have]):.3f} ({max(h[r] for h in have):.3f})"
                     for r in list(REGIONS) + ["visible"]]
            blink = [h["blink_peak"] for h in have]
            jit = [h["jitter"] for h in have]
            print(f"| {face} | {method} ({len(have)} clips) | " + " | ".join(cells)
                  + f" | {np.nanmedian(blink):.2f} ({np.nanmin(blink):.2f}) | {np.median(jit):.4f} ({max(jit):.4f}) |")


if __name__ == "__main__":
    raise SystemExit(main())
