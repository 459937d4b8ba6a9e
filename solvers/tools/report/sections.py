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
#: The rings' colour scale: from 0 mm (blue) to this distance and beyond (red), the same on every tile
#: and every page, so a colour means the same distance everywhere.
RING_SCALE_MM = 5.0
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
    """A settings value as an animator reads it: words and numbers, never a Python repr. Lists are
    shortened ("a, b, c, ... (20 in all)"), pairs read "name = value", nothing set reads "none"."""
    if isinstance(value, np.ndarray):
        return f"per-frame values ({value.size})"
    if value is None or (isinstance(value, (list, tuple, dict, str)) and not value):
        return "none"
    if isinstance(value, bool) or isinstance(value, np.bool_):
        return "on" if value else "off"
    if isinstance(value, (float, np.floating)):
        return f"{float(value):g}"
    if isinstance(value, dict):
        value = tuple(value.items())
    if isinstance(value, (list, tuple)):
        items = [_item(v) for v in value]
        text = ", ".join(items[:limit])
        return f"{text}, ... ({len(items)} in all)" if len(items) > limit else text
    source = getattr(value, "source", None)
    if source is not None and hasattr(value, "positions"):  # a MarkerSet: its file
        return Path(str(source)).name or "markers in the scene"
    if dataclasses.is_dataclass(value):
        return "set"
    return str(value)


def _item(value):
    """One element of a list setting: a pair reads "name = value", a table row its cells."""
    if isinstance(value, (list, tuple)) and len(value) == 2 and isinstance(value[0], str):
        return f"{value[0]} = {short(value[1], 4)}"
    if isinstance(value, (list, tuple)):
        return " ".join(short(v, 4) for v in value)
    return short(value, 4)


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
        advice = (info.get("plausibility") or {}).get("prior_advice")
        if advice:
            parts.append(f'<p class="warn">Not this actor\'s expressions: {esc(advice)}.</p>')
    else:
        parts.append('<p class="note">This strategy does not solve against a model of the actor.</p>')
    check = info.get("plausibility")
    if check is not None:
        if check.get("plausible"):
            parts.append('<p class="ok">Plausible: residual within the markers\' noise, no shape pinned at its '
                         'limit, no opposing shapes together.</p>')
        else:
            parts.append('<p class="warn">Not plausible animation: see the first warning below.</p>')
    return "".join(parts)


def worst_html(figure):
    """The residual plot's worst frames as links under it (numbered on the page, not on the plot)."""
    worst = (figure or {}).get("worst") or []
    if not worst:
        return ""
    links = "".join(f'<a class="chip" href="#weights" data-frame="{f:g}">#{n} frame {f:g}: {mm:.3f} mm</a>'
                    for n, (f, mm) in enumerate(worst, 1))
    return f'<p class="worst"><span class="what">Worst frames (circled):</span> {links}</p>'


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
    for name, c, m, d in zip(names, tile.captured, tile.model, tile.distance_mm):
        if not (np.isfinite(m).all()):
            continue
        col = _heat_colour(d / RING_SCALE_MM if np.isfinite(d) else 0.0)
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


def ring_legend():
    """The rings' colour scale as a bar: 0 mm blue to RING_SCALE_MM and beyond red."""
    stops = ", ".join(f"{_heat_colour(i / 10)} {i * 10}%" for i in range(11))
    marks = "".join(f'<span style="left:{100 * v / RING_SCALE_MM:.0f}%">{v:g}</span>'
                    for v in np.linspace(0, RING_SCALE_MM, 6))
    return (f'<div class="ring-legend" role="img" aria-label="colour of a marker ring by its distance, 0 to '
            f'{RING_SCALE_MM:g} mm and more"><span class="what">marker to solve distance (mm)</span>'
            f'<span class="scale"><span class="bar" style="background:linear-gradient(to right, {stops})"></span>'
            f'<span class="ticks">{marks}</span></span><span class="more">{RING_SCALE_MM:g} and more: red</span></div>')


def _source_svg(view, row, ghost_id=None):
    """The take's markers at ``row`` as the actor made them (``SourceView``): the neutral faint, each
    marker dark, a line from its neutral to where it is."""
    w, h = view.width, view.height
    here = view.at(row)[0]
    parts = [f'<svg class="source" viewBox="0 0 {w} {h}" width="{w}" height="{h}" role="img" '
             f'aria-label="the actor\'s markers at this frame">']
    for name, a, b in zip(view.names, view.neutral, here):
        if not np.isfinite(a).all():
            continue
        parts.append(f'<circle cx="{a[0]:.1f}" cy="{a[1]:.1f}" r="1.6" fill="#c8c8c8"/>')
        if np.isfinite(b).all():
            parts.append(f'<line x1="{a[0]:.1f}" y1="{a[1]:.1f}" x2="{b[0]:.1f}" y2="{b[1]:.1f}" stroke="#888" '
                         'stroke-width="1"/>')
            parts.append(f'<circle cx="{b[0]:.1f}" cy="{b[1]:.1f}" r="2.4" fill="#333"><title>{esc(name)}</title>'
                         "</circle>")
    parts.append("</svg>")
    return "".join(parts)


def tile_html(tile, names, index, source=None, row=None):
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
    side = ""
    if tile.source_png is not None:
        side = f'<img class="source" src="{png_uri(tile.source_png)}" height="{tile.height}" alt="the footage {what}">'
    elif source is not None and row is not None:
        side = _source_svg(source, row)
    return (f'<figure class="tile {esc(tile.kind)}"><div class="pair">{side}{img}{panel}</div>'
            f'<figcaption>{caption}</figcaption></figure>')


def contact_html(review, source=None):
    """The contact sheet: per picked frame the source (the footage, or the actor's markers: ``source``, a
    SourceView), the character rendered with the solved weights, and the markers carried onto it."""
    sheet = review.sheet
    if sheet is None or not sheet.tiles:
        why = review.sheet_note or "no renders were made"
        return f'<p class="note">No contact sheet: {esc(why)}.</p>'
    has_video = any(t.source_png is not None for t in sheet.tiles)
    first = ("the footage frame" if has_video else "the actor's markers as captured (dark; grey: their neutral), "
             "seen from the front" if source is not None else "")
    lead = f"Each frame: {first} beside " if first else "Each frame: "
    if sheet.marker_names:
        note = (lead + "the character rendered with the solved weights and, in the same view, its bound points "
                "(dots) with the take's markers carried onto it (rings); the colour is their distance, on the "
                "scale below. Click a frame number to zoom the plots there.")
    else:
        note = lead + "the character rendered with the solved weights. Click a frame number to zoom the plots there."
    if review.sheet_note:
        note += f" {review.sheet_note}"
    frames = np.asarray(review.result.frames, dtype=np.float64)

    def row(tile):
        hit = np.flatnonzero(frames == tile.frame)
        return int(hit[0]) if hit.size else None

    tiles = "".join(tile_html(t, sheet.marker_names, i, source, row(t)) for i, t in enumerate(sheet.tiles))
    legend = ring_legend() if sheet.marker_names else ""
    return f'<p class="note">{esc(note)}</p>{legend}<div class="sheet">{tiles}</div>'


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
