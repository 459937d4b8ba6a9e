"""The review page's picture in the docs (docs/images/review.png): the demo's page, its summary and weights,
photographed by headless Chromium.

    .venv/bin/python tests/e2e/review_screenshot.py [--page facecap-demo/sample_take_review.html] [--out docs/images/review.png]

Without ``--page`` it runs ``python -m facecap demo`` into a temporary folder first.
"""

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from browser_cdp import Browser, find_chromium

ROOT = Path(__file__).resolve().parents[2]
#: Page width in CSS pixels, the picture's width, and the colour levels kept per channel (fewer: smaller PNG).
PAGE_WIDTH, WIDTH, LEVELS = 1200, 800, 40


def shoot(page, out):
    chromium = find_chromium()
    if chromium is None:
        sys.exit("no Chromium (apt-get install -y chromium)")
    with Browser(chromium, width=PAGE_WIDTH, height=1000) as browser:
        browser.open(Path(page).resolve().as_uri())
        if browser.errors():
            sys.exit(f"the page has errors: {browser.errors()}")
        bottom = browser.evaluate("document.getElementById('weights').getBoundingClientRect().bottom + window.scrollY")
        data = browser.call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True,
                                                        "clip": {"x": 0, "y": 0, "width": PAGE_WIDTH,
                                                                 "height": bottom + 8, "scale": WIDTH / PAGE_WIDTH}})
    import base64

    import bpy  # bpy: Blender's PNG reader (no imaging library here)

    from facecap.solvers.io.images import write_png

    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "shot.png"
        raw.write_bytes(base64.b64decode(data["data"]))
        img = bpy.data.images.load(str(raw))
        w, h = img.size
        px = np.empty(w * h * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
    rgb = px.reshape(h, w, 4)[::-1, :, :3]
    step = 255.0 / (LEVELS - 1)
    write_png(out, (np.round(np.round(rgb * 255.0 / step) * step)).clip(0, 255).astype(np.uint8))
    print(f"{out}: {w}x{h}, {Path(out).stat().st_size / 1024:.0f} KB")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--page", default=None)
    parser.add_argument("--out", default=str(ROOT / "docs" / "images" / "review.png"))
    args = parser.parse_args()
    if args.page:
        return shoot(args.page, args.out)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run([sys.executable, "-m", "facecap", "demo", "--out", tmp], check=True, capture_output=True)
        shoot(Path(tmp) / "sample_take_review.html", args.out)


if __name__ == "__main__":
    main()
