"""The review page without a browser: its data survives packing, the display reduction never drops a
peak, the frames it pictures and the head motion it plots are the right ones, the markers it draws on
the character are the solve's own, its plots are valid plotly figures, and a 10-minute take's page
stays under 10 MB. (tests/e2e/test_review_browser.py opens the pages in Chromium.)"""

import json
import re
import time

import numpy as np
import plotly.graph_objects as go
import pytest
from review_takes import fabricated_result, sample_solve, stable_markers
from scipy.spatial.transform import Rotation

from facecap.solvers.tools.report import (
    Review,
    Truth,
    build_page,
    head_motion,
    marker_geometry,
    pick_frames,
    shared_plotly_js,
    write_review_page,
)
from facecap.solvers.tools.report import page as page_module
from facecap.solvers.tools.report.blob import Blob, envelope, unpack
from facecap.solvers.tools.report.figures import heat_columns


@pytest.fixture(scope="module")
def solved():
    return sample_solve(720)


def _meta_and_blob(html):
    meta = json.loads(re.search(r'<script type="application/json" id="facecap-meta">(.*?)</script>', html,
                                re.S).group(1).replace("<\\/", "</"))
    blob = re.search(r'<script type="application/octet-stream" id="facecap-blob">(.*?)</script>', html, re.S).group(1)
    return meta, unpack(blob, meta["arrays"])


# -- packing and reduction --------------------------------------------------------------------------------------
def test_blob_round_trip_within_half_a_step_and_keeps_gaps():
    rng = np.random.default_rng(1)
    blob = Blob()
    weights = rng.uniform(-0.2, 1.2, (5, 1000))
    weights[2, 17] = np.nan
    big = rng.normal(0.0, 1e4, 300)  # 1e7 steps of 1e-3: needs int32
    blob.add("w", weights, 1e-3)
    blob.add("big", big, 1e-3)
    blob.add_exact("frames", np.arange(1000) + 0.5)
    text, manifest = blob.pack()
    out = unpack(text, manifest)
    assert {e["name"]: e["dtype"] for e in manifest} == {"w": "i2", "big": "i4", "frames": "f8"}
    assert np.isnan(out["w"][2, 17]) and np.isfinite(out["w"]).sum() == weights.size - 1
    ok = np.isfinite(weights)
    assert np.abs(out["w"][ok] - weights[ok]).max() <= 0.5e-3 + 1e-12
    assert np.abs(out["big"] - big).max() <= 0.5e-3 + 1e-9
    assert np.array_equal(out["frames"], np.arange(1000) + 0.5)


@pytest.mark.parametrize("n, buckets", [(36_000, 1000), (36_000, 200), (1001, 500), (7, 3)])
def test_a_one_frame_spike_survives_the_envelope_anywhere(n, buckets):
    x = np.arange(n, dtype=np.float64) + 1
    rng = np.random.default_rng(n)
    for row in rng.choice(n, size=min(n, 25), replace=False):
        for sign in (1.0, -1.0):
            y = rng.uniform(0.0, 0.1, n) * sign
            y[row] = 0.9 * sign
            xs, ys = envelope(x, y, buckets)
            assert len(xs) <= max(2 * buckets, n)
            assert np.all(np.diff(xs) > 0), "points stay in frame order"
            k = int(np.argmax(np.abs(ys)))
            assert ys[k] == 0.9 * sign and xs[k] == x[row]


def test_envelope_keeps_every_bucket_minimum_and_maximum_and_gaps():
    n, buckets = 10_000, 100
    y = np.sin(np.arange(n) / 50.0)
    y[2000:2300] = np.nan  # a whole bucket and more missing
    xs, ys = envelope(np.arange(n, dtype=float), y, buckets)
    edges = (np.arange(buckets + 1) * n) // buckets
    for b in range(buckets):
        part = y[edges[b]:edges[b + 1]]
        inside = (xs >= edges[b]) & (xs < edges[b + 1])
        if np.isnan(part).all():
            assert np.isnan(ys[inside]).all() and inside.sum() == 1
        else:
            assert np.nanmax(ys[inside]) == np.nanmax(part) and np.nanmin(ys[inside]) == np.nanmin(part)


