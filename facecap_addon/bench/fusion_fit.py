"""The fits of the fusion benchmark (``fusion_bench --fit``, ``--fit-rom``, ``--smoothing``, ``--follow-weight``,
``--performers``): the fusion table and its map on the tuning clips, the ROM reference on the tuning faces' ROM
sessions, the comparisons the fused weights' smoothing and a guide-following clip's weight were chosen by, and what
a performer's own windows among the tuning clips do for their reported clips. Only tuning clips are fitted on
(roles ``tune``, ``tune-rom``, ``tune-random``, ``tune-follow``, ``tune-performers``); ``--performers`` alone reads
the reported clips, to judge them."""

import warnings
from dataclasses import replace

import numpy as np

from ...solvers.video.fusion import (
    UNSMOOTHED,
    FaceScores,
    fit_lid_gaze,
    fit_map,
    fit_table,
    fuse,
    lids_against_gaze,
    smooth_runs,
)
from ...solvers.video.response import ScoreResponse
from .fusion_clips import (CLIPS, MAP_ROLES, columns, follow_fit, jitter, judged_names, performer, region_rmse,
                           rom_fit, solve_rom_fit)


#: The roles of the tuning clips that perform a recording (the per-shape table is fitted on these alone).
PERFORMANCE_ROLES = ("tune", "tune-performers")


def fit(out, *, lid_gaze=None, clips=None, log=print):
    """Fit the fusion table on the tuning clips in ``out`` (``clips``, or the roles of :data:`MAP_ROLES`): first the
    solve's lids against its gaze (``lid_gaze``, on every tuning clip; or as given), then the per-shape gains (on the
    performances) with the lids so read; returns the table (not saved) and the constant baseline."""
    names = judged_names()
    every = list(clips) if clips is not None else [c for c in CLIPS if c.role in MAP_ROLES]
    raw = [columns(dict(np.load(out / f"{c.name}.npz")), names) for c in every]
    truth, solved, _ = (np.concatenate(p) for p in zip(*raw))
    if lid_gaze is None:
        lid_gaze = fit_lid_gaze(truth, solved, names)
        log(f"lids against the gaze fitted on {len(every)} clips: a full look down closes {-lid_gaze:.3f} of the "
            "lid gap")
    parts = [p for c, p in zip(every, tune_parts(raw, names, lid_gaze)) if c.role in PERFORMANCE_ROLES]
    truth, solved, corrected = (np.concatenate(p) for p in zip(*parts))
    tuned = [c.name for c in every if c.role in PERFORMANCE_ROLES]
    table = fit_table(np.nan_to_num(truth), solved, corrected, names,
                      measured_on={"clips": tuned, "frames": int(len(truth)),
                                   "command": "python -m facecap.facecap_addon.bench.fusion_bench --out DIR --fit"})
    log(f"fusion table fitted on {len(tuned)} clips, {len(truth)} frames")
    return replace(table, lid_gaze=lid_gaze), np.nanmean(truth, axis=0)


def tune_parts(parts, names, lid_gaze):
    """Cached clips' (truth, solve, corrected scores) with the solve's lids read against its gaze, as ``fuse`` reads
    them before the table and map."""
    return [(t, lids_against_gaze(s, names, lid_gaze), c) for t, s, c in parts]


#: The ridges the fusion map is chosen among (per clip, towards the per-shape table).
MAP_RIDGES = (3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3)


