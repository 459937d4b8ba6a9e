"""Where a take reads and writes, checked before any work by the one output policy
(``solvers.io.outputs``): no output may be one of the take's inputs, two outputs may not share a path,
an existing file is replaced only when it is facecap's own output of that kind, and every output must be
writable where it is going. Across a batch's takes, no two takes write one file and no take writes what
another reads.

Paths are compared after expanding ``~``, resolving ``..`` and symbolic links, and, on a
case-insensitive file system, ignoring case; an existing output is also compared by identity
(``os.path.samefile``: hard links, other spellings of one file).
"""

import os
from pathlib import Path

from ..errors import ConfigError
from ..io.outputs import Output, check_location, path_key, resolved
from ..io.outputs import check_outputs as check_output_policy

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
#: (TakeConfig attribute, config key, output kind) of every file a take writes
OUTPUTS = (
    ("output_blend", "[output.blend]", "blend"),
    ("output_weights", "[output.weights]", "weights_csv"),
    ("output_report", "[output.report]", "report"),
    ("output_actor_basis", "[output.actor_basis]", "npz"),
    ("output_profile", "[output.profile]", "npz"),
    ("output_gltf", "[output.gltf]", "glb"),
    ("output_fbx", "[output.fbx]", "fbx"),
    ("output_html", "[output.html]", "html"),
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
    rom = getattr(config, "video_rom", None)
    if rom is not None and rom.path is not None:
        found["[calibration.video]"] = Path(rom.path)
    if rom is not None and rom.guide is not None:
        found["[calibration.guide]"] = Path(rom.guide)
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
    return {key: getattr(config, attr) for attr, key, _ in OUTPUTS if getattr(config, attr, None) is not None}


def output_list(config):
    """The take's outputs as ``solvers.io.outputs.Output`` (key, path, kind)."""
    return [Output(key, getattr(config, attr), kind) for attr, key, kind in OUTPUTS
            if getattr(config, attr, None) is not None]


#: Low estimates of output sizes (bytes) for the free-space check: per weights-CSV value, per key in a
#: compressed .blend, and the fixed part of a report or page.
CSV_BYTES_PER_VALUE = 4
BLEND_BYTES_PER_KEY = 4
FIXED_BYTES = 16 << 10


def expected_sizes(config, frames, shapes, base_size=0):
    """[(Output, bytes)] the take's outputs will need at least (``solvers.io.outputs.check_free_space``):
    ``frames`` x ``shapes`` weights, the .blend the run opens being ``base_size`` bytes."""
    values = frames * max(1, shapes)
    sizes = {"blend": base_size + values * BLEND_BYTES_PER_KEY, "weights_csv": values * CSV_BYTES_PER_VALUE,
             "report": FIXED_BYTES + frames * 8, "html": FIXED_BYTES}
    return [(out, sizes.get(out.kind, FIXED_BYTES)) for out in output_list(config)]


def check_outputs(config, *, library=None, overwrite=False):
    """Raise ConfigError (one line naming the keys) unless the output policy allows every output of the
    take (``solvers.io.outputs.check_outputs``): none is an input or another output, an existing one is
    facecap's own output of its kind (or ``overwrite``), each can be written. ``library``: the folder a
    retune writes library versions to (``[tuning] out``)."""
    folders = [] if library is None else [("[tuning.out]", library)]
    check_output_policy(output_list(config), take_inputs(config), overwrite=overwrite, config=config.path,
                        folders=folders)


def check_writable(path, key, config_path, *, folder=False):
    """Raise ConfigError naming ``key`` when ``path`` cannot be written (``solvers.io.outputs.check_location``)."""
    check_location(path, key, config=config_path, folder=folder)


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
            for known, table in ((path_key(path), writers), (_identity(path), by_inode)):
                if known is None:
                    continue
                j, other = table.setdefault(known, (i, key))
                if j != i:
                    raise ConfigError(f"takes '{names[j]}' {other} and '{names[i]}' {key} write the same file "
                                      f"({resolved(path)}): one would be lost", path=config.path)
    for i, config in enumerate(configs):
        for key, path in take_inputs(config).items():
            for known, table in ((path_key(path), writers), (_identity(path), by_inode)):
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
