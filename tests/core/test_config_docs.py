"""docs/config.md is the option tables rendered (take configs, track configs, batch files) and docs/commands.md
every command's --help: both list everything and are regenerated with the code."""

from pathlib import Path

from facecap.facecap_addon import cli
from facecap.solvers.config.batch import BATCH_KEYS
from facecap.solvers.options import OPTIONS
from facecap.solvers.tools.config_docs import BATCH_DOCS, render, render_commands
from facecap.solvers.video.cli import TRACK_OPTIONS

DOCS = Path(__file__).resolve().parents[2] / "docs"
REGENERATE = "python -m facecap config-docs --out docs/config.md --commands docs/commands.md"


def test_the_reference_is_current():
    assert (DOCS / "config.md").read_text(encoding="utf-8") == render(), f"docs/config.md is stale: {REGENERATE}"


def test_the_command_reference_is_current():
    """The same words as --help prints; spacing aside, since argparse lays out its columns differently from
    Python 3.13 on (CI checks this on 3.11 and 3.13)."""
    text = render_commands(cli.command_helps())
    written = (DOCS / "commands.md").read_text(encoding="utf-8")
    assert written.split() == text.split(), f"docs/commands.md is stale: {REGENERATE}"


def test_every_command_is_in_the_command_reference():
    text = (DOCS / "commands.md").read_text(encoding="utf-8")
    for command in cli.COMMANDS:
        assert f"## `facecap {command}`" in text and f"usage: facecap {command} " in text, command
    assert "batch-worker" not in text


def test_every_option_is_documented_with_its_default_and_range():
    text = render()
    for o in OPTIONS:
        row = next(line for line in text.splitlines() if line.startswith(f"| `{o.key}` |") and o.doc.replace("|", "\\|") in line)
        if o.range_text():
            assert o.range_text() in row
        assert (o.ui or o.headless) and o.doc


def test_every_track_and_batch_key_is_documented():
    """``track``'s own [tracking] schema (points, max_points, reseed...) was in no page."""
    text = render()
    for o in TRACK_OPTIONS:  # the table the config is checked against
        assert f"### track [{o.section}]" in text
        assert f"| `{o.key}` |" in text and o.doc.split("`")[0][:20] in text, o.name
        if o.range_text():
            assert o.range_text() in text, o.name
    assert set(BATCH_DOCS) == set(BATCH_KEYS) and "### [batch]" in text and "[defaults.target]" in text
