"""``python -m vid2haircut <stage> ...`` (what the Snakemake rules call through sys.executable)."""

import os
import sys

# Idle OpenMP workers sleep instead of spinning: on 2 shared cores spinning torch threads starve the
# numba compositing threads (and each other). Set before torch is imported; a user's value wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from vid2haircut.cli import main  # noqa: E402

sys.exit(main())
