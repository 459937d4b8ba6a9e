"""Blender property arguments from the option table (``solvers.options``): a sidebar setting that is
a take-config option takes its default, range and description from there, so the two cannot drift."""

from ...solvers.options import option


def from_option(name, *, label, index=None, **overrides):
    """Keyword arguments for a ``bpy.props`` property of option ``name`` ("section.key").

    ``label`` is the property's UI name; ``index`` picks one number of a list option (e.g. the
    second smoothing weight); ``overrides`` win (a UI-only floor such as ``min=1.0`` for a frame rate,
    whose option only says ``> 0``).
    """
    opt = option(name)
    kw = {"name": label, "description": opt.doc}
    default = opt.default if index is None or opt.default is None else opt.default[index]
    if default is not None:
        kw["default"] = default
    low = opt.low if opt.low is not None else opt.above
    if low is not None:
        kw["min"] = low
    if opt.high is not None:
        kw["max"] = opt.high
    kw.update(overrides)
    return kw
