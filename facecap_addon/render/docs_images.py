"""The documentation's pictures, rendered headless from the sample character (``python -m facecap docs-images``).

PNGs, each a grid of renders of ``sample_blends/character.blend``:

``expressions.png``    the character at a few shape keys (or pairs of them) at weight 1
``markers.png``        the 68 marker points on the neutral face, coloured by region, front and side
``contact_sheet.png``  the demo retarget: frames of the sample take posed with the ground-truth weights
                       (top row) and with the solved weights (bottom row)
``rom_<sheet>.png``    every pose of each built-in ROM sheet, numbered, in the order performed (``rom_images``)

Renders use Blender's Workbench engine (OpenGL; headless through EGL, software rendering with Mesa's
llvmpipe when there is no GPU) or, with ``engine="cycles"``, Cycles on the CPU (no OpenGL needed).
The same inputs give the same bytes: fixed camera and lighting, no metadata in the PNG files.
"""

import dataclasses
import json
import tempfile
from pathlib import Path

import bpy
import bmesh  # after bpy: the bpy wheel makes bmesh importable
import numpy as np

from ...solvers.errors import FacecapError
from ...solvers.io.csv import read_weights_csv
from ...solvers.io.images import read_tga, write_png
from ...solvers.config import load_take_config
from ..headless.demo import SAMPLE_CONFIG
from ..headless.headless import run_take
from .render_state import mark_rendered
from ...solvers.io.outputs import check_files_in
from ...solvers.rom.sheets import SHEETS
from .rom_images import rom_sheets
from ..scene.scene_data import vertex_group_bindings

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "sample_blends"
DEFAULT_OUT = ROOT / "docs" / "images"

#: Grid spacing between tiles (pixels) and the page colour behind the transparent renders.
PAD = 6
BACKGROUND = (255, 255, 255)
#: Tile width / height (the head is taller than wide; the caption sits under the chin).
ASPECT = 0.8
#: What the command renders (``pictures``): the three above, and "rom" for the ROM sheets.
PICTURES = ("expressions", "markers", "contact_sheet", "rom")
#: Tile height of each picture relative to ``size`` (the marker layout larger: the dots are small).
SCALE = {"expressions": 1.0, "markers": 1.4, "contact_sheet": 0.75}
#: Height of the view (metres; the head is 0.236 m tall with the jaw open) and of its centre, and the
#: caption's offset from that centre.
VIEW_HEIGHT, VIEW_CENTRE_Z, CAPTION_Y = 0.27, -0.012, -0.123

#: (caption, {shape: weight}) per tile of expressions.png.
EXPRESSIONS = (
    ("neutral", {}),
    ("jawOpen", {"jawOpen": 1.0}),
    ("mouthSmile", {"mouthSmileLeft": 1.0, "mouthSmileRight": 1.0}),
    ("browInnerUp + browOuterUp", {"browInnerUp": 1.0, "browOuterUpLeft": 1.0, "browOuterUpRight": 1.0}),
    ("eyeBlink", {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0}),
    ("mouthPucker", {"mouthPucker": 1.0}),
    ("mouthFrown + browDown", {"mouthFrownLeft": 1.0, "mouthFrownRight": 1.0,
                               "browDownLeft": 1.0, "browDownRight": 1.0}),
    ("cheekPuff", {"cheekPuff": 1.0}),
)
#: Contact-sheet columns: the take's frame where each group of shapes peaks (sum of its truth weights),
#: plus the frame with the largest solve error.
CONTACT_PEAKS = (
    ("frown", ("mouthFrownLeft", "mouthFrownRight")),
    ("jawOpen", ("jawOpen",)),
    ("smile", ("mouthSmileLeft", "mouthSmileRight")),
    ("pucker", ("mouthPucker",)),
    ("brow raise", ("browInnerUp",)),
)
#: Marker colours by region (sRGB 0..1), as in sample_blends/marker_layout.json.
REGION_COLOURS = {"head": (0.10, 0.35, 0.85), "upper": (0.95, 0.55, 0.05), "lower": (0.10, 0.65, 0.25)}
#: Camera yaw (degrees about Z, positive towards the subject's left): expressions and contact sheet,
#: and the marker layout's second view.
YAW, SIDE_YAW = 15.0, 60.0


