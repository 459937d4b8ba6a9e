"""The ROM sheets' pictures for docs/rom.md (``python -m facecap docs-images``): ``rom_<sheet>.png`` per built-in
sheet (``solvers.rom.sheets.SHEETS``), the sample character holding every pose at the weights the sheet asks, in the
order performed (the neutral it starts from first), each numbered and labelled as the sheet numbers it."""

import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.io.images import write_png
from ...solvers.rom.sheets import SHEETS

#: Luma weights (Rec. 709) of the grey pictures, and the grey step: the sheets hold 77 faces, and a docs picture
#: stays under 150 KB (in grey, 128 levels: no banding on the skin).
LUMA, GREY_STEP = np.array([0.2126, 0.7152, 0.0722]), 2
#: Tile height relative to the command's ``size``, width / height, and columns per sheet.
SCALE, ASPECT = 0.66, 0.9
COLUMNS = {"facecap-24": 5, "arkit-51": 8}
#: The face from the chin (jaw open) to above the brows: view height and centre (metres), the caption's offset
#: from that centre (under the dropped chin) and its letters' height, the camera's yaw (degrees, as the expressions').
VIEW_HEIGHT, VIEW_CENTRE_Z, CAPTION_Y, CAPTION_SIZE, YAW = 0.19, -0.04, -0.088, 0.011, 15.0


def tile_size(size):
    """(width, height) in pixels of one ROM tile for the command's ``size``."""
    h = int(round(size * SCALE))
    return int(round(h * ASPECT)), h


def grey(page):
    """(H, W, 1) uint8: the (H, W, 3) ``page`` in grey levels of ``GREY_STEP``."""
    level = np.floor(page @ LUMA / GREY_STEP + 0.5) * GREY_STEP
    return np.clip(level, 0, 255).astype(np.uint8)[:, :, None]


def caption(number, pose):
    """A tile's caption: the pose's number in the sheet (1-based) and its label."""
    return f"{number} {pose.label}"


def rom_sheets(stage, out, size, compose, say):
    """Render ``rom_<sheet>.png`` for every built-in sheet into ``out`` with ``stage`` (docs_images' stage: the
    sample character, camera and caption) and ``compose`` (its grid); returns {picture name: path}. The stage's
    camera and caption are put back as they were."""
    missing = sorted({s for poses in SHEETS.values() for p in poses for s in p.shapes}
                     - {b.name for b in stage.face.data.shape_keys.key_blocks})
    if missing:
        raise FacecapError(f"the sample character lacks shape keys the ROM sheets ask: {missing}")
    cam, cap = stage.camera.data, stage.caption
    kept = (cam.ortho_scale, tuple(cap.location), cap.data.size, stage.scene.render.resolution_x,
            stage.scene.render.resolution_y)
    cam.ortho_scale = VIEW_HEIGHT  # the tiles are taller than wide: this is their height
    cap.location = (0.0, CAPTION_Y, cap.location[2])  # in the camera's frame: from the view's centre
    cap.data.size = CAPTION_SIZE
    stage.scene.render.resolution_x, stage.scene.render.resolution_y = tile_size(size)
    stage.look(YAW, height=VIEW_CENTRE_Z)
    written = {}
    try:
        for sheet, poses in SHEETS.items():
            say(f"rendering the ROM sheet {sheet} ({len(poses)} poses)")
            stage.pose({})
            tiles = [stage.render("neutral")]
            for i, pose in enumerate(poses, start=1):
                stage.pose(dict(pose.weights))
                tiles.append(stage.render(caption(i, pose)))
            path = out / f"rom_{sheet}.png"
            write_png(path, grey(compose(tiles, columns=COLUMNS.get(sheet, 8))))
            written[f"rom_{sheet}"] = path
    finally:
        stage.pose({})
        cam.ortho_scale, cap.location, cap.data.size = kept[0], kept[1], kept[2]
        stage.scene.render.resolution_x, stage.scene.render.resolution_y = kept[3], kept[4]
    return written
