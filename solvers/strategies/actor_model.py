"""How the ACTOR's face moves for each of the character's shapes, as well as facecap knows it.

A character's shape keys say how the character moves, not how the actor does: solving an actor's markers
against them gives weights that follow the character's geometry. ``build_actor_model`` assembles the
actor's own shapes at the take's markers (actor space: the stabilised head frame, metres) from what the
user gives, best first:

==============  =====================================================================================
tier            where each shape comes from
==============  =====================================================================================
calibration     a calibration pose per shape (``[calibration]``), measured
poses           some shapes measured from poses, the others the template's (if there is one) or the
                character's normalised per marker to the actor's range
profile         a stored per-performer profile (an earlier calibration of this actor)
template        a human face model fitted to the actor's neutral (``[actor] template``)
character       nothing known: the character's shapes carried into actor space and normalised per
                marker to the actor's range; the weights follow the character's geometry
==============  =====================================================================================

Shapes that no marker sees (no marker moves more than ``unseen_mm``) are held at rest unless freed.
"""

from dataclasses import dataclass, field

import numpy as np

from ..character.aliases import name_key
from ..character.basis import Basis
from ..engine import solve_bounded
from ..errors import FacecapError
from ..transforms import fit_similarity
from .base import as_target

TIERS = ("calibration", "poses", "profile", "template", "character")
#: A shape is measured well enough for the "calibration" tier when this share of the seen shapes is posed.
FULL_SHARE = 0.9
#: Range normalisation gains stay within this factor of 1.
MAX_GAIN = 4.0
#: Fit ratios (residual over noise) between which the range normalisation goes from none to all.
NORMALISE_FROM, NORMALISE_FULL = 1.6, 2.4
#: ... and the shares of markers whose range on the character is more than ``RANGE_FAR`` times off the actor's
#: between which it may: a high fit ratio with the character's ranges matching the actor's is the capture's error
#: (a landmark detector's points slide on the face; their filtered noise reads low), not the character's. Realism
#: benchmark, 5 draws: another person 0-3 %, the cartoon 0-8 %, the sample character 21-50 %; rendered footage's
#: landmarks: onto another person 4 %, onto the sample character 38 %.
RANGE_FAR, RANGE_FROM, RANGE_FULL = 3.0, 0.10, 0.20

STATEMENTS = {
    "calibration": "solved against the actor's own calibration poses",
    "poses": "solved against {measured} measured pose(s) of the actor; the other shapes are completed from the {prior}",
    "profile": "solved against the stored profile of this performer",
    "template": "solved against a human face template fitted to the actor's neutral (no calibration)",
    "character": ("nothing is known about the actor's face: the weights follow the character's geometry, not the "
                  "actor's expressions. Give calibration poses ([calibration] poses, or frames of the take labelled "
                  "with [calibration] poses), a performer profile ([actor] profile) or the human template "
                  "(install it once: `python -m facecap template fetch`, or Install Human Template in the sidebar with "
                  "the ICT-FaceKit download) to solve the actor's expressions"),
}


@dataclass(frozen=True)
class ActorKnowledge:
    """What the user gives about the actor (each optional).

    measured : Basis or None, measured poses (calibration take or labelled frames), any frame: aligned
        onto the take's neutral by a rigid fit of the markers they share
    profile : Basis or None, a stored per-performer profile (same alignment)
    template : TemplateFit or None, the human template fitted to the actor (in the character's frame)
    unseen : "rest" (shapes no marker sees are held at 0) or "solve"
    unseen_mm : a shape no marker moves by more than this is unseen
    normalise : range-normalise the character's shapes per marker in the "character" tier
    """

    measured: Basis = None
    profile: Basis = None
    template: object = None
    unseen: str = "rest"
    unseen_mm: float = 1.5
    normalise: bool = True


