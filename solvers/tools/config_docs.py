"""``python -m facecap config-docs [--out docs/config.md]``: the take-config reference, generated from
the option table (``solvers.options``) so it cannot drift from what the code accepts."""

import argparse
import sys
from pathlib import Path

from ..io.files import write_text_atomic
from ..options import OPTIONS, SECTIONS

INTRO = """# Take config reference

A take config is a TOML file describing one retarget: `python -m facecap retarget --config take.toml`.
Paths are relative to the config's folder. Every key is checked when the config is loaded: an unknown
key, a value of the wrong kind or out of range is one line naming the file and `[section.key]`, and
nothing runs. This page is generated from `solvers/options.py` (`python -m facecap config-docs`); the
*Sidebar* column names the control that sets the same option in Blender (`facecap.<prop>` is a
setting of the FaceCap sidebar, `op:` an option of an operator's dialog).
"""

SECTION_NOTES = {
    "target": "The character.",
    "source": "The take: markers, solved weights (`parallel`) or footage (a video take).",
    "clean": "Optional cleaning of the markers before the solve; every step is off unless named.",
    "binding": "How markers find their points on the character.",
    "stabilise": "Removing head motion.",
    "neutral": "The actor's neutral (T-pose) the take is measured against.",
    "align": "The actor-to-character alignment (geometric).",
    "solve": "The strategy and its priors; `bounds`, `locks` and `regions` take shape-name glob patterns.",
    "output": "What a headless run writes; a run never writes over one of its inputs.",
    "calibration": "The actor's calibration session (`calibrated`, `refine`).",
    "mapping": "Source channels to character shapes (`calibrated`, `refine`, `parallel`).",
    "examples": "Frames posed on the character (`linear`, `rbf`, `pca`).",
    "pca": "The `pca` strategy.",
    "refine": "The `refine` strategy (Choe & Ko).",
    "tracking": "Video takes: dense optical flow over the face.",
    "flow": "Video takes: flow-PCA features.",
    "tuning": "The animator feedback loop (`python -m facecap tune`).",
    "controls": "Per-shape controls applied to the solved weights, keyed by shape name or glob.",
}


def _kind(option):
    kinds = option.kind if isinstance(option.kind, tuple) else (option.kind,)
    words = {"floats": f"list of {option.length} numbers", "choice": "one of " + ", ".join(
        f"`{c}`" for c in option.choices), "names": "list of names", "frames": "[first, last]", "path": "file"}
    return " or ".join(words.get(k, k) for k in kinds)


def _default(option):
    d = option.default
    if d is None:
        return ""
    if isinstance(d, bool):
        return "`true`" if d else "`false`"
    if isinstance(d, tuple):
        return "`[" + ", ".join(f"{v:g}" for v in d) + "]`"
    return f"`{d:g}`" if isinstance(d, float) else f"`{d}`"


def render():
    """The reference as Markdown."""
    out = [INTRO]
    for section in SECTIONS:
        out += [f"## [{section}]", "", SECTION_NOTES.get(section, ""), "",
                "| key | kind | default | allowed | sidebar | description |", "|---|---|---|---|---|---|"]
        for o in (o for o in OPTIONS if o.section == section):
            where = f"`{o.ui}`" if o.ui else f"headless: {o.headless}"
            doc = o.doc.replace("|", "\\|") + (" **Required.**" if o.required else "")
            out.append(f"| `{o.key}` | {_kind(o)} | {_default(o)} | {o.range_text()} | {where} | {doc} |")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


DESCRIPTION = ("Write the config reference (docs/config.md) from the option tables of the take, track and batch "
               "configs, so it cannot drift from what the code accepts.")


def main(argv=None, *, parents=()):
    parser = argparse.ArgumentParser(prog="facecap config-docs", description=DESCRIPTION, parents=list(parents))
    parser.add_argument("--out", help="write here (default: print)")
    args = parser.parse_args(argv)
    text = render()
    if args.out:
        write_text_atomic(Path(args.out), text)
        print(f"wrote {args.out} ({len(OPTIONS)} options)")
    else:
        sys.stdout.write(text)
    return 0
