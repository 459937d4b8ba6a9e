"""The review page's static HTML: the header (take, character, strategy settings, warnings, timings),
the contact sheet and the binding. Plots are placeholders (``<div id="plot-...">``) that
``review.js`` fills."""

import base64
import dataclasses
from html import escape
from pathlib import Path

import numpy as np

#: The strategy sections of ``RetargetSettings`` that each strategy reads.
STRATEGY_SECTIONS = {"calibrated": ("calibration", "mapping"), "refine": ("calibration", "mapping", "refine"),
                     "parallel": ("mapping",), "linear": ("examples",), "rbf": ("examples",),
                     "pca": ("examples", "pca")}
MARKER_FIT = ("geometric", "calibrated", "refine")
#: Shown for every strategy that solves markers.
TAKE_FIELDS = ("stabilise_mode", "head_smoothing")
FIT_FIELDS = ("regularisation", "sparsity", "symmetry", "smoothing", "fine_iterations", "fine_weight")
#: Shown only when set.
OPTIONAL_FIELDS = ("bounds", "locks", "regions", "align_regions", "align_flag_mm", "master", "landmarks",
                   "head_target", "projection")
TIMING_NAMES = {"read": "read the take", "load_character": "open the character", "stabilise": "stabilise",
                "normalise": "neutral", "fit": "fit the strategy", "solve": "solve", "key": "key the weights",
                "total": "total (to the saved outputs)", "render": "render the contact sheet",
                "page": "write this page"}


def esc(value):
    return escape(str(value), quote=True)


def short(value, limit=12):
    """A settings value in a few words: long lists shortened, arrays and tables described."""
    if isinstance(value, np.ndarray):
        return f"per-frame values ({value.size})"
    if dataclasses.is_dataclass(value):
        return type(value).__name__
    if isinstance(value, (list, tuple)):
        items = [short(v, 4) for v in value]
        text = ", ".join(items[:limit])
        return f"[{text}{', ...' if len(items) > limit else ''}] ({len(items)})" if len(items) > 3 else f"[{text}]"
    if isinstance(value, float):
        return f"{value:g}"
    if value is None:
        return "none"
    source = getattr(value, "source", None)
    return str(source) if source is not None and hasattr(value, "positions") else str(value)


def neutral_text(settings):
    if settings.master is not None:
        return f"master T-pose {short(settings.master)} on the T-pose frames {short(settings.neutral_ranges or settings.neutral_frames)}"
    if settings.neutral_file is not None:
        return f"file {short(settings.neutral_file)}"
    if settings.neutral_detect:
        return "detected from the take"
    if settings.neutral_ranges:
        return "frames " + ", ".join(f"{a}-{b}" for a, b in settings.neutral_ranges)
    return "frames {}-{}".format(*settings.neutral_frames) if settings.neutral_frames else "none"


def settings_rows(settings):
    """(name, value text) rows of the settings that shaped this solve."""
    if settings is None:
        return []
    strategy = settings.strategy
    rows = [("strategy", strategy)]
    if strategy != "parallel" or settings.stable_markers:
        stable = "suggested from the take" if settings.auto_stable else short(settings.stable_markers)
        rows += [("stable markers", stable), ("neutral", neutral_text(settings))]
        rows += [(f.replace("_", " "), short(getattr(settings, f))) for f in TAKE_FIELDS]
    if strategy in MARKER_FIT:
        rows += [(f.replace("_", " "), short(getattr(settings, f))) for f in FIT_FIELDS]
    for section in STRATEGY_SECTIONS.get(strategy, ()):
        for f in dataclasses.fields(getattr(settings, section)):
            rows.append((f"{section}.{f.name}", short(getattr(getattr(settings, section), f.name))))
    for f in OPTIONAL_FIELDS:
        value = getattr(settings, f)
        if value not in (None, "", ()):
            rows.append((f.replace("_", " "), short(value)))
    return rows


def table(rows, cls="kv"):
    body = "".join(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in rows)
    return f'<table class="{cls}">{body}</table>'


