"""What a headless take writes about the actor, beside the .blend and the weights: the actor library a
calibrated or refine solve used (``[output] actor_basis``) and the performer profile a semantic solve measured
(``[output] profile``, read back by a later take's ``[actor] profile``), and the library versions a retune
stores (``tune``)."""

from pathlib import Path

from ...solvers.errors import ConfigError
from ...solvers.strategies.actor_model import profile_of
from ...solvers.tuning.store import save_version
from ...solvers.video.response import save_profile


def write_actor_basis(config, result, outputs):
    """``[output] actor_basis``: the library the strategy solved with (refine: refined)."""
    actor_basis = getattr(result.fitted, "actor_basis", None)
    if actor_basis is None:
        raise ConfigError(f"strategy '{result.strategy}' has no actor basis to store (calibrated and refine do)",
                          path=config.path, key="output.actor_basis")
    config.output_actor_basis.parent.mkdir(parents=True, exist_ok=True)
    actor_basis.save_npz(config.output_actor_basis)
    outputs["actor_basis"] = str(config.output_actor_basis)


def write_profile(config, result, outputs, response=None, performer=None):
    """``[output] profile``: the semantic solve's measured shapes of the actor and/or (a landmark take with a ROM on
    camera) the blendshape scores' ``response`` and/or (a guide followed) the ``performer``'s clip in the fusion
    map (the config check makes sure there is one or the other; a solve that measured nothing, without a response
    or a guide, is refused here too)."""
    model = getattr(result.fitted, "model", None)
    profile = None if model is None else profile_of(model)
    if profile is None and response is None and performer is None:
        raise ConfigError("a performer profile holds measured calibration poses: give [calibration] poses (and "
                          "markers, or frames of this take) with the semantic strategy", path=config.path,
                          key="output.profile")
    config.output_profile.parent.mkdir(parents=True, exist_ok=True)
    save_profile(config.output_profile, basis=profile, response=response, performer=performer)
    outputs["profile"] = str(config.output_profile)


def versions_folder(config):
    """``[tuning] out``, else the folder of the first [output] file, else ``<config folder>/library``."""
    if config.tuning is not None and config.tuning.out is not None:
        return config.tuning.out
    for path in (config.output_report, config.output_weights, config.output_blend):
        if path is not None:
            return Path(path).parent
    return config.path.parent / "library"


def store_retune(config, tuned):
    """Store the retune's new version (and, once, the original: the way back); the report's fields."""

    folder = versions_folder(config)
    saved = {}
    if config.tuning.library is None and not (folder / f"{tuned.parent_version.name}.npz").exists():
        saved["original"] = str(save_version(tuned.parent_version, folder))  # the way back, once
    if tuned.changed:
        saved["version"] = str(save_version(tuned.version, folder))
    return {**tuned.report(), "files": saved, "corrections_file": str(config.tuning.corrections)}