@dataclass(frozen=True, eq=False)
class ActorModel:
    """The actor's shapes at the markers, ``basis`` (character shape names, actor space), with where each
    came from (``sources``: measured, profile, template, completed (template or character), character, unseen)
    and the tier."""

    basis: Basis
    sources: tuple
    tier: str
    unseen: tuple
    notes: tuple = field(default_factory=tuple)
    gains: np.ndarray = None  # per-marker range normalisation of the "character" tier, else None
    fit_ratio: float = float("nan")  # "character" tier: its shapes' marker residual over the markers' noise
    mismatch: float = 0.0  # "character" tier: 0 (its shapes explain the actor) .. 1 (they do not: normalised)
    far: float = float("nan")  # "character" tier: share of markers whose range is RANGE_FAR times off the actor's

    def statement(self):
        if self.tier == "character" and self.mismatch == 0.0 and np.isfinite(self.fit_ratio):
            if self.fit_ratio <= NORMALISE_FROM or not np.isfinite(self.far):
                return (f"nothing is known about the actor's face, but the character's shapes explain the markers to "
                        f"{self.fit_ratio:.1f}x their noise: they are taken as the actor's (a character of the "
                        "actor's own proportions and expressions)")
            return (f"nothing is known about the actor's face, but the character's shapes move the markers over the "
                    f"actor's ranges ({100 * self.far:.0f}% of the markers {RANGE_FAR:g}x off): they are taken as the "
                    f"actor's; their residual, {self.fit_ratio:.1f}x the markers' noise, is taken as the capture's "
                    "error (points that do not follow the skin exactly, as a landmark detector's slide on the face)")
        measured = sum(s == "measured" for s in self.sources)
        prior = "human template" if "template" in self.sources or any(
            s == "completed (template)" for s in self.sources) else "character's shapes"
        return STATEMENTS[self.tier].format(measured=measured, prior=prior)

    def report(self):
        counts = {}
        for s in self.sources:
            counts[s] = counts.get(s, 0) + 1
        out = {"tier": self.tier, "statement": self.statement(), "shapes": counts, "unseen": list(self.unseen),
               "sources": dict(zip(self.basis.shape_names, self.sources))}
        if self.gains is not None:
            out["range_gains"] = [round(float(np.percentile(self.gains, q)), 3) for q in (5, 50, 95)]
            out["character_mismatch"] = round(self.mismatch, 3)
            out["character_fit_to_noise"] = None if not np.isfinite(self.fit_ratio) else round(self.fit_ratio, 2)
            out["character_ranges_far_off"] = None if not np.isfinite(self.far) else round(self.far, 3)
        return out


def _by_name(names, shapes):
    """{index into ``shapes``: index into ``names``} matched by name, then by alias key."""
    exact = {n: i for i, n in enumerate(names)}
    keyed = {name_key(n): i for i, n in enumerate(names)}
    out = {}
    for k, s in enumerate(shapes):
        i = exact.get(s, keyed.get(name_key(s)))
        if i is not None:
            out[k] = i
    return out


def into_take_frame(basis, names, neutral):
    """``basis`` (measured in its own head frame) rotated onto the take: (K, M, 3) deltas for the markers
    ``names`` (zeros where the basis has no such marker) and the list of markers it lacks."""
    common = [n for n in names if n in set(basis.marker_names)]
    if len(common) < 3:
        raise FacecapError(f"the calibration shares only {len(common)} marker(s) with the take (need 3)")
    src = basis.neutral[[basis.marker_names.index(n) for n in common]]
    dst = neutral[[names.index(n) for n in common]]
    rot = fit_similarity(src, dst, allow_scale=False).rotation
    out = np.zeros((basis.n_shapes, len(names), 3))
    for j, n in enumerate(names):
        if n in basis.marker_names:
            out[:, j] = basis.deltas[:, basis.marker_names.index(n)] @ rot.T
    return out, [n for n in names if n not in set(basis.marker_names)]


def range_gains(prior, deltas):
    """Per-marker gains (M,) that scale the actor's take ``deltas`` (F, M, 3) to the range the ``prior``
    (K, M, 3) gives each marker (Sony's normalisation of the actor's motion to the character's), within
    ``MAX_GAIN`` of 1. The character's range is the 95th percentile of its motion under sparse random
    weights; the actor's the 95th percentile of the take's."""
    rng = np.random.default_rng(0)
    K = prior.shape[0]
    w = rng.random((2000, K)) * (rng.random((2000, K)) < 0.15)
    motion = np.linalg.norm(np.einsum("fk,kmd->fmd", w, prior), axis=2)
    character = np.percentile(motion, 95, axis=0)
    with np.errstate(invalid="ignore"):
        actor = np.nanpercentile(np.linalg.norm(deltas, axis=2), 95, axis=0)
    gains = np.where((actor > 0) & np.isfinite(actor), character / np.where(actor > 0, actor, 1.0), 1.0)
    return np.clip(gains, 1.0 / MAX_GAIN, MAX_GAIN)


