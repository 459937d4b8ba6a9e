"""After every marker solve: is the result plausible animation, or a good fit hiding wrong weights?

Three symptoms, each measured, reported, and summed up in at most one warning line that says what to do (and,
apart from them, whether the expressions solved against are this actor's: ``prior_advice``):

* the fit residual against the markers' own noise (estimated from the take: the second difference of
  white noise has 6 times its variance, and a face moves little from one frame to the next at 60 fps);
* weights pinned at their upper bound (shapes that saturate to explain motion they do not make);
* opposing shapes active together (``jawLeft`` with ``jawRight``: a pair cancelling itself).
"""

import numpy as np

from ..capture.noise import marker_noise  # noqa: F401  (re-exported: the pipeline's noise estimate)
from ..strategies.semantic import opposing_pairs

#: A residual this many times the noise is a fit that does not describe the face.
RESIDUAL_RATIO = 3.0
#: A residual (RMS marker distance) above this many times the capture's noise (per coordinate) says the expressions
#: solved against are not the actor's. Realism benchmark (draws 100-101, 600 frames, dense, onto the sample): the
#: actor's own poses or ROM leave 1.8-2.1x, the human template 2.6x on its own family's actors but 4.8-5.0x on the
#: Face Cap head, 12 poses + template 3.2-4.1x there, the character's shapes 5.3-9.1x.
PRIOR_RATIO = 3.0
#: What the user is told to record, by what the solve knew.
APPROXIMATE = {"template": "the human template's expressions", "character": "the character's expressions",
               "poses": "the expressions completed from the template or the character"}
#: More than this share of the weights at the upper bound is pinning.
PINNED_SHARE = 0.02
#: A shape at its upper bound in more than this share of frames is named.
PINNED_SHAPE = 0.1
#: Both shapes of an opposing pair above this in more than ``OPPOSED_SHARE`` of frames.
OPPOSED_LEVEL, OPPOSED_SHARE = 0.15, 0.05


def check(weights, shape_names, upper, residual_rms, noise, *, held=()):
    """(report dict, warning line or None) for solved ``weights`` (F, K) with upper bounds ``upper`` (K,),
    the per-frame fit residual ``residual_rms`` (F,) (metres, RMS of the 3D marker distance) and the
    markers' ``noise`` (metres per coordinate); ``held`` names shapes held by locks (not judged)."""
    W = np.asarray(weights, dtype=np.float64)
    rows = np.isfinite(W).all(axis=1)
    free = np.array([n not in set(held) for n in shape_names])
    report, problems = {}, []
    res = np.asarray(residual_rms, dtype=np.float64) if residual_rms is not None else np.full(len(W), np.nan)
    if np.isfinite(res).any() and np.isfinite(noise) and noise > 0:
        ratio = float(np.nanmedian(res) / (noise * np.sqrt(3.0)))
        report.update(residual_mm=round(float(np.nanmedian(res)) * 1e3, 3), noise_mm=round(noise * 1e3, 3),
                      residual_to_noise=round(ratio, 2))
        if ratio > RESIDUAL_RATIO:
            problems.append(f"the fit leaves {np.nanmedian(res) * 1e3:.2f} mm at the markers, {ratio:.1f}x their "
                            f"noise ({noise * 1e3:.2f} mm): the shapes solved against do not describe this face")
    if rows.any() and free.any():
        top = W[rows][:, free] >= np.asarray(upper)[free] - 1e-3
        share = float(top.mean())
        per_shape = top.mean(axis=0)
        names = [n for n, f in zip(shape_names, free) if f]
        pinned = [(names[k], float(per_shape[k])) for k in np.argsort(-per_shape) if per_shape[k] > PINNED_SHAPE]
        report.update(at_upper=round(share, 4), pinned_shapes={n: round(s, 3) for n, s in pinned})
        if share > PINNED_SHARE or pinned:
            listed = ", ".join(f"{n} {100 * s:.0f}%" for n, s in pinned[:5]) or "spread over many shapes"
            problems.append(f"{100 * share:.1f}% of the weights sit at their upper bound ({listed} of frames)")
    opposed = []
    for a, b in opposing_pairs(shape_names):
        if not (free[a] and free[b]):
            continue
        both = float(np.mean((W[rows, a] > OPPOSED_LEVEL) & (W[rows, b] > OPPOSED_LEVEL))) if rows.any() else 0.0
        if both > OPPOSED_SHARE:
            opposed.append((shape_names[a], shape_names[b], both))
    report["opposed"] = {f"{a}+{b}": round(s, 3) for a, b, s in opposed}
    if opposed:
        problems.append("opposing shapes are active together (" + ", ".join(
            f"{a} and {b} in {100 * s:.0f}% of frames" for a, b, s in opposed[:3]) + ")")
    report["plausible"] = not problems
    if not problems:
        return report, None
    return report, _problem_line(problems)


def prior_advice(report, tier):
    """A line telling the user that the expressions solved against are not this actor's and what to record, when
    the ``report`` of ``check`` shows a residual above ``PRIOR_RATIO`` times the noise; None otherwise. ``tier``:
    the semantic solve's (``ActorModel.tier``). Also sets ``report["prior_mismatch"]`` and ``["prior_advice"]``."""
    ratio = report.get("residual_to_noise")
    if ratio is None or tier is None:
        return None
    times = ratio * np.sqrt(3.0)  # the RMS marker distance over the noise per coordinate
    report["prior_mismatch"] = bool(times > PRIOR_RATIO)
    if not report["prior_mismatch"]:
        return None
    left = (f"{report['residual_mm']:.2f} mm at the markers, {times:.1f}x the capture's noise "
            f"({report['noise_mm']:.2f} mm)")
    report["prior_advice"] = _advice(tier, left)
    return report["prior_advice"]


def _advice(tier, left):
    if tier in APPROXIMATE:
        return (f"the expressions solved against ({APPROXIMATE[tier]}) leave {left}: they are not this actor's, and "
                "the weights follow them. Record this performer's range of motion once (the facecap-24 sheet, "
                "docs/rom.md) and give it as [calibration] sequence, or give their performer profile ([actor] profile)")
    return (f"the actor's {tier} leaves {left}: it does not describe this take (another performer, markers placed "
            "elsewhere, a different day's face?). Record the range of motion again (docs/rom.md)")


def _problem_line(problems):
    return ("the solve is not plausible animation: " + "; ".join(problems) + ". Give the solve what it lacks of the "
            "actor's face (a range-of-motion session, [calibration] sequence: docs/rom.md; [actor] profile or "
            "template), check the binding, or lock the named shapes ([solve] locks)")