def summary_rows(review):
    """The header's key figures."""
    r = review.result
    frames = r.frames
    source = Path(review.source).name if review.source else "-"  # the full paths are in the JSON report
    rows = [("take", review.take), ("source", source), ("character", review.character or "-")]
    span = f"{frames.size} ({frames[0]:g} to {frames[-1]:g})"
    if review.fps:
        span += f", {frames.size / review.fps:.1f} s at {review.fps:g} fps"
    rows.append(("frames", span))
    rows.append(("shapes", f"{len(r.shape_names)}"))
    if r.marker_names:
        rows.append(("markers solved from", f"{len(r.marker_names)}"))
    ok = np.isfinite(r.residual_rms)
    if ok.any():
        res = r.residual_rms[ok] * 1e3
        where = {"character": "on the character", "actor": "on the actor's markers"}.get(r.residual_space, "")
        rows.append((f"RMS residual ({where})" if where else "RMS residual",
                     f"mean {res.mean():.3f} mm, 95th percentile {np.percentile(res, 95):.3f} mm, "
                     f"worst {res.max():.3f} mm at frame {r.frames[ok][np.argmax(res)]:g}"))
    unsolved = int((~np.isfinite(r.weights).all(axis=1)).sum()) if r.weights.size else 0
    if unsolved:
        rows.append(("unsolved frames", f"{unsolved}"))
    rows.append(("weights at a limit", f"{float(np.mean(r.at_bound)):.1f} of {len(r.shape_names)} shapes per frame on "
                 "average (at a slider's end, mostly 0: off)"))
    if review.truth is not None:
        rows.append(("against the truth", truth_text(review)))
    return rows


def truth_text(review):
    r = review.result
    truth = review.truth_values
    err = r.weights - truth
    if not np.isfinite(err).any():
        return f"{review.truth.source}: no frame and shape in common with the solve"
    rmse = float(np.sqrt(np.nanmean(err ** 2)))
    worst = np.nanmax(np.abs(np.where(np.isfinite(err), err, 0.0)), axis=0)
    k = int(np.argmax(worst))
    common = int(np.isfinite(truth).any(axis=0).sum())
    return (f"weights RMSE {rmse:.4f}, worst |error| {worst[k]:.3f} ({r.shape_names[k]}) over {common} shapes "
            f"({Path(review.truth.source).name})")


def timing_rows(review):
    timings = {**review.result.timings, **review.timings}
    return [(TIMING_NAMES.get(k, k.replace("_", " ")), f"{v:.2f} s") for k, v in timings.items()
            if isinstance(v, (int, float))]


def actor_html(review):
    """What the solve knew of the actor's face (the semantic strategy's tier) and whether the result is plausible
    animation: the first thing an animator should read."""
    info = review.result.info
    parts = []
    actor = info.get("actor_model")
    if actor:
        trusted = actor["tier"] != "character" or actor.get("character_mismatch", 1.0) == 0.0
        parts.append(f'<p class="{"ok" if trusted else "warn"}"><b>{esc(actor["tier"])}</b>: '
                     f'{esc(actor["statement"])}.</p>')
        if actor.get("unseen"):
            parts.append(f'<p class="note">Held at rest (no marker sees them): {esc(", ".join(actor["unseen"]))}.</p>')
    check = info.get("plausibility")
    if check is not None:
        if check.get("plausible"):
            parts.append('<p class="ok">Plausible: residual within the markers\' noise, no shape pinned at its '
                         'limit, no opposing shapes together.</p>')
        else:
            parts.append('<p class="warn">Not plausible animation: see the first warning below.</p>')
    return "".join(parts) or '<p class="note">This strategy does not solve against a model of the actor.</p>'


def warnings_html(review):
    notes = list(dict.fromkeys([*review.notes, *review.result.warnings]))
    if not notes:
        return '<p class="ok">No warnings.</p>'
    return '<ul class="warnings">' + "".join(f"<li>{esc(n)}</li>" for n in notes) + "</ul>"


