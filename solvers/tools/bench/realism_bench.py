"""``python -m facecap bench --realism``: the cross-character benchmark.

Seeded draws of a perturbed human actor (of the ICT face model, or the Face Cap head: ``families``) performing
real iPhone recordings (Live Link Face) with head motion, noise and gaps, captured with a studio's layouts,
solved onto the sample character, another person of the ICT face model and a cartoon, by every method of
``methods.METHODS``;
per face region: weights RMSE, mean per-shape correlation, the share of weights at the upper bound and
the jitter, each beside the truth's. Medians over the draws, and the worst draw.
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ...character.face_model import load_ict
from ...io.files import write_json_atomic
from ...io.outputs import Output, check_outputs
from ..synthetic.realism.actors import Perturbation
from ..synthetic.realism.families import FAMILIES, load_family
from ..synthetic.realism.layouts import LAYOUTS
from ..synthetic.realism.methods import METHODS, base_settings, bound_character, holds_found, load_template, run_method
from ..synthetic.realism.metrics import REGIONS, compare
from ..synthetic.realism.real_captures import markdown as real_markdown
from ..synthetic.realism.real_captures import run_real
from ..synthetic.realism.scenario import make_draw
from ..synthetic.realism.takes import load_performances
from ..synthetic.realism.targets import TARGETS, make_target
from .realism_docs import PLAN, write_docs

#: A benchmark row's key figures, in table order.
FIGURES = ("rmse", "r", "at_upper", "jitter")


def run(shared, *, draws=5, frames=1200, actors=("ict",), targets=("sample",), layouts=("dense",),
        methods=tuple(METHODS), perturbation=Perturbation(), first_seed=0, progress=None):
    """Every (actor family, draw, layout, target, method): a list of row dicts with the metrics per region."""
    shared = Path(shared)
    model = load_ict(shared / "data" / "ict-facekit")
    template = load_template(shared / "data" / "ict-facekit")  # the ICT model, as a user's template
    meshes = {t: make_target(t, model) for t in targets}
    rows = []
    for actor in actors:
        family = load_family(actor, shared, model)
        performances = load_performances(shared / "data" / "realdata" / "llf", family.model.shape_names)
        for seed in range(first_seed, first_seed + draws):
            rows += _draw_rows(actor, family, performances, seed, frames, layouts, targets, methods, meshes,
                               template, perturbation, progress)
    return rows


def _draw_rows(actor, family, performances, seed, frames, layouts, targets, methods, meshes, template, perturbation,
               progress):
    """The rows of one draw of ``family`` (every layout, target and method)."""
    rows = []
    for layout in layouts:
        draw = make_draw(family, performances, seed, layout=layout, frames=frames, perturbation=perturbation)
        for target in targets:
            try:  # bound once for every method (a binding by position takes seconds)
                character, bind_error = bound_character(meshes[target], draw, base_settings(draw)), ""
            except Exception as exc:  # noqa: BLE001  (a binding that fails fails every method's row)
                character, bind_error = None, f"binding: {type(exc).__name__}: {exc}"
            for method in methods:
                t0 = time.perf_counter()
                try:
                    if character is None:
                        raise RuntimeError(bind_error)
                    weights, names, upper, result = run_method(method, draw, meshes[target], template,
                                                               character=character)
                    metrics = compare(weights, names, draw.truth, draw.shape_names, upper=upper,
                                      frames=draw.performance_frames)
                    metrics["holds"] = holds_found(method, draw, result)
                    error = ""
                except Exception as exc:  # noqa: BLE001  (a method that fails is a row of the table)
                    metrics, error = None, f"{type(exc).__name__}: {exc}"
                row = {"actor": actor, "seed": seed, "layout": layout, "target": target, "method": method,
                       "metrics": metrics, "seconds": time.perf_counter() - t0, "error": error,
                       "performance": draw.description}
                rows.append(row)
                if progress:
                    progress(row)
    return rows


def _finite(reduce, values):
    """reduce over the finite values; NaN when there are none (the zero method moves no shape: no r)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(reduce(values)) if values.size else float("nan")


def summarise(rows):
    """{(actor, layout, target, method): {"median": {region: {figure: value}}, "worst": ..., "n": draws,
    "errors": n}}."""
    groups = {}
    for row in rows:
        groups.setdefault((row["actor"], row["layout"], row["target"], row["method"]), []).append(row)
    out = {}
    for key, group in groups.items():
        ok = [r["metrics"] for r in group if r["metrics"] is not None]
        summary = {"n": len(group), "errors": len(group) - len(ok), "median": {}, "worst": {}}
        for region in ("all",) + tuple(r for r, _ in REGIONS):
            have = [m[region] for m in ok if region in m]
            if not have:
                continue
            summary["median"][region] = {f: _finite(np.nanmedian, [m[f] for m in have]) for f in have[0]}
            summary["worst"][region] = {"rmse": _finite(np.nanmax, [m["rmse"] for m in have]),
                                        "r": _finite(np.nanmin, [m["r"] for m in have])}
        holds = [m["holds"] for m in ok if m.get("holds")]
        if holds:  # a ROM method: its holds found within 5 frames of their middles, over every draw
            summary["holds"] = [sum(h[0] for h in holds), sum(h[1] for h in holds)]
        out[key] = summary
    return out