def test_heat_columns_keep_each_marker_worst_frame():
    values = np.full((36_000, 3), 0.4)
    values[12_345, 1] = 5.0
    values[:, 2] = np.nan
    centres, top = heat_columns(np.arange(36_000, dtype=float) + 1, values, columns=1200)
    assert top.shape == (3, 1200) and centres.shape == (1200,)
    col = 12_345 * 1200 // 36_000
    assert top[1, col] == 5.0 and np.count_nonzero(top[1] == 5.0) == 1
    assert centres[col] - 15 <= 12_346 <= centres[col] + 15
    assert np.isnan(top[2]).all() and np.all(top[0] == 0.4)


# -- what the page shows ------------------------------------------------------------------------------------------
def test_picked_frames_are_the_worst_residuals_and_the_strongest_peaks(solved):
    result = solved[0]
    picks = pick_frames(result, worst=3, peaks=5, fps=60)
    worst = [row for row, kind, _ in picks if kind == "worst"]
    peaks = [(row, label) for row, kind, label in picks if kind == "peak"]
    assert [row for row, _, _ in picks] == sorted(row for row, _, _ in picks)
    assert len(worst) == 3 and int(np.nanargmax(result.residual_rms)) in worst
    assert min(abs(a - b) for i, a in enumerate(worst) for b in worst[i + 1:]) >= 36  # a second apart (or F/20)
    r = result.residual_rms
    assert all(r[row] >= np.nanpercentile(r, 95) for row in worst)
    w = np.nan_to_num(result.weights)
    strongest = result.shape_names[int(np.argmax(w.max(axis=0)))]
    assert any(strongest in label for _, label in peaks)
    for row, label in peaks:
        name, value = label.split()[1], float(label.split()[2])
        k = result.shape_names.index(name)
        assert row == int(np.argmax(w[:, k])) and value == pytest.approx(w[row, k], abs=0.005)


def test_head_motion_is_the_synthetic_head_motion(solved):
    result, _, _, _, take = solved
    head = head_motion(result.stabilise)
    true = Rotation.from_rotvec(take.head_rotvec_deg, degrees=True).as_euler("xyz", degrees=True)
    ok = ~head["flagged"]
    # the solve recovers the head to 0.15 deg (the demo's figure); the Euler split must not add to it
    assert np.abs(head["rotation"][ok] - true[ok]).max() < 0.25
    assert head["units"] == "mm" and head["translation"].shape == (720, 3)
    assert np.nanmax(np.abs(head["translation"])) < 200  # the head's centre, not the capture origin


def test_markers_carried_onto_the_character_are_the_solves_residual(solved):
    result, _, settings, basis, _ = solved
    geometry, why = marker_geometry(result, basis, settings)
    assert why == "" and geometry.names == result.marker_names
    rows = np.arange(result.frames.size)
    distance = np.linalg.norm(geometry.captured(rows) - geometry.model(rows), axis=2)
    ok = np.isfinite(result.frame_marker_residual)
    assert ok.mean() > 0.9
    assert np.abs(distance[ok] - result.frame_marker_residual[ok]).max() < 1e-12
    assert np.allclose(geometry.binding_mm, result.alignment_residual * 1e3, atol=1e-9)


def test_no_marker_geometry_says_why(solved):
    result, _, settings, _, _ = solved
    geometry, why = marker_geometry(result, None, settings)
    assert geometry is None and "vertex groups" in why


