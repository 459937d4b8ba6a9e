"""``python -m facecap <command>``: the headless command line (see facecap_addon/cli.py)."""

import sys

from .facecap_addon.cli import main

sys.exit(main(sys.argv[1:]))
