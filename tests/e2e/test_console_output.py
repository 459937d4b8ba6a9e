"""What a new user sees: the demo, then the real-capture example of the README (c3d.org's Facial-Sing onto the
sample character), print only facecap's own lines: no Blender line (``Read blend: ...``, ``Info: Saved copy
as ...``), no Python warning or traceback, one line per warning, no Python list in a message. ``--quiet``
keeps only the warnings; ``--verbose`` shows Blender's lines, marked as Blender's."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from shared_data import REALDATA, skip_without

ROOT = Path(__file__).resolve().parents[2]
FACIAL_SING = REALDATA / "c3d" / "c3dorg_29_Facial-Sing.c3d"
#: What Blender prints of its own (the log's "blend |" lines, operator reports) and what Python's warnings look like.
FOREIGN = re.compile(r"Read blend|^Info: |^Warning: |^\d\d:\d\d\.\d+ +\S+ +\| |Saved copy|Traceback|Warning\b.*:\d+|^\s+warnings\.warn")

pytestmark = pytest.mark.slow


def run(args, cwd):
    proc = subprocess.run([sys.executable, "-m", "facecap", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.splitlines(), proc.stderr.splitlines()


def assert_only_facecap_lines(out, err):
    foreign = [line for line in out + err if FOREIGN.search(line)]
    assert not foreign, f"lines that are not facecap's: {foreign}"
    assert all(line.startswith("facecap: ") for line in err), [line for line in err if not line.startswith("facecap: ")]
    warnings = [line for line in err if line.startswith("facecap: warning: ")]
    assert not [w for w in warnings if "['" in w or "column cosine" in w], warnings  # words, not reprs and algebra
    assert len(warnings) == len(set(warnings)), "a warning said twice"
    return warnings


def same_figure(documented, printed):
    """Whether ``printed`` (a float) rounds to ``documented`` (the docs' text, e.g. "0.177") at the docs' precision."""
    decimals = len(documented.split(".")[1]) if "." in documented else 0
    return abs(float(printed) - float(documented)) <= 0.5 * 10 ** -decimals + 1e-12


def test_demo_prints_only_facecap_lines_and_its_verbosity_levels(tmp_path):
    out, err = run(["demo", "--out", "demo"], tmp_path)
    warnings = assert_only_facecap_lines(out, err)
    assert out[0].startswith("facecap demo: ") and any("RMSE" in line for line in out)
    assert any(line.startswith("facecap: [5/5]") for line in err)
    # the conditioning warnings say what to do, with the config line that does it
    # (the default semantic solve holds the shapes no marker sees, gaze on skin markers, at rest);
    # the first says it is expected here (issue 40: a new user took it for a failure)
    assert warnings[0].startswith("facecap: warning: expected for the sample take (")
    assert any("held at rest: eyeLookDownLeft, " in w and w.endswith('[solve] unseen_shapes = "solve" solves them '
                                                                     "anyway") for w in warnings), warnings
    readme_demo_table_agrees(out)

    out_q, err_q = run(["demo", "--out", "quiet", "--quiet"], tmp_path)
    assert all(line.startswith("facecap: warning: ") for line in err_q) and len(err_q) == len(warnings), err_q
    assert out_q[0] == out[0]  # the product is not hidden

    _, err_v = run(["-v", "demo", "--out", "verbose"], tmp_path)
    blender = [line for line in err_v if line.startswith("blender: ")]
    assert any("Read blend" in line for line in blender) and any("Saved copy" in line for line in blender), err_v


def readme_demo_table_agrees(out):
    """The README's accuracy table gives the figures the demo prints (issue 40: docs whose figures a command makes)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    printed = "\n".join(out)
    weights = re.search(r"RMSE ([0-9.]+), max \|error\| ([0-9.]+) \((\w+)\)", printed)
    head = re.search(r"median ([0-9.]+) deg, max ([0-9.]+) deg", printed)
    scale = re.search(r"scale ([0-9.]+)", printed)
    row = re.search(r"\| RMSE ([0-9.]+), max abs error ([0-9.]+) \(`(\w+)`\)", readme)
    assert row and same_figure(row[1], weights[1]) and same_figure(row[2], weights[2]) and row[3] == weights[3], printed
    row = re.search(r"\| head rotation vs ground truth \| median ([0-9.]+) deg, max ([0-9.]+) deg \|", readme)
    assert row and same_figure(row[1], head[1]) and same_figure(row[2], head[2]), printed
    row = re.search(r"\| actor scale recovered \| ([0-9.]+) ", readme)
    assert row and same_figure(row[1], scale[1]), printed


def readme_real_capture_config():
    """The README's real-capture take config (the TOML block after "**A real capture.**")."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return re.search(r"\*\*A real capture\.\*\*.*?```toml\n(.*?)```", text, re.S).group(1)


@skip_without(FACIAL_SING)
def test_the_readme_real_capture_example_prints_one_line_per_fact(tmp_path):
    config = tmp_path / "facial_sing.toml"
    text = readme_real_capture_config()
    for name, path in (("sample_blends/character.blend", ROOT / "sample_blends" / "character.blend"),
                       ("Facial-Sing.c3d", FACIAL_SING)):
        assert f'"{name}"' in text
        text = text.replace(f'"{name}"', f'"{path.as_posix()}"')
    config.write_text(text)
    out, err = run(["retarget", "--config", str(config)], tmp_path)
    warnings = assert_only_facecap_lines(out, err)
    # Unlabeled1 (no neutral) and the head band (off the face) each named once, with what to do
    assert sum("Unlabeled1" in w for w in warnings) == 1, warnings
    assert sum("root-1" in w for w in warnings) == 1, warnings
    assert any("root-1" in w and "max_distance_mm" in w for w in warnings), warnings
    assert (tmp_path / "out" / "facial_sing.blend").is_file()
    # what the README says it prints, at the README's precision, and the warning it explains
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    documented = re.search(r"It prints `mean residual ([0-9.]+) mm`", readme)[1]
    assert same_figure(documented, re.search(r"mean residual ([0-9.]+) mm", "\n".join(out))[1]), out
    said = re.search(r'"warning: the solve is not plausible animation: the fit leaves ([0-9.]+) mm at the markers, '
                     r'([0-9.]+)x their noise"', " ".join(readme.split()))
    (last,) = [w for w in warnings if "the solve is not plausible animation" in w]
    fit = re.search(r"the fit leaves ([0-9.]+) mm at the markers, ([0-9.]+)x their noise", last)
    assert same_figure(said[1], fit[1]) and same_figure(said[2], fit[2]), last
