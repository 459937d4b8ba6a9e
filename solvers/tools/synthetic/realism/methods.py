"""The solves the realism benchmark compares, each run the way a user would run it (the product pipeline,
the character bound as the layout allows), plus two references: all weights at zero, and a plain
per-frame bounded least squares written independently of the pipeline (``plain_solve``)."""

from dataclasses import replace

import numpy as np
from scipy.optimize import lsq_linear

from ....character.basis import Basis
from ....character.binding_map import BindingSettings
from ....character.template import HumanTemplate
from ....errors import FacecapError
from ....pipeline import RetargetSettings, retarget
from ....pipeline.binding import bind_character
from ....rom.sheets import SHEETS
from ....strategies.options import ActorSettings, CalibrationSettings, StrategyInputs
from .takes import REST

#: name -> what it is (the order of the tables)
METHODS = {
    "zero": "all weights 0",
    "plain": "plain per-frame bounded least squares on the character's shapes (reference)",
    "geometric": "geometric strategy (the default before the semantic solve)",
    "calibrated-old": "calibrated strategy, one pose per shape (before)",
    "nothing": "semantic, nothing known of the actor (the default)",
    "poses12": "semantic, 12 calibration poses",
    "poses12+template": "semantic, 12 calibration poses and the human template",
    "template": "semantic, the human template (no calibration)",
    "calibration": "semantic, one calibration pose per shape (perfect poses, frame ranges typed)",
    "rom24": "semantic, the facecap-24 ROM performed imperfectly, its poses found",
    "rom24+template": "semantic, the facecap-24 ROM and the human template",
    "rom51": "semantic, the arkit-51 ROM (a pose per shape) performed imperfectly, its poses found",
    "rom51+template": "semantic, the arkit-51 ROM and the human template",
    "oracle": "semantic with the actor's true (linear) shapes as its profile (no user has them)",
}


#: The ROM methods' sheets.
ROM_METHODS = {"rom24": "facecap-24", "rom51": "arkit-51"}


def holds_found(name, draw, result):
    """(within, total): of the holds a ROM method's session performed, how many were found within 5 frames of their
    true middle (None for other methods)."""
    if result is None or not name.startswith("rom") or "rom" not in result.info:
        return None
    session = draw.roms[ROM_METHODS[name.split("+")[0]]]
    middles = {p["label"]: p["middle"] for p in result.info["rom"]["poses_table"]}
    found = [middles.get(session.poses[j].label) for j in session.performed if j >= 0]
    true = [m for j, m in zip(session.performed, session.middles) if j >= 0]
    return sum(f is not None and abs(f - t) <= 5 for f, t in zip(found, true)), len(true)


def _poses(table):
    return tuple((name, (tuple(frames),)) for name, frames in table.items())


def bound_character(mesh, draw, settings):
    """The character's shapes at the draw's markers: vertex groups, or for a layout bound by position the
    automatic binding and, when it refuses (ambiguous, no fit), the layout's landmark pairs, as a user would."""
    if not draw.layout.by_position:
        return bind_character(mesh, draw.markers, settings, BindingSettings(mode="vertex_groups")).basis
    try:
        return bind_character(mesh, draw.markers, settings, BindingSettings(mode="nearest")).basis
    except FacecapError:
        if not draw.layout.landmarks:
            raise
        landmarks = BindingSettings(mode="nearest", landmarks=draw.layout.landmarks)
        return bind_character(mesh, draw.markers, settings, landmarks).basis


def base_settings(draw):
    """The take settings every method starts from: the layout's stable markers, the neutral hold."""
    return RetargetSettings(stable_markers=draw.layout.stable, neutral_frames=(1, REST))