def fit_cross(out, table, *, clips=None, log=print):
    """The fusion map on the tuning faces' clips (``clips``, or the roles of :data:`MAP_ROLES`: performances, ROM
    sessions and random activations alike): its ridge chosen on :func:`performer_folds` (a face and a performer
    nobody tuned on, as every user's take is: the median visible RMSE of the judged clips, the larger ridge on a tie
    to 3 decimals); the older criterion, each tuning identity left out with every performer kept, printed beside.
    Returns (the map, what it was measured on)."""
    names = judged_names()
    clips = list(clips) if clips is not None else [c for c in CLIPS if c.role in MAP_ROLES]
    parts = dict(zip([c.name for c in clips], tune_parts([columns(dict(np.load(out / f"{c.name}.npz")), names)
                                                          for c in clips], names, table.lid_gaze)))
    identity_folds = [([c for c in clips if c.face != face], [c for c in clips if c.face == face], table)
                      for face in sorted({c.face for c in clips})]
    folds = [(kept, judged, fit(out, lid_gaze=table.lid_gaze, clips=kept, log=lambda _m: None)[0])
             for kept, judged in performer_folds(clips)]
    curves = {}
    for label, runs in (("identity", identity_folds), ("performer", folds)):
        curves[label] = {}
        for lam in MAP_RIDGES:
            errs = []
            for kept, judged, tab in runs:
                held = replace(tab, map=fit_map([parts[c.name] for c in kept], names, lam))
                for c in judged:
                    truth, solved, corrected = parts[c.name]
                    errs.append(region_rmse(_map_only(held, solved, corrected, names), truth, names)["visible"])
            curves[label][lam] = round(float(np.median(errs)), 3)
    scores = curves["performer"] if folds else curves["identity"]
    best = min(scores.values())
    lam = max(k for k, v in scores.items() if v == best)
    for label, what in (("identity", "each tuning identity left out"),
                        ("performer", "a tuning identity and performer left out")):
        if curves[label] and (label == "identity" or folds):
            log(f"fusion map, {what}: visible RMSE per ridge "
                + ", ".join(f"{k:g}: {v:.3f}" for k, v in curves[label].items()))
    log(f"fusion map: ridge {lam:g} chosen" + (" with a performer left out" if folds else ""))
    measured = {"map_clips": [c.name for c in clips], "map_ridge": lam,
                "map_ridge_cv": {f"{k:g}": v for k, v in scores.items()},
                "map_ridge_cv_identity": {f"{k:g}": v for k, v in curves["identity"].items()}}
    return fit_map(list(parts.values()), names, lam), measured


def performer_folds(clips):
    """[(kept, judged)]: each tuning identity with each tuning performer left out in turn; fitted on the other
    identities' clips but that performer's (their ROM sessions and random activations kept: nobody's habits),
    judged on the left-out identity's performances of that performer. Empty with fewer than two performers."""
    people = sorted({performer(c) for c in clips if c.role in PERFORMANCE_ROLES})
    if len(people) < 2:
        return []
    folds = []
    for face in sorted({c.face for c in clips}):
        for who in people:
            judged = [c for c in clips if c.face == face and c.role in PERFORMANCE_ROLES and performer(c) == who]
            kept = [c for c in clips if c.face != face and performer(c) != who]
            if judged and kept:
                folds.append((kept, judged))
    return folds


def lid_gaze_check(out, table, *, log=print):
    """How reading the solve's lids against its gaze was chosen, on the tuning clips only: the table refitted without
    it and with it (``table.lid_gaze``), each tuning identity's clips through a map fitted without that identity at
    the table's ridge; the median visible and lids RMSE of its performances and of every tuning clip."""
    names = judged_names()
    lam = table.measured_on.get("map_ridge", 0.03)
    clips = [c for c in CLIPS if c.role in MAP_ROLES]
    raw = [columns(dict(np.load(out / f"{c.name}.npz")), names) for c in clips]
    got = {}
    for slope in (0.0, table.lid_gaze):
        tab = fit(out, lid_gaze=slope, log=lambda _m: None)[0]
        parts = dict(zip([c.name for c in clips], tune_parts(raw, names, slope)))
        rows = {"performances": [], "every tuning clip": []}
        for face in sorted({c.face for c in clips}):
            held = replace(tab, map=fit_map([parts[c.name] for c in clips if c.face != face], names, lam))
            for c in clips:
                if c.face == face:
                    truth, solved, corrected = parts[c.name]
                    r = region_rmse(_map_only(held, solved, corrected, names), truth, names)
                    rows["every tuning clip"].append(r)
                    if c.role == "tune":
                        rows["performances"].append(r)
        got[slope] = rows
    for kind in ("performances", "every tuning clip"):
        (a, b) = (got[k][kind] for k in (0.0, table.lid_gaze))
        med = lambda rows, key: float(np.median([r[key] for r in rows]))  # noqa: E731
        peaks = [np.nanmin([r["blink_peak"] for r in rows]) for rows in (a, b)]
        log(f"lids against the gaze, {kind} ({len(a)} clips, each identity left out): visible "
            f"{med(a, 'visible'):.4f} -> {med(b, 'visible'):.4f}, lids {med(a, 'lids'):.4f} -> {med(b, 'lids'):.4f}"
            + (f", worst blink peak {peaks[0]:.2f} -> {peaks[1]:.2f}" if kind == "performances" else ""))
    return got


