"""Range-of-motion sessions performed as people perform them: a sheet's poses in order, each ramped up from the
neutral, held for a random while with the face wobbling, and released, the head moving throughout.

Imperfect on purpose: a performer gives 80-100 % of what is asked (each shape of a combined expression its own
share), 1-3 neighbouring shapes of the same face region leak in (up to 0.15), holds last 0.5-1.5 s, ramps
0.2-0.45 s, rests 0.4-1.0 s. A session may skip a pose or add an expression the sheet does not ask for.
The truth kept: where each hold is and what weights the performer actually gave there.
"""

from dataclasses import dataclass

import numpy as np

from .metrics import region_of
from .takes import REST, CaptureSettings, capture

#: Seconds: lead-in neutral, ramps, holds, rests between poses.
LEAD, RAMP, HOLD, REST_S = (1.2, 2.0), (0.2, 0.45), (0.5, 1.5), (0.4, 1.0)
#: What a performer gives of an asked shape; how many neighbours leak in, and how much at most.
INTENSITY, LEAKS, LEAK = (0.8, 1.0), (1, 3), 0.15
#: The hold's wobble: relative amplitude and frequency (Hz).
WOBBLE, WOBBLE_HZ = 0.06, (0.4, 1.2)


@dataclass(frozen=True, eq=False)
class RomSession:
    """A captured ROM session with its truth.

    markers : MarkerSet (mm) of the session
    poses : the sheet as asked (tuple of ``rom.sheets.Pose``)
    performed : per hold, the index of the sheet's pose it performs (-1: an expression the sheet does not ask)
    holds : (H, 2) the holds' first and last frames (frame numbers), in the order performed
    given : (H, K) the weights the performer actually gave in each hold (their mean over the hold)
    weights : (F, K) the whole session's weights
    """

    markers: object
    poses: tuple
    performed: tuple
    holds: np.ndarray
    given: np.ndarray
    weights: np.ndarray

    @property
    def middles(self):
        return self.holds.mean(axis=1)


def _smooth_ramp(n):
    s = np.linspace(0.0, 1.0, max(n, 2))
    return s * s * (3 - 2 * s)


def _asked(pose, index, rng):
    """The weights (K,) a performer gives for ``pose``: each asked shape at its own 80-100 %, 1-3 neighbours of the
    same region leaking in."""
    K = len(index)
    target = np.zeros(K)
    for shape, weight in pose.weights:
        if shape in index:
            target[index[shape]] = weight * rng.uniform(*INTENSITY)
    regions = {region_of(s) for s in pose.shapes}
    names = sorted(index, key=index.get)
    near = [index[n] for n in names if region_of(n) in regions and target[index[n]] == 0.0]
    if near:
        for k in rng.choice(near, size=min(len(near), int(rng.integers(LEAKS[0], LEAKS[1] + 1))), replace=False):
            target[k] = rng.uniform(0.0, LEAK)
    return target


def rom_weights(shape_names, poses, rng, *, fps=60.0, skip=(), extra=0, timing=None):
    """Weights (F, K) of a session performing ``poses`` (skipping the indices ``skip``, adding ``extra``
    expressions of two random shapes at random places); returns (weights, performed, holds (H, 2) 1-based frame
    numbers, given (H, K)). ``timing``: (lead, ramp, hold, rest) ranges in seconds (default: ``LEAD``, ``RAMP``,
    ``HOLD``, ``REST_S``; a rendered clip uses shorter ones)."""
    lead, ramp, hold_s, rest_s = (LEAD, RAMP, HOLD, REST_S) if timing is None else timing
    index = {n: i for i, n in enumerate(shape_names)}
    order = [j for j in range(len(poses)) if j not in set(skip)]
    for _ in range(extra):
        order.insert(int(rng.integers(0, len(order) + 1)), -1)
    sec = lambda r: int(round(rng.uniform(*r) * fps))  # noqa: E731
    rows = [np.zeros((max(REST, sec(lead)), len(shape_names)))]
    t = len(rows[0])
    holds, given = [], []
    for j in order:
        if j >= 0:
            target = _asked(poses[j], index, rng)
        else:
            target = np.zeros(len(shape_names))
            target[rng.choice(len(shape_names), size=2, replace=False)] = rng.uniform(0.5, 1.0, size=2)
        up, hold, down, rest = sec(ramp), sec(hold_s), sec(ramp), sec(rest_s)
        tt = np.arange(hold) / fps
        wobble = 1.0 + WOBBLE * np.sin(2 * np.pi * rng.uniform(*WOBBLE_HZ) * tt + rng.uniform(0, 2 * np.pi))
        held = np.clip(wobble[:, None] * target[None], 0.0, 1.0)
        block = np.concatenate([_smooth_ramp(up)[:, None] * held[0], held, _smooth_ramp(down)[::-1, None] * held[-1],
                                np.zeros((rest, len(shape_names)))])
        holds.append((t + up + 1, t + up + hold))
        given.append(held.mean(axis=0))
        rows.append(block)
        t += len(block)
    rows.append(np.zeros((int(fps), len(shape_names))))
    return np.concatenate(rows), tuple(order), np.array(holds, dtype=np.float64), np.array(given)


def rom_session(actor, poses, rng, *, stable=(), capture_settings=CaptureSettings(), skip=(), extra=0,
                source="ROM session"):
    """A RomSession of ``actor`` (an ActorFace) performing the sheet ``poses``, captured with its own head motion
    and noise (``capture_settings``, a quarter of the gaps: a calibration is recorded with care)."""
    weights, performed, holds, given = rom_weights(actor.shape_names, poses, rng, skip=skip, extra=extra)
    quiet = CaptureSettings(max_deg=capture_settings.max_deg, max_offset=capture_settings.max_offset,
                            noise=capture_settings.noise, gaps=capture_settings.gaps / 4)
    markers = capture(actor, weights, rng, settings=quiet, stable=stable, source=source)
    return RomSession(markers, tuple(poses), performed, holds, given, weights)
