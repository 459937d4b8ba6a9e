"""The review page in a real browser: headless Chromium opens what ``retarget --html`` wrote, offline, and
the page draws every plot with the traces it should, loads every image, answers hover and zoom, and
keeps a one-frame spike of a 10-minute take on screen at any zoom; a batch's index links its pages,
which share one plotly.min.js.

Needs Debian's ``chromium``; without it these tests are skipped, except in CI (``FACECAP_CI=1``, set by
``.ci/run``), where a missing browser fails them.
"""

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from browser_cdp import Browser, find_chromium
from png_pixels import png_pixels

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"
sys.path.insert(0, str(ROOT / "tests" / "core"))
from review_takes import fabricated_result, stable_markers  # noqa: E402

from facecap.solvers.tools.report import (  # noqa: E402
    Review,
    TakeSummary,
    shared_plotly_js,
    write_batch_index,
    write_review_page,
)

pytestmark = pytest.mark.slow

PLOTS_JS = """Array.from(document.querySelectorAll('.plot')).map(el => ({
  id: el.id, traces: el.data ? el.data.length : -1, drawn: !!el.querySelector('.main-svg'),
  visible: el.data ? el.data.filter(t => t.visible === undefined || t.visible === true).length : -1}))"""
IMAGES_JS = """({img: Array.from(document.images).map(i => [i.id, i.complete, i.naturalWidth, i.naturalHeight]),
  ghosts: Array.from(document.querySelectorAll('svg image[data-from]')).map(g => (g.getAttribute('href') || '').slice(0, 22))})"""


@pytest.fixture(scope="module")
def chromium():
    path = find_chromium()
    if path is None:
        reason = "no headless Chromium (Debian: apt-get install -y chromium) for the review page's browser tests"
        if os.environ.get("FACECAP_CI") == "1":
            pytest.fail(f"{reason}; CI must install it")
        pytest.skip(reason)
    return path


def decode_png(data, tmp_path):
    """(H, W, 3) uint8 of PNG bytes."""
    path = tmp_path / "decoded.png"
    path.write_bytes(data)
    return png_pixels(path).astype(np.uint8)


def offline(browser):
    return [u for u in browser.requested_urls() if not u.startswith(("file://", "data:", "blob:"))]


@pytest.fixture(scope="module")
def cli_page(tmp_path_factory):
    """``retarget --html --truth`` on the sample take, as a TD runs it."""
    tmp = tmp_path_factory.mktemp("review_cli")
    config = tmp / "take.toml"
    config.write_text(f"""
[target]
blend = "{SAMPLES / 'character.blend'}"
object = "Face"
[source]
markers = "{SAMPLES / 'sample_take.csv'}"
units = "mm"
fps = 60
[stabilise]
markers = {list(stable_markers())!r}
[neutral]
frames = [1, 50]
[output]
weights = "out/weights.csv"
""".replace("'", '"'))
    out = tmp / "out" / "review.html"
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "facecap", "retarget", "--config", str(config), "--html", str(out),
                           "--truth", str(SAMPLES / "sample_take_weights.csv")], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert f"html: {out}" in proc.stdout
    print(f"retarget --html: {time.perf_counter() - t0:.1f} s, page {out.stat().st_size / 1e6:.2f} MB")
    return out


def test_cli_page_opens_offline_and_draws_everything(chromium, cli_page, tmp_path):
    with Browser(chromium) as browser:
        t0 = time.perf_counter()
        browser.open(cli_page.as_uri())
        print(f"page ready in the browser after {time.perf_counter() - t0:.1f} s")
        assert browser.errors() == []
        assert offline(browser) == [], "the page must not reach the network"
        assert browser.evaluate("window.facecapError || null") is None
        plots = {p["id"]: p for p in browser.evaluate(PLOTS_JS)}
        expected = {"weights": 2 * 52, "residual": 2, "heat": 1, "head_rotation": 3, "head_translation": 3,
                    "stabilise": 3, "binding": 1}
        assert {k.removeprefix("plot-"): v["traces"] for k, v in plots.items()} == expected
        assert all(p["drawn"] for p in plots.values())
        assert plots["plot-weights"]["visible"] == 16  # the 8 most active shapes and their truth
        images = browser.evaluate(IMAGES_JS)
        assert len(images["img"]) >= 9 and all(c and w == 224 and h == 280 for _, c, w, h in images["img"])
        assert len(images["ghosts"]) == len(images["img"]) and all(g == "data:image/png;base64," for g in images["ghosts"])
        shot = decode_png(browser.screenshot(), tmp_path)
        ink = (shot.astype(int).sum(axis=2) < 600).mean()  # anything clearly darker than the page's greys
        assert shot.shape[0] > 3000 and 0.02 < ink < 0.6, f"screenshot {shot.shape}, ink {ink:.3f}"
        assert len(np.unique(shot.reshape(-1, 3)[::97], axis=0)) > 200, "plots and renders, not flat colour"


