"""Accuracy over distributions of random scenarios, side by side with plain references.

``python -m facecap bench --accuracy [--draws N]`` prints, as median / 90th percentile / worst over
the draws of :mod:`.scenarios` and :mod:`.scenarios_footage`:

* **stabilisation** - weights RMSE of the geometric solve with ``[stabilise] markers = "auto"``
  divided by that with the true rigid set (and the draws where "auto" declined, naming candidates);
* **solve** - weights RMSE with the true rigid set;
* **tracking** - per footage kind: median error (px) over the samples that are really visible
  (a lost sample counts as an infinite error) and lost samples (%), for ``track_points`` and a plain
  pyramidal LK that re-registers every frame to the reference frame (:func:`~.reference_trackers.plain_lk`);
* **flow** - per footage kind: median end-point error (px) on the face of ``dense_flow`` and of
  plain DIS from the reference to every frame (:func:`~.reference_trackers.plain_dis`).

The plain references are deliberately the textbook ~20 lines (tests/core keeps its own copy).
"""

import argparse
import tempfile
import time
import warnings

import numpy as np

from ...capture.stable_markers import suggest_stable_markers
from ...errors import FacecapError
from ...pipeline import RetargetSettings, retarget
from ...video.flow import dense_flow
from ...video.reading import Footage
from ...video.tracking import auto_seeds, track_points
from .reference_trackers import plain_dis, plain_lk
from ..synthetic.scenarios_footage import KINDS, footage_scenario


def summary(values):
    """(median, 90th percentile, worst) of finite ``values``."""
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    if v.size == 0:
        return (np.nan, np.nan, np.nan)
    return float(np.median(v)), float(np.percentile(v, 90)), float(v.max())


def stable_rows(seeds, *, n_frames=360):
    """Per draw: weights RMSE with the true rigid set and with "auto", and what "auto" said."""
    from ..synthetic.scenarios import marker_scenario  # loads scipy

    rows = []
    for seed in seeds:
        s = marker_scenario(seed, n_frames=n_frames)
        true = RetargetSettings(stable_markers=s.character.rigid, neutral_frames=s.neutral_frames)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            r_true = retarget(s.markers, s.character.basis, true)
            row = {"seed": seed, "rmse_true": _rmse(r_true.weights, s.weights), "params": s.params}
            try:
                r_auto = retarget(s.markers, s.character.basis,
                                  RetargetSettings(stable_markers=(), neutral_frames=s.neutral_frames, auto_stable=True))
                row["rmse_auto"], sug = _rmse(r_auto.weights, s.weights), r_auto.stable_suggestion
            except FacecapError as exc:  # "auto" declined and named its candidates
                row["rmse_auto"], row["declined"] = np.nan, str(exc)
                sug = suggest_stable_markers(s.markers, reference_frames=s.neutral_frames)
            row.update(ok=sug.ok, chosen=len(sug.names), problems=list(sug.problems),
                       wrong=sum(n not in set(s.character.rigid) for n in sug.names))
        row["ratio"] = row["rmse_auto"] / row["rmse_true"]
        rows.append(row)
    return rows


def _rmse(w, truth):
    return float(np.sqrt(np.nanmean((w - truth) ** 2)))


def track_row(scenario, *, max_points=48):
    """Tracking figures of one :class:`~.scenarios_footage.FootageScenario` for ours and the plain LK
    (:func:`~.reference_trackers.plain_lk`)."""

    footage = Footage(scenario.path)
    names, seeds = auto_seeds(footage.frame(1), scenario.face_box(), max_points=max_points)
    truth = scenario.truth(seeds, 1)
    hidden = scenario.hidden(truth, margin=10.0)  # within half a window of an edge or the occluder: either way
    near = scenario.hidden(truth, margin=-10.0)
    row = {"kind": scenario.kind, "seed": scenario.seed, "size": scenario.size}
    t0 = time.perf_counter()
    ours = track_points(footage, points=seeds).markers.positions
    t1 = time.perf_counter()
    plain = plain_lk(scenario.path, seeds)
    t2 = time.perf_counter()
    for label, pos, secs in (("ours", ours, t1 - t0), ("plain", plain, t2 - t1)):
        err = np.linalg.norm(pos - truth, axis=2)
        seen = ~hidden
        row[f"{label}_median_px"] = float(np.median(np.where(np.isnan(err), np.inf, err)[seen]))
        row[f"{label}_lost_pct"] = float(100 * np.isnan(err[seen]).mean())
        wrong = near & np.isfinite(err) & (err > 3.0)  # really hidden, yet given a wrong position
        row[f"{label}_wrong_hidden"] = int(wrong.sum())
        row[f"{label}_s"] = secs
    return row


