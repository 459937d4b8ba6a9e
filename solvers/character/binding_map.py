"""How a take's markers are bound to a character (``[binding]``), and the ``marker,target`` map file.

``BindingSettings`` carries the ``[binding]`` options (or the sidebar's): the mode, the map, the
landmarks and the distance beyond which a marker stays unbound. The map file is a CSV, one marker a
row; a target is a vertex group name, a vertex index, or a point ``x,y,z`` on the neutral (quoted,
or as three more cells)::

    # marker,target
    marker,target
    A7,chin_C
    B2L,1234
    C1R,"0.031,-0.052,0.004"
    C1L,-0.031,-0.052,0.004
"""

import csv
from dataclasses import dataclass
from pathlib import Path

from ..errors import FacecapError, InputFileError
from ..io.files import read_text_input
from ..options import default
from .binding import parse_target

MODES = ("vertex_groups", "map", "nearest")


@dataclass(frozen=True)
class BindingSettings:
    """Where the take's markers sit on the character.

    mode : "vertex_groups" (a vertex group named after each marker), "map" (``map``) or "nearest"
        (the actor's neutral aligned to the surface; by ``landmarks`` when given, else automatically)
    map : ((marker, target text), ...) for ``mode = "map"``, or empty to read ``map_path``
    map_path : the ``marker,target`` CSV, or None
    landmarks : ((marker, target text), ...) for ``mode = "nearest"``; at least 3 pairs, or none
    max_distance_mm : markers (or map targets) farther than this from the surface stay unbound
    """

    mode: str = default("binding.mode")
    map: tuple = ()
    map_path: object = None
    landmarks: tuple = ()
    max_distance_mm: float = default("binding.max_distance_mm")

    def __post_init__(self):
        if self.mode not in MODES:
            raise FacecapError(f"binding: unknown mode {self.mode!r}; expected one of {', '.join(MODES)}")

    @property
    def by_position(self):
        """Whether the binding is by position (map or nearest), stored rather than read from names."""
        return self.mode != "vertex_groups"

    def targets(self):
        """{marker: target text} of the map (read from ``map_path`` when ``map`` is empty)."""
        if self.map:
            return dict(self.map)
        if self.map_path is None:
            raise FacecapError("binding mode \"map\" needs a map: a marker,target CSV ([binding] map)")
        return read_binding_map(self.map_path)


def read_binding_map(path):
    """{marker: target text} from a ``marker,target`` CSV (see the module docstring).

    Raises InputFileError naming the file and line: a row without a target, a repeated marker,
    a target that is neither a name, an index nor three numbers, an empty file.
    """
    path = Path(path)
    text = read_text_input(path, "file not found (a marker,target CSV for [binding] map)")
    out, first = {}, True
    for line, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if not any(cells) or cells[0].startswith("#"):
            continue
        if first and [c.lower() for c in cells[:2]] == ["marker", "target"]:
            first = False
            continue
        first = False
        out.update(_row(path, line, cells, out))
    if not out:
        raise InputFileError(path, "no marker,target rows (expected e.g. 'mouth_corner_L,lip_corner_L')")
    return out


def _row(path, line, cells, seen):
    while cells and not cells[-1]:
        cells.pop()
    if len(cells) not in (2, 4) or not cells[0]:
        raise InputFileError(path, f"expected marker,target or marker,x,y,z; got {len(cells)} cell(s): {cells}",
                             line=line)
    marker = cells[0]
    if marker in seen:
        raise InputFileError(path, f"marker '{marker}' is mapped twice", line=line)
    target = cells[1] if len(cells) == 2 else ",".join(cells[1:])
    try:
        parse_target(target)
    except FacecapError as exc:
        raise InputFileError(path, f"marker '{marker}': {exc}", line=line) from None
    if len(cells) == 4 and isinstance(parse_target(target), str):
        raise InputFileError(path, f"marker '{marker}': x,y,z must be three numbers; got {cells[1:]}", line=line)
    return {marker: target}


__all__ = ["BindingSettings", "MODES", "read_binding_map"]