def run_method(name, draw, mesh, template, *, character=None):
    """(weights (F, K), shape names, upper bounds (K,), the RetargetResult or None) of method ``name`` on ``draw``
    onto ``mesh`` (``character``: its shapes at the draw's markers when already bound, ``bound_character``)."""
    settings = base_settings(draw)
    character = bound_character(mesh, draw, settings) if character is None else character
    if name == "zero":
        return np.zeros((len(draw.truth), character.n_shapes)), character.shape_names, character.upper, None
    if name == "plain":
        return plain_solve(draw, character), character.shape_names, character.upper, None
    inputs = StrategyInputs()
    if name == "geometric":
        settings = replace(settings, strategy="geometric")
    elif name == "calibrated-old":
        settings = replace(settings, strategy="calibrated", calibration=CalibrationSettings(
            poses=_poses(draw.calibration_poses)))
        inputs = StrategyInputs(calibration=draw.calibration)
    else:
        settings = replace(settings, strategy="semantic", actor=ActorSettings(template="none"))
        if name in ("poses12", "poses12+template"):
            settings = replace(settings, calibration=CalibrationSettings(poses=_poses(draw.few_poses)))
            inputs = replace(inputs, calibration=draw.few)
        if name == "calibration":
            settings = replace(settings, calibration=CalibrationSettings(poses=_poses(draw.calibration_poses)))
            inputs = replace(inputs, calibration=draw.calibration)
        if name.startswith("rom"):
            sheet = ROM_METHODS[name.split("+")[0]]
            settings = replace(settings, calibration=CalibrationSettings(sequence=SHEETS[sheet]))
            inputs = replace(inputs, calibration=draw.roms[sheet].markers)
        if name in ("template", "poses12+template") or name.endswith("+template"):
            inputs = replace(inputs, template=template)
        if name == "oracle":  # the actor's own shapes, as no user can know them (combination terms left out)
            a = draw.actor
            inputs = replace(inputs, profile=Basis(a.shape_names, a.names, a.neutral, a.deltas))
    res = retarget(draw.markers, character, settings, inputs=inputs)
    return res.weights, res.shape_names, character.upper, res


def plain_solve(draw, character):
    """The plain reference: per-frame rigid head fit (Kabsch) on the stable markers, the neutral the median of
    the rest frames, a similarity onto the bound points, and ``scipy.optimize.lsq_linear`` per frame within the
    slider ranges; a frame's missing markers are left out of its fit."""
    markers = draw.markers.to_units("m")
    names = [n for n in character.marker_names if n in markers.names]
    P = markers.positions
    stable = [markers.names.index(n) for n in draw.layout.stable]
    ref = np.nanmedian(P[:REST][:, stable], axis=0)
    out = np.empty_like(P)
    for f in range(len(P)):
        ok = np.isfinite(P[f, stable, 0])
        a, b = P[f, stable][ok], ref[ok]
        ca, cb = a.mean(axis=0), b.mean(axis=0)
        u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
        d = np.sign(np.linalg.det(u @ vt))
        R = (u @ np.diag([1.0, 1.0, d]) @ vt).T
        out[f] = (P[f] - ca) @ R.T + cb
    idx = [markers.names.index(n) for n in names]
    neutral = np.nanmedian(out[:REST][:, idx], axis=0)
    target = character.subset_markers(names)
    src, dst = neutral - neutral.mean(axis=0), target.neutral - target.neutral.mean(axis=0)
    u, s, vt = np.linalg.svd(src.T @ dst)
    d = np.sign(np.linalg.det(u @ vt))
    R = (u @ np.diag([1.0, 1.0, d]) @ vt).T
    scale = (s * [1.0, 1.0, d]).sum() / (src**2).sum()
    deltas = scale * (out[:, idx] - neutral) @ R.T
    A = target.deltas.reshape(target.n_shapes, -1).T
    weights = np.zeros((len(P), target.n_shapes))
    for f in range(len(P)):
        rows = np.repeat(np.isfinite(deltas[f, :, 0]), 3)
        if rows.sum() >= 3:
            weights[f] = lsq_linear(A[rows], deltas[f].ravel()[rows], bounds=(target.lower, target.upper),
                                    method="bvls").x
    return weights


def load_template(path):
    """The human template from ``path`` (an ICT-FaceKit face file or folder, or a converted template)."""
    return HumanTemplate.load(path)