def flow_row(scenario, *, grid_step=1):
    """Dense-flow end-point error on the face (median px over frames and face pixels), ours vs plain DIS
    (:func:`~.reference_trackers.plain_dis`)."""

    x, y, w, h = scenario.face_box()
    t0 = time.perf_counter()
    ours = dense_flow(scenario.path).flows
    t1 = time.perf_counter()
    plain = plain_dis(scenario.path)
    t2 = time.perf_counter()
    row = {"kind": scenario.kind, "seed": scenario.seed, "size": scenario.size}
    box = (slice(y, y + h, grid_step), slice(x, x + w, grid_step))
    pts = np.stack(np.meshgrid(np.arange(x, x + w, grid_step, dtype=float),
                               np.arange(y, y + h, grid_step, dtype=float)), axis=-1)
    truth = [scenario.motion.forward(t, pts) - pts for t in range(scenario.n_frames)]
    for label, flows, secs in (("ours", ours, t1 - t0), ("plain", plain, t2 - t1)):
        errs = [np.median(np.linalg.norm(flows[t][box] - truth[t], axis=-1)) for t in range(1, scenario.n_frames)]
        row[f"{label}_median_px"] = float(np.median(errs))
        row[f"{label}_worst_frame_px"] = float(np.max(errs))
        row[f"{label}_s"] = secs
    return row


def footage_rows(kinds, draws, *, size=(640, 480), n_frames=60, directory=None):
    """{"track": rows of :func:`track_row`, "flow": rows of :func:`flow_row`} over ``draws`` clips of every kind
    (each clip rendered once)."""

    out = {"track": [], "flow": []}
    with tempfile.TemporaryDirectory(dir=directory) as d:
        for kind in kinds:
            for seed in range(draws):
                sc = footage_scenario(seed, kind, d, size=size, n_frames=n_frames)
                out["track"].append(track_row(sc))
                out["flow"].append(flow_row(sc, grid_step=2))
    return out


def _fmt(stats, unit=""):
    return " / ".join(f"{v:.3f}{unit}" for v in stats)


def main(argv=None):
    """Print the accuracy tables; returns the exit status."""


    parser = argparse.ArgumentParser(prog="facecap bench --accuracy")
    parser.add_argument("--draws", type=int, default=30, help="marker takes drawn (default 30)")
    parser.add_argument("--clips", type=int, default=3, help="clips per footage kind (default 3)")
    parser.add_argument("--size", default="640x480", help="footage resolution (default 640x480)")
    parser.add_argument("--frames", type=int, default=60, help="frames per clip (default 60)")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    print(f"stabilisation + solve over {args.draws} random takes (median / p90 / worst):")
    rows = stable_rows(range(args.draws))
    declined = [r for r in rows if not np.isfinite(r["ratio"])]
    print(f"  auto / true rigid set, weights RMSE ratio: {_fmt(summary(r['ratio'] for r in rows), 'x')}")
    print(f"  weights RMSE, true rigid set:              {_fmt(summary(r['rmse_true'] for r in rows))}")
    print(f"  auto declined (named candidates) in {len(declined)} of {len(rows)} draws")
    footage = footage_rows(list(KINDS), args.clips, size=size, n_frames=args.frames)
    for what in ("track", "flow"):
        print(f"{what} per footage kind, {args.clips} clips of {args.frames} frames at {size[0]}x{size[1]} "
              "(median / p90 / worst over the clips of each clip's median error):")
        rows = footage[what]
        for kind in KINDS:
            k = [r for r in rows if r["kind"] == kind]
            line = (f"  {kind:18s} ours {_fmt(summary(r['ours_median_px'] for r in k), ' px')}"
                    f" | plain {_fmt(summary(r['plain_median_px'] for r in k), ' px')}")
            if what == "track":
                line += (f" | lost ours {np.mean([r['ours_lost_pct'] for r in k]):.2f}% plain "
                         f"{np.mean([r['plain_lost_pct'] for r in k]):.2f}% | wrong while hidden ours "
                         f"{sum(r['ours_wrong_hidden'] for r in k)} plain {sum(r['plain_wrong_hidden'] for r in k)}")
            print(line, flush=True)
    return 0