#: The shares of the map's tuning clips a performer's guide-following clip may weigh (``--follow-weight``).
FOLLOW_SHARES = (0.0, 1 / 24, 1 / 12, 1 / 6, 1 / 3, 2 / 3, 4 / 3)


def follow_weight_check(out, table, *, log=print):
    """How much a performer's clip that follows the guide weighs in the map (``follow.FOLLOW_SHARE``), chosen on the
    tuning faces only: each tuning identity's clips through a map fitted without that identity (at the table's
    ridge), with its own clip following the guide from the same camera (role tune-follow) at each share of
    :data:`FOLLOW_SHARES` of the map's clips (0: none). Judged on the performances of the tuning performer the guide
    is not from (``TUNING_OTHER``: Alex's own, from the guide's recording, favour any weight), the best median wins,
    the smaller share on a tie to 3 decimals; the guide's performer, the ROM sessions and the random activations are
    printed beside. Returns {share: {kind: (median, worst visible RMSE)}}."""
    names = judged_names()
    lam = table.measured_on.get("map_ridge", 0.03)
    clips = [c for c in CLIPS if c.role in MAP_ROLES]
    parts = dict(zip([c.name for c in clips], tune_parts([columns(dict(np.load(out / f"{c.name}.npz")), names)
                                                          for c in clips], names, table.lid_gaze)))
    guides = {(c.face, c.azimuth): c for c in CLIPS if c.role == "tune-follow"}
    guide = next(iter(guides.values())).recording

    def kind(c):
        if c.role != "tune":
            return c.role
        return "the guide's performer" if c.recording == guide else "another performer"

    got = {}
    for share in FOLLOW_SHARES:
        errs = {}
        for face in sorted({c.face for c in clips}):
            kept = [c.name for c in clips if c.face != face]
            held = replace(table, map=fit_map([parts[n] for n in kept], names, lam),
                           measured_on={**table.measured_on, "map_clips": kept})
            for az in sorted({c.azimuth for c in clips}):
                tab = held
                if share > 0:
                    tab = follow_fit(out, guides[face, az], held, clips=share * len(kept)).performer(held)
                for c in clips:
                    if c.face == face and c.azimuth == az:
                        truth, solved, corrected = parts[c.name]
                        errs.setdefault(kind(c), []).append(
                            region_rmse(_map_only(tab, solved, corrected, names), truth, names)["visible"])
        got[share] = {k: (round(float(np.median(v)), 3), round(float(np.max(v)), 3)) for k, v in errs.items()}
        log(f"a guide followed at {share:.4g} of the map's clips (each tuning identity left out): "
            + ", ".join(f"{k} {v[0]:.3f} (worst {v[1]:.3f})" for k, v in got[share].items()))
    best = min(v["another performer"][0] for v in got.values())
    chosen = min(k for k, v in got.items() if v["another performer"][0] == best)
    log(f"chosen {chosen:.4g}: the best median on another performer's performances, the smallest share on a tie")
    return got


#: The tuning performers ``--performers`` fits on, in turn: the shipped fit's two, all three, and each of the
#: shipped two left out (Sentien's own windows, role tune-performers, standing in).
PERFORMER_FITS = (("alex", "jmtechart"), ("alex", "jmtechart", "sentien"), ("jmtechart", "sentien"),
                  ("alex", "sentien"))
#: The roles of the clips ``--performers`` reads (rendered first when missing).
PERFORMERS_READ = (*MAP_ROLES, "tune-performers", "report", "report-others")


