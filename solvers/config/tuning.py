"""The [tuning] and [controls] sections of a take config (issue 7).

``[tuning]``::

    corrections = "corrections.csv"   # frame,<shape>,... rows of corrected weights (``tune``)
    mu = 3.0                          # optional prior of the per-marker correction; absent = automatic
    library = "lib/calibrated-1a2b+tune8f-3c4d.npz"   # a stored version to solve with
    out = "lib"                       # where new versions go; default: next to the [output] files

``[controls]``: per-shape everyday controls applied after the solve, keyed by shape name or glob
(quote globs: ``"mouth*" = { gain = 1.1 }``), and/or ``preset = "controls.json"`` (entries of
the table win over the preset's)::

    jawOpen = { gain = 1.2, offset = 0.0, clamp = [0, 1], curve = "smoothstep", smoothing = 0.05,
                mute = false, lock = 0.3 }

Errors name the file and the ``[section.key]``.
"""

from dataclasses import dataclass
from pathlib import Path

from ..character.shape_controls import control_from_dict, load_preset
from ..errors import ConfigError, FacecapError
from ..io.outputs import user_path

TUNING_KEYS = {"corrections": str, "mu": (int, float), "library": str, "out": str}


@dataclass(frozen=True)
class TuningConfig:
    """[tuning] with absolute paths (None where not given)."""

    corrections: Path = None
    mu: float = None
    library: Path = None
    out: Path = None


def parse_tuning(path, section, base):
    """``[tuning]`` (a dict from the TOML) -> TuningConfig; ``base`` is the config's folder."""
    section = section or {}
    if not isinstance(section, dict):
        raise ConfigError("[tuning] must be a table", path=path)
    for key, value in section.items():
        if key not in TUNING_KEYS:
            raise ConfigError(f"unknown key; known keys: {', '.join(TUNING_KEYS)}", path=path, key=f"tuning.{key}")
        if not isinstance(value, TUNING_KEYS[key]) or isinstance(value, bool):
            raise ConfigError(f"wrong type {type(value).__name__}", path=path, key=f"tuning.{key}")
    mu = section.get("mu")
    if mu is not None and not mu > 0:
        raise ConfigError(f"must be > 0 (inf = gains only); got {mu}", path=path, key="tuning.mu")
    resolve = lambda v: None if v is None else user_path(v, base)  # noqa: E731
    return TuningConfig(corrections=resolve(section.get("corrections")), mu=None if mu is None else float(mu),
                        library=resolve(section.get("library")), out=resolve(section.get("out")))


def parse_controls(path, section, base):
    """``[controls]`` -> {shape or glob: ShapeControl} (the preset's entries first, the table's over them)."""

    section = section or {}
    if not isinstance(section, dict):
        raise ConfigError("[controls] must be a table", path=path)
    controls = {}
    if "preset" in section:
        preset = section["preset"]
        if not isinstance(preset, str):
            raise ConfigError(f"expected a file name; got {preset!r}", path=path, key="controls.preset")
        preset_path = user_path(preset, base)
        if not preset_path.is_file():
            raise ConfigError(f"file not found: {preset_path}", path=path, key="controls.preset")
        controls.update(load_preset(preset_path))
    for key, body in section.items():
        if key == "preset":
            continue
        try:
            controls[key] = control_from_dict(body, where="control")
        except FacecapError as exc:
            raise ConfigError(str(exc).removeprefix("control: "), path=path, key=f"controls.{key}") from None
    return controls
