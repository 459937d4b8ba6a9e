"""The review page: one HTML file that works offline (``[output] html``, ``retarget --html``, the sidebar's
*Export Review Report*).

plotly.js comes from the installed ``plotly`` package (bundled in the extension). A single report
embeds it (``plotly_js="embed"``, the default: one self-contained file to mail or archive, 4.8 MB of
it the library); the reports of a batch share one ``plotly.min.js`` beside them (``plotly_js=<path of
that file>``, written once by ``shared_plotly_js``), which each page loads by a relative path.
"""

import importlib.util
import json
import os
import time
from datetime import datetime, timezone
from pathlib import Path

from ...errors import FacecapError
from ...io.files import atomic_path
from ...io.outputs import Output, check_outputs
from .blob import Blob
from .figures import binding_figure, build_figures
from .review import source_view
from .sections import (
    actor_html,
    binding_html,
    contact_html,
    esc,
    settings_rows,
    summary_rows,
    table,
    timing_rows,
    warnings_html,
    worst_html,
)
from .shapes import shapes_html

ASSETS = Path(__file__).resolve().parent / "assets"
PLOTLY_JS = "plotly.min.js"
SECTIONS = (("summary", "Summary"), ("weights", "Weights"), ("shapes", "Shapes"), ("residual", "Residual"),
            ("head", "Head motion"), ("contact", "Contact sheet"), ("binding", "Binding"))


class MissingPlotlyError(FacecapError):
    """plotly (its plotly.min.js) is not installed."""


def plotly_js_source():
    """Path of ``plotly.min.js``: bundled beside this module in the extension zip (``build-extension``
    takes it from the locked plotly wheel), else inside the installed plotly package (whose Python code
    is never imported)."""
    bundled = Path(__file__).resolve().parent / "assets" / PLOTLY_JS
    if bundled.is_file():
        return bundled
    spec = importlib.util.find_spec("plotly")
    if spec is not None and spec.submodule_search_locations:
        path = Path(list(spec.submodule_search_locations)[0]) / "package_data" / PLOTLY_JS
        if path.is_file():
            return path
    raise MissingPlotlyError("the review report needs plotly.js from the 'plotly' package, which is not "
                             "installed (it is bundled with the extension; elsewhere: pip install plotly)")


def plotly_version(source=None):
    head = Path(source or plotly_js_source()).read_text(encoding="utf-8", errors="replace")[:300]
    marker = "plotly.js v"
    return head.split(marker, 1)[1].split()[0] if marker in head else "unknown"


def shared_plotly_js(folder):
    """Write ``plotly.min.js`` into ``folder`` (atomically) unless the same file is already there; its path.

    The reports of a batch then pass it as ``plotly_js`` and load it by a relative path.
    """
    source = plotly_js_source()
    target = Path(folder) / PLOTLY_JS
    data = source.read_bytes()
    if not (target.is_file() and target.stat().st_size == len(data) and target.read_bytes() == data):
        check_outputs([Output("the review pages' shared script", target, "plotly_js")])  # not someone's file
        target.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(target) as tmp:
            tmp.write_bytes(data)
    return target


def _script_text(text):
    """``text`` safe inside a <script> element (no early end tag, no comment opener)."""
    return text.replace("</", "<\\/").replace("<!--", "<\\!--")


def _plotly_tag(path, plotly_js):
    """The <script> that loads plotly.js, and how the page says where it is."""
    if plotly_js == "embed":
        source = plotly_js_source()
        code = source.read_text(encoding="utf-8")
        if "</script" in code.lower():
            code = code.replace("</script", "<\\/script").replace("</SCRIPT", "<\\/SCRIPT")
        return f"<script>{code}</script>", f"plotly.js {plotly_version(source)} (embedded)"
    js = Path(plotly_js)
    if not js.is_file():
        raise MissingPlotlyError(f"{js}: not found (the shared plotly.min.js of the review pages; shared_plotly_js "
                                 "writes it)")
    try:
        rel = os.path.relpath(js.resolve(), Path(path).resolve().parent)
    except ValueError:  # another drive (Windows): no relative path, so embed it
        return _plotly_tag(path, "embed")
    rel = rel.replace(os.sep, "/")
    return f'<script src="{esc(rel)}"></script>', rel


