"""``python -m facecap template``: install the optional human template (docs/strategies.md, "semantic").

    python -m facecap template convert PATH [--out FILE]   # the ICT-FaceKit download -> facecap's template
    python -m facecap template info [FILE]                  # where the template is, and what it holds

The model is not shipped with facecap (ICT-FaceKit, MIT, USC Institute for Creative Technologies); the
conversion is hash-checked, so the accuracy figures in docs/accuracy.md hold for what it installs.
"""

import argparse
import sys
from pathlib import Path

from ..character.ict_release import RELEASE_COMMIT
from ..character.template import HumanTemplate, convert, template_path


def _progress(done, total):
    print(f"\rfacecap: reading ICT-FaceKit {done}/{total} OBJ files", end="\n" if done == total else "",
          file=sys.stderr, flush=True)


def main(argv=None, *, parents=()):
    parser = argparse.ArgumentParser(
        prog="facecap template", parents=list(parents),
        description="Install the optional human template from a copy of ICT-FaceKit (hash-checked), or say where "
                    "the installed one is; the semantic strategy fits it to the actor when nothing else is known.")
    sub = parser.add_subparsers(dest="action", required=True)
    p = sub.add_parser("convert", help="convert a copy of ICT-FaceKit into facecap's template: the zip as downloaded "
                                       f"from GitHub (release {RELEASE_COMMIT[:7]}, docs/strategies.md), the "
                                       "repository folder or its FaceXModel folder")
    p.add_argument("source", help="the ICT-FaceKit download: its zip, the repository folder or FaceXModel/ (or a "
                                  "reduced ict_face.npz)")
    p.add_argument("--out", default=None, help=f"where to write it (default: {template_path()}, which [actor] "
                                                "template = \"auto\" finds)")
    p = sub.add_parser("info", help="where the template is and what it holds")
    p.add_argument("path", nargs="?", default=None, help=f"a template file (default: {template_path()})")
    args = parser.parse_args(argv)
    if args.action == "convert":
        out = convert(Path(args.source).expanduser(), None if args.out is None else Path(args.out).expanduser(),
                      progress=_progress if sys.stderr.isatty() else None)
        print(f"facecap: human template written to {out}", file=sys.stdout)
        return 0
    path = Path(args.path).expanduser() if args.path else template_path()
    if not path.exists():
        print(f"facecap: no human template at {path}; install one with `python -m facecap template convert`")
        return 1
    t = HumanTemplate.load(path)
    m = t.model
    print(f"{path}: {len(m.shape_names)} shapes, {m.identity.shape[0]} identity modes, {m.n_vertices} vertices, "
          f"data digest {m.digest[:16]}...")
    return 0