def png_uri(png):
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _points_svg(tile, names, ghost_id):
    """An SVG the size of the render: the render faint, the bound points (dots) and the take's markers
    (rings), a line between each pair, coloured by their distance."""
    w, h = tile.width, tile.height
    parts = [f'<svg class="markers" viewBox="0 0 {w} {h}" width="{w}" height="{h}" role="img" '
             f'aria-label="markers on the character">',
             f'<image data-from="{ghost_id}" x="0" y="0" width="{w}" height="{h}" opacity="0.28"/>']
    top = max(1.0, float(np.nanmax(tile.distance_mm))) if np.isfinite(tile.distance_mm).any() else 1.0
    for name, c, m, d in zip(names, tile.captured, tile.model, tile.distance_mm):
        if not (np.isfinite(m).all()):
            continue
        col = _heat_colour(d / top if np.isfinite(d) else 0.0)
        title = f"<title>{esc(name)}: {d:.2f} mm</title>" if np.isfinite(d) else f"<title>{esc(name)}: missing</title>"
        if np.isfinite(c).all():
            parts.append(f'<line x1="{m[0]:.1f}" y1="{m[1]:.1f}" x2="{c[0]:.1f}" y2="{c[1]:.1f}" stroke="{col}" '
                         'stroke-width="1.2"/>')
            parts.append(f'<circle cx="{c[0]:.1f}" cy="{c[1]:.1f}" r="3.2" fill="none" stroke="{col}" '
                         f'stroke-width="1.4">{title}</circle>')
        parts.append(f'<circle cx="{m[0]:.1f}" cy="{m[1]:.1f}" r="1.8" fill="{col}">{title}</circle>')
    parts.append("</svg>")
    return "".join(parts)


def _heat_colour(t):
    """Blue (near) to red (far) for t in 0..1."""
    t = float(min(max(t, 0.0), 1.0))
    r, g, b = int(40 + 200 * t), int(110 + 40 * (1 - abs(2 * t - 1)) - 60 * t), int(200 * (1 - t) + 30)
    return f"rgb({r},{g},{b})"


def tile_html(tile, names, index):
    img_id = f"tile-{index}"
    if np.isfinite(tile.frame):
        caption = f'<a href="#weights" data-frame="{tile.frame:g}">frame {tile.frame:g}</a> &middot; {esc(tile.label)}'
    else:  # the binding: the neutral, no frame of the take
        caption = esc(tile.label)
    if tile.distance_mm is not None and np.isfinite(tile.distance_mm).any():
        caption += f" &middot; markers {np.nanmean(tile.distance_mm):.2f} mm mean, {np.nanmax(tile.distance_mm):.2f} max"
    what = f"at frame {tile.frame:g}" if np.isfinite(tile.frame) else "at its neutral"
    img = (f'<img id="{img_id}" src="{png_uri(tile.png)}" width="{tile.width}" height="{tile.height}" '
           f'alt="the character {what}">')
    panel = _points_svg(tile, names, img_id) if tile.captured is not None else ""
    return f'<figure class="tile {esc(tile.kind)}"><div class="pair">{img}{panel}</div><figcaption>{caption}</figcaption></figure>'


def contact_html(review):
    sheet = review.sheet
    if sheet is None or not sheet.tiles:
        why = review.sheet_note or "no renders were made"
        return f'<p class="note">No contact sheet: {esc(why)}.</p>'
    if sheet.marker_names:
        note = ("Each frame rendered with the solved weights (left) and, in the same view, the character's bound "
                "points (dots) with the take's markers carried onto the character (rings); the colour is their "
                "distance. Click a frame number to zoom the plots there.")
    else:
        note = "Each frame rendered with the solved weights. Click a frame number to zoom the plots there."
    if review.sheet_note:
        note += f" {review.sheet_note}"
    tiles = "".join(tile_html(t, sheet.marker_names, i) for i, t in enumerate(sheet.tiles))
    return f'<p class="note">{esc(note)}</p><div class="sheet">{tiles}</div>'


def binding_html(review, has_plot):
    sheet = review.sheet
    parts = []
    if sheet is not None and sheet.binding is not None:
        parts.append('<p class="note">The character\'s neutral with its bound points (dots) and the take\'s '
                     'neutral markers aligned onto them (rings); a long line is a marker bound to the wrong place '
                     'or a vertex group to check.</p>')
        parts.append('<div class="sheet">' + tile_html(sheet.binding, sheet.marker_names, "binding") + "</div>")
    if has_plot:
        parts.append('<div class="plot" id="plot-binding"></div>')
    if not parts:
        parts.append(f'<p class="note">No binding to show: {esc(review.sheet_note or "this strategy binds no markers")}.</p>')
    return "".join(parts)