def performer_groups():
    """{(performer, face): the clips each performer is judged on}: Alex's and Sentien's reported clips per reported
    face; Jason's, who has no other window, his tuning clips (the tuning identities), judged only by a fit without
    him."""
    def of(role, face):
        return [c for c in CLIPS if c.role == role and c.face == face]
    return {("alex", "ict-mean"): of("report", "ict-mean"), ("alex", "facecap"): of("report", "facecap"),
            ("jmtechart", "ict"): [c for c in CLIPS if c.role == "tune" and performer(c) == "jmtechart"],
            ("sentien", "ict-mean"): of("report-others", "ict-mean"),
            ("sentien", "facecap"): of("report-others", "facecap")}


def performer_fit_clips(people):
    """The clips a fit on the tuning performers ``people`` reads: the ROM sessions and random activations (nobody's
    habits) and those performers' windows."""
    return [c for c in CLIPS if (c.role in MAP_ROLES and performer(c) is None)
            or (c.role in PERFORMANCE_ROLES and performer(c) in people)]


def performers_check(out, reference, *, log=print):
    """What the fused weights of each performer's clips (uncalibrated) owe to that performer being tuned on: the
    table and map fitted on each set of :data:`PERFORMER_FITS` (as ``--fit`` fits them), every group of
    :func:`performer_groups` judged; a performer's cell marked "seen" when the fit read their other windows. Returns
    {fit: {group: (median visible, worst visible, median brows, seen)}}."""
    names = judged_names()
    groups = performer_groups()
    got = {}
    for people in PERFORMER_FITS:
        clips = performer_fit_clips(people)
        table = fit(out, clips=clips, log=lambda _m: None)[0]
        cross, measured = fit_cross(out, table, clips=clips, log=lambda m: log(f"  {' + '.join(people)}: {m}"))
        table = replace(table, map=cross, reference=reference)
        row = {}
        for (who, face), group in groups.items():
            rows = []
            for clip in group:
                data = dict(np.load(out / f"{clip.name}.npz"))
                truth = columns(data, names)[0]
                fused, _ = fuse(data["solved"], tuple(str(n) for n in data["solved_names"]),
                                FaceScores(data["scores"], tuple(str(n) for n in data["score_names"]),
                                           data["neutral"], fps=clip.fps), table=table)
                rows.append(region_rmse(columns({**data, "solved": fused}, names)[1], truth, names))
            vis, brows = [r["visible"] for r in rows], [r["brows"] for r in rows]
            row[who, face] = (float(np.median(vis)), float(np.max(vis)), float(np.median(brows)), who in people)
        got[people] = row
        log(f"fitted on {' + '.join(people)}: {len(clips)} clips, the map's ridge {measured['map_ridge']:g}")
    log("Each performer's clips, fused uncalibrated: visible median (worst), brows median; (seen): the fit read "
        "that performer's other windows")
    log("| fitted on | " + " | ".join(f"{who}, {face}" for who, face in groups) + " |")
    log("|---|" + "---|" * len(groups))
    for people, row in got.items():
        log(f"| {' + '.join(people)} | " + " | ".join(f"{v[0]:.3f} ({v[1]:.3f}), brows {v[2]:.3f}"
                                                       + (" (seen)" if v[3] else "") for v in row.values()) + " |")
    return got


def _map_only(table, solved, corrected, names):
    """The fused weights of cached columns (on the map's ``names``, the scores already corrected) through
    ``table``'s map, every input had (NaN read as 0)."""
    S = len(names)
    W = table.map.weights(table, np.ones(S, bool), np.ones(S, bool))
    return np.clip(np.nan_to_num(np.concatenate([corrected, solved], axis=1)) @ W, 0.0, 1.0)


#: The smoothing widths (frames at 30 frames/s) ``--smoothing`` compares on the tuning clips.
SMOOTHING_FRAMES = (0.0, 0.5, 0.7, 1.0, 1.5, 2.0)


