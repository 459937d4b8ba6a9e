"""Every command and option that writes a file goes through the one output policy (``solvers/io/outputs.py``;
reliability-3 #01: ``template convert --out`` did not, and replaced its own source).

``test_every_option_of_every_command_is_known_to_write_or_not`` lists the options of every command, as its own
parser has them (the command line's, and the tools it forwards to), and fails on one this file does not classify:
a new option has to say whether it writes. ``test_every_writer_refuses_a_file_it_did_not_write`` then runs each
writing option with its output naming a file facecap did not write: refused in one line naming the file and
``--overwrite``, before any work, every file there unchanged.
"""

import argparse
import contextlib
import io
import sys
import time
import tomllib
from pathlib import Path

import pytest

from facecap.facecap_addon import cli
from facecap.solvers.extension_builds import BUILDS

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "sample_blends"

#: (command, option) -> the output it names (each run by ``CASES`` below)
WRITES = {
    ("retarget", "--config"): "[output] blend, weights, report, html, gltf, fbx, actor_basis, profile",
    ("retarget", "--html"): "the review page",
    ("tune", "--config"): "[output] files and [tuning] out (the library versions)",
    ("batch", "takes"): "every take's [output] files",
    ("batch", "--summary"): "the summary JSON, its CSV and index page",
    ("demo", "--out"): "the demo's .blend, weights, report and review page in that folder",
    ("convert", "out"): "the converted file",
    ("track", "--config"): "[output] markers, confidence, report",
    ("config-docs", "--out"): "the config reference",
    ("config-docs", "--commands"): "the command reference",
    ("bench --realism", "--json"): "the benchmark's rows",
    ("docs-images", "--out"): "the three pictures in that folder",
    ("rig-bench", "--docs"): "rigify_face.png in that folder",
    ("template fetch", "--out"): "the human template (checked before the download)",
    ("template convert", "--out"): "the human template",
    ("build-extension", "--out"): "the extension zips in that folder",
    ("build-extension", "--release"): "SHA256SUMS and RELEASE_NOTES.md beside the zips (checked before the build)",
}
#: Options that write nothing a user names (with why, where it is not plain)
NOT_WRITING = {
    "*": ("--quiet", "--verbose", "--overwrite"),
    "retarget": ("--replace", "--truth"),
    "batch": ("--jobs", "--scheduler", "--resume", "--replace"),
    "inspect": ("--units", "--unit-scale", "--fps", "--up-axis", "--weights", "--columns", "file", "--json"),  # stdout
    "convert": ("--units", "--unit-scale", "--fps", "--up-axis", "--weights", "--columns", "file", "--out-units"),
    "compare": ("--frames", "--examples", "--seed", "--strategy"),
    # bench writes only in temporary folders of its own
    "bench": ("--quick", "--accuracy", "--realism", "--landmarks", "--draws", "--clips", "--size", "--frames",
              "--batch", "--batch-takes", "--batch-jobs", "--repeat", "--clean", "--memory"),
    "bench --realism": ("--shared", "--draws", "--frames", "--targets", "--layouts", "--methods", "--exact-actor",
                        "--real", "--first-seed", "--actors", "--docs", "--from-json"),
    "docs-images": ("--size", "--engine", "--solved", "--pictures"),
    "rig-bench": ("--capture", "--frames", "--sample-frames", "--repeat", "--reference", "--long-only"),
    "template fetch": ("--url", "--keep"),  # the download goes to facecap's cache (its temporaries cleaned)
    "template convert": ("source",),
    "template info": ("path",),
    # fetch puts the Face Landmarker bundle into facecap's cache (staged, hash-checked, renamed): nothing a user names
    "landmark-models": ("action", "--url"),
    # --cache: facecap's wheel cache, where verified wheels are added under their own names; --docs edits only the
    # generated block of a page that has one (refused without it), as bench --realism --docs
    "build-extension": ("--build", "--platform", "--cache", "--docs"),
}
#: Commands without options of their own (landmark-models fills facecap's cache)
COMMANDS = [[c] for c in cli.COMMANDS if c != "template"] + [["template", s] for s in ("fetch", "convert", "info")] \
    + [["bench", "--realism"]]


def options(argv):
    """The options of the parser that answers ``argv --help`` (the command's own, or the forwarded tool's)."""
    seen = []
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(argparse.ArgumentParser, "print_help", lambda self, file=None: seen.append(self))
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()), \
                contextlib.suppress(SystemExit):
            cli.main([*argv, "--help"])
    assert seen, argv
    return [a.option_strings[-1] if a.option_strings else a.dest for a in seen[-1]._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction, argparse._VersionAction))]


def test_every_option_of_every_command_is_known_to_write_or_not():
    unknown, stale = [], set(WRITES)
    for argv in COMMANDS:
        command = " ".join(argv)
        for option in options(argv):
            stale.discard((command, option))
            if (command, option) not in WRITES and option not in NOT_WRITING["*"] + NOT_WRITING.get(command, ()):
                unknown.append(f"{command} {option}")
    assert not unknown, f"say whether these write (WRITES / NOT_WRITING): {unknown}"
    assert not stale, f"WRITES names options no command has: {sorted(stale)}"
    assert set(WRITES) == {(c, o) for c, o, *_ in CASES}


NOTES = b"a user's notes: not facecap's\n"


