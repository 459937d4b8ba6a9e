"""Where a take reads and writes, checked before any work: no output may be one of the take's inputs,
two outputs may not share a path, and every output must be writable where it is going.

Paths are compared after expanding ``~``, resolving ``..`` and symbolic links, and, on a
case-insensitive file system, ignoring case; an existing output is also compared by identity
(``os.path.samefile``: hard links, other spellings of one file).
"""

import os
from pathlib import Path

from ..errors import ConfigError

#: (TakeConfig attribute, config key) of every file a take reads
INPUTS = (
    ("path", "the config itself"),
    ("target_blend", "[target.blend]"),
    ("markers_path", "[source.markers]"),
    ("weights_path", "[source.weights]"),
    ("calibration_path", "[calibration.markers]"),
    ("actor_basis_path", "[calibration.basis]"),
    ("actor_profile_path", "[actor.profile]"),
    ("examples_weights_path", "[examples.weights]"),
    ("examples_markers_path", "[examples.markers]"),
    ("training_path", "[refine.training]"),
    ("binding_map_path", "[binding.map]"),
    ("truth_path", "--truth"),
)
#: (TakeConfig attribute, config key) of every file a take writes
OUTPUTS = (
    ("output_blend", "[output.blend]"),
    ("output_weights", "[output.weights]"),
    ("output_report", "[output.report]"),
    ("output_actor_basis", "[output.actor_basis]"),
    ("output_profile", "[output.profile]"),
    ("output_gltf", "[output.gltf]"),
    ("output_fbx", "[output.fbx]"),
    ("output_html", "[output.html]"),
)


def take_inputs(config):
    """{config key: Path} of every file the take reads."""
    found = {key: getattr(config, attr) for attr, key in INPUTS if getattr(config, attr, None) is not None}
    s = config.settings
    for key, value in (("[neutral.file]", s.neutral_file), ("[neutral.master]", s.master)):
        if isinstance(value, (str, Path)):
            found[key] = Path(value)
    if getattr(config, "video", None) is not None:
        found["[source.video]"] = Path(config.video.path)
    tuning = getattr(config, "tuning", None)
    if tuning is not None:
        for key, value in (("[tuning.corrections]", tuning.corrections), ("[tuning.library]", tuning.library)):
            if value is not None:
                found[key] = Path(value)
    if getattr(config, "controls_preset", None) is not None:
        found["[controls.preset]"] = config.controls_preset
    return found


def take_outputs(config):
    """{config key: Path} of every file the take writes (the library folder of a retune is checked by
    ``check_outputs`` as a folder)."""
    return {key: getattr(config, attr) for attr, key in OUTPUTS if getattr(config, attr, None) is not None}


def resolved(path):
    """``path`` with ``~`` expanded and ``..`` / symbolic links resolved (the parts that exist)."""
    return Path(os.path.expanduser(str(path))).resolve()


def _case_insensitive(folder):
    """Whether ``folder`` (or its nearest existing ancestor) lives on a case-insensitive file system."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    flipped = Path(str(folder).swapcase())
    return flipped != folder and flipped.exists() and os.path.samefile(flipped, folder)


def _key(path):
    p = resolved(path)
    return str(p).casefold() if _case_insensitive(p.parent) else str(p)


def _same(a, b):
    if _key(a) == _key(b):
        return True
    try:
        return os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(config, *, library=None):
    """Raise ConfigError (one line naming both keys) when an output is one of the take's inputs, or
    two outputs share a path; then check every output can be written (``check_writable``).
    ``library``: the folder a retune writes library versions to (``[tuning] out``)."""
    inputs, outputs = take_inputs(config), take_outputs(config)
    for out_key, out in outputs.items():
        for in_key, inp in inputs.items():
            if _same(out, inp):
                raise ConfigError(f"{out_key} is the same file as {in_key} ({resolved(inp)}): a take never writes "
                                  "over what it reads", path=config.path)
    keys = list(outputs)
    for i, a in enumerate(keys):
        for b in keys[i + 1:]:
            if _same(outputs[a], outputs[b]):
                raise ConfigError(f"{a} and {b} are the same file ({resolved(outputs[a])}): one would be lost",
                                  path=config.path)
    if library is not None:
        for in_key, inp in inputs.items():
            if _same(library, inp):
                raise ConfigError(f"[tuning.out] is {in_key} ({resolved(inp)}); it must be a folder for the "
                                  "library versions", path=config.path)
        check_writable(library, "[tuning.out]", config.path, folder=True)
    for key, out in outputs.items():
        check_writable(out, key, config.path)


def check_writable(path, key, config_path, *, folder=False):
    """Raise ConfigError naming ``key`` when ``path`` cannot be written: a file where a folder is
    needed (or the reverse), a read-only folder, a name or path too long for the file system."""
    path = Path(os.path.expanduser(str(path)))

    def fail(message):
        raise ConfigError(f"{key} {path}: {message}", path=config_path)

    if path.exists():
        if folder and not path.is_dir():
            fail("is a file; a folder is needed")
        if not folder and path.is_dir():
            fail("is a folder; a file name is needed")
        if not os.access(path, os.W_OK):
            fail("is not writable")
    parent = path.parent
    while not parent.exists():
        if parent.parent == parent:
            break
        parent = parent.parent
    if not parent.is_dir():
        fail(f"cannot be created: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        fail(f"cannot be written: the folder {parent} is read-only")
    try:
        name_max = os.pathconf(parent, "PC_NAME_MAX")
        path_max = os.pathconf(parent, "PC_PATH_MAX")
    except (OSError, ValueError, AttributeError):  # no pathconf (Windows): the usual limits
        name_max, path_max = 255, 4096
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)
    if longest > name_max - 40:  # room for the temporary file's name beside it
        fail(f"a name in the path is {longest} bytes; this file system allows {name_max} (less the room a "
             "temporary file beside it needs)")
    if len(os.fsencode(str(path.resolve()))) > path_max - 40:
        fail(f"the path is longer than this file system allows ({path_max} bytes)")


def check_across_takes(configs, names=None):
    """Raise ConfigError before any work when takes of one batch would write the same file, or one
    take would write a file another reads (takes run in any order, at the same time).

    configs : sequence of TakeConfig
    names : the takes' names for the message (default: their config files)
    """
    names = [str(c.path) for c in configs] if names is None else list(names)
    writers = {}  # path key -> (take index, output key)
    by_inode = {}  # (device, inode) of an existing output -> (take index, output key)
    for i, config in enumerate(configs):
        for key, path in take_outputs(config).items():
            for known, table in ((_key(path), writers), (_identity(path), by_inode)):
                if known is None:
                    continue
                j, other = table.setdefault(known, (i, key))
                if j != i:
                    raise ConfigError(f"takes '{names[j]}' {other} and '{names[i]}' {key} write the same file "
                                      f"({resolved(path)}): one would be lost", path=config.path)
    for i, config in enumerate(configs):
        for key, path in take_inputs(config).items():
            for known, table in ((_key(path), writers), (_identity(path), by_inode)):
                j, other = table.get(known, (i, None)) if known is not None else (i, None)
                if j != i:
                    raise ConfigError(f"take '{names[i]}' reads {key} ({resolved(path)}), which take '{names[j]}' "
                                      f"writes as {other}: takes of a batch run in any order", path=config.path)


def _identity(path):
    """(device, inode) of an existing file, else None (hard links and other spellings of one file)."""
    try:
        st = os.stat(os.path.expanduser(str(path)))
    except OSError:
        return None
    return st.st_dev, st.st_ino