def tile_size(size, picture):
    """(width, height) in pixels of one tile of ``picture`` (a key of ``SCALE``)."""
    h = int(round(size * SCALE[picture]))
    return int(round(h * ASPECT)), h


def picture_files(pictures):
    """The files the ``pictures`` write (the ROM sheets: one per built-in sheet)."""
    return [f"{p}.png" for p in pictures if p != "rom"] + ([f"rom_{s}.png" for s in SHEETS] if "rom" in pictures else [])


def check_pictures(out=None, solved=None, *, pictures=PICTURES, overwrite=False):
    """The output policy for the pictures in ``out`` (default: the checkout's docs/images, facecap's own, whose
    pictures are replaced as they are): refused, before anything is rendered, where a file facecap did not
    write is in the way (unless ``overwrite``). Returns the folder."""
    return check_files_in(DEFAULT_OUT if out is None else out, picture_files(pictures), "--out", "png",
                          inputs={"--solved": solved}, overwrite=overwrite, owned=(DEFAULT_OUT,))


def docs_images_command(args, *, say, out):
    """``python -m facecap docs-images``: render what ``args`` ask (``--pictures``: comma-separated, default all)
    and print each picture written, with its size, to ``out``; returns the exit status."""
    pictures = PICTURES if args.pictures is None else tuple(p.strip() for p in args.pictures.split(",") if p.strip())
    written = render_docs_images(args.solved, args.out, size=args.size, engine=args.engine, pictures=pictures, say=say,
                                 overwrite=getattr(args, "overwrite", False))
    for name, path in written.items():
        print(f"  {name}: {path} ({path.stat().st_size / 1024:.0f} KB)", file=out)
    return 0


def render_docs_images(solved=None, out=None, *, size=280, engine="workbench", pictures=PICTURES, say=print,
                       overwrite=False):
    """``python -m facecap docs-images``: the ``pictures``, the contact sheet from ``solved`` (a weights CSV)
    or, by default, from a retarget of the sample take (weights only). Returns {name: path}."""
    unknown = [p for p in pictures if p not in PICTURES]
    if unknown or not pictures:  # named before the output check (which lists the files they write)
        raise FacecapError(f"docs-images: pictures must be some of {', '.join(PICTURES)}; got {', '.join(unknown)}")
    out = check_pictures(out, solved, pictures=pictures, overwrite=overwrite)
    if solved is not None or "contact_sheet" not in pictures:
        return generate(solved, out, size=size, engine=engine, pictures=pictures, say=say)
    with tempfile.TemporaryDirectory(prefix="facecap-docs-") as tmp:
        say("retargeting the sample take")
        solved = Path(tmp) / "sample_take_weights_solved.csv"
        config = dataclasses.replace(load_take_config(SAMPLE_CONFIG), output_blend=None, output_report=None,
                                     output_weights=solved)
        run_take(config, quiet=True)
        return generate(solved, out, size=size, engine=engine, pictures=pictures, say=say)