def smoothing_check(out, table, *, log=print):
    """How the fused weights' smoothing over time (``fusion.SMOOTHING_S``) was chosen, on the tuning clips only: each
    tuning identity's performance clips fused through a map fitted without that identity (as ``fit_cross`` judges
    its ridge), smoothed by each width of :data:`SMOOTHING_FRAMES` (blinks left sharp, as ``fuse`` does), their
    jitter against their truth's, the visible RMSE and the blink peaks (medians, worst). The width at which the
    fused weights are as rough as the truth is the one to keep."""
    names = judged_names()
    lam = table.measured_on.get("map_ridge", 0.03)
    clips = [c for c in CLIPS if c.role in MAP_ROLES]
    parts = dict(zip([c.name for c in clips], tune_parts([columns(dict(np.load(out / f"{c.name}.npz")), names)
                                                          for c in clips], names, table.lid_gaze)))
    sharp = np.array([n in UNSMOOTHED for n in names])
    rows = {s: [] for s in SMOOTHING_FRAMES}
    truth_jitter = []
    for face in sorted({c.face for c in clips}):
        tab = replace(table, map=fit_map([parts[c.name] for c in clips if c.face != face], names, lam))
        for c in clips:
            if c.role != "tune" or c.face != face:
                continue
            truth, solved, corrected = parts[c.name]
            fused = _map_only(tab, solved, corrected, names)
            truth_jitter.append(jitter(truth))
            for sigma in SMOOTHING_FRAMES:
                smooth = fused.copy()
                if sigma > 0:
                    every = np.ones(len(fused), dtype=bool)
                    for j in np.flatnonzero(~sharp):
                        smooth[:, j] = smooth_runs(fused[:, j], every, sigma)
                rows[sigma].append(region_rmse(np.clip(smooth, 0.0, 1.0), truth, names))
    log(f"smoothing on the tuning clips ({len(truth_jitter)}, each identity through a map fitted without it): "
        f"truth jitter {np.median(truth_jitter):.4f}")
    for sigma, got in rows.items():
        vis, jit, blink = ([g[k] for g in got] for k in ("visible", "jitter", "blink_peak"))
        log(f"  sigma {sigma:g} frames: jitter {np.median(jit):.4f} ({max(jit):.4f}), visible {np.median(vis):.4f} "
            f"({max(vis):.4f}), blink peak {np.nanmedian(blink):.2f} ({np.nanmin(blink):.2f})")
    return rows


def fit_reference(out, *, log=print):
    """The tuning faces' ROM response (``FusionTable.reference``): each "tune-rom" clip fitted alone, then per score
    the median gain and offset over the clips that calibrated it; the identity for a score fewer than half of them
    calibrated (it does not respond on these faces)."""
    rom_clips = [c for c in CLIPS if c.role == "tune-rom" and (out / f"{c.name}.npz").is_file()]
    reference = median_response([rom_fit(out, c).response for c in rom_clips])
    log(f"ROM reference fitted on {len(rom_clips)} clips: {len(reference.changed())} scores")
    return reference, [c.name for c in rom_clips]


def fit_solve_reference(out):
    """The tuning faces' landmark solve's ROM response (what ``solve_rom_fit`` is relative to), as
    :func:`fit_reference` fits theirs for the scores; None when a tuning ROM clip is not in ``out``."""
    rom_clips = [c for c in CLIPS if c.role == "tune-rom"]
    if not all((out / f"{c.name}.npz").is_file() for c in rom_clips):
        return None
    return median_response([solve_rom_fit(out, c) for c in rom_clips])


def median_response(fits):
    """One ScoreResponse from several clips' (same names): per name the median gain and offset over the clips that
    changed it; the identity for a name fewer than half of them changed."""
    names = fits[0].names
    changed = np.array([[n in f.changed() for n in names] for f in fits])
    gains, offsets = np.stack([f.gain for f in fits]), np.stack([f.offset for f in fits])
    keep = changed.sum(axis=0) * 2 > len(fits)
    gain, offset = np.ones(len(names)), np.zeros(len(names))
    with warnings.catch_warnings():  # a kept score calibrated on some clips only: the median of those
        warnings.simplefilter("ignore", RuntimeWarning)
        gain[keep] = np.nanmedian(np.where(changed, gains, np.nan)[:, keep], axis=0)
        offset[keep] = np.nanmedian(np.where(changed, offsets, np.nan)[:, keep], axis=0)
    return ScoreResponse(names, gain, offset, fits[0].sheet)
