"""docs/config.md is the option table rendered: it lists every option and is regenerated with it."""

from pathlib import Path

from facecap.solvers.options import OPTIONS
from facecap.solvers.tools.config_docs import render

DOC = Path(__file__).resolve().parents[2] / "docs" / "config.md"


def test_the_reference_is_current():
    assert DOC.read_text(encoding="utf-8") == render(), "docs/config.md is stale: python -m facecap config-docs --out docs/config.md"


def test_every_option_is_documented_with_its_default_and_range():
    text = render()
    for o in OPTIONS:
        row = next(line for line in text.splitlines() if line.startswith(f"| `{o.key}` |") and o.doc.replace("|", "\\|") in line)
        if o.range_text():
            assert o.range_text() in row
        assert (o.ui or o.headless) and o.doc