def generate(solved, out=None, *, size=280, engine="workbench", pictures=PICTURES, say=print):
    """Render the pictures into ``out``; returns {name: path}.

    Parameters
    ----------
    solved : str or Path
        Solved weights CSV of the sample take for the contact sheet (``python -m facecap demo`` writes
        ``facecap-demo/sample_take_weights_solved.csv``; ``docs-images`` retargets the take first).
    out : str or Path, optional
        Output folder (created); default ``docs/images`` of this checkout.
    size : int
        Tile height in pixels (width ``ASPECT`` times that).
    engine : {"workbench", "cycles"}
    pictures : sequence of ``PICTURES`` names
    say : callable(str)
        Progress messages.
    """
    if engine not in ("workbench", "cycles"):
        raise FacecapError(f"docs-images: engine must be 'workbench' or 'cycles', got '{engine}'")
    if size < 32:
        raise FacecapError(f"docs-images: size must be at least 32 pixels, got {size}")
    unknown = [p for p in pictures if p not in PICTURES]
    if unknown or not pictures:
        raise FacecapError(f"docs-images: pictures must be some of {', '.join(PICTURES)}; got {', '.join(unknown)}")
    blend = SAMPLE / "character.blend"
    if not blend.is_file():
        raise FacecapError(f"{blend}: not found (docs-images renders the sample character of a source checkout)")
    out = DEFAULT_OUT if out is None else Path(out)
    if "contact_sheet" in pictures:  # a bad CSV fails before any render
        take = _read_take(SAMPLE / "sample_take_weights.csv", Path(solved))
    with tempfile.TemporaryDirectory(prefix="facecap-docs-") as tmp:
        stage = _Stage(blend, engine, Path(tmp))
        written = {}
        for picture, draw in (("expressions", _expressions), ("markers", _markers),
                              ("contact_sheet", lambda *a: _contact_sheet(*a, *take))):
            if picture not in pictures:
                continue
            say(f"rendering {picture}")
            stage.scene.render.resolution_x, stage.scene.render.resolution_y = tile_size(size, picture)
            written[picture] = draw(stage, out / f"{picture}.png")
        if "rom" in pictures:
            written.update(rom_sheets(stage, out, size, compose, say))
    return written


class _Stage:
    """The sample character opened in Blender with a camera, a caption and render settings."""

    def __init__(self, blend, engine, tmp):
        bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False)
        self.scene = scene = bpy.context.scene
        self.face = bpy.data.objects["Face"]
        self.tmp = tmp
        render = scene.render
        render.engine = "BLENDER_WORKBENCH" if engine == "workbench" else "CYCLES"
        render.resolution_percentage = 100
        render.film_transparent = True
        render.image_settings.file_format = "TARGA_RAW"
        render.image_settings.color_mode = "RGBA"
        scene.view_settings.view_transform = "Standard"  # the materials' colours as they are (AgX greys them)
        scene.view_settings.look = "None"
        if engine == "workbench":
            shading = scene.display.shading
            shading.light, shading.color_type = "STUDIO", "MATERIAL"
            shading.show_cavity = False
            scene.display.render_aa = "8"
        else:
            _cycles_setup(scene)
        cam = bpy.data.objects.new("DocsCamera", bpy.data.cameras.new("DocsCamera"))
        cam.data.type = "ORTHO"
        cam.data.ortho_scale = VIEW_HEIGHT  # the tiles are taller than wide: this is their height
        scene.collection.objects.link(cam)
        scene.camera = cam
        self.camera = cam
        self.caption = self.text("DocsCaption", (0.0, CAPTION_Y), 0.015, (0.12, 0.12, 0.12))
        self.look(0.0)

    def text(self, name, xy, height, colour, align="CENTER"):
        """A text object fixed in the camera's view at ``xy`` (metres from the view centre)."""
        curve = bpy.data.curves.new(name, "FONT")
        curve.size = height
        curve.align_x, curve.align_y = align, "CENTER"
        obj = bpy.data.objects.new(name, curve)
        obj.data.materials.append(_material(name, colour))
        self.scene.collection.objects.link(obj)
        obj.parent = self.camera
        obj.location = (xy[0], xy[1], -0.5)  # in front of the camera, which looks down its -Z
        return obj

    def look(self, yaw_deg, distance=1.0, height=VIEW_CENTRE_Z):
        """Point the camera at the head from ``yaw_deg`` about Z (0: straight at the face, from -Y)."""
        a = np.radians(yaw_deg)
        self.camera.location = (distance * np.sin(a), -distance * np.cos(a), height)
        self.camera.rotation_euler = (np.pi / 2, 0.0, a)

    def pose(self, weights):
        """Set every shape key to ``weights`` ({name: value}; the others to 0)."""
        for block in self.face.data.shape_keys.key_blocks[1:]:
            block.value = float(weights.get(block.name, 0.0))

    def render(self, caption=""):
        """Render the current pose; returns an (H, W, 4) uint8 RGBA tile, top row first."""
        self.caption.data.body = caption
        path = self.tmp / "tile.tga"
        self.scene.render.filepath = str(path)
        mark_rendered()  # a review page forked from here could not render
        bpy.ops.render.render(write_still=True)
        return read_tga(path)