def take_config(folder, output):
    lines = (SAMPLES / "sample_take.csv").read_text().splitlines()
    (folder / "take.csv").write_text("\n".join(lines[:31]) + "\n")
    (folder / "take.toml").write_text(f'[target]\nblend = "{SAMPLES / "character.blend"}"\nobject = "Face"\n'
                                      '[source]\nmarkers = "take.csv"\nunits = "mm"\n[stabilise]\nmarkers = "auto"\n'
                                      f'[neutral]\nframes = [1, 10]\n{output}\n')
    return "take.toml"


def _corrections(folder):
    """An animator's corrections file for ``tune`` (inputs are checked before outputs: it must exist)."""
    (folder / "c.csv").write_text("frame,jawOpen\n5,0.5\n")
    return []


def track_config(folder):
    import cv2
    import numpy as np

    (folder / "seq").mkdir()
    base = cv2.GaussianBlur((np.random.default_rng(0).random((48, 64)) * 255).astype(np.uint8), (5, 5), 1.5)
    for i in range(3):
        cv2.imwrite(str(folder / "seq" / f"f{i + 1:03d}.png"), np.roll(base, i, axis=1))
    (folder / "p.csv").write_text("name,x,y\na,20,20\nb,40,24\nc,30,30\n")
    (folder / "track.toml").write_text('[source]\nvideo = "seq/f%03d.png"\nfps = 30\n[tracking]\npoints = "p.csv"\n'
                                       '[output]\nmarkers = "notes.txt"\n')
    return "track.toml"


VERSION = tomllib.loads((ROOT / "blender_manifest.toml").read_text())["version"]
ZIP = BUILDS[0].zip_name(VERSION, BUILDS[0].platforms[0])


def zips(folder):
    (folder / "dist").mkdir()
    return ["--build", BUILDS[0].name, "--platform", BUILDS[0].platforms[0], "--out", "dist"]


#: (command, option, argv after the command (``{f}``: the scratch folder), the file that must stay as it was)
CASES = [
    ("retarget", "--config", lambda f: ["--config", take_config(f, '[output]\nreport = "notes.txt"')], "notes.txt"),
    ("retarget", "--html", lambda f: ["--config", take_config(f, '[output]\nweights = "o/w.csv"'), "--html",
                                      "notes.txt"], "notes.txt"),
    ("tune", "--config", lambda f: ["--config", take_config(f, '[tuning]\ncorrections = "c.csv"\n[output]\n'
                                                               'weights = "notes.txt"'), *_corrections(f)], "notes.txt"),
    ("batch", "takes", lambda f: [take_config(f, '[output]\nweights = "notes.txt"'), "--summary", "o/s.json"],
     "notes.txt"),
    ("batch", "--summary", lambda f: [take_config(f, '[output]\nweights = "o/w.csv"'), "--summary", "notes.txt"],
     "notes.txt"),
    ("demo", "--out", lambda f: ["--out", "."], "sample_take_report.json"),
    ("convert", "out", lambda f: [str(SAMPLES / "sample_take.csv"), "notes.csv"], "notes.csv"),
    ("track", "--config", lambda f: ["--config", track_config(f)], "notes.txt"),
    ("config-docs", "--out", lambda f: ["--out", "notes.txt"], "notes.txt"),
    ("config-docs", "--commands", lambda f: ["--commands", "notes.txt"], "notes.txt"),
    ("bench --realism", "--json", lambda f: ["--json", "notes.txt", "--draws", "1"], "notes.txt"),
    ("docs-images", "--out", lambda f: ["--out", ".", "--solved", str(SAMPLES / "sample_take_weights.csv")],
     "contact_sheet.png"),
    ("rig-bench", "--docs", lambda f: ["--docs", ".", "--long-only", "--frames", "60"], "rigify_face.png"),
    ("template fetch", "--out", lambda f: ["--url", "http://127.0.0.1:9/ict.zip", "--out", "notes.txt"], "notes.txt"),
    ("template convert", "--out", lambda f: [str(SAMPLES / "character_basis.npz"), "--out", "notes.txt"],
     "notes.txt"),
    ("build-extension", "--out", zips, f"dist/{ZIP}"),
    ("build-extension", "--release", lambda f: [*zips(f), "--release", f"v{VERSION}"], "dist/RELEASE_NOTES.md"),
]


@pytest.mark.parametrize("command, option, args, kept", CASES, ids=[f"{c} {o}" for c, o, *_ in CASES])
def test_every_writer_refuses_a_file_it_did_not_write(tmp_path, monkeypatch, command, option, args, kept):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("FACECAP_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("FACECAP_CACHE", str(tmp_path / "cache"))
    argv = [*command.split(), *args(tmp_path)]
    (tmp_path / kept).write_bytes(NOTES)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    err = io.StringIO()
    start = time.monotonic()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(argv)
    lines = [line for line in err.getvalue().splitlines() if line.startswith("facecap") and "exists and is not" in line]
    assert rc == 1 and len(lines) == 1, (rc, err.getvalue()[-2000:])
    assert "--overwrite" in lines[0], lines[0]
    assert Path(kept).name in lines[0], lines[0]
    assert time.monotonic() - start < 20, "refused only after work"
    assert {p: p.read_bytes() for p in before} == before  # (a batch still writes its own summary of the failure)
    assert "Traceback" not in err.getvalue() and "internal error" not in err.getvalue()
    assert sys.exc_info() == (None, None, None)