def test_truth_is_matched_by_frame_and_name():
    truth = Truth(np.array([3.0, 1.0, 2.0]), ("b", "a"), np.array([[30, 3], [10, 1], [20, 2]], dtype=float))
    out = truth.aligned(np.array([1.0, 2.0, 4.0]), ("a", "c", "b"))
    assert np.array_equal(out[:2, 0], [1, 2]) and np.array_equal(out[:2, 2], [10, 20])
    assert np.isnan(out[2]).all() and np.isnan(out[:, 1]).all()


# -- the page ---------------------------------------------------------------------------------------------------
def _validate(figure):
    """Every trace and the layout must be valid plotly (plotly.js ignores misspelt attributes silently)."""
    data = []
    for t in figure["traces"]:
        trace = dict(t["trace"])
        if "y" in t:  # points come from the blob in the page
            trace["x"], trace["y"] = [1, 2], [0.0, 1.0]
        data.append(trace)
    go.Figure(data=data, layout=figure["layout"])  # raises ValueError on anything invalid


def test_page_figures_are_valid_plotly_with_the_expected_traces(solved):
    result, truth, settings, basis, _ = solved
    geometry, _ = marker_geometry(result, basis, settings)
    review = Review(result=result, take="sample", settings=settings, fps=60.0, geometry=geometry,
                    truth=Truth(result.frames, result.shape_names, truth, "truth.csv"))
    html, figures = build_page(review)
    counts = {f["id"]: len(f["traces"]) for f in figures}
    K = len(result.shape_names)
    assert counts == {"weights": 2 * K, "residual": 2, "heat": 1, "head_rotation": 3, "head_translation": 3,
                      "stabilise": 3, "binding": 1}
    for figure in figures:
        _validate(figure)
    meta, arrays = _meta_and_blob(html)
    assert np.abs(arrays["weights"] - result.weights.T).max() <= 0.5e-3 + 1e-12
    assert np.abs(arrays["truth"] - truth.T).max() <= 0.5e-3 + 1e-12
    assert np.nanmax(np.abs(arrays["residual"] - result.residual_rms * 1e3)) <= 0.5e-4 + 1e-12
    shown = [t["trace"]["name"] for t in meta["figures"][0]["traces"][:K] if t["trace"].get("visible", True) is True]
    peaks = np.argsort(-np.nanmax(result.weights, axis=0))[:8]
    assert sorted(shown) == sorted(result.shape_names[k] for k in peaks)
    assert "RMSE" in html and "No contact sheet" in html  # truth summary; no renders without Blender


def test_strategies_without_markers_or_head_leave_those_plots_out(solved):
    result = solved[0]
    from dataclasses import replace

    parallel = replace(result, stabilise=None, frame_marker_residual=None, residual_rms=np.full(result.frames.size, np.nan),
                       strategy="parallel", marker_names=())
    html, figures = build_page(Review(result=parallel, take="weights only"))
    assert [f["id"] for f in figures] == ["weights"]
    assert "No head motion" in html and "does not fit markers" in html


def test_the_page_says_what_the_solve_knew_of_the_actor_and_whether_it_is_plausible(solved):
    """A semantic solve states its tier first; a geometric one says it has no model of the actor."""
    from facecap.solvers.pipeline import RetargetSettings, retarget

    _, _, _, basis, take = solved
    semantic = retarget(take.markers, basis, RetargetSettings(stable_markers(), (1, 50)))
    html, _ = build_page(Review(result=semantic, take="sample"))
    actor = html[html.index("<h3>The actor</h3>"):html.index("<h3>Warnings</h3>")]
    assert "<b>character</b>: nothing is known about the actor" in actor and "taken as the actor" in actor
    assert "Held at rest (no marker sees them): eyeLookDownLeft" in actor and "Plausible:" in actor
    html, _ = build_page(Review(result=solved[0], take="sample"))
    assert "does not solve against a model of the actor" in html