def _cycles_setup(scene):
    """Cycles on the CPU, few samples, a fixed seed; a grey world and a key light stand in for
    Workbench's studio lighting, and the materials' viewport colours become their base colours."""
    scene.cycles.device = "CPU"
    scene.cycles.samples = 32
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.seed = 0
    world = scene.world or bpy.data.worlds.new("DocsWorld")
    scene.world = world
    world.color = (0.25, 0.25, 0.25)
    if world.node_tree is not None:
        background = world.node_tree.nodes.get("Background")
        if background is not None:
            background.inputs["Color"].default_value = (0.25, 0.25, 0.25, 1.0)
    light = bpy.data.objects.new("DocsKey", bpy.data.lights.new("DocsKey", "SUN"))
    light.data.energy = 2.5
    light.rotation_euler = (np.radians(50), 0.0, np.radians(-25))
    scene.collection.objects.link(light)
    for mat in bpy.data.materials:
        _base_colour(mat, tuple(mat.diffuse_color))


def _base_colour(mat, rgba):
    if mat.node_tree is not None:  # Blender >= 5.0 materials always have nodes; 4.x only if asked
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        if bsdf is not None:
            bsdf.inputs["Base Color"].default_value = rgba


def _material(name, colour):
    """A material of one flat colour (Workbench's material colour; Cycles' base colour)."""
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    _base_colour(mat, (*colour, 1.0))
    return mat


def compose(tiles, columns, background=BACKGROUND, pad=PAD):
    """Alpha-composite equal RGBA tiles onto ``background`` in a grid, row by row.

    Parameters
    ----------
    tiles : list of (H, W, 4) uint8
    columns : int

    Returns
    -------
    (rows * (H + pad) + pad, columns * (W + pad) + pad, 3) uint8
    """
    h, w = tiles[0].shape[:2]
    rows = -(-len(tiles) // columns)
    page = np.empty((rows * (h + pad) + pad, columns * (w + pad) + pad, 3), dtype=np.float64)
    page[:] = background
    for i, tile in enumerate(tiles):
        y0, y1, x0, x1 = tile_box(i, columns, (w, h), pad)
        alpha = tile[:, :, 3:4] / 255.0
        page[y0:y1, x0:x1] = tile[:, :, :3] * alpha + page[y0:y1, x0:x1] * (1.0 - alpha)
    return np.round(page).astype(np.uint8)


def tile_box(index, columns, tile, pad=PAD):
    """(y0, y1, x0, x1) of tile ``index`` in a ``compose``d grid of ``tile`` = (width, height) tiles."""
    w, h = tile
    r, c = divmod(index, columns)
    y, x = pad + r * (h + pad), pad + c * (w + pad)
    return y, y + h, x, x + w


def _expressions(stage, path):
    stage.look(YAW)
    tiles = []
    for caption, weights in EXPRESSIONS:
        stage.pose(weights)
        tiles.append(stage.render(caption))
    stage.pose({})
    write_png(path, compose(tiles, columns=4))
    return path


def _markers(stage, path):
    """The markers as small spheres at the weighted centroids of their vertex groups (the binding the
    solve uses) on the neutral face, from the front and from ``SIDE_YAW``; a colour legend under the front view."""
    layout = json.loads((SAMPLE / "marker_layout.json").read_text(encoding="utf-8"))
    regions = {m["name"]: m["region"] for m in layout["markers"]}
    mesh = stage.face.data
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    spheres, dots = {}, []
    for region, colour in REGION_COLOURS.items():
        spheres[region] = _icosphere(f"DocsMarker_{region}", radius=0.0025)
        spheres[region].materials.append(_material(f"DocsMarker_{region}", colour))
    for name, (idx, w) in sorted(vertex_group_bindings(stage.face, list(regions)).items()):
        obj = bpy.data.objects.new(f"DocsMarker_{name}", spheres[regions[name]])
        obj.location = tuple(w @ co[idx])
        stage.scene.collection.objects.link(obj)
        dots.append(obj)
    labels = {"head": "stable (head)", "upper": "upper face", "lower": "lower face"}
    legend = [stage.text(f"DocsLegend_{region}", (-0.1 + 0.072 * i, CAPTION_Y), 0.011, colour, align="LEFT")
              for i, (region, colour) in enumerate(REGION_COLOURS.items())]
    for obj, region in zip(legend, REGION_COLOURS):
        obj.data.body = labels[region]
    stage.pose({})
    tiles = []
    for yaw in (0.0, SIDE_YAW):
        stage.look(yaw)
        for obj in legend:
            obj.hide_render = yaw != 0.0
        tiles.append(stage.render("" if yaw == 0.0 else f"{len(regions)} markers"))
    for obj in legend + dots:  # the next picture is of the face alone
        bpy.data.objects.remove(obj)
    write_png(path, compose(tiles, columns=2))
    return path


def _icosphere(name, radius):
    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=2, radius=radius)
    bm.to_mesh(mesh)
    bm.free()
    for poly in mesh.polygons:
        poly.use_smooth = True
    return mesh


