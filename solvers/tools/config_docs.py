"""``python -m facecap config-docs [--out docs/config.md] [--commands docs/commands.md]``: the config reference
(take configs from the option table ``solvers.options``, track configs from ``video.cli.TRACK_OPTIONS``, batch
files from ``config.batch``) and the command reference (every command's ``--help``), generated from the code
so they cannot drift from what it accepts."""

import argparse
import sys
from pathlib import Path

from ..errors import FacecapError
from ..io.files import write_text_atomic
from ..io.outputs import Output, check_outputs
from ..options import OPTIONS, SECTIONS
from ..video.cli import TRACK_OPTIONS

INTRO = """# Config reference

Three kinds of TOML file: a [take config](#take-config) describes one retarget (`facecap retarget --config
take.toml`), a [track config](#track-config) one tracking of footage (`facecap track --config track.toml`), a
[batch file](#batch-file) a shoot of takes (`facecap batch shoot.toml`). Paths are relative to the file's
folder. Every key is checked when the file is loaded: an unknown key, a value of the wrong kind or out of
range names the file and `[section.key]`, and nothing runs. This page is generated from the code
(`python -m facecap config-docs --out docs/config.md`).

## Take config

The *Sidebar* column names the control that sets the same option in Blender (`facecap.<prop>` is a setting of
the FaceCap sidebar, `op:` an option of an operator's dialog).
"""
TRACK_INTRO = """## Track config

`facecap track --config track.toml` tracks footage into 2D markers ([video.md](video.md)). Its `[tracking]`
is not a take config's (a video take's `[tracking]` describes the dense flow of its face region, above).
"""
BATCH_INTRO = """## Batch file

`facecap batch shoot.toml` runs the takes a batch file lists ([batch.md](batch.md)). Its `[defaults]` holds
take-config sections (`[defaults.target]`, `[defaults.output]`, ...) merged into every take; a take's own
keys win, key by key. In `[defaults.output]` values, `{take}` is the take config's file name without `.toml`.
"""
#: The keys of a batch file's [batch] table (``config.batch.BATCH_KEYS``) and what they mean.
BATCH_DOCS = {
    "takes": ("list of files, folders and globs", "The take configs, relative to the batch file: a folder means "
              "every `.toml` in it, a glob every match. **Required.**"),
}

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


def _cell(text):
    return str(text).replace("|", "\\|")


def render():
    """The reference as Markdown: take configs, track configs, batch files."""
    out = [INTRO]
    for section in SECTIONS:
        out += [f"### [{section}]", "", SECTION_NOTES.get(section, ""), "",
                "| key | kind | default | allowed | sidebar | description |", "|---|---|---|---|---|---|"]
        for o in (o for o in OPTIONS if o.section == section):
            where = f"`{o.ui}`" if o.ui else f"headless: {o.headless}"
            doc = _cell(o.doc) + (" **Required.**" if o.required else "")
            out.append(f"| `{o.key}` | {_kind(o)} | {_default(o)} | {o.range_text()} | {where} | {doc} |")
        out.append("")
    out.append(TRACK_INTRO)
    for section in dict.fromkeys(o.section for o in TRACK_OPTIONS):
        out += [f"### track [{section}]", "", "| key | kind | default | allowed | description |", "|---|---|---|---|---|"]
        out += [f"| `{o.key}` | {_kind(o)} | {_default(o)} | {o.range_text()} | "
                f"{_cell(o.doc + (' **Required.**' if o.required else ''))} |"
                for o in TRACK_OPTIONS if o.section == section]
        out.append("")
    out += [BATCH_INTRO, "### [batch]", "", "| key | kind | description |", "|---|---|---|"]
    out += [f"| `{key}` | {kind} | {_cell(doc)} |" for key, (kind, doc) in BATCH_DOCS.items()]
    out += ["", "### [defaults.&lt;section&gt;]", "",
            "Any key of the take config's sections above, checked the same way: "
            + ", ".join(f"`[defaults.{s}]`" for s in SECTIONS) + ".", ""]
    return "\n".join(out).rstrip() + "\n"


DESCRIPTION = ("Write the config reference (docs/config.md) from the option tables of the take, track and batch "
               "configs, so it cannot drift from what the code accepts.")


COMMANDS_INTRO = """# Command reference

Every command of `python -m facecap` (and of `blender -b -P <extension>/facecap_addon/cli.py -- ...`) with its
options, as its `--help` prints them. Generated from the code: `python -m facecap config-docs --commands
docs/commands.md`. How the commands fit together: [command-line.md](command-line.md).
"""


def render_commands(helps):
    """The command reference as Markdown from ``helps``: [(command, its --help text)], the top level first."""
    out = [COMMANDS_INTRO]
    for command, text in helps:
        title = f"`facecap {command}`" if command else "`facecap`"
        out += [f"## {title}", "", "```text", text.rstrip(), "```", ""]
    return "\n".join(out).rstrip() + "\n"


def main(argv=None, *, parents=(), commands=None):
    """``commands``: a callable returning [(command, --help text)] (the command line's), for ``--commands``."""
    parser = argparse.ArgumentParser(prog="facecap config-docs", description=DESCRIPTION, parents=list(parents))
    parser.add_argument("--out", help="write the config reference here (default: print it)")
    parser.add_argument("--commands", metavar="PATH", help="also write the command reference here (docs/commands.md)")
    parser.add_argument("--overwrite", action="store_true", help="let --out / --commands replace a file that is not "
                        "facecap's reference (default: refused)")
    args = parser.parse_args(argv)
    check_outputs([Output("--out", args.out, "config_docs"), Output("--commands", args.commands, "commands_docs")],
                  overwrite=args.overwrite)  # None paths are left out
    text = render()
    if args.out:
        write_text_atomic(Path(args.out), text)
        print(f"wrote {args.out} ({len(OPTIONS)} take-config options, track and batch keys)")
    else:
        sys.stdout.write(text)
    if args.commands:
        if commands is None:
            raise FacecapError("--commands needs the command line: run it as python -m facecap config-docs")
        helps = commands()
        write_text_atomic(Path(args.commands), render_commands(helps))
        print(f"wrote {args.commands} ({len(helps) - 1} commands)")
    return 0