def test_ten_minute_page_is_under_10_mb(tmp_path):
    result, clean = fabricated_result(36_000)
    review = Review(result=result, take="long", fps=60.0, truth=Truth(result.frames, result.shape_names, clean))
    t0 = time.perf_counter()
    info = write_review_page(tmp_path / "long.html", review)
    seconds = time.perf_counter() - t0
    print(f"36,000 frames x 52 shapes x 68 markers (+ truth): {info['bytes'] / 1e6:.2f} MB in {seconds:.2f} s")
    assert info["bytes"] < 10e6
    html = (tmp_path / "long.html").read_text(encoding="utf-8")
    meta, arrays = _meta_and_blob(html)
    assert arrays["weights"].shape == (52, 36_000)  # every frame is in the page, for zooming


def test_a_shared_plotly_js_is_written_once_and_loaded_by_relative_path(tmp_path, solved):
    js = shared_plotly_js(tmp_path / "batch")
    mtime = js.stat().st_mtime_ns
    assert shared_plotly_js(tmp_path / "batch") == js and js.stat().st_mtime_ns == mtime
    info = write_review_page(tmp_path / "batch" / "takes" / "a.html", Review(result=solved[0], take="a"),
                             plotly_js=js)
    html = info["path"].read_text(encoding="utf-8")
    assert '<script src="../plotly.min.js"></script>' in html
    assert info["bytes"] < 2e6  # the 4.8 MB library is not inside


