"""Real captures onto the sample character, solved as a user would (no truth: judged by how plausible the
weights are): Facial-Sing (NaturalPoint C3D, 38 markers, bound by position automatically) and the two
blenderFace subjects (16 markers, bound by the documented map ``sample_blends/blenderface_binding.csv``)."""

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ....character.binding_map import BindingSettings
from ....io import import_markers
from ....pipeline import RetargetSettings, retarget
from ....pipeline.binding import bind_character
from ....strategies.options import StrategyInputs
from .targets import SAMPLE_DIR, sample_character


@dataclass(frozen=True)
class Capture:
    name: str
    path: str  # under the shared folder
    read: dict
    stable: tuple
    neutral: tuple
    binding: BindingSettings


#: Facial-Sing's markers on six of the sample character's vertex groups: the landmarks a user gives when
#: automatic binding asks for them (``[binding.landmarks]``, docs/binding.md).
FACIAL_SING_LANDMARKS = {"section7-2": "nose_tip_C", "section14-2": "chin_C", "section11-1": "mouth_corner_L",
                         "section12-1": "mouth_corner_R", "section1-1": "brow_inner_L", "section2-1": "brow_inner_R"}


def landmarks_toml(landmarks):
    """The ``[binding.landmarks]`` table of a take config for {marker: vertex group}."""
    return "[binding.landmarks]\n" + "".join(f'{marker} = "{group}"\n' for marker, group in landmarks.items())


CAPTURES = (
    Capture("Facial-Sing", "data/realdata/c3d/c3dorg_29_Facial-Sing.c3d", {},
            ("root-1", "root-2", "root-3", "root-4", "root-5", "root-6"), (1, 100), BindingSettings(mode="nearest")),
    Capture("blenderFace 1", "data/blenderface/Subject_01.csv", {"units": "bu", "unit_scale": 0.1876, "fps": 60},
            ("BL4", "BR4", "CL4", "CR4"), (800, 985),
            BindingSettings(mode="map", map_path=SAMPLE_DIR / "blenderface_binding.csv")),
    Capture("blenderFace 2", "data/blenderface/Subject_02.csv", {"units": "bu", "unit_scale": 0.1610, "fps": 60},
            ("BL4", "BR4", "CL4", "CR4"), (700, 940),
            BindingSettings(mode="map", map_path=SAMPLE_DIR / "blenderface_binding.csv")),
)
GAZE_PREFIX = "eyeLook"


def run_real(shared, *, strategies=("geometric", "semantic"), template=None):
    """One row per (capture, strategy): weights at the upper bound, the shapes pinned most, the largest gaze
    weight, the plausibility verdict and the fit residual; with a ``template`` (HumanTemplate) also the semantic
    solve with it ("semantic + template")."""
    mesh = sample_character()
    rows = []
    solves = [(s, s, None) for s in strategies]
    if template is not None:
        solves.append(("semantic + template", "semantic", StrategyInputs(template=template)))
    for capture in CAPTURES:
        markers = import_markers(Path(shared) / capture.path, **capture.read).markers.to_units("m")
        settings = RetargetSettings(stable_markers=capture.stable, neutral_frames=capture.neutral)
        basis = bind_character(mesh, markers, settings, capture.binding).basis
        for label, strategy, inputs in solves:
            res = retarget(markers, basis, replace(settings, strategy=strategy), inputs=inputs)
            W = np.nan_to_num(res.weights)
            at_top = W >= basis.upper[None] - 1e-3
            gaze = [k for k, n in enumerate(res.shape_names) if n.startswith(GAZE_PREFIX)]
            pinned = sorted(((float(at_top[:, k].mean()), n) for k, n in enumerate(res.shape_names)), reverse=True)[:3]
            check = res.info.get("plausibility", {})
            rows.append({"capture": capture.name, "strategy": label, "frames": int(W.shape[0]),
                         "markers": len(res.marker_names), "at_upper": float(at_top.mean()),
                         "pinned": [(n, round(s, 3)) for s, n in pinned if s > 0],
                         "gaze_max": float(W[:, gaze].max()) if gaze else 0.0,
                         "plausible": bool(check.get("plausible", False)),
                         "residual_to_noise": check.get("residual_to_noise"),
                         "tier": res.info.get("actor_model", {}).get("tier", "")})
    return rows


def markdown(rows):
    lines = ["| capture | strategy | frames | markers | weights at 1.0 | most pinned (share of frames) | largest gaze "
             "weight | residual / noise | plausible |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        pinned = ", ".join(f"{n} {100 * s:.0f}%" for n, s in r["pinned"]) or "none"
        ratio = "-" if r["residual_to_noise"] is None else f"{r['residual_to_noise']:.1f}"
        lines.append(f"| {r['capture']} | {r['strategy']} | {r['frames']} | {r['markers']} | "
                     f"{100 * r['at_upper']:.1f}% | {pinned} | {r['gaze_max']:.2f} | {ratio} | "
                     f"{'yes' if r['plausible'] else 'no'} |")
    return "\n".join(lines)
