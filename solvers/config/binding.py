"""``[binding]``: how the take's markers are bound to the character (``BindingSettings``).

``mode = "vertex_groups"`` (the default; ``vertex_groups = true`` in older configs), ``"map"`` with
``map = "binding.csv"``, or ``"nearest"`` with optional ``landmarks = {marker = "group or index"}``
(at least three) and ``max_distance_mm``. Errors name the ``[binding.key]``.
"""

import os

from ..character.binding import parse_target
from ..character.binding_map import BindingSettings
from ..errors import ConfigError, FacecapError
from ..io.outputs import user_path
from ..options import default


def parse_binding(path, section):
    """[binding] -> BindingSettings (``map_path`` absolute, resolved against the config's folder)."""
    section = dict(section or {})
    legacy = section.get("vertex_groups")
    mode = section.get("mode")
    if legacy is not None:
        if mode is None and not legacy:
            raise ConfigError("false needs a binding mode: set mode = \"map\" or \"nearest\"", path=path,
                              key="binding.vertex_groups")
        if mode is not None and legacy != (mode == "vertex_groups"):
            raise ConfigError(f"vertex_groups = {str(legacy).lower()} contradicts mode = \"{mode}\"; give only mode",
                              path=path, key="binding.vertex_groups")
    mode = mode or default("binding.mode")
    if "map" in section and mode != "map":
        raise ConfigError(f"a map is only read with mode = \"map\" (mode is \"{mode}\")", path=path, key="binding.map")
    if mode == "map" and "map" not in section:
        raise ConfigError("mode = \"map\" needs map = \"<marker,target CSV>\"", path=path, key="binding.map")
    landmarks = section.get("landmarks")
    if landmarks is not None and mode != "nearest":
        raise ConfigError(f"landmarks are only used with mode = \"nearest\" (mode is \"{mode}\")", path=path,
                          key="binding.landmarks")
    if "max_distance_mm" in section and mode == "vertex_groups":
        raise ConfigError("max_distance_mm applies to mode = \"map\" or \"nearest\"", path=path,
                          key="binding.max_distance_mm")
    map_path = None
    if "map" in section:
        map_path = user_path(section["map"], path.parent)
        if not map_path.is_file():
            raise ConfigError(f"file not found: {map_path}", path=path, key="binding.map")
    return BindingSettings(mode=mode, map_path=map_path, landmarks=_landmarks(path, landmarks),
                           max_distance_mm=float(section.get("max_distance_mm", default("binding.max_distance_mm"))))


def _landmarks(path, landmarks):
    """((marker, target text), ...) of ``landmarks``: at least 3, each a vertex group, index or x,y,z."""
    if landmarks is None:
        return ()
    if len(landmarks) < 3:
        raise ConfigError(f"expected at least 3 marker = \"vertex group or index\" pairs; got {len(landmarks)}",
                          path=path, key="binding.landmarks")
    pairs = []
    for marker, target in landmarks.items():
        key = f"binding.landmarks.{marker}"
        if isinstance(target, bool) or not isinstance(target, (str, int)):
            raise ConfigError(f"expected a vertex group name or a vertex index; got {target!r}", path=path, key=key)
        if isinstance(target, int) and target < 0:
            raise ConfigError(f"a vertex index is >= 0; got {target}", path=path, key=key)
        try:
            parse_target(target)
        except FacecapError as exc:
            raise ConfigError(str(exc), path=path, key=key) from None
        pairs.append((marker, str(target)))
    return tuple(pairs)
