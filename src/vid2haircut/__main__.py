"""``python -m vid2haircut <stage> ...`` (what the Snakemake rules call through sys.executable)."""

import sys

from vid2haircut.cli import main

sys.exit(main())