def fit_ratio(basis, deltas, noise, *, frames=600):
    """How far the shapes ``basis`` (K, M, 3) are from explaining ``deltas`` (F, M, 3): the median marker
    residual of a quick per-frame bounded solve on up to ``frames`` frames, over the markers' ``noise``
    (metres per coordinate; ~1 when the shapes describe the face, 2.5-3 for a stylised character's
    shapes against a human actor)."""
    F = deltas.shape[0]
    sel = np.unique(np.linspace(0, F - 1, min(F, frames)).astype(int))
    D = deltas[sel]
    K = basis.shape[0]
    res = solve_bounded(basis.reshape(K, -1).T, D.reshape(len(sel), -1), dims=3, regularisation=1e-3,
                        sparsity=1e-3, relative=True, lower=0.0, upper=1.0)
    r2 = res.residual_norms(3)
    seen = np.isfinite(D[:, :, 0])
    if not seen.any() or not noise > 0:
        return float("nan")
    return float(np.sqrt(np.median(r2[seen])) / (noise * np.sqrt(3.0)))


def normalisation_share(ratio):
    """How much of the range normalisation to apply for a ``fit_ratio``: none while the character's shapes
    explain the actor's motion (a self-retarget, a character of the actor's own shape family: ratio below
    ``NORMALISE_FROM``), all of it from ``NORMALISE_FULL`` up."""
    if not np.isfinite(ratio):
        return 1.0
    return float(np.clip((ratio - NORMALISE_FROM) / (NORMALISE_FULL - NORMALISE_FROM), 0.0, 1.0))


def range_share(gains):
    """How much of the range normalisation the per-marker ``gains`` call for: none while at most ``RANGE_FROM``
    of the markers are more than ``RANGE_FAR`` times off, all of it from ``RANGE_FULL``."""
    far = float(np.mean(np.abs(np.log(gains)) > np.log(RANGE_FAR))) if len(gains) else 0.0
    return float(np.clip((far - RANGE_FROM) / (RANGE_FULL - RANGE_FROM), 0.0, 1.0)), far


def character_normalisation(prior, deltas, usable, noise):
    """Per-marker gains (M,) that map the character's shapes ``prior`` (K, M, 3) onto the actor's range (1 on
    markers not ``usable``), applied as far as the character's shapes fail to explain the take's ``deltas`` and
    its ranges are off the actor's; returns (gains, fit ratio, share applied, share of markers far off)."""
    ratio = fit_ratio(prior[:, usable], deltas[:, usable], noise if noise is not None else float("nan"))
    full = range_gains(prior[:, usable], deltas[:, usable])
    by_range, far = range_share(full)
    share = min(normalisation_share(ratio), by_range)
    gains = np.ones(prior.shape[1])
    gains[usable] = np.exp(share * np.log(full))
    return gains, ratio, share, far