#: Pairs of things on the page that must not overlap, as (name, a selector, b selector, within each plot?).
OVERLAPS_JS = """(() => {
  const rects = (root, sel) => Array.from(root.querySelectorAll(sel)).map(e => [e, e.getBoundingClientRect()])
    .filter(([, r]) => r.width > 0 && r.height > 0);
  const hit = (a, b) => Math.min(a.right, b.right) - Math.max(a.left, b.left) > 1 &&
                        Math.min(a.bottom, b.bottom) - Math.max(a.top, b.top) > 1;
  const label = e => (e.textContent || e.getAttribute('data-title') || e.getAttribute('class') || e.tagName).trim().slice(0, 40);
  const out = [], checked = {};
  function pairs(name, root, selA, selB) {
    const a = rects(root, selA), b = selB === selA ? a : rects(root, selB);
    checked[name] = (checked[name] || 0) + a.length * b.length;
    a.forEach(([ea, ra], i) => b.forEach(([eb, rb], j) => {
      if ((selA !== selB || j > i) && ea !== eb && !ea.contains(eb) && !eb.contains(ea) && hit(ra, rb))
        out.push([name, label(ea), label(eb)]);
    }));
  }
  for (const plot of document.querySelectorAll('.plot')) {
    const legend = plot.querySelector('.legend .scrollbox') ? '.legend .traces' : '.legend .traces';
    pairs('mode bar / legend', plot, '.modebar-btn', legend);
    pairs('mode bar / labels', plot, '.modebar-btn', '.annotation, .gtitle, .colorbar');
    pairs('labels', plot, '.annotation', '.annotation');
    pairs('labels / colour bar', plot, '.annotation', '.colorbar');
    pairs('plot text', plot, '.textpoint', '.textpoint');
  }
  pairs('worst frames', document, 'p.worst a.chip', 'p.worst a.chip');
  pairs('ring scale', document, '.ring-legend .ticks span, .ring-legend .what, .ring-legend .more',
        '.ring-legend .ticks span, .ring-legend .what, .ring-legend .more');
  pairs('contact sheet', document, 'figure.tile', 'figure.tile');
  pairs('tile panels', document, 'figure.tile .pair > *', 'figure.tile .pair > *');
  pairs('small plots', document, 'button.small', 'button.small');
  return {overlaps: out, checked: checked};
})()"""


def test_nothing_on_the_page_overlaps(chromium, cli_page):
    """Plotly's toolbar once covered legend entries and the worst-frame labels collided: every legend
    entry, label, colour bar, link and tile is checked by its bounding box in the browser."""
    with Browser(chromium, width=1280, height=900) as browser:
        browser.open(cli_page.as_uri())
        found = browser.evaluate(OVERLAPS_JS)
        checked = found["checked"]
        assert checked["mode bar / legend"] > 50 and checked["labels"] >= 42 and checked["worst frames"] >= 90
        assert checked["contact sheet"] >= 64 and checked["small plots"] > 2500, checked
        assert found["overlaps"] == [], found["overlaps"][:10]
        assert browser.evaluate("document.querySelectorAll('#plot-residual .textpoint').length") == 0


def test_hover_toggle_and_zoom_work(chromium, cli_page):
    with Browser(chromium) as browser:
        browser.open(cli_page.as_uri())
        # hover: the unified hover box lists the visible curves' values at that frame
        browser.evaluate("Plotly.Fx.hover('plot-weights', {xval: 300}, 'xy')")
        hover = browser.evaluate("document.querySelector('#plot-weights .hoverlayer').textContent")
        assert "300" in hover and any(ch.isdigit() for ch in hover.split("300", 1)[1])
        # toggle: the buttons show every shape, none, and the most active again
        for button, count in (("all", 104), ("none", 0), ("shown", 16)):
            browser.evaluate(f"document.querySelector('button[data-shapes=\"{button}\"]').click()")
            visible = browser.evaluate("document.getElementById('plot-weights').data.filter(t => t.visible === true).length")
            assert visible == count, button
        # zoom one plot: every time plot follows, and the curves are reduced again for the new range
        browser.evaluate("Plotly.relayout('plot-weights', {'xaxis.range': [200, 260]}).then(() => true)", await_promise=True)
        time.sleep(0.5)
        ranges = browser.evaluate("""['plot-residual', 'plot-heat', 'plot-head_rotation', 'plot-stabilise']
          .map(id => document.getElementById(id).layout.xaxis.range)""")
        assert all(r == [200, 260] for r in ranges), ranges
        xs = browser.evaluate("Array.from(document.getElementById('plot-weights').data[0].x)")
        inside = [x for x in xs if 200 <= x <= 260]
        assert inside == list(range(200, 261)), "every frame of a zoomed range is drawn"
        assert browser.errors() == []


