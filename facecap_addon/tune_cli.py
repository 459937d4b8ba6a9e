"""``python -m facecap tune --config take.toml``: the animator feedback loop, headless (issue 7).

Solves the take (with ``[tuning] library`` if given), reads ``[tuning] corrections``, re-optimises
what the strategy learned (``solvers.tuning.take.retune_take``, the same call as the Blender
Retune operator), stores the new library version in ``[tuning] out`` (never overwriting) and
writes the re-solved take exactly as ``retarget`` does (.blend / weights CSV / report, with the
tuning figures in the report). ``retarget`` uses the helpers here to honour ``[tuning] library``
and ``[controls]``.
"""

import dataclasses
from pathlib import Path


def prepare_solve(config, character, inputs):
    """(character, inputs, settings, info) for the solve: ``[tuning] library`` applied and the
    ``[controls]`` locks added to the solve's locks."""
    from ..solvers.tuning.store import load_version
    from ..solvers.character.shape_controls import locks_from_controls
    from ..solvers.tuning.take import apply_version

    settings, info = config.settings, {}
    tuning = config.tuning
    if tuning is not None and tuning.library is not None:
        version = load_version(tuning.library)
        character, inputs, settings = apply_version(version, character, inputs, settings)
        info["library"] = {"file": str(tuning.library), "version": version.name, "parent": version.parent}
    if config.controls:
        names = character.shape_names if hasattr(character, "shape_names") else character.names
        locks = locks_from_controls(config.controls, names)
        if locks:
            settings = dataclasses.replace(settings, locks=tuple(settings.locks) + locks)
    return character, inputs, settings, info


def finish_solve(config, result, fps):
    """The result with ``[controls]`` applied to its weights (after the solve, as in the sidebar)."""
    from ..solvers.character.shape_controls import apply_controls

    if not config.controls:
        return result
    return dataclasses.replace(result, weights=apply_controls(result.weights, result.shape_names, config.controls, fps))


def versions_folder(config):
    """``[tuning] out``, else the folder of the first [output] file, else ``<config folder>/library``."""
    if config.tuning is not None and config.tuning.out is not None:
        return config.tuning.out
    for path in (config.output_report, config.output_weights, config.output_blend):
        if path is not None:
            return Path(path).parent
    return config.path.parent / "library"


def tune_solver(config, state):
    """A ``solve`` for ``run_retarget``: solve, retune from the corrections, store the version; the
    re-solved result is returned and the figures land in ``state``."""
    from ..solvers.errors import ConfigError
    from ..solvers.tuning.store import read_corrections_csv, save_version
    from ..solvers.pipeline import retarget
    from ..solvers.tuning.take import retune_take

    tuning = config.tuning
    if tuning is None or tuning.corrections is None:
        raise ConfigError("the tune command needs the animator's corrections (frame,<shape>,... CSV)",
                          path=config.path, key="tuning.corrections")

    def solve(markers, character, settings, inputs, info):
        names = character.shape_names if hasattr(character, "shape_names") else character.names
        corrections = read_corrections_csv(tuning.corrections, names)
        base = retarget(markers, character, settings, inputs=inputs)
        parent = info.get("library", {}).get("version", "")
        tuned = retune_take(markers, character, settings, inputs, corrections, mu=tuning.mu, base=base, parent=parent)
        folder = versions_folder(config)
        saved = {}
        if not parent and not (folder / f"{tuned.parent_version.name}.npz").exists():
            saved["original"] = str(save_version(tuned.parent_version, folder))  # the way back, once
        if tuned.changed:
            saved["version"] = str(save_version(tuned.version, folder))
        state.update(tuned=tuned, saved=saved)
        return tuned.result, {"tuning": {**tuned.report(), "files": saved, "corrections_file": str(tuning.corrections)}}

    return solve


def cmd_tune(args):
    """The ``tune`` subcommand."""
    from ..solvers.config import load_take_config
    from .cli import run_retarget

    config = load_take_config(args.config)
    state = {}
    result, outputs = run_retarget(config, solve=tune_solver(config, state))
    tuned = state["tuned"]
    v = tuned.version
    print(f"retuned '{result.strategy}' from {len(tuned.frames)} corrected frame(s): corrected RMSE "
          f"{tuned.corrected_rmse_before:.4f} -> {tuned.corrected_rmse_after:.4f}; other frames moved "
          f"{tuned.others_moved:.1%}")
    if tuned.changed:
        print(f"  new version: {v.name} (parent {v.parent}) -> {state['saved']['version']}")
    else:
        print(f"  library unchanged ({v.name}); no new version written")
    if "original" in state["saved"]:
        print(f"  original: {tuned.parent_version.name} -> {state['saved']['original']}")
    for note in tuned.notes:
        print(f"  note: {note}")
    for key, value in outputs.items():
        print(f"  {key}: {value}")
    return 0
