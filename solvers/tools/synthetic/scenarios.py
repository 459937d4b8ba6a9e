"""Seeded random scenarios for tests and benchmarks: characters, actors and marker takes.

One integer seed gives one draw; tests assert on the median and the worst case over many draws, so
no algorithm is tuned to one sample (the bundled sample take is one draw among many). A draw:

* **character** - an ellipsoid head of random proportions with a bump for the nose, 20-120 bound
  points with arbitrary names (shuffled, so no order gives the layout away), with or without a
  band of dedicated head markers, and a set of shapes (ARKit names, so
  :func:`~.synth.performance_weights` drives them) acting on chosen regions only: ``"full"``
  (brows, eyes, cheeks, nose, mouth, jaw), ``"lower_mid"`` (upper face rigid too), ``"lower"``
  (mouth and jaw only) - every marker no shape moves is rigid with the head;
* **actor** - the character scaled (0.85-1.2) with per-axis proportions (+-8 %);
* **take** - a performance of the shapes with smooth head motion (5-35 degrees, 1-8 cm), marker
  noise (0.1-0.6 mm), ordinary gaps (runs of 2-30 frames), long gaps (10-35 % of the take) on a
  few rigid markers, and occasional outliers (a sample thrown 5-30 mm).

The footage side (textures, warps, codecs) is :mod:`.scenarios_footage`.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ...character.basis import Basis
from ...markers import MarkerSet
from .synth import head_motion, performance_weights

REGIONS = ("upper", "mid", "lower")
#: Shape -> region it deforms and where on the face its centre lies (azimuth, elevation; radians, +az = left).
SHAPES = {
    "browInnerUp": ("upper", 0.0, 0.55), "browDownLeft": ("upper", 0.3, 0.5), "browDownRight": ("upper", -0.3, 0.5),
    "browOuterUpLeft": ("upper", 0.6, 0.5), "browOuterUpRight": ("upper", -0.6, 0.5),
    "eyeBlinkLeft": ("mid", 0.35, 0.3), "eyeBlinkRight": ("mid", -0.35, 0.3),
    "eyeSquintLeft": ("mid", 0.45, 0.2), "eyeSquintRight": ("mid", -0.45, 0.2),
    "eyeWideLeft": ("mid", 0.35, 0.35), "eyeWideRight": ("mid", -0.35, 0.35),
    "cheekSquintLeft": ("mid", 0.55, 0.05), "cheekSquintRight": ("mid", -0.55, 0.05), "cheekPuff": ("mid", 0.0, -0.1),
    "noseSneerLeft": ("mid", 0.12, 0.1), "noseSneerRight": ("mid", -0.12, 0.1),
    "jawOpen": ("lower", 0.0, -0.6), "jawLeft": ("lower", 0.0, -0.65),
    "mouthSmileLeft": ("lower", 0.35, -0.3), "mouthSmileRight": ("lower", -0.35, -0.3),
    "mouthFrownLeft": ("lower", 0.35, -0.35), "mouthFrownRight": ("lower", -0.35, -0.35),
    "mouthPucker": ("lower", 0.0, -0.3), "mouthFunnel": ("lower", 0.0, -0.32),
    "mouthLowerDownLeft": ("lower", 0.15, -0.4), "mouthLowerDownRight": ("lower", -0.15, -0.4),
    "mouthUpperUpLeft": ("lower", 0.15, -0.2), "mouthUpperUpRight": ("lower", -0.15, -0.2),
    "mouthStretchLeft": ("lower", 0.4, -0.35), "mouthStretchRight": ("lower", -0.4, -0.35),
    "mouthPressLeft": ("lower", 0.12, -0.3), "mouthPressRight": ("lower", -0.12, -0.3),
    "mouthDimpleLeft": ("lower", 0.45, -0.3), "mouthLeft": ("lower", 0.0, -0.3),
    "mouthRollLower": ("lower", 0.0, -0.38), "mouthShrugLower": ("lower", 0.0, -0.5), "mouthClose": ("lower", 0.0, -0.33),
}
COVERAGE = {"full": ("upper", "mid", "lower"), "lower_mid": ("mid", "lower"), "lower": ("lower",)}
NAME_STYLES = ("M{:03d}", "mk_{}", "LED{}", "pt{}", "dot.{:02d}", "Face_{}", "c3d_{:04d}")


@dataclass(frozen=True, eq=False)
class Character:
    """A random character: its basis (metres, faces -Y, Z up) and the truth about its layout."""

    basis: Basis
    rigid: tuple  # markers no shape moves (the true stable set)
    head: tuple  # dedicated head markers (empty for layouts without them)
    region: dict  # marker -> "head", "upper", "mid" or "lower"
    coverage: str  # which regions the shapes act on (a COVERAGE key)


@dataclass(frozen=True, eq=False)
class Actor:
    scale: float
    proportions: np.ndarray  # (3,) per-axis factors on top of ``scale``


@dataclass(frozen=True, eq=False)
class MarkerScenario:
    """One draw: character, actor and a take with its ground truth."""

    seed: int
    character: Character
    actor: Actor
    markers: MarkerSet  # the take as captured (mm, capture axes, noise, gaps, outliers)
    weights: np.ndarray  # (F, K) ground-truth weights of ``character.basis.shape_names``
    rest: int  # neutral hold at the start: frames 1..rest
    noise_mm: float
    params: dict = field(default_factory=dict)  # everything drawn, JSON-ready, for reports

    @property
    def neutral_frames(self):
        return (1, self.rest)


def _layout(rng, n_markers, with_head):
    """(azimuth, elevation, region) of every marker: a head band (optional) and the face regions."""
    az, el, region = [], [], []
    if with_head:
        n_head = int(rng.integers(4, 9))
        for i in range(n_head):  # forehead top, temples, sides of the head: spread around the skull
            a = -1.35 + 2.7 * (i + rng.uniform(0.2, 0.8)) / n_head
            az.append(a)
            el.append(rng.uniform(0.75, 1.0) if abs(a) < 0.9 else rng.uniform(0.25, 0.6))
            region.append("head")
    n_face = n_markers - len(az)
    share = rng.dirichlet([3.0, 4.0, 5.0]) * 0.6 + np.array([0.25, 0.3, 0.45]) * 0.4
    counts = np.maximum(3, np.round(share * n_face).astype(int))
    counts[-1] = n_face - counts[:-1].sum()
    bands = {"upper": (0.42, 0.72), "mid": (-0.12, 0.42), "lower": (-0.8, -0.12)}
    for name, count in zip(REGIONS, counts):
        lo, hi = bands[name]
        width = 1.15 if name != "lower" else 0.95
        for _ in range(count):
            az.append(rng.uniform(-width, width))
            el.append(rng.uniform(lo, hi))
            region.append(name)
    return np.array(az), np.array(el), region


def _surface(az, el, radii, nose):
    """Points on the front of an ellipsoid head (metres, facing -Y) with a nose bump."""
    pts = np.stack([np.sin(az) * np.cos(el), -np.cos(az) * np.cos(el), np.sin(el)], axis=1) * radii
    bump = nose * np.exp(-((az / 0.18) ** 2 + ((el - 0.05) / 0.25) ** 2))
    pts[:, 1] -= bump
    return pts


def random_character(rng, *, n_markers=None, coverage=None, with_head=None, n_shapes=None):
    """A random :class:`Character` (see the module docstring); options fix what would be drawn."""
    n_markers = int(rng.integers(20, 121)) if n_markers is None else int(n_markers)
    with_head = bool(rng.random() < 0.7) if with_head is None else bool(with_head)
    coverage = str(rng.choice(list(COVERAGE))) if coverage is None else coverage
    radii = np.array([rng.uniform(0.065, 0.085), rng.uniform(0.085, 0.11), rng.uniform(0.1, 0.13)])
    az, el, region = _layout(rng, n_markers, with_head)
    pts = _surface(az, el, radii, rng.uniform(0.01, 0.025))
    moving = COVERAGE[coverage]
    pool = [s for s, (r, _, _) in SHAPES.items() if r in moving]
    if n_shapes is not None:
        pool = list(rng.choice(pool, size=min(int(n_shapes), len(pool)), replace=False))
    deltas = np.zeros((len(pool), len(pts), 3))
    for k, shape in enumerate(pool):
        reg, a, e = SHAPES[shape]
        centre = _surface(np.array([a + rng.normal(0, 0.05)]), np.array([e + rng.normal(0, 0.05)]), radii, 0.0)[0]
        reach = rng.uniform(0.025, 0.045) * (1.4 if shape.startswith("jaw") else 1.0)
        d = np.linalg.norm(pts - centre, axis=1) / reach
        falloff = np.where(d < 1.0, (1.0 - d**2) ** 2, 0.0)  # compact support: rigid stays exactly rigid
        falloff *= np.array([r in moving and r != "head" for r in region])
        direction = rng.normal(size=3)
        direction[2] += -1.5 if shape.startswith(("jaw", "mouthLowerDown")) else 0.0
        direction /= np.linalg.norm(direction)
        amp = rng.uniform(0.004, 0.012) * (2.0 if shape == "jawOpen" else 1.0)
        deltas[k] = amp * falloff[:, None] * direction
    style = str(rng.choice(NAME_STYLES))
    numbers = rng.permutation(len(pts)) + int(rng.integers(0, 50))
    names = [style.format(int(i)) for i in numbers]
    order = rng.permutation(len(pts))  # the file order gives nothing away
    names = [names[i] for i in order]
    pts, region = pts[order], [region[i] for i in order]
    deltas = deltas[:, order]
    basis = Basis(tuple(pool), tuple(names), pts, deltas)
    rigid = tuple(n for n, m in zip(names, np.abs(deltas).max(axis=(0, 2)) if len(pool) else np.zeros(len(names)))
                  if m == 0.0)
    head = tuple(n for n, r in zip(names, region) if r == "head")
    return Character(basis, rigid, head, dict(zip(names, region)), coverage)


def random_actor(rng):
    """A random :class:`Actor`: overall scale 0.85-1.2, per-axis proportions within +-8 %."""
    return Actor(float(rng.uniform(0.85, 1.2)), rng.uniform(0.92, 1.08, size=3))


def _gaps(rng, visible, names, rigid, rest, gap_fraction, max_gap, n_long):
    """Clear samples of ``visible`` (F, M) in place: ordinary gaps everywhere after ``rest``, plus
    one long gap on ``n_long`` rigid markers. Returns {marker: (start frame index, length)}."""
    F, M = visible.shape
    for m in range(M):
        target = int(round(gap_fraction * rng.uniform(0.0, 2.0) * (F - rest)))
        missing = 0
        while missing < target:
            length = int(rng.integers(2, max_gap + 1))
            start = int(rng.integers(rest, max(rest + 1, F - length)))
            visible[start: start + length, m] = False
            missing = int((~visible[:, m]).sum())
    long = {}
    rigid_idx = [i for i, n in enumerate(names) if n in set(rigid)]
    for m in rng.permutation(rigid_idx)[:n_long]:
        length = int(rng.uniform(0.1, 0.35) * (F - rest))
        start = int(rng.integers(rest, F - length))
        visible[start: start + length, m] = False
        long[names[m]] = (start, length)
    return long


def random_take(rng, character, actor, *, n_frames=360, fps=60.0, rest=40, max_deg=None, max_offset=None,
                noise_mm=None, gap_fraction=None, max_gap=30, n_long_gaps=None, outlier_rate=None):
    """A take of ``character``'s shapes performed by ``actor``: (MarkerSet in mm, weights (F, K), params)."""
    basis = character.basis
    max_deg = float(rng.uniform(5.0, 35.0)) if max_deg is None else float(max_deg)
    max_offset = float(rng.uniform(0.01, 0.08)) if max_offset is None else float(max_offset)
    noise_mm = float(rng.uniform(0.1, 0.6)) if noise_mm is None else float(noise_mm)
    gap_fraction = float(rng.uniform(0.0, 0.08)) if gap_fraction is None else float(gap_fraction)
    n_long_gaps = int(rng.integers(0, 4)) if n_long_gaps is None else int(n_long_gaps)
    outlier_rate = float(rng.choice([0.0, 0.0005, 0.002])) if outlier_rate is None else float(outlier_rate)
    weights = performance_weights(basis.shape_names, n_frames, fps=fps, rest=rest, seed=int(rng.integers(1 << 31)))
    face = basis.neutral[None] + np.einsum("fk,kmd->fmd", weights, basis.deltas)
    face = face * (actor.scale * actor.proportions)
    rotvec, offset = head_motion(n_frames, fps=fps, rest=rest, max_deg=max_deg, max_offset=max_offset,
                                 seed=int(rng.integers(1 << 31)))
    R = Rotation.from_rotvec(rotvec).as_matrix()
    pivot = np.array([0.0, rng.uniform(0.01, 0.05), rng.uniform(-0.15, -0.08)]) * actor.scale
    moved = np.einsum("fij,fmj->fmi", R, face - pivot) + pivot + offset[:, None]
    Rc = Rotation.from_euler("xyz", [rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-180, 180)],
                             degrees=True).as_matrix()
    capture = (moved @ Rc.T + rng.uniform(-1.0, 1.0, size=3) + [0, 0, 1.6]) * 1e3
    noisy = capture + rng.normal(0.0, noise_mm, size=capture.shape)
    visible = np.ones(capture.shape[:2], dtype=bool)
    long = _gaps(rng, visible, basis.marker_names, character.rigid, rest, gap_fraction, max_gap, n_long_gaps)
    outliers = rng.random(visible.shape) < outlier_rate
    outliers[:rest] = False
    kick = rng.normal(size=capture.shape)
    kick *= (rng.uniform(5.0, 30.0, size=capture.shape[:2]) / np.linalg.norm(kick, axis=2))[..., None]
    noisy[outliers] += kick[outliers]
    noisy[~visible] = np.nan
    markers = MarkerSet(basis.marker_names, np.arange(1, n_frames + 1, dtype=np.float64), noisy, fps=fps,
                        units="mm", source="scenario take")
    params = {"max_deg": round(max_deg, 2), "max_offset_m": round(max_offset, 4), "noise_mm": round(noise_mm, 3),
              "gap_fraction": round(gap_fraction, 3), "long_gaps": {k: list(v) for k, v in long.items()},
              "outliers": int(outliers.sum()), "gaps": round(float((~visible).mean()), 4)}
    return markers, weights, params


def marker_scenario(seed, *, n_frames=360, fps=60.0, rest=40, **options):
    """Draw number ``seed``: a random character, actor and take (:class:`MarkerScenario`).

    ``options`` fix what would otherwise be drawn: ``n_markers``, ``coverage``, ``with_head``,
    ``n_shapes`` (character) and ``max_deg``, ``max_offset``, ``noise_mm``, ``gap_fraction``,
    ``max_gap``, ``n_long_gaps``, ``outlier_rate`` (take).
    """
    rng = np.random.default_rng([21, int(seed)])
    char_keys = ("n_markers", "coverage", "with_head", "n_shapes")
    character = random_character(rng, **{k: v for k, v in options.items() if k in char_keys})
    actor = random_actor(rng)
    markers, weights, params = random_take(rng, character, actor, n_frames=n_frames, fps=fps, rest=rest,
                                           **{k: v for k, v in options.items() if k not in char_keys})
    params.update(n_markers=character.basis.n_markers, n_shapes=character.basis.n_shapes,
                  coverage=character.coverage, head_markers=len(character.head), rigid=len(character.rigid),
                  actor_scale=round(actor.scale, 3))
    return MarkerScenario(int(seed), character, actor, markers, weights, rest, params["noise_mm"], params)