def test_missing_plotly_is_a_one_line_error(monkeypatch, solved):
    monkeypatch.setattr(page_module.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(page_module.MissingPlotlyError, match="pip install plotly"):
        build_page(Review(result=solved[0], take="a"))


def test_page_text_cannot_end_its_scripts_early(solved):
    from dataclasses import replace

    result = replace(solved[0], warnings=("</script><script>alert(1)</script>",))
    html, _ = build_page(Review(result=result, take="</script>"))
    assert html.count("<script") == html.count("</script>")
    assert "&lt;/script&gt;" in html


def test_a_2d_tracks_page_plots_the_in_plane_head_motion():
    from review_takes import sample_basis, stable_markers
    from test_pipeline_2d import tracks_2d

    from facecap.solvers import RetargetSettings, retarget
    from facecap.solvers.tools.synthetic.synth import performance_weights

    basis = sample_basis()
    truth = performance_weights(basis.shape_names, 240, seed=0)
    result = retarget(tracks_2d(basis, truth, stable_markers()), basis, RetargetSettings(stable_markers(), (1, 50)))
    head = head_motion(result.stabilise)
    assert head["units"] == "px" and head["rotation"].shape == (240, 1) and head["translation"].shape == (240, 2)
    assert 4.0 < np.nanmax(np.abs(head["rotation"])) < 9.0  # the synthetic roll: up to 8 degrees
    geometry, why = marker_geometry(result, basis, RetargetSettings(stable_markers(), (1, 50)))
    assert geometry is None and "2D" in why
    html, figures = build_page(Review(result=result, take="2d"))
    counts = {f["id"]: len(f["traces"]) for f in figures}
    assert counts["head_rotation"] == 1 and counts["head_translation"] == 2
    for figure in figures:
        _validate(figure)


def test_the_settings_table_reads_as_words_not_python(solved):
    """``mapping.table []``, ``(0.0, 0.3)``, ``None``, ``True`` once leaked into the table."""
    from dataclasses import replace

    from facecap.solvers.strategies.options import CalibrationSettings, MappingSettings
    from facecap.solvers.tools.report.sections import settings_rows

    settings = solved[2]
    for strategy in ("geometric", "calibrated", "parallel", "linear", "pca", "refine"):
        rows = settings_rows(replace(settings, strategy=strategy, mapping=MappingSettings(),
                                     calibration=CalibrationSettings(), locks=(("tongueOut", 0.0),)))
        for name, value in rows:
            assert not re.search(r"[\[\]{}']|\bNone\b|\bTrue\b|\bFalse\b|\(\)|^\(", value), (strategy, name, value)
    rows = dict(settings_rows(replace(settings, strategy="parallel", mapping=MappingSettings(table=(("a", "b", 1.0),)),
                                      locks=(("tongueOut", 0.0),))))
    assert rows["mapping.table"] == "a b 1" and rows["mapping.mirror"] == "off" and rows["locks"] == "tongueOut = 0"
    assert dict(settings_rows(replace(settings, strategy="parallel")))["mapping.table"] == "none"


def test_heat_map_rows_are_grouped_by_face_region(solved):
    result, _, settings, basis, _ = solved
    geometry, _ = marker_geometry(result, basis, settings)
    _, figures = build_page(Review(result=result, take="sample", settings=settings, geometry=geometry))
    heat = next(f for f in figures if f["id"] == "heat")
    regions = [a["text"] for a in heat["layout"]["annotations"]]
    assert regions == ["head (stable)", "forehead and brows", "eyes", "nose", "cheeks", "mouth", "jaw and chin"]
    rows = heat["traces"][0]["trace"]["y"]
    assert sorted(rows) == sorted(result.marker_names) and rows[0].startswith("head_")
    assert len(heat["layout"]["shapes"]) == len(regions) - 1  # a line between two regions


def test_rings_use_one_absolute_scale_with_a_legend(solved):
    """A 0.45 mm frame once showed red: each tile coloured its rings by its own worst marker."""
    from facecap.solvers.tools.report.review import ContactSheet, Tile
    from facecap.solvers.tools.report.sections import RING_SCALE_MM, _heat_colour, contact_html

    result = solved[0]
    pts = np.array([[10.0, 10.0], [20.0, 20.0]])
    tiles = tuple(Tile(float(result.frames[i]), "t", "peak", b"\x89PNG", 224, 280, pts, pts + 1, np.array(d))
                  for i, d in ((0, [0.2, 0.45]), (1, [0.2, 4.9])))
    html = contact_html(Review(result=result, take="t", sheet=ContactSheet(tiles, ("a", "b"))))
    first, second = html.split('<figure')[1:3]
    assert _heat_colour(0.45 / RING_SCALE_MM) in first and _heat_colour(1.0) not in first  # not red
    assert _heat_colour(4.9 / RING_SCALE_MM) in second
    assert 'class="ring-legend"' in html and f"{RING_SCALE_MM:g} and more: red" in html


def test_a_phone_take_shows_the_head_the_phone_measured(solved):
    """A Live Link Face page said "No head motion" although the file has head angles."""
    from dataclasses import replace

    result = replace(solved[0], stabilise=None, frame_marker_residual=None, strategy="parallel", marker_names=(),
                     residual_rms=np.full(solved[0].frames.size, np.nan))
    angles = np.radians(np.stack([np.linspace(-10, 10, result.frames.size)] * 3, axis=1))
    html, figures = build_page(Review(result=result, take="phone", head_angles=angles))
    head = next(f for f in figures if f["id"] == "head_rotation")
    assert [t["trace"]["name"] for t in head["traces"]] == ["yaw (turn)", "pitch (nod)", "roll (tilt)"]
    assert "No head motion" not in html and "as the phone tracked it" in html
    _, arrays = _meta_and_blob(html)
    assert np.abs(arrays["head_rotation"][0] - np.linspace(-10, 10, result.frames.size)).max() <= 0.5e-3


def test_every_shape_has_a_small_plot_worst_first_against_the_truth(solved):
    result, truth = solved[0], solved[1]
    html, _ = build_page(Review(result=result, take="s", truth=Truth(result.frames, result.shape_names, truth)))
    order = [int(k) for k in re.findall(r'<button class="small" data-shape="(\d+)"', html)]
    assert sorted(order) == list(range(len(result.shape_names)))
    rmse = np.sqrt(np.nanmean((result.weights - truth) ** 2, axis=0))
    assert np.all(np.diff(rmse[order]) <= 1e-12), "worst first"