def test_a_one_frame_spike_stays_visible_at_every_zoom(chromium, tmp_path):
    row, shape = 23_456, 5
    result, _ = fabricated_result(36_000, spike=(row, shape, 0.95))
    page = tmp_path / "spike.html"
    info = write_review_page(page, Review(result=result, take="spike", fps=60.0))
    spike_frame = float(result.frames[row])
    with Browser(chromium) as browser:
        t0 = time.perf_counter()
        browser.open(page.as_uri(), timeout=120)
        print(f"36,000-frame page: {info['bytes'] / 1e6:.2f} MB, ready in the browser after {time.perf_counter() - t0:.1f} s")
        assert browser.errors() == []
        trace = f"document.getElementById('plot-weights').data[{shape}]"
        for zoom in (None, [spike_frame - 30, spike_frame + 30], [spike_frame - 9000, spike_frame + 3000],
                     [100, 5000]):  # the whole take, close, wide, elsewhere (the spike then in the context)
            if zoom is not None:
                browser.evaluate(f"Plotly.relayout('plot-weights', {{'xaxis.range': {zoom}}}).then(() => true)", await_promise=True)
                time.sleep(0.3)
            xs = browser.evaluate(f"Array.from({trace}.x)")
            ys = browser.evaluate(f"Array.from({trace}.y)")
            assert len(xs) <= 2 * (2000 + 2 * 150), "reduced to the screen"
            k = int(np.nanargmax(np.array([np.nan if y is None else y for y in ys], dtype=float)))
            assert abs(ys[k] - 0.95) <= 0.5e-3 and xs[k] == spike_frame, zoom
        assert browser.errors() == []


def test_batch_index_links_pages_sharing_one_plotly(chromium, tmp_path):
    folder = tmp_path / "batch"
    js = shared_plotly_js(folder)
    records = []
    for i in range(2):
        result, _ = fabricated_result(720, seed=i)
        page = write_review_page(folder / "takes" / f"take{i}.html", Review(result=result, take=f"take{i}"),
                                 plotly_js=js)
        records.append(TakeSummary(take=f"take{i}", status="ok", frames=720,
                                   residual_mm=list(result.residual_rms * 1e3), report=page["path"], strategy="geometric"))
    records.append(TakeSummary(take="take2", status="failed", message="take2.csv line 7: expected a number"))
    index = write_batch_index(folder / "index.html", records)["path"]
    with Browser(chromium) as browser:
        browser.open(index.as_uri(), ready="document.readyState === 'complete'")
        assert browser.errors() == [] and offline(browser) == []
        rows = browser.evaluate("Array.from(document.querySelectorAll('#takes tbody tr')).map(r => r.className)")
        assert rows == ["ok", "ok", "bad"]
        assert browser.evaluate("document.querySelectorAll('#takes svg.spark').length") == 2
        assert "expected a number" in browser.evaluate("document.querySelector('#takes tbody tr.bad').textContent")
        links = browser.evaluate("Array.from(document.querySelectorAll('#takes a')).map(a => a.href)")
        assert len(links) == 2
        for link in links:
            browser.events.clear()
            browser.open(link)
            assert browser.errors() == [] and browser.evaluate("window.facecapError || null") is None
            assert js.as_uri() in browser.requested_urls(), "the shared plotly.min.js"
            assert browser.evaluate("document.getElementById('plot-weights').data.length") == 52


def test_a_page_without_its_plotly_says_so(chromium, tmp_path):
    js = shared_plotly_js(tmp_path)
    result, _ = fabricated_result(720)
    page = write_review_page(tmp_path / "lonely.html", Review(result=result, take="lonely"), plotly_js=js)["path"]
    js.unlink()
    with Browser(chromium) as browser:
        browser.open(page.as_uri())
        message = browser.evaluate("window.facecapError")
        assert "plotly.min.js must be beside this page" in message
        assert browser.evaluate("document.getElementById('facecap-error').hidden") is False
        assert not [e for e in browser.errors() if e.startswith("exception")]