def markdown(summary):
    """The summary as Markdown tables: overall per actor family, layout and target, then per region."""
    lines = []
    order = {name: i for i, name in enumerate(FAMILIES)}
    keys = sorted(summary, key=lambda k: (order.get(k[0], 99), k[1], k[2],
                                          list(METHODS).index(k[3]) if k[3] in METHODS else 99))
    lines.append("| actor | layout | target | method | draws | RMSE (median) | RMSE (worst) | mean per-shape r (shapes "
                 "moved) | at upper | jitter (truth) |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|")
    for key in keys:
        s = summary[key]
        head = " | ".join(key)
        if "all" not in s["median"]:
            lines.append(f"| {head} | {s['n']} | failed | | | | |")
            continue
        m, w = s["median"]["all"], s["worst"]["all"]
        lines.append(f"| {head} | {s['n'] - s['errors']}/{s['n']} | {m['rmse']:.3f} | "
                     f"{w['rmse']:.3f} | {m['r']:.2f} ({m['r_moved']:.2f}) | {100 * m['at_upper']:.1f}% | "
                     f"{m['jitter']:.4f} "
                     f"({m['truth_jitter']:.4f}) |")
    found = [(k, summary[k]["holds"]) for k in keys if "holds" in summary[k]]
    if found:
        lines += ["", "ROM holds found within 5 frames of their true middles (all draws):", "",
                  "| actor | layout | target | method | holds |", "|---|---|---|---|---|"]
        lines += [f"| {' | '.join(k)} | {w}/{n} ({100 * w / max(n, 1):.1f} %) |" for k, (w, n) in found]
    regions = [r for r, _ in REGIONS]
    lines += ["", "Weights RMSE per region (median over draws; mean per-shape r in brackets):", "",
              "| actor | layout | target | method | " + " | ".join(regions) + " |",
              "|---|---|---|---|" + "---|" * len(regions)]
    for key in keys:
        med = summary[key]["median"]
        cells = [f"{med[r]['rmse']:.3f} ({med[r]['r']:.2f})" if r in med else "" for r in regions]
        lines.append(f"| {' | '.join(key)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog="python -m facecap bench --realism", description=__doc__.splitlines()[0])
    parser.add_argument("--shared", default=str(Path(__file__).resolve().parents[4] / "shared"),
                        help="the shared data folder holding data/ict-facekit and data/realdata/llf "
                             "(default: shared/ beside the checkout)")
    parser.add_argument("--draws", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0, help="the first draw's seed (default 0: the draws the "
                        "docs report; tune on others, e.g. 100)")
    parser.add_argument("--frames", type=int, default=1200, help="frames per take at 60 fps (default 1200)")
    parser.add_argument("--actors", default=",".join(FAMILIES), help="comma-separated actor families of "
                        f"{', '.join(FAMILIES)} (the ICT face model; the Face Cap head, not of the template's family)")
    parser.add_argument("--targets", default="sample,ict,toon", help=f"comma-separated of {', '.join(TARGETS)}")
    parser.add_argument("--layouts", default="dense", help=f"comma-separated of {', '.join(LAYOUTS)}")
    parser.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated of {', '.join(METHODS)}")
    parser.add_argument("--exact-actor", action="store_true", help="actors with the model's own expressions "
                        "(a best case for the template)")
    parser.add_argument("--real", action="store_true", help="also the real captures (Facial-Sing, blenderFace) onto "
                        "the sample character, judged by how plausible their weights are (no truth)")
    parser.add_argument("--json", help="write every row and the summary here")
    parser.add_argument("--docs", metavar="FOLDER", help="run the docs' plan (every tier, both actor families, every "
                        "character and layout it reports; --targets, --layouts and --methods are ignored) and write "
                        "its tables into FOLDER's accuracy.md and strategies.md (docs: between their generated markers)")
    parser.add_argument("--from-json", metavar="FILE", help="the rows of an earlier run (its --json) instead of "
                        "running again: print and, with --docs, write its tables")
    parser.add_argument("--overwrite", action="store_true",
                        help="let --json replace a file facecap did not write")
    args = parser.parse_args(argv)
    check_outputs([Output("--json", args.json, "bench_json")], overwrite=args.overwrite)  # before hours of work
    perturbation = Perturbation.none() if args.exact_actor else Perturbation()

    def progress(row):
        m = row["metrics"]
        figures = "failed: " + row["error"] if m is None else \
            f"RMSE {m['all']['rmse']:.3f} r {m['all']['r']:.2f} at upper {100 * m['all']['at_upper']:.1f}%"
        print(f"{row['actor']:>7} draw {row['seed']} {row['layout']:>11} {row['target']:>6} {row['method']:>17}: "
              f"{figures} "
              f"({row['seconds']:.1f} s)", flush=True)

    plan = PLAN if args.docs else ((tuple(args.layouts.split(",")), tuple(args.targets.split(",")),
                                    tuple(args.methods.split(","))),)
    rows = json.loads(Path(args.from_json).read_text())["rows"] if args.from_json else []
    for layouts, targets, methods in () if args.from_json else plan:
        rows += run(args.shared, draws=args.draws, frames=args.frames, actors=tuple(args.actors.split(",")),
                    targets=targets, layouts=layouts, methods=methods, perturbation=perturbation,
                    first_seed=args.first_seed, progress=progress)
    summary = summarise(rows)
    print()
    print(markdown(summary))
    if args.docs:
        for page in write_docs(args.docs, summary, draws=args.draws, frames=args.frames):
            print(f"wrote the realism tables into {page}")
    real = run_real(args.shared, template=load_template(Path(args.shared) / "data" / "ict-facekit")) \
        if args.real else []
    if real:
        print()
        print(real_markdown(real))
    if args.json:
        write_json_atomic(Path(args.json), {"rows": rows, "summary": {" / ".join(k): v for k, v in summary.items()},
                                            "real": real})
    return 0