def build_actor_model(character, names, neutral, knowledge, *, character_deltas=None, deltas=None, noise=None):
    """The actor's shapes for ``character``'s shape names at the take's markers.

    Parameters
    ----------
    character : Basis or Target (shape names and bounds)
    names, neutral : the take's marker names (M) and neutral (M, 3), actor space
    knowledge : ActorKnowledge
    character_deltas : (K, M, 3) the character's shapes carried into actor space at ``names`` (rows of
        markers not bound on the character are NaN), needed for the "character" tier and as a prior
    deltas : (F, M, 3) the take's deltas (for the range normalisation of the "character" tier)

    Returns
    -------
    ActorModel
    """
    target = as_target(character)
    shapes = target.names
    K, M = len(shapes), len(names)
    notes = []
    basis = np.zeros((K, M, 3))
    sources = ["" for _ in range(K)]
    usable = np.ones(M, dtype=bool)  # markers every shape of the result knows
    for label, given in (("profile", knowledge.profile), ("measured", knowledge.measured)):
        if given is None:
            continue
        moved, lacking = into_take_frame(given, names, neutral)
        if lacking:
            notes.append(f"{label}: {len(lacking)} marker(s) of the take are not in it and are not solved from: "
                         f"{lacking[:8]}")
            usable &= ~np.isin(np.array(names), lacking)
        for k, i in _by_name(given.shape_names, shapes).items():
            basis[k], sources[k] = moved[i], label
        unused = sorted(set(given.shape_names) - {given.shape_names[i] for i in _by_name(given.shape_names, shapes).values()})
        if unused:
            notes.append(f"{label}: pose(s) {unused[:8]} name no shape of the character and are not used")
    prior, prior_name = None, ""
    if knowledge.template is not None:
        t = knowledge.template
        prior, prior_name = np.zeros((K, M, 3)), "template"
        for k, i in _by_name(t.shape_names, shapes).items():
            prior[k] = t.deltas[i]
        notes.extend(t.notes)
    elif character_deltas is not None:
        prior, prior_name = np.nan_to_num(character_deltas), "character"
        unbound = ~np.isfinite(character_deltas).all(axis=(0, 2))
        if unbound.any() and not all(sources):
            usable &= ~unbound
            notes.append(f"{int(unbound.sum())} marker(s) have no binding on the character and are not solved from: "
                         f"{[n for n, u in zip(names, unbound) if u]}")
    known = np.array([bool(s) for s in sources])
    gains, share, ratio, far = None, 0.0, float("nan"), float("nan")
    if prior is not None and not known.all():
        # unposed shapes straight from the prior (the template's fitted shapes; the character's normalised to the
        # actor's range as far as they fail to explain the markers), not mapped through the measured ones: a 3x3
        # map per marker through a few poses overfits where those move little (realism benchmark, 12 poses onto the
        # sample character: 0.163 -> 0.156, mean per-shape r 0.41 -> 0.54, cheekSquint had come out 30x the
        # actor's; with the template: median 0.073 -> 0.074, r 0.80 -> 0.82, worst draw 0.173 -> 0.126, 68
        # landmarks 0.089 -> 0.074)
        filled = prior
        if prior_name == "character" and knowledge.normalise and deltas is not None and usable.any():
            gains, ratio, share, far = character_normalisation(prior, deltas, usable, noise)
            filled = prior / gains[None, :, None]
        label = f"completed ({prior_name})" if known.any() else prior_name
        unfilled = basis.copy()
        for k in np.flatnonzero(~known):
            basis[k], sources[k], unfilled[k] = filled[k], label, prior[k]
    else:
        unfilled = basis
    # what a shape moves before any range normalisation (a shape the character moves no marker with is unseen)
    size = np.linalg.norm(unfilled[:, usable], axis=2).max(axis=1) if usable.any() else np.zeros(K)
    if prior_name == "character" and not known.any():
        tier = "character"
    elif known.any():
        posed = sum(s == "measured" for s in sources)
        seen = K - sum(not s for s in sources)
        tier = ("calibration" if posed >= FULL_SHARE * seen else "poses") if posed else "profile"
    else:
        tier = prior_name or "character"
    missing = [shapes[k] for k in range(K) if not sources[k]]
    if missing:
        notes.append(f"{len(missing)} shape(s) have no source and stay at rest: {', '.join(missing[:8])}")
        sources = [s or "none" for s in sources]
    unseen = tuple(shapes[k] for k in range(K) if size[k] * 1e3 < knowledge.unseen_mm)
    if unseen and knowledge.unseen == "rest":
        notes.append(f"{len(unseen)} shape(s) move no marker by {knowledge.unseen_mm:g} mm and are held at rest: "
                     f"{', '.join(unseen[:10])}{' ...' if len(unseen) > 10 else ''}; "
                     '[solve] unseen_shapes = "solve" solves them anyway')
    if not usable.any():
        raise FacecapError("no marker of the take is known to every shape (bind the markers on the character, or "
                           "give calibration poses that include them)")
    lower, upper = target.lower, target.upper
    used = tuple(n for n, u in zip(names, usable) if u)
    actor = Basis(shapes, used, neutral[usable], basis[:, usable], lower, upper)
    keep = gains is not None and tier == "character"  # the report's range gains are the nothing-known tier's
    return ActorModel(actor, tuple(sources), tier, unseen if knowledge.unseen == "rest" else (), tuple(notes),
                      gains[usable] if keep else None, ratio if keep else float("nan"), share if keep else 0.0,
                      far if keep else float("nan"))


def profile_of(model):
    """The performer profile an ActorModel gives (a Basis of its measured shapes, actor space), or None when
    nothing of it was measured. A later take reads it with ``[actor] profile``; the shapes it lacks are
    completed there as in that take's own tier."""
    keep = [k for k, s in enumerate(model.sources) if s in ("measured", "profile")]
    if not keep:
        return None
    b = model.basis
    return Basis(tuple(b.shape_names[k] for k in keep), b.marker_names, b.neutral, b.deltas[keep],
                 b.lower[keep], b.upper[keep])
