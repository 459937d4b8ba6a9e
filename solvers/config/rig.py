"""``[rig]``: a rig's controls as the solve's target (``RigSettings``).

``preset`` and/or ``controls`` name the controls; ``object`` is the rig a preset needs (the
``shape_keys`` preset needs none: it uses ``[target] object``). Errors name the ``[rig.key]``.
"""

from dataclasses import dataclass

from ..errors import ConfigError
from ..options import default

CONTROL_KEYS = ("object", "path", "axes", "lower", "upper", "name")


@dataclass(frozen=True)
class RigSettings:
    """What ``[rig]`` asks for (see ``solvers.options``: ``rig.*``)."""

    preset: str = None
    object: str = None
    controls: tuple = ()  # ({object, path, axes?, lower?, upper?, name?}, ...)
    method: str = default("rig.method")
    poses: str = None
    nonlinear: bool = default("rig.nonlinear")
    refine: bool = default("rig.refine")
    probes: int = default("rig.probes")


def parse_rig(path, section):
    """[rig] -> RigSettings, or None when the config has no [rig] section."""
    if section is None:
        return None
    section = dict(section)
    controls = []
    for i, spec in enumerate(section.get("controls", [])):
        key = f"rig.controls[{i}]"
        if not isinstance(spec, dict):
            raise ConfigError("expected a table {object, path, ...}", path=path, key=key)
        unknown = sorted(set(spec) - set(CONTROL_KEYS))
        if unknown:
            raise ConfigError(f"unknown key(s) {unknown}; known: {', '.join(CONTROL_KEYS)}", path=path, key=key)
        for need in ("object", "path"):
            if not isinstance(spec.get(need), str) or not spec[need]:
                raise ConfigError(f"needs {need} = \"...\"", path=path, key=key)
        axes = spec.get("axes", [0, 1, 2])
        if not (isinstance(axes, list) and axes and all(a in (0, 1, 2) for a in axes)):
            raise ConfigError(f"axes must be a list of 0, 1, 2; got {axes!r}", path=path, key=key)
        for bound in ("lower", "upper"):
            if bound in spec and (isinstance(spec[bound], bool) or not isinstance(spec[bound], (int, float))):
                raise ConfigError(f"{bound} must be a number; got {spec[bound]!r}", path=path, key=key)
        if "lower" in spec and "upper" in spec and spec["lower"] >= spec["upper"]:
            raise ConfigError(f"lower ({spec['lower']}) must be below upper ({spec['upper']})", path=path, key=key)
        controls.append(dict(spec))
    preset = section.get("preset")
    if preset is None and not controls:
        raise ConfigError("name the controls: preset = \"rigify_face\" / \"arkit_sliders\" / \"shape_keys\", "
                          "or controls = [{object, path}, ...]", path=path, key="rig.preset")
    if preset in ("rigify_face", "arkit_sliders") and not section.get("object"):
        raise ConfigError(f"preset \"{preset}\" needs the rig: object = \"<armature or control object>\"",
                          path=path, key="rig.object")
    method = section.get("method", default("rig.method"))
    if method == "poses" and not section.get("poses"):
        raise ConfigError("method = \"poses\" needs poses = \"<action with one named pose per frame>\"",
                          path=path, key="rig.poses")
    if section.get("poses") and method != "poses":
        raise ConfigError("poses are read with method = \"poses\"", path=path, key="rig.poses")
    return RigSettings(preset=preset, object=section.get("object"), controls=tuple(controls), method=method,
                       poses=section.get("poses"), nonlinear=section.get("nonlinear", default("rig.nonlinear")),
                       refine=section.get("refine", default("rig.refine")),
                       probes=section.get("probes", default("rig.probes")))