def contact_frames(frames, names, truth, solved):
    """The contact sheet's frames: where each ``CONTACT_PEAKS`` group peaks in ``truth``, and the frame
    of the largest absolute weight error, in take order.

    Parameters
    ----------
    frames : (F,) frame numbers
    names : sequence of K shape names
    truth, solved : (F, K) weights

    Returns
    -------
    list of (row index, label)
    """
    picked = {}
    for label, shapes in CONTACT_PEAKS:
        cols = [names.index(s) for s in shapes if s in names]
        if cols:
            picked.setdefault(int(np.argmax(truth[:, cols].sum(axis=1))), label)
    worst = int(np.nanargmax(np.nanmax(np.abs(solved - truth), axis=1)))
    picked.setdefault(worst, "worst frame")
    return sorted(picked.items())


def _read_take(truth_path, solved_path):
    """(frames, names, truth, solved) of the sample take, the solve's columns in the truth's order."""
    frames, names, truth = read_weights_csv(truth_path)
    s_frames, s_names, solved = read_weights_csv(solved_path)
    missing = [n for n in names if n not in s_names]
    if missing or not np.array_equal(frames, s_frames):
        what = f"shapes missing: {', '.join(missing[:3])}" if missing else f"frames differ from {truth_path.name}"
        raise FacecapError(f"{solved_path}: not a solve of the sample take ({what})")
    return frames, names, truth, solved[:, [s_names.index(n) for n in names]]


def _contact_sheet(stage, path, frames, names, truth, solved):
    picks = contact_frames(frames, names, truth, solved)
    stage.look(YAW)
    top, bottom = [], []
    for row, label in picks:
        rmse = float(np.sqrt(np.nanmean((solved[row] - truth[row]) ** 2)))
        stage.pose(dict(zip(names, truth[row])))
        top.append(stage.render(f"truth {int(frames[row])}: {label}"))
        stage.pose(dict(zip(names, np.nan_to_num(solved[row]))))
        bottom.append(stage.render(f"solved: RMSE {rmse:.3f}"))
    stage.pose({})
    write_png(path, compose(top + bottom, columns=len(picks)))
    return path