def build_page(review, *, path="review.html", plotly_js="embed"):
    """The HTML text of ``review``'s page and its figures (for tests)."""
    blob = Blob()
    figures = build_figures(review, blob)
    if review.geometry is not None and review.geometry.names:
        figures.append(binding_figure(review.geometry))
    packed, manifest = blob.pack()
    plotly_tag, plotly_where = _plotly_tag(path, plotly_js)
    meta = {"figures": figures, "arrays": manifest, "fps": review.fps, "plotly": plotly_where,
            "take": review.take}
    r = review.result
    by_id = {f["id"]: f for f in figures}

    def plots(*ids):
        return "".join((f'<h3>{esc(by_id[i]["title"])}</h3>' if by_id[i]["title"] else "")
                       + f'<div class="plot" id="plot-{i}"></div>' for i in ids if i in by_id)

    css = (ASSETS / "review.css").read_text(encoding="utf-8")
    js = (ASSETS / "review.js").read_text(encoding="utf-8")
    generated = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    nav = " ".join(f'<a href="#{k}">{v}</a>' for k, v in SECTIONS)
    if "head_rotation" not in by_id:
        head_note = '<p class="note">No head motion: this take was not stabilised (no 3D markers).</p>'
    elif review.result.stabilise is None:
        head_note = ('<p class="note">The head as the phone tracked it (its yaw, pitch and roll). Solved weights '
                     'need no stabilisation: nothing was removed from them.</p>')
    else:
        head_note = ""
    sheet = review.sheet
    tile = sheet.tiles[0] if sheet is not None and sheet.tiles else None
    source = None if tile is None else source_view(r, review.geometry, tile.width, tile.height)
    residual_missing = "" if "residual" in by_id else \
        f'<p class="note">No marker residual: the {esc(r.strategy)} strategy does not fit markers.</p>'
    body = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>facecap review: {esc(review.take)}</title>
<style>{css}</style>
{plotly_tag}
</head><body>
<header><h1>facecap review: {esc(review.take)}</h1><nav>{nav}</nav></header>
<div id="facecap-error" class="error" hidden></div>
<main>
<section id="summary"><h2>Summary</h2>
<div class="cols"><div>{table(summary_rows(review))}</div>
<div><h3>Strategy and settings</h3>{table(settings_rows(review.settings))}</div></div>
<h3>The actor</h3>{actor_html(review)}
<h3>Warnings</h3>{warnings_html(review)}
<h3>Timings</h3>{table(timing_rows(review), cls="kv timings")}
</section>
<section id="weights"><h2>Weights</h2>
<p class="note">Drag to zoom, double-click for the whole take; click a shape in the legend to show or hide it
(double-click: only it){"; dotted: the ground truth" if review.truth is not None else ""}. Curves keep each screen
pixel's lowest and highest frame, so a one-frame spike is always drawn.</p>
<div class="buttons"><button data-shapes="shown">Most active</button><button data-shapes="all">All shapes</button>
<button data-shapes="none">None</button></div>
{plots("weights")}
</section>
<section id="shapes"><h2>Shapes</h2>{shapes_html(review)}</section>
<section id="residual"><h2>Residual</h2>{residual_missing}{plots("residual")}{worst_html(by_id.get("residual"))}{plots("heat")}</section>
<section id="head"><h2>Head motion</h2>{head_note}{plots("head_rotation", "head_translation", "stabilise")}</section>
<section id="contact"><h2>Contact sheet</h2>{contact_html(review, source)}</section>
<section id="binding"><h2>Binding</h2>{binding_html(review, "binding" in by_id)}</section>
</main>
<footer>facecap review page, {esc(generated)}; plots by {esc(plotly_where)}.</footer>
<script type="application/json" id="facecap-meta">{_script_text(json.dumps(meta, separators=(",", ":"), allow_nan=False))}</script>
<script type="application/octet-stream" id="facecap-blob">{packed}</script>
<script>{_script_text(js)}</script>
</body></html>
"""
    return body, figures


def write_review_page(path, review, *, plotly_js="embed"):
    """Write ``review``'s page to ``path`` (atomically). Returns {"path", "bytes", "seconds"}.

    plotly_js : "embed" (default: plotly.js inside the page) or the path of a shared ``plotly.min.js``
        (``shared_plotly_js``), loaded by its path relative to the page.
    """
    t0 = time.perf_counter()
    path = Path(path)
    text, _ = build_page(review, path=path, plotly_js=plotly_js)
    data = text.encode("utf-8")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return {"path": path, "bytes": len(data), "seconds": time.perf_counter() - t0}
